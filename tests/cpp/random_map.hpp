#pragma once
// A random map for the join tests: features scattered around, a random SPD covariance, ids as
// given. Inline: several test files include it.
#include <cstdint>
#include <random>
#include <vector>

#include "dcslam/core/gaussian_map.hpp"

namespace dcslam {

inline GaussianMap random_map(std::mt19937_64& rng, const std::vector<std::int64_t>& ids) {
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> uniform(-20, 20);
  GaussianMap map;
  for (std::int64_t id : ids) map.append_feature(Vec2(uniform(rng), uniform(rng)), id);
  map.x().head<3>() = Vec3(uniform(rng), uniform(rng), uniform(rng) / 7.0);
  const Eigen::Index d = map.dim();
  Eigen::MatrixXd A(d, d);
  for (Eigen::Index i = 0; i < d; ++i)
    for (Eigen::Index j = 0; j < d; ++j) A(i, j) = 0.1 * normal(rng);
  map.P() = A * A.transpose() + 0.05 * Eigen::MatrixXd::Identity(d, d);
  return map;
}

}  // namespace dcslam
