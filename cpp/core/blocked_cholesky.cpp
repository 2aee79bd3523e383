#include "dcslam/core/blocked_cholesky.hpp"

#include <algorithm>

#include <Eigen/Cholesky>

namespace dcslam {

using Index = Eigen::Index;

std::int64_t factor_panel(Eigen::MatrixXd& S, Index k0, Index width) {
  const Index N = S.rows();
  width = std::min(width, N - k0);
  const Index below = N - k0 - width;
  auto diagonal = S.block(k0, k0, width, width);
  const Eigen::LLT<Eigen::MatrixXd> llt(diagonal);
  if (llt.info() != Eigen::Success) return -1;
  diagonal.triangularView<Eigen::Lower>() = llt.matrixL();
  if (below > 0) {
    auto panel = S.block(k0 + width, k0, below, width);
    diagonal.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
    S.block(k0 + width, k0 + width, below, below).selfadjointView<Eigen::Lower>().rankUpdate(panel, -1.0);
  }
  const auto w = static_cast<std::int64_t>(width), b = static_cast<std::int64_t>(below);
  return std::max<std::int64_t>(1, (b * b * w / 2 + b * w * w / 2 + w * w * w / 3) / 8);
}

ResumableCholesky::ResumableCholesky(Index size, Index panel_width, std::int64_t work_unit)
    : size_(size), panel_width_(std::max<Index>(1, panel_width)),
      work_unit_(std::max<std::int64_t>(1, work_unit)) {}

std::int64_t ResumableCholesky::step(Eigen::MatrixXd& S) {
  const Index k0 = next_panel_;
  const Index width = std::min(panel_width_, size_ - k0);
  const Index k1 = k0 + width;
  const Index below = size_ - k1;
  const auto w = static_cast<std::int64_t>(width), b = static_cast<std::int64_t>(below);
  if (next_tile_ < 0) {
    auto diagonal = S.block(k0, k0, width, width);
    const Eigen::LLT<Eigen::MatrixXd> llt(diagonal);
    if (llt.info() != Eigen::Success) {
      failed_ = true;
      return -1;
    }
    diagonal.triangularView<Eigen::Lower>() = llt.matrixL();
    if (below > 0) {
      auto panel = S.block(k1, k0, below, width);
      diagonal.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
      next_tile_ = k1;
    } else {
      next_panel_ = size_;
    }
    return std::max<std::int64_t>(1, (b * w * w / 2 + w * w * w / 3) / 8);
  }
  // A tile [c, c + t) of the trailing columns: its part on and below the diagonal minus the
  // panel's rows times the panel's rows of the tile. Tiles are as wide as the work unit allows
  // for the panel's tallest tile, so the split depends on the sizes only.
  const Index tile = std::clamp<Index>(static_cast<Index>(work_unit_ / std::max<std::int64_t>(1, b * w)),
                                       1, below);
  const Index c = next_tile_;
  const Index t = std::min(tile, size_ - c);
  const auto panel = S.block(k1, k0, below, width);
  S.block(c, c, size_ - c, t).noalias() -=
      panel.bottomRows(size_ - c) * panel.middleRows(c - k1, t).transpose();
  next_tile_ = c + t;
  if (next_tile_ == size_) {
    next_tile_ = -1;
    next_panel_ = k1;
  }
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(size_ - c) * t * w / 8);
}

std::int64_t ResumableCholesky::remaining_work() const {
  if (done()) return 0;
  const auto left = static_cast<std::int64_t>(size_ - next_panel_);
  return std::max<std::int64_t>(1, left * left * left / 24);
}

}  // namespace dcslam
