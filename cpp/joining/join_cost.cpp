#include "dcslam/joining/join_cost.hpp"

#include <algorithm>

#include "dcslam/core/resumable_work.hpp"

namespace dcslam::join_cost {

using Index = Eigen::Index;

namespace {
// Multiply-adds' worth of an assembled element (copies between column- and row-major blocks).
constexpr Index kAssembleElementCost = 48;
}  // namespace

std::int64_t relinearise_begin(std::int64_t r) { return 1 + r; }

// One step over s = [R1; matched f_i; matched f_j] (dimension ds = 3 + 4r), as its units
// count it: P_ss H' (5 ds a pair), S's lower triangle (11 r^2 / 2), the Cholesky factor of the
// 2r x 2r S ((2r)^3 / 3 multiply-adds), and the solves and products (2 ds r + 3 r^2).
std::int64_t relinearise_step(std::int64_t r) {
  const std::int64_t ds = 3 + 4 * r;
  return std::max<std::int64_t>(1, 7 * ds * r + 17 * r * r / 2 + r * r * r / 3);
}

// A gathered element is a strided read: about 24 multiply-adds' worth.
Index gather_columns_per_unit(Index work_unit, Index ds) {
  return std::max<Index>(1, work_unit / (24 * ds));
}
std::int64_t gather(Index columns, Index ds) { return 3 * static_cast<std::int64_t>(columns * ds); }

// Units are sized by multiply-adds (14 ds for a pair's columns of P_ss H', up to 24 r for its
// column of S); the work they return is calibrated to time (relinearise_step()).
Index relinearise_pairs_per_unit(Index work_unit, Index ds, Index r) {
  return std::max<Index>(1, work_unit / (14 * ds + 24 * r));
}
std::int64_t gain_columns(Index pairs, Index ds) {
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(5 * ds * pairs));
}
std::int64_t factor_column(Index k, Index r) { return 11 * (r - k); }

// Memory-bound: three passes over ds x 2r matrices.
std::int64_t step_solve(Index ds, Index r) {
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(2 * ds * r + 3 * r * r));
}

std::int64_t relinearise_finish(std::int64_t second_dim, std::int64_t r) { return second_dim * r / 4; }

// O(n) a pair: its two columns of P H' over all of m1 and m2.
std::int64_t constrain(std::int64_t pairs, std::int64_t rows) { return pairs * 9 * rows; }
std::int64_t begin_factor(std::int64_t r) { return r * r; }

// A row of the triangular solve costs about (2r)^2 / 2 multiply-adds.
std::int64_t solve_row(std::int64_t r) { return std::max<std::int64_t>(1, r * r / 4); }

// Sized in multiply-adds: with r in the hundreds a fixed row count would cost tens of ms in
// one step.
Index solve_rows_per_unit(Index work_unit, Index block_columns, Index r) {
  const Index r2 = 2 * r;
  return std::clamp<Index>(work_unit / std::max<Index>(1, r2 * r2 / 2), 64, 4 * block_columns);
}

// An assembled row: its 6 + 2r low-rank factors, copied between column- and row-major blocks.
std::int64_t assemble_row(std::int64_t r) { return work_units((6 + 2 * r) * kAssembleElementCost); }
Index assemble_rows_per_unit(Index work_unit, Index k) {
  return std::max<Index>(16, work_unit / (kAssembleElementCost * (6 + k)));
}

// A zeroed element of a fresh matrix: a write, and a 4 KB page fault per 512 of them (about a
// microsecond). A unit zeroes a quarter of its work's elements (256 KB at the default unit).
Index prefault_columns_per_unit(Index work_unit, Index rows) {
  return std::max<Index>(1, work_units(work_unit) / (4 * std::max<Index>(1, rows)));
}
std::int64_t prefault(Index columns, Index rows) { return 1 + 4 * static_cast<std::int64_t>(columns * rows); }

// A written element of the result costs a write plus a dot product of length 3 + 2r.
std::int64_t fill_element(std::int64_t r) { return 1 + work_units(3 + 2 * r); }

// A tile element costs its base (a gather, and for m2 a rotation: about 16 multiply-adds'
// worth) plus its dot product of length 3 + k. A tile is never shorter than the block is wide:
// the block's first tile mirrors its whole diagonal square (JoinFill::fill_next_tile()).
Index fill_tile_rows(Index work_unit, Index width, Index k) {
  return std::max<Index>(std::max<Index>(64, width), work_unit / (width * (19 + k)));
}

}  // namespace dcslam::join_cost
