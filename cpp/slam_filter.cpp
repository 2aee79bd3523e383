#include "dcslam/slam_filter.hpp"

namespace dcslam {

Estimate to_estimate(const GaussianMap& map, Eigen::MatrixXd covariance) {
  Estimate estimate;
  estimate.robot = map.robot();
  const Eigen::Index n = map.num_features();
  estimate.landmarks.resize(n, 2);
  for (Eigen::Index k = 0; k < n; ++k) estimate.landmarks.row(k) = map.feature(k).transpose();
  estimate.landmark_ids = map.ids();
  estimate.covariance = std::move(covariance);
  return estimate;
}

}  // namespace dcslam
