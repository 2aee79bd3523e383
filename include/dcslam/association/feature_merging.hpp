#pragma once
// Two features of one map that stand for one landmark (a duplicate: its first measurement
// after a gate failure started a second feature) are merged by imposing f_a = f_b exactly, the
// constraint a D&C join imposes on a matched pair, and marginalising f_b. The tests that decide
// when to merge live in EkfSlam (docs/data_association.md, "Duplicated features").
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"

namespace dcslam {

// Mahalanobis distance^2 of f_a - f_b under its covariance P_aa + P_bb - P_ab - P_ba, plus
// 2 feature_sigma^2 I when each feature carries an independent error of that size that the
// map does not hold (SlamConfig::join_feature_sigma, for features from different D&C local
// maps); infinity when that covariance is not positive definite (the two are already one).
double feature_difference_distance_sq(const GaussianMap& map, Eigen::Index a, Eigen::Index b,
                                      double feature_sigma = 0.0);

// The noise-free EKF update with h = f_a - f_b = 0: K = P H' S^-1 with P H' = P[:, a] - P[:, b]
// and S = P_aa + P_bb - P_ab - P_ba; x <- x - K (f_a - f_b), P <- P - K S K'. Afterwards f_b
// equals f_a and their rows of P coincide, so deleting f_b is the exact marginal. O(n^2).
// Returns false, leaving the map unchanged, when S is not positive definite.
bool impose_equal_features(GaussianMap& map, Eigen::Index a, Eigen::Index b);

// Whether features a and b of a map may stand for one landmark (e.g. they were never paired in
// one scan): what the map's covariance cannot tell.
using MayBeOneLandmark = std::function<bool(Eigen::Index, Eigen::Index)>;

// The one feature j != k of `map` that k may be a duplicate of: within `radius` of it, f_k - f_j
// compatible with 0 (D^2 <= gate) and may_be_one(k, j); -1 when there is none or more than one
// (no ambiguity to resolve, which is what a joint test would be for). The test adds
// `feature_sigma` as feature_difference_distance_sq() does. O(n).
Eigen::Index merge_partner(const GaussianMap& map, Eigen::Index k, double radius, double gate, double feature_sigma,
                           const MayBeOneLandmark& may_be_one);

// Told of each merge (merged id, kept id) as it is made.
using OnMerge = std::function<void(std::int64_t, std::int64_t)>;

// Merges every pair of features that are each other's merge_partner(), keeping the one with the
// smaller id, in rounds until a round merges nothing (at most n rounds: each round that merges
// removes a feature). `on_merge`, if given, hears of each merge before the next round's partner
// search, so that a may_be_one that follows the merges (D&C's seen-with lists) sees a merged
// feature's history in the feature it is kept as. Returns (merged id, kept id) for each merge.
// O(n^2) a round for the search, O(n^2) a merge.
std::vector<std::pair<std::int64_t, std::int64_t>> merge_duplicate_features(
    GaussianMap& map, double radius, double gate, double feature_sigma, const MayBeOneLandmark& may_be_one,
    const OnMerge& on_merge = nullptr);

}  // namespace dcslam
