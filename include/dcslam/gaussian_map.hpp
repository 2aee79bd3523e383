#pragma once
// A stochastic map (x, P) of DESIGN.md §2: x = [robot pose (3); f_1 (2); ...; f_n (2)] in the
// map's base frame, P its full, dense, symmetric covariance. Storage keeps capacity headroom
// so that adding a feature does not reallocate P at every step.
//
// Invariant after every public operation of the filters: P is fully symmetric (both
// triangles hold valid values).
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "dcslam/geometry.hpp"

namespace dcslam {

class GaussianMap {
 public:
  using Index = Eigen::Index;
  static constexpr Index kRobotDim = 3;
  static constexpr Index kFeatureDim = 2;

  // A map whose robot sits at its base frame's origin with zero covariance.
  GaussianMap();

  // A map of the given dimension whose storage fits exactly (no headroom: for maps that
  // will not grow, such as the results of joins). Contents are left uninitialised.
  static GaussianMap uninitialized(Index dim);

  Index dim() const { return dim_; }
  Index num_features() const { return (dim_ - kRobotDim) / kFeatureDim; }
  static Index feature_offset(Index k) { return kRobotDim + kFeatureDim * k; }

  auto x() { return x_.head(dim_); }
  auto x() const { return x_.head(dim_); }
  auto P() { return P_.topLeftCorner(dim_, dim_); }
  auto P() const { return P_.topLeftCorner(dim_, dim_); }

  Vec3 robot() const { return x_.head<3>(); }
  Vec2 feature(Index k) const { return x_.segment<2>(feature_offset(k)); }

  // Feature ids, one per feature, in state order.
  const std::vector<std::int64_t>& ids() const { return ids_; }
  std::vector<std::int64_t>& ids() { return ids_; }

  // Appends a feature with the given mean; its covariance rows and columns are zero (the
  // caller fills them). Returns its index. Amortised O(1) except for the zeroing, O(n).
  Index append_feature(const Vec2& mean, std::int64_t id);

  // Removes features by index (any order, no duplicates) in one O(n^2) compaction pass.
  void remove_features(std::vector<Index> indices);
  // Removes feature k in O(n) by moving the last feature into its place (state order is not
  // kept). Returns the former index of the feature now at k, or -1 if k was the last one.
  Index swap_remove_feature(Index k);

  // Hands the covariance over (moved, without a copy, when the storage fits exactly) and
  // leaves the map empty: for the last use of a map, such as turning it into an Estimate.
  Eigen::MatrixXd release_covariance();

  // Sets the logical size, keeping the leading block; new entries are zero.
  void resize(Index dim);
  void reserve(Index dim);
  Index capacity() const { return P_.rows(); }

 private:
  Eigen::VectorXd x_;
  Eigen::MatrixXd P_;
  Index dim_ = kRobotDim;
  std::vector<std::int64_t> ids_;
};

}  // namespace dcslam
