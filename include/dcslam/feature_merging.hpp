#pragma once
// Two features of one map that stand for one landmark (a duplicate: its first measurement
// after a gate failure started a second feature) are merged by imposing f_a = f_b exactly, the
// constraint a D&C join imposes on a matched pair, and marginalising f_b. The tests that decide
// when to merge live in EkfSlam (docs/data_association.md, "Duplicated features").
#include <Eigen/Core>

#include "dcslam/gaussian_map.hpp"

namespace dcslam {

// Mahalanobis distance^2 of f_a - f_b under its covariance P_aa + P_bb - P_ab - P_ba; infinity
// when that covariance is not positive definite (the two are already one).
double feature_difference_distance_sq(const GaussianMap& map, Eigen::Index a, Eigen::Index b);

// The noise-free EKF update with h = f_a - f_b = 0: K = P H' S^-1 with P H' = P[:, a] - P[:, b]
// and S = P_aa + P_bb - P_ab - P_ba; x <- x - K (f_a - f_b), P <- P - K S K'. Afterwards f_b
// equals f_a and their rows of P coincide, so deleting f_b is the exact marginal. O(n^2).
// Returns false, leaving the map unchanged, when S is not positive definite.
bool impose_equal_features(GaussianMap& map, Eigen::Index a, Eigen::Index b);

}  // namespace dcslam
