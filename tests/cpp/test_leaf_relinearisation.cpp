// A local map rebuilt from its own measurements (leaf_relinearisation.hpp): in the linear case it
// is the EKF's map whatever the linearisation point; with exact measurements and the true point
// the fitted poses are the true ones and the rebuilt means are the truth.
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/joining/leaf_relinearisation.hpp"

namespace dcslam {
namespace {

using Index = Eigen::Index;

struct LeafRun {
  EkfSlam ekf;
  LeafLog log;  // as DCSlam logs it (ids as update() gave them)
  std::vector<Vec3> truth;  // poses 0..s
  std::vector<Vec2> landmarks;
};

// `steps` motions along an arc over a grid of landmarks, each landmark seen within 4 m, with
// the given noise scale (0: exact measurements); known ids.
LeafRun run_leaf(const SlamConfig& config, int steps, double noise, bool known_heading, std::uint64_t seed) {
  LeafRun run{EkfSlam(config), {}, {Vec3::Zero()}, {}};
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  for (int i = -2; i <= 8; ++i)
    for (int j = -4; j <= 6; ++j) run.landmarks.emplace_back(1.7 * i + 0.4 * j, 1.6 * j);
  const Mat3 Q = Vec3(0.01, 0.0025, known_heading ? 0.0 : 0.0004).asDiagonal();
  const Mat2 R = config.observation == ObservationModel::Point ? Mat2(Vec2(0.01, 0.0025).asDiagonal())
                                                               : Mat2(Vec2(0.0025, 0.0003).asDiagonal());
  for (int k = 0; k < steps; ++k) {
    const Vec3 u_true(0.5, 0.0, 0.06);
    run.truth.push_back(compose(run.truth.back(), u_true));
    Vec3 u = u_true;
    for (int a = 0; a < 3; ++a) u(a) += noise * std::sqrt(Q(a, a)) * normal(rng);
    run.ekf.predict(u, Q);
    run.log.u.push_back(u);
    run.log.Q.push_back(Q);
    std::vector<Vec2> z;
    std::vector<std::int64_t> ids;
    for (std::size_t id = 0; id < run.landmarks.size(); ++id) {
      if ((inverse_transform_point(run.truth.back(), run.landmarks[id])).norm() > 4.0) continue;
      Vec2 measured = observe(config.observation, config.sensor_offset, run.truth.back(), run.landmarks[id]);
      measured += noise * Vec2(std::sqrt(R(0, 0)) * normal(rng), std::sqrt(R(1, 1)) * normal(rng));
      z.push_back(measured);
      ids.push_back(static_cast<std::int64_t>(id));
    }
    MeasurementMatrix Z(static_cast<Index>(z.size()), 2);
    for (std::size_t i = 0; i < z.size(); ++i) Z.row(static_cast<Index>(i)) = z[i].transpose();
    const std::vector<std::int64_t> given = run.ekf.update(Z, {R}, &ids);
    for (std::size_t i = 0; i < given.size(); ++i) {
      run.log.measurements.push_back(LeafMeasurement{z[i], R, given[i], k + 1});
    }
  }
  return run;
}

SlamConfig known_config(ObservationModel model) {
  SlamConfig config;
  config.observation = model;
  config.association = Association::Known;
  config.join_association = JoinAssociation::Known;
  return config;
}

TEST(LeafRelinearisation, TheLinearCaseRebuildsTheEkfMapAtAnyPoint) {
  const SlamConfig config = known_config(ObservationModel::Point);
  LeafRun run = run_leaf(config, 25, 1.0, true, 4);
  const GaussianMap& map = run.ekf.map();
  ASSERT_GT(map.num_features(), 10);
  const LeafLog sealed = seal_leaf_log(run.log, map, run.ekf.merged_ids());
  std::mt19937_64 rng(9);
  std::normal_distribution<double> normal;
  LeafPoint point;
  point.end = map.robot() + Vec3(0.3 * normal(rng), 0.3 * normal(rng), 0.0);  // the heading is known
  for (Index j = 0; j < map.num_features(); ++j) {
    point.features.emplace_back(map.feature(j) + 0.3 * Vec2(normal(rng), normal(rng)));
  }
  std::vector<Vec3> poses;
  fit_leaf_poses(sealed, leaf_weights(sealed), point, LeafModel{config.observation, config.sensor_offset}, poses);
  const GaussianMap rebuilt = rebuild_leaf(map, sealed, point, poses, LeafModel{config.observation, config.sensor_offset});
  EXPECT_EQ(rebuilt.ids(), map.ids());
  const double scale_x = map.x().cwiseAbs().maxCoeff(), scale_P = map.P().cwiseAbs().maxCoeff();
  EXPECT_LT((rebuilt.x() - map.x()).cwiseAbs().maxCoeff(), 1e-9 * scale_x);
  EXPECT_LT((rebuilt.P() - map.P()).cwiseAbs().maxCoeff(), 1e-9 * scale_P);
}

TEST(LeafRelinearisation, ExactMeasurementsAtTheTruthGiveTheTruth) {
  const SlamConfig config = known_config(ObservationModel::RangeBearing);
  LeafRun run = run_leaf(config, 30, 0.0, false, 5);
  const GaussianMap& map = run.ekf.map();
  const LeafLog sealed = seal_leaf_log(run.log, map, run.ekf.merged_ids());
  LeafPoint point;
  point.end = run.truth.back();
  for (Index j = 0; j < map.num_features(); ++j) {
    point.features.emplace_back(run.landmarks[static_cast<std::size_t>(map.ids()[static_cast<std::size_t>(j)])]);
  }
  const LeafModel model{config.observation, config.sensor_offset};
  std::vector<Vec3> poses;  // from dead reckoning, which is exact here
  EXPECT_LT(fit_leaf_poses(sealed, leaf_weights(sealed), point, model, poses), 1e-20);
  // Started elsewhere, the fit finds the true poses.
  for (Vec3& pose : poses) pose += Vec3(0.2, -0.1, 0.05);
  EXPECT_LT(fit_leaf_poses(sealed, leaf_weights(sealed), point, model, poses), 1e-16);
  for (std::size_t t = 0; t < poses.size(); ++t) {
    EXPECT_LT((poses[t] - run.truth[t + 1]).cwiseAbs().maxCoeff(), 1e-9) << t;
  }
  const GaussianMap rebuilt = rebuild_leaf(map, sealed, point, poses, model);
  EXPECT_LT((rebuilt.robot() - run.truth.back()).cwiseAbs().maxCoeff(), 1e-9);
  for (Index j = 0; j < map.num_features(); ++j) {
    EXPECT_LT((rebuilt.feature(j) - *point.features[static_cast<std::size_t>(j)]).cwiseAbs().maxCoeff(), 1e-9);
  }
  // Its covariance is the EKF's linearised at the truth: close to the EKF's own, which was
  // linearised at its estimates (equal to the truth here, up to rounding).
  EXPECT_LT((rebuilt.P() - map.P()).cwiseAbs().maxCoeff(), 1e-9 * map.P().cwiseAbs().maxCoeff());
}

TEST(LeafRelinearisation, SealingRefusesAFeatureWithoutMeasurements) {
  const SlamConfig config = known_config(ObservationModel::Point);
  LeafRun run = run_leaf(config, 5, 1.0, true, 6);
  LeafLog log = run.log;
  const std::int64_t first = log.measurements.front().feature;
  std::vector<LeafMeasurement> kept;
  for (const LeafMeasurement& m : log.measurements) {
    if (m.feature != first) kept.push_back(m);
  }
  log.measurements = kept;
  EXPECT_THROW(seal_leaf_log(log, run.ekf.map(), run.ekf.merged_ids()), std::logic_error);
}

}  // namespace
}  // namespace dcslam
