#pragma once
// A local map rebuilt from its own measurements at a given linearisation point
// (docs/divide_and_conquer.md, "Leaves re-linearised from their own measurements").
//
// A local map's EKF linearised every odometry step and measurement where its own estimate
// stood. Re-linearising only the joins above it (join_tree.hpp) leaves those linearisations in
// place, so the tree converges to the optimum of "local maps as measurements", not to the batch
// optimum. Here a local map is rebuilt from what its EKF was built from (LeafLog: each step's
// u, Q and each measurement it used, z, R, with the feature it ended in) at a point of the
// whole problem: its base, end pose and features where the global estimate puts them (in the
// base frame), its intermediate poses at their optimum given those (fit_leaf_poses()). The
// result (rebuild_leaf()) is the Gaussian over [end pose; features] that the leaf's least
// squares problem, linearised at that point and with the intermediate poses marginalised,
// defines: the mean is that problem's minimiser, the covariance its inverse Schur complement.
// A tree pass over such leaves is then one Gauss–Newton step of the full batch problem.
#include <cstdint>
#include <optional>
#include <vector>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/observation.hpp"
#include "dcslam/core/slam_filter.hpp"

namespace dcslam {

// One measurement a local map's EKF used. `pose`: predicts of the local map before it (0: its
// base). `feature`: while the local map is open, the id update() gave; once sealed
// (seal_leaf_log()), the slot of the feature it ended in (0..p-1, in the local map's order).
struct LeafMeasurement {
  Vec2 z = Vec2::Zero();
  Mat2 R = Mat2::Identity();
  std::int64_t feature = 0;
  std::int64_t pose = 0;
};

// What a local map's EKF was built from: O(steps + measurements), appended O(1) a measurement.
struct LeafLog {
  std::vector<Vec3> u;
  std::vector<Mat3> Q;
  std::vector<LeafMeasurement> measurements;
};

// The observation model the local maps were built with.
struct LeafModel {
  ObservationModel observation = ObservationModel::RangeBearing;
  Vec3 sensor_offset = Vec3::Zero();
};

// `log` (ids as update() gave them) with each measurement's feature replaced by its slot in
// `map`, the local map it built, after following the local map's merges (`merged`: dropped id
// -> the id it was merged into). The measurements of a feature the local map removed (a
// tentative one) are left out, as the batch problem of the run's map leaves them out; with
// min_sightings = 2 such a feature was seen once, and leaving it out changes nothing (one
// measurement adds no information, and the EKF marginalised it). Throws std::logic_error if a
// feature of `map` has no measurement.
LeafLog seal_leaf_log(const LeafLog& log, const GaussianMap& map, const IdAliases& merged);

// Where the whole problem puts a local map's elements, in its base frame: its end pose, and
// each of its features (std::nullopt for a feature the global map does not hold: a tentative
// one dropped by a later join; it keeps only its first sighting, linearised where that
// measurement puts it, so it adds no information and the join drops it as in the run).
struct LeafPoint {
  Vec3 end = Vec3::Zero();
  std::vector<std::optional<Vec2>> features;
};

// The weights of a log's residuals: Q^-1 and R^-1, a zero variance (a known heading, an exactly
// known motion) weighted as a constraint (a floor of 1e-12 of the largest variance).
struct LeafWeights {
  std::vector<Mat3> odometry;
  std::vector<Mat2> measurements;
};
LeafWeights leaf_weights(const LeafLog& log);

// The intermediate poses x_1..x_{s-1} (base frame; x_0 is the base, x_s the end) that minimise
// the leaf's odometry and measurement residuals with the end pose and the features the global
// map holds fixed at `point` (the other features' measurements are left out):
// Gauss–Newton, block-tridiagonal in the poses, O(s + m) a step, halved where a step would
// raise the objective. `poses` is the start (empty: dead reckoning with the gap to the end
// spread along the path) and receives the fit; a heading a motion knows exactly (zero
// variance) is set from the pose before. Returns the objective at the fit,
// Σ |⊖x_{t-1}⊕x_t - u_t|²_{Q^-1} + Σ |z - h(x_t, f)|²_{R^-1} (`weights`: leaf_weights(log)).
double fit_leaf_poses(const LeafLog& log, const LeafWeights& weights, const LeafPoint& point, const LeafModel& model,
                      std::vector<Vec3>& poses);

// The local map `map` (its ids and feature order; its log `log`, sealed) rebuilt at `point`
// with the intermediate poses `poses` (fit_leaf_poses()): a Kalman filter over [robot;
// features] run through the log with every odometry step and measurement linearised at the
// point (residual form, ⊖x_{t-1}⊕x_t - u and z - h(x_t, f), as the batch problem has them),
// which gives the linearised least-squares problem's marginal over [end pose; features]
// exactly. Zero variances (the first base, a known heading) stay zero, as in the EKF.
// O(s n + m n^2) for n = 3 + 2p, the EKF's own order. `innovation_distance_sq`, if given, is
// set to the sum of the filter's normalised innovations squared, nu' S^-1 nu: the minimum of
// the leaf's linearised least-squares problem (the prediction-error decomposition).
GaussianMap rebuild_leaf(const GaussianMap& map, const LeafLog& log, const LeafPoint& point,
                         const std::vector<Vec3>& poses, const LeafModel& model,
                         double* innovation_distance_sq = nullptr);

}  // namespace dcslam
