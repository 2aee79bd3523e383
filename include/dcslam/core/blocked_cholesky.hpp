#pragma once
// S = L L' of a symmetric positive definite matrix, in place in its lower triangle, as
// resumable work: a right-looking blocked factorisation, one panel a step (factor the panel's
// diagonal block, solve the panel below it, update the whole trailing lower triangle with it).
// The panels depend only on the matrix size and the panel width, never on how the steps are
// spread over calls, so the factor is bitwise the same however it is sliced (amortized D&C
// runs one step per frame when the budget is small). The one implementation for the map
// join's constraints (ConstrainedUpdate, JoinRelinearisation) and RJC's joint test
// (JointCompatibilityEnforcement).
#include <cstdint>

#include <Eigen/Core>

#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

class ResumableCholesky : public ResumableWork<ResumableCholesky> {
 public:
  ResumableCholesky() = default;
  // Factors `S`; only its lower triangle is read.
  ResumableCholesky(Eigen::MatrixXd S, Eigen::Index panel_width);

  // The next panel. If its diagonal block is not positive definite the factorisation is over
  // and failed(), S left partly factored.
  std::int64_t step(std::int64_t budget);
  bool done() const { return next_panel_ >= matrix_.rows() || failed_; }
  bool failed() const { return failed_; }
  // The trailing updates dominate: about size^3 / 3 multiply-adds.
  std::int64_t remaining_work() const;
  // S while it is factored; L in its lower triangle once done() and not failed().
  const Eigen::MatrixXd& matrix() const { return matrix_; }

 private:
  Eigen::MatrixXd matrix_;
  Eigen::Index panel_width_ = 1;
  Eigen::Index next_panel_ = 0;  // first column of the next panel
  bool failed_ = false;
};

}  // namespace dcslam
