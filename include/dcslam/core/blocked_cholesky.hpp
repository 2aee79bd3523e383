#pragma once
// S = L L' of a symmetric positive definite matrix, in place in its lower triangle, as
// resumable work (right-looking, blocked), at two granularities: factor_panel() does a panel
// and its whole trailing update at once (the map join's constraints), ResumableCholesky splits
// the trailing update into tiles (RJC's hypotheses). The two sum in different orders, so
// serving both users with one would move the last bits of the other's results. In
// ResumableCholesky a step either factors one panel's diagonal block and solves the panel
// below it, or applies the panel to one tile of columns of the trailing lower triangle. The
// panels and tiles depend only on the matrix size, the panel width and the work unit, never on
// how the steps are spread over calls, so the factor is bitwise the same however it is sliced
// (amortized D&C runs one step per frame when the budget is small).
#include <cstdint>

#include <Eigen/Core>

namespace dcslam {

// One panel [k0, k0 + width) of a right-looking blocked Cholesky factorisation S = L L', in
// place in the lower triangle: factor the diagonal block, solve the panel below it, update the
// whole trailing lower triangle at once. Panels in order give the same factor however they are
// spread over calls. Returns the work in units of eight multiply-adds, or -1 if the diagonal
// block is not positive definite (S is then left partly factored).
std::int64_t factor_panel(Eigen::MatrixXd& S, Eigen::Index k0, Eigen::Index width);

class ResumableCholesky {
 public:
  ResumableCholesky() = default;
  // `work_unit` bounds one step's multiply-adds where the sizes allow (a tile is at least one
  // column wide).
  ResumableCholesky(Eigen::Index size, Eigen::Index panel_width, std::int64_t work_unit);

  // One step on `S` (the same matrix, sized `size`, every call). Returns its work in units of
  // eight multiply-adds, or -1 if a diagonal block is not positive definite (S is then left
  // partly factored and the factorisation is over).
  std::int64_t step(Eigen::MatrixXd& S);
  bool done() const { return next_panel_ >= size_ || failed_; }
  bool failed() const { return failed_; }
  // Work left in the units of step() (the trailing updates dominate: about size^3 / 3).
  std::int64_t remaining_work() const;

 private:
  Eigen::Index size_ = 0;
  Eigen::Index panel_width_ = 1;
  std::int64_t work_unit_ = 1;
  Eigen::Index next_panel_ = 0;   // first column of the panel being factored or applied
  Eigen::Index next_tile_ = -1;   // -1: the panel is not factored yet; else the next tile column
  bool failed_ = false;
};

}  // namespace dcslam
