#include "dcslam/association/conditioned_model.hpp"

#include <limits>

#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

namespace {

std::uint64_t key_of(const Pairing& pairing) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(pairing.measurement)) << 32) |
         static_cast<std::uint32_t>(pairing.feature);
}

}  // namespace

ConditionedPairingModel::ConditionedPairingModel(const PairingModel& base, Eigen::Index expected_pairings)
    : base_(base) {
  lower_.resize(2 * expected_pairings, 2 * expected_pairings);
  whitened_.resize(2 * expected_pairings);
  cross_.resize(2 * expected_pairings, 2);
}

void ConditionedPairingModel::write_cross(const Pairing& pairing, CrossColumns cross) const {
  for (std::size_t c = 0; c < kept_.size(); ++c) {
    cross.middleRows<2>(2 * static_cast<Eigen::Index>(c)) = base_.covariance(kept_[c], pairing);
  }
}

void ConditionedPairingModel::solve_cross(const Pairing& pairing, CrossBlock& cross) const {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  if (cross.rows() < 2 * m) cross.conservativeResize(2 * m, 2);
  write_cross(pairing, cross.topRows(2 * m));
  auto cross_kept = cross.topRows(2 * m);
  lower_.topLeftCorner(2 * m, 2 * m).triangularView<Eigen::Lower>().solveInPlace(cross_kept);
}

const ConditionedPairingModel::CrossBlock& ConditionedPairingModel::cached_cross(const Pairing& pairing) const {
  const auto found = cache_.find(key_of(pairing));
  if (found != cache_.end()) return found->second;
  CrossBlock cross(2 * static_cast<Eigen::Index>(kept_.size()), 2);
  solve_cross(pairing, cross);
  return cache_.emplace(key_of(pairing), std::move(cross)).first->second;
}

void ConditionedPairingModel::prepare(const std::vector<Pairing>& pairings) const {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  if (m == 0) return;
  std::vector<Pairing> missing;
  for (const Pairing& pairing : pairings) {
    if (cache_.count(key_of(pairing)) == 0) missing.push_back(pairing);
  }
  if (missing.empty()) return;
  Eigen::MatrixXd cross(2 * m, 2 * static_cast<Eigen::Index>(missing.size()));
  for (std::size_t p = 0; p < missing.size(); ++p) {
    write_cross(missing[p], cross.middleCols<2>(2 * static_cast<Eigen::Index>(p)));
  }
  lower_.topLeftCorner(2 * m, 2 * m).triangularView<Eigen::Lower>().solveInPlace(cross);
  for (std::size_t p = 0; p < missing.size(); ++p) {
    cache_.emplace(key_of(missing[p]), CrossBlock(cross.middleCols<2>(2 * static_cast<Eigen::Index>(p))));
  }
}

Vec2 ConditionedPairingModel::innovation(const Pairing& pairing) const {
  if (kept_.empty()) return base_.innovation(pairing);
  const auto m = static_cast<Eigen::Index>(kept_.size());
  return base_.innovation(pairing) - cached_cross(pairing).transpose() * whitened_.head(2 * m);
}

Mat2 ConditionedPairingModel::covariance(const Pairing& a, const Pairing& b) const {
  if (kept_.empty()) return base_.covariance(a, b);
  const CrossBlock& cross_a = cached_cross(a);
  const CrossBlock& cross_b = cached_cross(b);  // an insertion leaves cross_a's storage in place
  return base_.covariance(a, b) - cross_a.transpose() * cross_b;
}

void ConditionedPairingModel::condition(const Pairing& pairing, Vec2& innovation, Mat2& covariance) {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  solve_cross(pairing, cross_);
  auto cross_kept = cross_.topRows(2 * m);
  innovation = base_.innovation(pairing) - cross_kept.transpose() * whitened_.head(2 * m);
  covariance = base_.covariance(pairing, pairing) - cross_kept.transpose() * cross_kept;
}

void ConditionedPairingModel::keep(const Pairing& pairing, const Eigen::LLT<Mat2>& factor, const Vec2& innovation) {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  if (lower_.rows() < 2 * m + 2) {
    const Eigen::Index size = std::max<Eigen::Index>(2 * m + 2, 4 * m);
    lower_.conservativeResize(size, size);
    whitened_.conservativeResize(size);
  }
  lower_.block(2 * m, 0, 2, 2 * m) = cross_.topRows(2 * m).transpose();
  lower_.block<2, 2>(2 * m, 2 * m) = factor.matrixL();
  whitened_.segment<2>(2 * m) = factor.matrixL().solve(innovation);
  kept_.push_back(pairing);
  cache_.clear();
}

bool ConditionedPairingModel::keep_if_within(const Pairing& pairing, double gate) {
  Vec2 innovation;
  Mat2 covariance;
  condition(pairing, innovation, covariance);
  const Eigen::LLT<Mat2> factor(covariance);
  if (factor.info() != Eigen::Success || factor.matrixL().solve(innovation).squaredNorm() > gate) return false;
  keep(pairing, factor, innovation);
  return true;
}

double ConditionedPairingModel::conditional_distance_sq(const Pairing& pairing) {
  Vec2 innovation;
  Mat2 covariance;
  condition(pairing, innovation, covariance);
  const Eigen::LLT<Mat2> factor(covariance);
  if (factor.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return factor.matrixL().solve(innovation).squaredNorm();
}

double ConditionedPairingModel::joint_distance_sq() const {
  return whitened_.head(2 * static_cast<Eigen::Index>(kept_.size())).squaredNorm();
}

std::int64_t ConditionedPairingModel::condition_work(std::int64_t kept) {
  return kPairingCovarianceUnits * (kept + 1) + kept * kept / 2;
}

}  // namespace dcslam
