#include "dcslam/core/slam_filter.hpp"

namespace dcslam {

Estimate to_estimate(const GaussianMap& map, Eigen::MatrixXd covariance) {
  Estimate estimate;
  estimate.robot = map.robot();
  const Eigen::Index n = map.num_features();
  estimate.landmarks.resize(n, 2);
  for (Eigen::Index k = 0; k < n; ++k) estimate.landmarks.row(k) = map.feature(k).transpose();
  estimate.landmark_ids = map.ids();
  const Eigen::Index m = map.num_poses();
  estimate.past_poses.resize(m, 3);
  for (Eigen::Index k = 0; k < m; ++k) estimate.past_poses.row(k) = map.pose(k).transpose();
  estimate.past_pose_ids = map.pose_ids();
  estimate.covariance = std::move(covariance);
  return estimate;
}

}  // namespace dcslam
