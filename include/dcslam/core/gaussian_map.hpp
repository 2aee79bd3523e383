#pragma once
// A stochastic map (x, P) of docs/design.md §2: x = [robot pose (3); f_1 (2); ...; f_n (2);
// q_1 (3); ...; q_m (3)] in the map's base frame, P its full, dense, symmetric covariance. The
// q_k are past robot poses (docs/design.md §4.5: kept at local-map boundaries by D&C joins with
// JoinOptions::keep_first_robot), oldest first, each with an id (the step it was recorded at).
// Only join results hold past poses: a map that grows (EKF, local maps) holds none, so the
// features stay at fixed offsets whatever the number of poses. Storage keeps capacity headroom
// so that adding a feature does not reallocate P at every step.
//
// Invariant after every public operation of the filters: P is fully symmetric (both
// triangles hold valid values).
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/geometry.hpp"

namespace dcslam {

class GaussianMap {
 public:
  using Index = Eigen::Index;
  static constexpr Index kRobotDim = 3;
  static constexpr Index kFeatureDim = 2;
  static constexpr Index kPoseDim = 3;

  // A map whose robot sits at its base frame's origin with zero covariance.
  GaussianMap();

  // A map of the given size whose storage fits exactly (no headroom: for maps that will not
  // grow, such as the results of joins). Contents and ids are left uninitialised.
  static GaussianMap uninitialized(Index num_features, Index num_poses = 0);

  Index dim() const { return dim_; }
  Index num_features() const { return (dim_ - kRobotDim - kPoseDim * num_poses()) / kFeatureDim; }
  Index num_poses() const { return static_cast<Index>(pose_ids_.size()); }
  static Index feature_offset(Index k) { return kRobotDim + kFeatureDim * k; }
  Index pose_offset(Index k) const { return dim_ - kPoseDim * (num_poses() - k); }

  auto x() { return x_.head(dim_); }
  auto x() const { return x_.head(dim_); }
  auto P() { return P_.topLeftCorner(dim_, dim_); }
  auto P() const { return P_.topLeftCorner(dim_, dim_); }

  Vec3 robot() const { return x_.head<3>(); }
  Vec2 feature(Index k) const { return x_.segment<2>(feature_offset(k)); }
  Vec3 pose(Index k) const { return x_.segment<3>(pose_offset(k)); }

  // Feature ids, one per feature, in state order.
  const std::vector<std::int64_t>& ids() const { return ids_; }
  std::vector<std::int64_t>& ids() { return ids_; }
  // Past pose ids, one per past pose, in state order. Their number is fixed at construction.
  const std::vector<std::int64_t>& pose_ids() const { return pose_ids_; }
  std::vector<std::int64_t>& pose_ids() { return pose_ids_; }

  // Appends a feature with the given mean; its covariance rows and columns are zero (the
  // caller fills them). Returns its index. Amortised O(1) except for the zeroing, O(n).
  // Throws on a map holding past poses (it would move them).
  Index append_feature(const Vec2& mean, std::int64_t id);

  // Removes features by index (any order, no duplicates) in one O(n^2) compaction pass; past
  // poses stay, after the remaining features.
  void remove_features(std::vector<Index> indices);
  // Removes feature k in O(n) by moving the last feature into its place (state order is not
  // kept). Returns the former index of the feature now at k, or -1 if k was the last one.
  // Throws on a map holding past poses.
  Index swap_remove_feature(Index k);

  // Copies P's lower triangle onto its upper one, for updates that write only the lower one
  // (a symmetric rank update). In square tiles: the plain transposed copy of the whole
  // triangle runs at a fraction of the speed on maps of hundreds of features.
  void mirror_lower_triangle();

  // Hands the covariance over (moved, without a copy, when the storage fits exactly) and
  // leaves the map empty: for the last use of a map, such as turning it into an Estimate.
  Eigen::MatrixXd release_covariance();

  // Sets the logical size, keeping the leading block; new entries are zero. Throws on a map
  // holding past poses.
  void resize(Index dim);
  void reserve(Index dim);
  Index capacity() const { return P_.rows(); }

 private:
  Eigen::VectorXd x_;
  Eigen::MatrixXd P_;
  Index dim_ = kRobotDim;
  std::vector<std::int64_t> ids_;
  std::vector<std::int64_t> pose_ids_;
};

}  // namespace dcslam
