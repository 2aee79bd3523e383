#pragma once
// A uniform grid over 2D points for candidate search (docs/design.md §3.4 and §6): items are
// bucketed by the integer coordinates of the cell that holds them, so that a query around a
// point only visits the cells that overlap its disc or box. With bounded density every
// operation is O(1) and a query is O(cells touched + items in them).
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "dcslam/core/geometry.hpp"

namespace dcslam {

class SpatialHash {
 public:
  // cell_size > 0 and finite, else InvalidArgument. A cell of about the query radius keeps a
  // query to 3x3 cells.
  explicit SpatialHash(double cell_size);

  double cell_size() const { return cell_size_; }
  std::size_t size() const { return items_.size(); }
  bool contains(int id) const { return items_.count(id) != 0; }
  // Position of a stored item; InvalidArgument if absent.
  Vec2 position(int id) const;

  // InvalidArgument if the id is already stored or the point is not finite.
  void insert(int id, const Vec2& point);
  // InvalidArgument if the id is absent or the point is not finite.
  void move(int id, const Vec2& point);
  // InvalidArgument if the id is absent.
  void remove(int id);
  void clear();

  // Replaces `out` with the ids of the items at distance <= radius from center, in no
  // particular order. `out` keeps its capacity, so a reused vector does not allocate.
  void query(const Vec2& center, double radius, std::vector<int>& out) const;
  // Replaces `out` with the ids of the items with lo <= p <= hi (both axes, inclusive).
  void query_box(const Vec2& lo, const Vec2& hi, std::vector<int>& out) const;

 private:
  struct Item {
    Vec2 point;
    std::uint64_t cell;
  };
  // Cells keep a copy of the point so that a query reads one contiguous bucket.
  struct CellEntry {
    int id;
    double x;
    double y;
  };
  struct CellKeyHash {
    std::size_t operator()(std::uint64_t key) const;
  };
  using Cells = std::unordered_map<std::uint64_t, std::vector<CellEntry>, CellKeyHash>;

  std::int32_t cell_coordinate(double value) const;
  static std::uint64_t pack(std::int32_t ix, std::int32_t iy);
  std::uint64_t cell_of(const Vec2& point) const;
  void detach(int id, std::uint64_t cell);
  // Visits every item whose cell overlaps [lo, hi] and keeps those accepted by `inside`.
  template <typename Inside>
  void collect(const Vec2& lo, const Vec2& hi, Inside inside, std::vector<int>& out) const;

  double cell_size_;
  Cells cells_;
  std::unordered_map<int, Item> items_;
};

}  // namespace dcslam
