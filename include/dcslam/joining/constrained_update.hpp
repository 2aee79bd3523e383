#pragma once
// The join's fused update (docs/design.md §4.4): the matched pairs imposed as ideal constraints
// f_i - f'_j = 0 on the stacked map without building it, as resumable work. Constrain: P H'
// and h, a few pairs at a time, at the linearisation point; factor: S = H P H' = L L', a panel
// at a time; solve: W = P H' L^-T, a block of rows at a time; assemble: the result's means and
// the low-rank factors of its covariance, a block of output rows at a time. The fill
// (JoinFill) then writes the covariance P_out = P_stacked - W W' from them.
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/joining/join_frame.hpp"
#include "dcslam/joining/join_layout.hpp"
#include "dcslam/joining/join_options.hpp"

namespace dcslam {

// Every block of the result's covariance is a "base" (a block of P1, or of J_2 P2 J_2') plus a
// low-rank term L N' with inner dimension 3 + 2r:
//   columns of m2's kept elements: L = [J_R P1_RR or cov(E1, R1) | W], N = [J_R | -W];
//   columns of m1's kept elements: L = [W | J_R or 0],               N = [-W | cov(E1, R1)]
// (E1: m1's kept elements, R1 among them when kept). `left` holds [JP | W | J] in output row
// order; right_* hold N for each column kind.
struct LowRankCorrection {
  // Row-major: the assembly writes it a row at a time, so its pages are first touched a few
  // rows per unit of work rather than all of them by the first row.
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> left;
  Eigen::MatrixXd right_second;
  Eigen::MatrixXd right_first;
};

class ConstrainedUpdate {
 public:
  using Pairs = std::vector<std::pair<Eigen::Index, Eigen::Index>>;

  // Linearised at R1 = first_robot (in m1's base) and m2's state = second_x. The maps, pairs
  // and layout must outlive the update, which is neither copied nor moved.
  ConstrainedUpdate(const GaussianMap& first, const GaussianMap& second, const Pairs& pairs,
                    const JoinLayout& layout, const JoinOptions& options, const Vec3& first_robot,
                    const Eigen::VectorXd& second_x);
  ConstrainedUpdate(const ConstrainedUpdate&) = delete;
  ConstrainedUpdate& operator=(const ConstrainedUpdate&) = delete;

  // The columns of P H' of the next pairs: as many as `budget` pays for, at least one and at
  // most join_cost::kPairsPerUnit (each pair's columns are independent, so any count gives the
  // same result).
  std::int64_t constrain_next_pairs(std::int64_t budget);
  bool constrained() const { return next_pair_ == static_cast<Eigen::Index>(pairs_.size()); }
  // S = H P H' from the rows of P H' (O(r^2)); the factorisation then runs a panel at a time,
  // ending with h whitened.
  void begin_factor();
  std::int64_t factor_next_panel();
  bool factored() const { return cholesky_.done(); }
  // h' S^-1 h of the imposed pairs at the linearisation point, once factored(): what imposing
  // them adds to the least-squares objective of the linearised problem.
  double constraint_distance_sq() const { return whitened_h_.squaredNorm(); }
  std::int64_t solve_next_rows();
  Eigen::Index solve_rows_left() const { return gain_.rows() - next_solve_row_; }
  // The result (covariance not yet written) and the factors of the fill, once assembled.
  // assemble_next_rows() first zeroes the column-major factors a block of columns a step
  // (prefault_next()), then assembles a block of rows a step.
  void begin_assemble();
  std::int64_t assemble_next_rows();
  bool assembling() const { return next_assemble_row_ >= 0; }
  bool assembled() const { return assembling() && next_assemble_row_ == result_.dim(); }
  Eigen::Index assembly_rows_left() const { return result_.dim() - next_assemble_row_; }
  // J_2's rotation: R1's at the linearisation point.
  const Mat2& rotation() const { return rotation_; }
  // The result: ids and means once assembled, its covariance still to be written.
  const GaussianMap& result() const { return result_; }
  GaussianMap take_result() { return std::move(result_); }
  LowRankCorrection take_correction() { return std::move(correction_); }

 private:
  const GaussianMap& first_;
  const GaussianMap& second_;
  const Pairs& pairs_;
  const JoinLayout& layout_;
  const JoinOptions& options_;
  JoinFrame frame_;  // m2 moved into B1 at the linearisation point
  Mat2 rotation_;
  Eigen::Matrix<double, Eigen::Dynamic, 3> J_R_kept_;  // rows of J_R for m2's kept elements
  Eigen::Index next_pair_ = 0;
  ResumableCholesky cholesky_;  // S = H P H', becoming L (S = L L') in its lower triangle
  Eigen::MatrixXd gain_;          // P H' (rows: F1, then all of m2), then W in place
  Eigen::VectorXd whitened_h_;    // h, then L^-1 h
  Eigen::Index next_solve_row_ = 0;
  // Writes zeros into the next columns of right_second, then of right_first. Their pages are
  // first touched here, a bounded amount a step: written by the assembly a few rows at a time,
  // a column-major matrix has every page touched by its first rows, and a freshly mapped one
  // then faults all its pages in that one step (0.5 ms on Victoria Park's 64-leaf join).
  std::int64_t prefault_next();
  Eigen::Index next_prefault_column_ = 0;  // over right_second's columns, then right_first's
  Eigen::Index next_assemble_row_ = -1;  // -1: assembly not begun
  GaussianMap result_;
  LowRankCorrection correction_;
};

}  // namespace dcslam
