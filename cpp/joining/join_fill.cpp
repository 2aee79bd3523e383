#include "dcslam/joining/join_fill.hpp"

#include <algorithm>
#include <utility>
#include <vector>

#include "dcslam/joining/join_cost.hpp"
#include "dcslam/joining/parallel_tasks.hpp"

namespace dcslam {

using Index = Eigen::Index;

JoinFill::JoinFill(const GaussianMap& first, const GaussianMap& second, const JoinLayout& layout,
                   const JoinOptions& options, const Mat2& rotation, Index pairs,
                   LowRankCorrection correction, GaussianMap result)
    : first_(first),
      second_(second),
      layout_(layout),
      block_columns_(options.block_columns),
      work_unit_(options.work_unit),
      rotation_(rotation),
      element_cost_(join_cost::fill_element(static_cast<std::int64_t>(pairs))),
      correction_(std::move(correction)),
      result_(std::move(result)) {}

void JoinFill::write_moved_second_block(Index row_begin, Index rows, Index col_begin, Index width,
                                        Index out_row, Index out_col, Eigen::MatrixXd& scratch) {
  const auto P2 = second_.P();
  const Index features_end = layout_.second_kept_features_end();
  // J_2 mixes the x and y of a pair: where the block splits one, it is gathered widened by
  // the missing partner, so tiles and column blocks may start and end anywhere.
  const auto widened = [&](Index begin, Index size) {
    return std::make_pair(begin - (second_role(begin, features_end) == SecondRole::Y ? 1 : 0),
                          begin + size + (second_role(begin + size - 1, features_end) == SecondRole::X ? 1 : 0));
  };
  const auto [row0, row1] = widened(row_begin, rows);
  const auto [col0, col1] = widened(col_begin, width);
  scratch.resize(row1 - row0, col1 - col0);
  for (Index b = col0; b < col1; ++b) {
    const Index src_col = layout_.second_kept_rows[static_cast<std::size_t>(b)];
    for (Index a = row0; a < row1; ++a) {
      scratch(a - row0, b - col0) = P2(layout_.second_kept_rows[static_cast<std::size_t>(a)], src_col);
    }
  }
  rotate_second_rows(scratch, rotation_, row0, features_end);
  rotate_second_columns(scratch, rotation_, col0, features_end);
  result_.P().block(out_row, out_col, rows, width) =
      scratch.block(row_begin - row0, col_begin - col0, rows, width);
}

void JoinFill::write_first_block(Index row_begin, Index rows, Index col_begin, Index width,
                                Index out_row, Index out_col) {
  const auto P1 = first_.P();
  auto out = result_.P().block(out_row, out_col, rows, width);
  for (Index b = 0; b < width; ++b) {
    const Index src_col = layout_.first_kept_rows[static_cast<std::size_t>(col_begin + b)];
    for (Index a = 0; a < rows; ++a) {
      out(a, b) = P1(layout_.first_kept_rows[static_cast<std::size_t>(row_begin + a)], src_col);
    }
  }
}

// One block of columns [col, col + width) inside one segment: the lower part (rows >= col)
// is computed as base + L N', then mirrored into the rows above the diagonal of later
// columns. The base is a block of P1 or of J_2 P2 J_2' where rows and columns come from the
// same map, 0 across the maps.
Index JoinFill::block_width(Index col) const {
  const JoinLayout::Segment& columns = layout_.segment_of(col);
  return std::min(block_columns_, columns.out_begin + columns.size - col);
}

Index JoinFill::tile_rows(Index width) const {
  return join_cost::fill_tile_rows(work_unit_, width, static_cast<Index>(correction_.right_first.cols()) - 3);
}

// The rows above the diagonal are the earlier blocks' transposed. Written with the block,
// rather than by each earlier block into every later column: a fresh result's pages are then
// first touched a block at a time, not all in one unit of work. In square tiles: one long
// transposed copy runs at a fraction of the speed.
void JoinFill::mirror_above(Index col, Index width) {
  auto out = result_.P();
  for (Index c0 = 0; c0 < col; c0 += block_columns_) {
    const Index tile_width = std::min(block_columns_, col - c0);
    out.block(c0, col, tile_width, width) = out.block(col, c0, width, tile_width).transpose();
  }
}

std::int64_t JoinFill::write_tile(Index col, Index width, Index row0, Index row1, Eigen::MatrixXd& scratch) {
  const Index k = static_cast<Index>(correction_.right_first.cols()) - 3;
  auto out = result_.P();
  const JoinLayout::Segment& columns = layout_.segment_of(col);
  const Index local_col = columns.local_begin + (col - columns.out_begin);
  const Index rows = row1 - row0;
  for (const JoinLayout::Segment& segment : layout_.segments) {
    const Index begin = std::max(row0, segment.out_begin);
    const Index end = std::min(row1, segment.out_begin + segment.size);
    if (begin >= end) continue;
    const Index local_row = segment.local_begin + (begin - segment.out_begin);
    if (segment.second != columns.second) {
      out.block(begin, col, end - begin, width).setZero();
    } else if (segment.second) {
      write_moved_second_block(local_row, end - begin, local_col, width, begin, col, scratch);
    } else {
      write_first_block(local_row, end - begin, local_col, width, begin, col);
    }
  }
  if (columns.second) {
    out.block(row0, col, rows, width).noalias() +=
        correction_.left.leftCols(3 + k).middleRows(row0, rows) *
        correction_.right_second.middleRows(local_col, width).transpose();
  } else {
    out.block(row0, col, rows, width).noalias() +=
        correction_.left.rightCols(3 + k).middleRows(row0, rows) *
        correction_.right_first.middleRows(local_col, width).transpose();
  }
  if (row0 == col) {
    // The diagonal square was computed whole, and base + L N' is symmetric only up to
    // rounding there: its lower triangle, like every other entry below the diagonal, is the
    // one kept, so that P is exactly symmetric (as the EKF keeps it).
    auto diagonal = out.block(col, col, width, width);
    diagonal.triangularView<Eigen::StrictlyUpper>() = diagonal.transpose();
  }
  return static_cast<std::int64_t>(rows) * width * element_cost_;
}

std::int64_t JoinFill::fill_next_tile() {
  const Index out_dim = result_.dim();
  const Index col = next_out_col_;
  const Index width = block_width(col);
  // The block is written a tile of rows at a time, rows from the diagonal down: the tiles
  // keep the block's width (so the GEMM streams the low-rank factor once per block, as
  // unsliced) and bound a unit of work when r is large.
  const Index row0 = next_fill_row_ > col ? next_fill_row_ : col;
  const Index row1 = std::min(out_dim, row0 + tile_rows(width));
  if (row0 == col && col > 0) mirror_above(col, width);
  const std::int64_t work = write_tile(col, width, row0, row1, scratch_);
  next_fill_row_ = row1;
  if (row1 == out_dim) {
    next_out_col_ += width;
    next_fill_row_ = 0;
  }
  return work;
}

// Each column block's lower part depends on the inputs alone, and its tiles are those
// fill_next_tile() writes (the same products of the same sizes), so the blocks run side by
// side and each entry is the one the tile-by-tile fill computes; the mirrors, which read the
// earlier blocks' lower parts, follow once every block is written.
std::int64_t JoinFill::fill_rest(int threads) {
  std::int64_t work = 0;
  while (!done() && next_fill_row_ != 0) work += fill_next_tile();
  const Index out_dim = result_.dim();
  std::vector<Index> starts;
  for (Index col = next_out_col_; col < out_dim; col += block_width(col)) starts.push_back(col);
  std::vector<std::int64_t> block_work(starts.size(), 0);
  run_for_each(starts.size(), threads, [&](std::size_t b) {
    const Index col = starts[b];
    const Index width = block_width(col);
    const Index tile = tile_rows(width);
    Eigen::MatrixXd scratch;
    for (Index row0 = col; row0 < out_dim; row0 += tile) {
      block_work[b] += write_tile(col, width, row0, std::min(out_dim, row0 + tile), scratch);
    }
  });
  run_for_each(starts.size(), threads, [&](std::size_t b) { mirror_above(starts[b], block_width(starts[b])); });
  for (const std::int64_t block : block_work) work += block;
  next_out_col_ = out_dim;
  return work;
}

}  // namespace dcslam
