#pragma once
// The cost model of a join's resumable work (docs/divide_and_conquer.md, the amortized
// schedule): what one unit of each phase counts and how many rows, pairs or columns make one.
// Work is counted in ResumableWork's unit (core/resumable_work.hpp), so budgets mean time across
// joins of any size.
// Every size here depends only on the join's sizes and JoinOptions::work_unit, never on how
// the work is sliced, so the result is bitwise the same however a join is spread over steps.
// r: matched pairs; k = 2r: constraint rows; ds = 3 + 4r: the variables the constraints
// involve (R1, the matched f_i, the matched f_j).
#include <cstdint>

#include <Eigen/Core>

namespace dcslam::join_cost {

// The re-linearisation (JoinRelinearisation): its set-up, and one Gauss–Newton step.
std::int64_t relinearise_begin(std::int64_t r);
std::int64_t relinearise_step(std::int64_t r);
// Columns of s0 and P_ss gathered in one unit, and the work of gathering `columns` of them.
Eigen::Index gather_columns_per_unit(Eigen::Index work_unit, Eigen::Index ds);
std::int64_t gather(Eigen::Index columns, Eigen::Index ds);
// Pairs of one unit of building P_ss H' or S, and the work of `pairs` of P_ss H''s columns.
Eigen::Index relinearise_pairs_per_unit(Eigen::Index work_unit, Eigen::Index ds, Eigen::Index r);
std::int64_t gain_columns(Eigen::Index pairs, Eigen::Index ds);
// S's lower triangle: pair column k of r.
std::int64_t factor_column(Eigen::Index k, Eigen::Index r);
// The solves and products of one step (both Gauss–Newton's and Newton's).
std::int64_t step_solve(Eigen::Index ds, Eigen::Index r);
// m2 moved to the point found: m2's rows of P0 g.
std::int64_t relinearise_finish(std::int64_t second_dim, std::int64_t r);

// The association's units (JoinAssociator, RJC, chunked JCBB), in a join's: on Victoria Park
// they take 2-7 ns each (hashed and scattered covariance blocks of a large P), a join's fill
// about 2, so a budget spent on association took three times its share of a step
// (BENCHMARKS.md, "Where Victoria Park's worst amortized steps come from").
constexpr std::int64_t kAssociationUnitCost = 3;

// The constrained update (ConstrainedUpdate): at most this many pairs' columns of P H' a step
// (fewer where the step's budget pays for fewer: 16 at Victoria Park's budgets were a 0.3 ms
// step, D&C's worst), the work of `pairs` of them over `rows` rows; S = H P H' from them.
constexpr Eigen::Index kPairsPerUnit = 16;
std::int64_t constrain(std::int64_t pairs, std::int64_t rows);
std::int64_t begin_factor(std::int64_t r);
// A row of the triangular solve W = P H' L^-T, and the rows of one unit.
std::int64_t solve_row(std::int64_t r);
Eigen::Index solve_rows_per_unit(Eigen::Index work_unit, Eigen::Index block_columns, Eigen::Index r);
// An assembled row (its 6 + k low-rank factors), and the rows of one unit.
std::int64_t assemble_row(std::int64_t r);
Eigen::Index assemble_rows_per_unit(Eigen::Index work_unit, Eigen::Index k);
// Zeroing the low-rank factors before the assembly: the columns of one unit, of `rows` rows,
// and the work of `columns` of them.
Eigen::Index prefault_columns_per_unit(Eigen::Index work_unit, Eigen::Index rows);
std::int64_t prefault(Eigen::Index columns, Eigen::Index rows);

// The fill (JoinFill): a written element of the result, and the rows of one tile of a column
// block `width` wide.
std::int64_t fill_element(std::int64_t r);
Eigen::Index fill_tile_rows(Eigen::Index work_unit, Eigen::Index width, Eigen::Index k);

}  // namespace dcslam::join_cost
