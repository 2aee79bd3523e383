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

namespace dcslam {

class ResumableCholesky {
 public:
  ResumableCholesky() = default;
  ResumableCholesky(Eigen::Index size, Eigen::Index panel_width);

  // The next panel of `S` (the same matrix, sized `size`, every call). Returns its work in
  // units of eight multiply-adds, or -1 if the panel's diagonal block is not positive definite
  // (S is then left partly factored and the factorisation is over).
  std::int64_t step(Eigen::MatrixXd& S);
  bool done() const { return next_panel_ >= size_ || failed_; }
  bool failed() const { return failed_; }
  // Work left in the units of step() (the trailing updates dominate: about size^3 / 3).
  std::int64_t remaining_work() const;

 private:
  Eigen::Index size_ = 0;
  Eigen::Index panel_width_ = 1;
  Eigen::Index next_panel_ = 0;  // first column of the next panel
  bool failed_ = false;
};

}  // namespace dcslam
