#include <cmath>
#include <set>
#include <string>

#include <gtest/gtest.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/datasets/simulator.hpp"

namespace dcslam {
namespace {

constexpr double kPi = 3.14159265358979323846;
const Trajectory kTrajectories[] = {Trajectory::Straight, Trajectory::Loop,
                                    Trajectory::LawnMowing, Trajectory::Snail};

// Measurement noise must be > 0 (the filters need a positive definite R): 1e-15 is far below
// the tolerances of the comparisons.
SimulationConfig noise_free(SimulationConfig config) {
  config.odometry_sigma.setZero();
  config.range_sigma_fraction = 1e-15;
  config.bearing_sigma = 1e-15;
  config.point_sigma = 1e-15;
  return config;
}

Vec3 pose(const Simulation& sim, Eigen::Index k) { return sim.poses.row(k).transpose(); }
Vec2 landmark(const Simulation& sim, std::int64_t i) {
  return sim.landmarks.row(static_cast<Eigen::Index>(i)).transpose();
}

TEST(Simulator, NoiseFreeMeasurementsAreTheObservationModel) {
  for (const ObservationModel model : {ObservationModel::RangeBearing, ObservationModel::Point}) {
    for (const Trajectory trajectory : kTrajectories) {
      SimulationConfig config;
      config.trajectory = trajectory;
      config.steps = 60;
      config.observation = model;
      config.sensor_offset = Vec3(0.3, -0.1, 0.2);
      config.fov = kPi;
      const Simulation sim = simulate(noise_free(config));
      ASSERT_GT(sim.measurements.rows(), 0);
      for (int k = 0; k < config.steps; ++k) {
        // u is the relative motion between consecutive true poses.
        const Vec3 u = sim.odometry.row(k).transpose();
        EXPECT_LT((compose(pose(sim, k), u) - pose(sim, k + 1)).norm(), 1e-12);
        for (auto i = sim.step_offsets[k]; i < sim.step_offsets[k + 1]; ++i) {
          const Vec2 expected = observe(model, config.sensor_offset, pose(sim, k + 1),
                                        landmark(sim, sim.true_ids[i]));
          EXPECT_LT(innovation(model, sim.measurements.row(i).transpose(), expected).norm(), 1e-12);
        }
      }
    }
  }
}

TEST(Simulator, PosesStartAtTheOriginAndMoveOneStepLength) {
  for (const Trajectory trajectory : kTrajectories) {
    SimulationConfig config;
    config.trajectory = trajectory;
    config.steps = 101;
    const Simulation sim = simulate(config);
    ASSERT_EQ(sim.poses.rows(), 102);
    EXPECT_EQ(pose(sim, 0), Vec3::Zero());
    for (int k = 0; k < config.steps; ++k) {
      const Vec3 d = compose(invert(pose(sim, k)), pose(sim, k + 1));
      EXPECT_NEAR(d.x(), 1.0, 1e-9);
      EXPECT_NEAR(d.y(), 0.0, 1e-9);
      EXPECT_TRUE(std::abs(d.z()) < 1e-9 || std::abs(std::abs(d.z()) - kPi / 2) < 1e-9);
    }
  }
}

TEST(Simulator, OdometryAndMeasurementNoiseHaveTheConfiguredSigmas) {
  SimulationConfig config;
  config.steps = 20000;
  config.trajectory = Trajectory::LawnMowing;
  const Simulation sim = simulate(config);
  const Vec3 sigma = config.odometry_sigma;
  EXPECT_EQ(sim.odometry_covariance, Mat3(sigma.array().square().matrix().asDiagonal()));

  Eigen::Matrix3d second_moment = Eigen::Matrix3d::Zero();
  Vec3 mean = Vec3::Zero();
  for (int k = 0; k < config.steps; ++k) {
    const Vec3 true_motion = compose(invert(pose(sim, k)), pose(sim, k + 1));
    Vec3 e = sim.odometry.row(k).transpose() - true_motion;
    e.z() = wrap_angle(e.z());
    const Vec3 normalized = e.cwiseQuotient(sigma);
    mean += normalized;
    second_moment += normalized * normalized.transpose();
  }
  mean /= config.steps;
  second_moment /= config.steps;
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(mean(i), 0.0, 0.05);
    EXPECT_GT(second_moment(i, i), 0.95);
    EXPECT_LT(second_moment(i, i), 1.05);
    for (int j = 0; j < i; ++j) EXPECT_NEAR(second_moment(i, j), 0.0, 0.05);
  }

