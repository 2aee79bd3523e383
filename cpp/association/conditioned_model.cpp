#include "dcslam/association/conditioned_model.hpp"

#include <limits>

#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

namespace {

std::uint64_t key_of(const Pairing& pairing) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(pairing.measurement)) << 32) |
         static_cast<std::uint32_t>(pairing.feature);
}

// The gate test of a conditioned pairing: its covariance's factor and its whitened innovation,
// false when the covariance is not positive definite or the innovation lies outside `gate`.
bool whitened_within(const Mat2& covariance, const Vec2& innovation, double gate, Eigen::LLT<Mat2>& factor,
                     Vec2& whitened) {
  factor.compute(covariance);
  if (factor.info() != Eigen::Success) return false;
  whitened = factor.matrixL().solve(innovation);
  return whitened.squaredNorm() <= gate;
}

}  // namespace

ConditionedPairingModel::ConditionedPairingModel(const PairingModel& base, Eigen::Index expected_pairings)
    : base_(base) {
  lower_.resize(2 * expected_pairings, 2 * expected_pairings);
  whitened_.resize(2 * expected_pairings);
  cross_.resize(2 * expected_pairings, 2);
}

void ConditionedPairingModel::write_cross(const Pairing& pairing, CrossColumns cross) const {
  base_.covariances_with(kept_.data(), kept_.size(), pairing, cross);
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

std::size_t ConditionedPairingModel::prepare(const std::vector<Pairing>& pairings) const {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  if (m == 0) return 0;
  std::vector<Pairing> missing;
  for (const Pairing& pairing : pairings) {
    if (cache_.count(key_of(pairing)) == 0) missing.push_back(pairing);
  }
  if (missing.empty()) return 0;
  Eigen::MatrixXd cross(2 * m, 2 * static_cast<Eigen::Index>(missing.size()));
  for (std::size_t p = 0; p < missing.size(); ++p) {
    write_cross(missing[p], cross.middleCols<2>(2 * static_cast<Eigen::Index>(p)));
  }
  lower_.topLeftCorner(2 * m, 2 * m).triangularView<Eigen::Lower>().solveInPlace(cross);
  for (std::size_t p = 0; p < missing.size(); ++p) {
    cache_.emplace(key_of(missing[p]), CrossBlock(cross.middleCols<2>(2 * static_cast<Eigen::Index>(p))));
  }
  return missing.size();
}

bool ConditionedPairingModel::prepared(const Pairing& pairing) const {
  return kept_.empty() || cache_.count(key_of(pairing)) > 0;
}

Eigen::Index ConditionedPairingModel::panel_pairings(std::int64_t kept, Eigen::Index left, std::int64_t work_unit) {
  Eigen::Index count = 0;
  for (std::int64_t work = 0; count < std::min(left, kMaxPanelPairings); ++count) {
    work += condition_work(kept + count);
    if (count >= kMinPanelPairings && work > work_unit) break;
  }
  return count;
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
  return base_.covariance(a, b) - cross_a.transpose().lazyProduct(cross_b);
}

void ConditionedPairingModel::condition(const Pairing& pairing, Vec2& innovation, Mat2& covariance) {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  solve_cross(pairing, cross_);
  auto cross_kept = cross_.topRows(2 * m);
  innovation = base_.innovation(pairing) - cross_kept.transpose() * whitened_.head(2 * m);
  covariance = base_.covariance(pairing, pairing) - cross_kept.transpose().lazyProduct(cross_kept);
}

void ConditionedPairingModel::reserve_factor(Eigen::Index rows) {
  if (lower_.rows() >= rows) return;
  const Eigen::Index size = std::max<Eigen::Index>(rows, 2 * lower_.rows());
  lower_.conservativeResize(size, size);
  whitened_.conservativeResize(size);
}

void ConditionedPairingModel::keep(const Pairing& pairing, const Eigen::LLT<Mat2>& factor, const Vec2& whitened) {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  reserve_factor(2 * m + 2);
  lower_.block(2 * m, 0, 2, 2 * m) = cross_.topRows(2 * m).transpose();
  lower_.block<2, 2>(2 * m, 2 * m) = factor.matrixL();
  whitened_.segment<2>(2 * m) = whitened;
  kept_.push_back(pairing);
  cache_.clear();
}

bool ConditionedPairingModel::keep_if_within(const Pairing& pairing, double gate) {
  Vec2 innovation;
  Mat2 covariance;
  condition(pairing, innovation, covariance);
  Eigen::LLT<Mat2> factor;
  Vec2 whitened;
  if (!whitened_within(covariance, innovation, gate, factor, whitened)) return false;
  keep(pairing, factor, whitened);
  return true;
}

// The panel's pairings conditioned on K are a PairingModel of their own (nu_a|K, C_ab|K from
// the panel's w_a), in which the sequential test runs as above; the rows it adds to L are
// [w_a' | the panel factor's row], those keep() would have added one by one.
std::size_t ConditionedPairingModel::keep_each_within(const std::vector<Pairing>& pairings,
                                                      const std::vector<double>& gates, int max_rejections,
                                                      std::vector<char>& kept) {
  const auto m = static_cast<Eigen::Index>(kept_.size());
  const auto count = static_cast<Eigen::Index>(pairings.size());
  kept.clear();
  panel_cross_.resize(2 * m, 2 * count);
  for (Eigen::Index p = 0; p < count; ++p) {
    write_cross(pairings[static_cast<std::size_t>(p)], panel_cross_.middleCols<2>(2 * p));
  }
  if (m > 0) lower_.topLeftCorner(2 * m, 2 * m).triangularView<Eigen::Lower>().solveInPlace(panel_cross_);
  // Every w_a' w_b and w_a' L^-1 nu_K of the panel in two products, not a small one per pair.
  panel_gram_.noalias() = panel_cross_.transpose() * panel_cross_;
  panel_shift_.noalias() = panel_cross_.transpose() * whitened_.head(2 * m);

  panel_lower_.resize(2 * count, 2 * count);
  panel_whitened_.resize(2 * count);
  panel_cross_taken_.resize(2 * count, 2);
  std::vector<Eigen::Index>& taken = panel_taken_;
  taken.clear();
  int rejections = 0;
  for (Eigen::Index p = 0; p < count && rejections < max_rejections; ++p) {
    const Pairing& pairing = pairings[static_cast<std::size_t>(p)];
    kept.push_back(0);
    Vec2 innovation = base_.innovation(pairing) - panel_shift_.segment<2>(2 * p);
    Mat2 covariance = base_.covariance(pairing, pairing) - panel_gram_.block<2, 2>(2 * p, 2 * p);
    const auto t = static_cast<Eigen::Index>(taken.size());
    if (t > 0) {
      for (Eigen::Index r = 0; r < t; ++r) {
        const Eigen::Index q = taken[static_cast<std::size_t>(r)];
        panel_cross_taken_.middleRows<2>(2 * r) =
            base_.covariance(pairings[static_cast<std::size_t>(q)], pairing) - panel_gram_.block<2, 2>(2 * q, 2 * p);
      }
      auto cross_taken = panel_cross_taken_.topRows(2 * t);
      panel_lower_.topLeftCorner(2 * t, 2 * t).triangularView<Eigen::Lower>().solveInPlace(cross_taken);
      innovation -= cross_taken.transpose().lazyProduct(panel_whitened_.head(2 * t));
      covariance -= cross_taken.transpose().lazyProduct(cross_taken);
    }
    Eigen::LLT<Mat2> factor;
    Vec2 whitened;
    if (!whitened_within(covariance, innovation, gates[static_cast<std::size_t>(p)], factor, whitened)) {
      ++rejections;
      continue;
    }
    panel_lower_.block(2 * t, 0, 2, 2 * t) = panel_cross_taken_.topRows(2 * t).transpose();
    panel_lower_.block<2, 2>(2 * t, 2 * t) = factor.matrixL();
    panel_whitened_.segment<2>(2 * t) = whitened;
    taken.push_back(p);
    kept.back() = 1;
  }
  if (taken.empty()) return kept.size();
  const auto t = static_cast<Eigen::Index>(taken.size());
  reserve_factor(2 * (m + t));
  for (Eigen::Index r = 0; r < t; ++r) {
    const Eigen::Index q = taken[static_cast<std::size_t>(r)];
    lower_.block(2 * (m + r), 0, 2, 2 * m) = panel_cross_.middleCols<2>(2 * q).transpose();
    lower_.block(2 * (m + r), 2 * m, 2, 2 * (r + 1)) = panel_lower_.block(2 * r, 0, 2, 2 * (r + 1));
    kept_.push_back(pairings[static_cast<std::size_t>(q)]);
  }
  whitened_.segment(2 * m, 2 * t) = panel_whitened_.head(2 * t);
  cache_.clear();
  return kept.size();
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
