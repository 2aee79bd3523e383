#include "dcslam/core/spatial_hash.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

void require_finite(const Vec2& point, const char* what) {
  if (!point.allFinite()) throw InvalidArgument(std::string(what) + ": point must be finite");
}

}  // namespace

SpatialHash::SpatialHash(double cell_size) : cell_size_(cell_size) {
  if (!(cell_size > 0.0) || !std::isfinite(cell_size)) {
    throw InvalidArgument("SpatialHash: cell_size must be positive and finite");
  }
}

std::size_t SpatialHash::CellKeyHash::operator()(std::uint64_t key) const {
  // splitmix64 finaliser: packed neighbouring cells differ in few low bits of each half, and
  // the standard identity hash would cluster them into neighbouring buckets.
  key ^= key >> 30;
  key *= 0xbf58476d1ce4e5b9ULL;
  key ^= key >> 27;
  key *= 0x94d049bb133111ebULL;
  key ^= key >> 31;
  return static_cast<std::size_t>(key);
}

std::int32_t SpatialHash::cell_coordinate(double value) const {
  // Clamping keeps far-away points representable; it is monotone, so a query's cell range
  // still covers every item inside its box (the exact test filters the rest).
  constexpr double lowest = static_cast<double>(std::numeric_limits<std::int32_t>::min());
  constexpr double highest = static_cast<double>(std::numeric_limits<std::int32_t>::max());
  const double cell = std::floor(value / cell_size_);
  return static_cast<std::int32_t>(std::clamp(cell, lowest, highest));
}

std::uint64_t SpatialHash::pack(std::int32_t ix, std::int32_t iy) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(ix)) << 32) |
         static_cast<std::uint64_t>(static_cast<std::uint32_t>(iy));
}

std::uint64_t SpatialHash::cell_of(const Vec2& point) const {
  return pack(cell_coordinate(point.x()), cell_coordinate(point.y()));
}

Vec2 SpatialHash::position(int id) const {
  const auto found = items_.find(id);
  if (found == items_.end()) throw InvalidArgument("SpatialHash::position: unknown id");
  return found->second.point;
}

void SpatialHash::insert(int id, const Vec2& point) {
  require_finite(point, "SpatialHash::insert");
  const std::uint64_t cell = cell_of(point);
  if (!items_.emplace(id, Item{point, cell}).second) {
    throw InvalidArgument("SpatialHash::insert: id " + std::to_string(id) + " already stored");
  }
  cells_[cell].push_back(CellEntry{id, point.x(), point.y()});
}

void SpatialHash::move(int id, const Vec2& point) {
  require_finite(point, "SpatialHash::move");
  const auto found = items_.find(id);
  if (found == items_.end()) throw InvalidArgument("SpatialHash::move: unknown id");
  Item& item = found->second;
  const std::uint64_t cell = cell_of(point);
  item.point = point;
  if (cell == item.cell) {
    for (CellEntry& entry : cells_.find(cell)->second) {
      if (entry.id == id) entry = CellEntry{id, point.x(), point.y()};
    }
    return;
  }
  detach(id, item.cell);
  item.cell = cell;
  cells_[cell].push_back(CellEntry{id, point.x(), point.y()});
}

void SpatialHash::remove(int id) {
  const auto found = items_.find(id);
  if (found == items_.end()) throw InvalidArgument("SpatialHash::remove: unknown id");
  detach(id, found->second.cell);
  items_.erase(found);
}

void SpatialHash::clear() {
  cells_.clear();
  items_.clear();
}

void SpatialHash::detach(int id, std::uint64_t cell) {
  const auto bucket = cells_.find(cell);
  std::vector<CellEntry>& entries = bucket->second;
  // Cells hold a handful of items, so a scan beats keeping a slot index per item up to date.
  *std::find_if(entries.begin(), entries.end(),
                [id](const CellEntry& entry) { return entry.id == id; }) = entries.back();
  entries.pop_back();
  // Dropping empty cells keeps the scan-all fallback of large queries proportional to items.
  if (entries.empty()) cells_.erase(bucket);
}

template <typename Inside>
void SpatialHash::collect(const Vec2& lo, const Vec2& hi, Inside inside,
                          std::vector<int>& out) const {
  out.clear();
  if (!(lo.x() <= hi.x()) || !(lo.y() <= hi.y())) return;
  const std::int32_t x0 = cell_coordinate(lo.x());
  const std::int32_t x1 = cell_coordinate(hi.x());
  const std::int32_t y0 = cell_coordinate(lo.y());
  const std::int32_t y1 = cell_coordinate(hi.y());
  const double cells_in_box =
      (static_cast<double>(x1) - x0 + 1.0) * (static_cast<double>(y1) - y0 + 1.0);
  // A box much larger than the occupied area is cheaper to answer by scanning occupied cells.
  if (cells_in_box > static_cast<double>(cells_.size())) {
    for (const auto& [cell, entries] : cells_) {
      for (const CellEntry& entry : entries) {
        if (inside(Vec2(entry.x, entry.y))) out.push_back(entry.id);
      }
    }
    return;
  }
  for (std::int64_t ix = x0; ix <= x1; ++ix) {
    for (std::int64_t iy = y0; iy <= y1; ++iy) {
      const auto bucket =
          cells_.find(pack(static_cast<std::int32_t>(ix), static_cast<std::int32_t>(iy)));
      if (bucket == cells_.end()) continue;
      for (const CellEntry& entry : bucket->second) {
        if (inside(Vec2(entry.x, entry.y))) out.push_back(entry.id);
      }
    }
  }
}

void SpatialHash::query(const Vec2& center, double radius, std::vector<int>& out) const {
  require_finite(center, "SpatialHash::query");
  if (std::isnan(radius)) throw InvalidArgument("SpatialHash::query: radius is NaN");
  const double radius_sq = radius * radius;
  const Vec2 half(radius, radius);
  collect(
      center - half, center + half,
      [&](const Vec2& p) { return (p - center).squaredNorm() <= radius_sq; },
      out);
}

void SpatialHash::query_box(const Vec2& lo, const Vec2& hi, std::vector<int>& out) const {
  if (lo.hasNaN() || hi.hasNaN()) throw InvalidArgument("SpatialHash::query_box: NaN bound");
  collect(
      lo, hi,
      [&](const Vec2& p) {
        return lo.x() <= p.x() && p.x() <= hi.x() && lo.y() <= p.y() && p.y() <= hi.y();
      },
      out);
}

}  // namespace dcslam
