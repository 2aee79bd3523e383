#pragma once
// The last phase of a join (docs/design.md §4.4): the result's covariance written column block
// by column block, already compacted, each block as its base (a block of P1, of J_2 P2 J_2',
// or 0 across the maps) plus the low-rank correction L N' the constrained update assembled;
// resumable a tile of rows at a time.
#include <cstdint>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/joining/constrained_update.hpp"
#include "dcslam/joining/join_layout.hpp"
#include "dcslam/joining/join_options.hpp"

namespace dcslam {

class JoinFill {
 public:
  // `result` holds the means (ConstrainedUpdate::take_result()); `rotation` is J_2's, `pairs`
  // the number of matched pairs. The maps and layout must outlive the fill.
  JoinFill(const GaussianMap& first, const GaussianMap& second, const JoinLayout& layout,
           const JoinOptions& options, const Mat2& rotation, Eigen::Index pairs,
           LowRankCorrection correction, GaussianMap result);
  JoinFill(const JoinFill&) = delete;
  JoinFill& operator=(const JoinFill&) = delete;

  // One tile of rows of the next column block; returns its work.
  std::int64_t fill_next_tile();
  // Every tile left, the column blocks side by side on up to `threads` threads: the same
  // result, entry for entry, and the same work as fill_next_tile() until done().
  std::int64_t fill_rest(int threads);
  bool done() const { return next_out_col_ == result_.dim(); }
  // Columns of the result not yet written.
  Eigen::Index columns_left() const { return result_.dim() - next_out_col_; }
  // The joined map; valid once done().
  GaussianMap take_result() { return std::move(result_); }

 private:
  // The width of the column block starting at output column `col`, and its tiles' rows.
  Eigen::Index block_width(Eigen::Index col) const;
  Eigen::Index tile_rows(Eigen::Index width) const;
  // Rows [row0, row1) of the column block [col, col + width), rows >= col; returns its work.
  std::int64_t write_tile(Eigen::Index col, Eigen::Index width, Eigen::Index row0, Eigen::Index row1,
                          Eigen::MatrixXd& scratch);
  // The column block's rows above the diagonal, from the earlier blocks' lower parts.
  void mirror_above(Eigen::Index col, Eigen::Index width);
  // Writes J_2 P2 J_2' for m2's kept elements, local rows [row_begin, row_begin + rows) x
  // local columns [col_begin, col_begin + width), into the output at (out_row, out_col),
  // through `scratch`.
  void write_moved_second_block(Eigen::Index row_begin, Eigen::Index rows, Eigen::Index col_begin,
                                Eigen::Index width, Eigen::Index out_row, Eigen::Index out_col,
                                Eigen::MatrixXd& scratch);
  // Writes P1 for m1's kept features, local rows [row_begin, row_begin + rows) x local columns
  // [col_begin, col_begin + width) (indices into first_kept_rows), at (out_row, out_col).
  void write_first_block(Eigen::Index row_begin, Eigen::Index rows, Eigen::Index col_begin,
                         Eigen::Index width, Eigen::Index out_row, Eigen::Index out_col);

  const GaussianMap& first_;
  const GaussianMap& second_;
  const JoinLayout& layout_;
  Eigen::Index block_columns_;
  Eigen::Index work_unit_;
  Mat2 rotation_;
  std::int64_t element_cost_;
  LowRankCorrection correction_;
  GaussianMap result_;
  Eigen::Index next_out_col_ = 0;
  Eigen::Index next_fill_row_ = 0;  // next row of the column block being filled
  Eigen::MatrixXd scratch_;  // fill_next_tile()'s
};

}  // namespace dcslam