  double range_mean = 0, bearing_mean = 0, range_var = 0, bearing_var = 0;
  const auto total = static_cast<double>(sim.measurements.rows());
  ASSERT_GT(total, 100000);
  for (int k = 0; k < config.steps; ++k) {
    for (auto i = sim.step_offsets[k]; i < sim.step_offsets[k + 1]; ++i) {
      const Vec2 expected = observe(config.observation, config.sensor_offset, pose(sim, k + 1),
                                    landmark(sim, sim.true_ids[i]));
      const Vec2 nu = innovation(config.observation, sim.measurements.row(i).transpose(), expected);
      // R is built from the true range, not from the noisy one.
      EXPECT_DOUBLE_EQ(std::sqrt(sim.measurement_covariances(i, 0)),
                       config.range_sigma_fraction * expected.x());
      EXPECT_EQ(sim.measurement_covariances(i, 1), 0.0);
      const double range_error = nu.x() / (config.range_sigma_fraction * expected.x());
      const double bearing_error = nu.y() / config.bearing_sigma;
      range_mean += range_error / total;
      bearing_mean += bearing_error / total;
      range_var += range_error * range_error / total;
      bearing_var += bearing_error * bearing_error / total;
    }
  }
  EXPECT_NEAR(range_mean, 0.0, 0.02);
  EXPECT_NEAR(bearing_mean, 0.0, 0.02);
  EXPECT_NEAR(range_var, 1.0, 0.03);
  EXPECT_NEAR(bearing_var, 1.0, 0.03);
}

TEST(Simulator, SeesAboutSixteenFeaturesPerStep) {
  for (const double fov : {2 * kPi, kPi, kPi / 3}) {
    for (const Trajectory trajectory : kTrajectories) {
      SimulationConfig config;
      config.trajectory = trajectory;
      config.steps = 400;
      config.fov = fov;
      const Simulation sim = simulate(config);
      const double per_step = static_cast<double>(sim.measurements.rows()) / config.steps;
      EXPECT_GT(per_step, 16 * 0.8) << to_string(trajectory) << " fov " << fov;
      EXPECT_LT(per_step, 16 * 1.2) << to_string(trajectory) << " fov " << fov;
    }
  }
}

TEST(Simulator, LoopReturnsToItsStartAndRevisitsEarlyFeatures) {
  SimulationConfig config;
  config.trajectory = Trajectory::Loop;
  config.steps = 200;
  const Simulation sim = simulate(config);
  EXPECT_LT(pose(sim, config.steps).norm(), 1e-9);
  const Eigen::Vector2d extent =
      sim.poses.leftCols<2>().colwise().maxCoeff() - sim.poses.leftCols<2>().colwise().minCoeff();
  EXPECT_NEAR(extent.x(), 50.0, 1e-9);
  EXPECT_NEAR(extent.y(), 50.0, 1e-9);
  const std::set<std::int64_t> early(sim.true_ids.begin(),
                                     sim.true_ids.begin() + sim.step_offsets[5]);
  int revisited = 0;
  for (auto i = sim.step_offsets[config.steps - 5]; i < sim.step_offsets[config.steps]; ++i) {
    revisited += early.count(sim.true_ids[i]) ? 1 : 0;
  }
  EXPECT_GT(revisited, 10);
}

TEST(Simulator, LawnMowingSweepsParallelLanes) {
  SimulationConfig config;
  config.trajectory = Trajectory::LawnMowing;
  config.steps = 500;
  const Simulation sim = simulate(config);
  const int lane = static_cast<int>(std::lround(std::sqrt(500.0 * 3)));
  for (int k = 0; k < config.steps; ++k) {
    EXPECT_GE(sim.poses(k + 1, 1), sim.poses(k, 1) - 1e-9);  // never goes back in y
    EXPECT_GT(sim.poses(k, 0), -1e-9);
    EXPECT_LT(sim.poses(k, 0), lane + 1e-9);
  }
  EXPECT_GT(sim.poses(config.steps, 1), 30.0);
}

TEST(Simulator, SnailSpiralsInwardWithoutCrossingItself) {
  SimulationConfig config;
  config.trajectory = Trajectory::Snail;
  config.steps = 500;
  const Simulation sim = simulate(config);
  std::set<std::pair<long, long>> visited;
  for (int k = 0; k <= config.steps; ++k) {
    visited.insert({std::lround(sim.poses(k, 0)), std::lround(sim.poses(k, 1))});
  }
  EXPECT_EQ(visited.size(), static_cast<std::size_t>(config.steps + 1));
  const Eigen::Vector2d low = sim.poses.leftCols<2>().colwise().minCoeff();
  const Eigen::Vector2d high = sim.poses.leftCols<2>().colwise().maxCoeff();
  const Eigen::Vector2d centre = (low + high) / 2;
  const Eigen::Vector2d end = sim.poses.row(config.steps).head<2>();
  EXPECT_LT((end - centre).norm(), 0.25 * (high - low).norm());
}

TEST(Simulator, ClutterIsTheConfiguredFractionAndLiesInTheFootprint) {
  for (const double rate : {0.1, 0.5}) {
    SimulationConfig config;
    config.steps = 2000;
    config.clutter = rate;
    config.fov = kPi;
    const Simulation sim = simulate(config);
    std::int64_t spurious = 0;
    for (Eigen::Index i = 0; i < sim.measurements.rows(); ++i) {
      if (sim.true_ids[static_cast<std::size_t>(i)] != -1) continue;
      ++spurious;
      EXPECT_GE(sim.measurements(i, 0), config.min_range);
      EXPECT_LE(sim.measurements(i, 0), config.max_range);
      EXPECT_LE(std::abs(sim.measurements(i, 1)), config.fov / 2);
    }
    EXPECT_NEAR(static_cast<double>(spurious) / static_cast<double>(sim.measurements.rows()), rate,
                0.02);
  }
}

TEST(Simulator, SameSeedSameRunOtherSeedOtherRun) {
  SimulationConfig config;
  config.trajectory = Trajectory::Snail;
  config.steps = 300;
  config.clutter = 0.2;
  const Simulation a = simulate(config), b = simulate(config);
  EXPECT_EQ(a.landmarks, b.landmarks);
  EXPECT_EQ(a.odometry, b.odometry);
  EXPECT_EQ(a.measurements, b.measurements);
  EXPECT_EQ(a.measurement_covariances, b.measurement_covariances);
  EXPECT_EQ(a.true_ids, b.true_ids);
  config.seed = 1;
  const Simulation c = simulate(config);
  // Another seed may place another number of landmarks: compare sizes before contents.
  EXPECT_TRUE(a.landmarks.rows() != c.landmarks.rows() || a.landmarks != c.landmarks);
  ASSERT_EQ(a.odometry.rows(), c.odometry.rows());
  EXPECT_NE(a.odometry, c.odometry);
}

TEST(Simulator, ScanOrderIsShuffled) {
  SimulationConfig config;
  config.steps = 50;
  const Simulation sim = simulate(config);
  int sorted_scans = 0;
  for (int k = 0; k < config.steps; ++k) {
    sorted_scans += std::is_sorted(sim.true_ids.begin() + sim.step_offsets[k],
                                   sim.true_ids.begin() + sim.step_offsets[k + 1])
                        ? 1
                        : 0;
  }
  EXPECT_LT(sorted_scans, 3);
}

TEST(Simulator, NumFeaturesOverridesTheDensity) {
  for (const std::int64_t n : {std::int64_t{100}, std::int64_t{20000}}) {
    SimulationConfig config;
    config.trajectory = Trajectory::Snail;
    config.steps = 300;
    config.num_features = n;
    const Simulation sim = simulate(config);
    EXPECT_EQ(sim.landmarks.rows(), n);
    for (std::int64_t id : sim.true_ids) EXPECT_LT(id, n);
  }
}

TEST(Simulator, ZeroHeadingNoiseZeroesTheHeadingVariance) {
  SimulationConfig config;
  config.steps = 20;
  config.zero_heading_noise = true;
  const Simulation sim = simulate(config);
  EXPECT_EQ(sim.odometry_covariance(2, 2), 0.0);
  for (int k = 0; k < config.steps; ++k) EXPECT_EQ(sim.odometry(k, 2), 0.0);
}

TEST(Simulator, BadParametersAreNamed) {
  const auto expect_named = [](SimulationConfig config, const std::string& name) {
    try {
      simulate(config);
      ADD_FAILURE() << name << " was accepted";
    } catch (const InvalidArgument& error) {
      EXPECT_NE(std::string(error.what()).find(name), std::string::npos) << error.what();
    }
  };
  SimulationConfig config;
  config.steps = 0;
  expect_named(config, "steps");
  config = {};
  config.fov = 7;
  expect_named(config, "fov");
  config = {};
  config.clutter = 1;
  expect_named(config, "clutter");
  config = {};
  config.min_range = 3;
  expect_named(config, "min_range");
  config = {};
  config.odometry_sigma.x() = -1;
  expect_named(config, "odometry_sigma");
  config = {};
  config.num_features = -5;
  expect_named(config, "num_features");
  config = {};
  config.trajectory = Trajectory::Snail;
  config.side_steps = 5;
  expect_named(config, "steps");
  EXPECT_THROW(parse_trajectory("circle", "trajectory"), InvalidArgument);
}

}  // namespace
}  // namespace dcslam
