#include "dcslam/core/blocked_cholesky.hpp"

#include <algorithm>
#include <utility>

#include <Eigen/Cholesky>

namespace dcslam {

using Index = Eigen::Index;

ResumableCholesky::ResumableCholesky(Eigen::MatrixXd S, Index panel_width)
    : matrix_(std::move(S)), panel_width_(std::max<Index>(1, panel_width)) {}

std::int64_t ResumableCholesky::step(std::int64_t) {
  Eigen::MatrixXd& S = matrix_;
  const Index size = S.rows();
  const Index k0 = next_panel_;
  const Index width = std::min(panel_width_, size - k0);
  const Index below = size - k0 - width;
  const auto w = static_cast<std::int64_t>(width), b = static_cast<std::int64_t>(below);
  auto diagonal = S.block(k0, k0, width, width);
  const Eigen::LLT<Eigen::MatrixXd> llt(diagonal);
  if (llt.info() != Eigen::Success) {
    failed_ = true;
    return std::max<std::int64_t>(1, work_units(w * w * w / 3));
  }
  diagonal.triangularView<Eigen::Lower>() = llt.matrixL();
  if (below > 0) {
    auto panel = S.block(k0 + width, k0, below, width);
    diagonal.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
    S.block(k0 + width, k0 + width, below, below).selfadjointView<Eigen::Lower>().rankUpdate(panel, -1.0);
  }
  next_panel_ = k0 + width;
  return std::max<std::int64_t>(1, work_units(b * b * w / 2 + b * w * w / 2 + w * w * w / 3));
}

std::int64_t ResumableCholesky::remaining_work() const {
  if (done()) return 0;
  const auto left = static_cast<std::int64_t>(matrix_.rows() - next_panel_);
  return std::max<std::int64_t>(1, work_units(left * left * left / 3));
}

}  // namespace dcslam
