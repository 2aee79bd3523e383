#include <cmath>
#include <random>
#include <string>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/input_checks.hpp"
#include "dcslam/core/observation.hpp"
#include "numeric_jacobian.hpp"
#include "print_parameters.hpp"

namespace dcslam {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// The textbook EKF on the full state with dense H, F and augmentation Jacobians: the oracle
// for the sparse one. It shares only the geometry functions, whose Jacobians are tested
// against central differences in test_geometry.cpp.
struct DenseEkf {
  SlamConfig config;
  VectorXd x = VectorXd::Zero(3);
  MatrixXd P = MatrixXd::Zero(3, 3);
  std::vector<std::int64_t> ids;

  void predict(const Vec3& u, const Mat3& Q) {
    const Eigen::Index n = x.size();
    Mat3 F_R, G_R;
    x.head<3>() = compose(x.head<3>(), u, &F_R, &G_R);
    MatrixXd F = MatrixXd::Identity(n, n);
    F.topLeftCorner<3, 3>() = F_R;
    MatrixXd G = MatrixXd::Zero(n, 3);
    G.topRows<3>() = G_R;
    P = F * P * F.transpose() + G * Q * G.transpose();
  }

  void update(const MeasurementMatrix& z, const std::vector<Mat2>& R,
              const std::vector<std::int64_t>& measured_ids) {
    const Eigen::Index n = x.size();
    std::vector<std::pair<int, int>> paired;  // (measurement, feature)
    std::vector<int> fresh;
    for (int i = 0; i < z.rows(); ++i) {
      const auto it = std::find(ids.begin(), ids.end(), measured_ids[i]);
      if (it == ids.end()) fresh.push_back(i);
      else paired.emplace_back(i, static_cast<int>(it - ids.begin()));
    }
    const Eigen::Index k = static_cast<Eigen::Index>(paired.size());
    if (k > 0) {
      MatrixXd H = MatrixXd::Zero(2 * k, n), Rk = MatrixXd::Zero(2 * k, 2 * k);
      VectorXd nu(2 * k);
      for (Eigen::Index a = 0; a < k; ++a) {
        const auto [i, f] = paired[static_cast<std::size_t>(a)];
        Mat23 H_R;
        Mat2 H_f;
        const Vec2 z_hat = observe(config.observation, config.sensor_offset, x.head<3>(),
                                   x.segment<2>(3 + 2 * f), &H_R, &H_f);
        H.block<2, 3>(2 * a, 0) = H_R;
        H.block<2, 2>(2 * a, 3 + 2 * f) = H_f;
        nu.segment<2>(2 * a) = innovation(config.observation, z.row(i).transpose(), z_hat);
        Rk.block<2, 2>(2 * a, 2 * a) = R.size() == 1 ? R[0] : R[static_cast<std::size_t>(i)];
      }
      const MatrixXd S = H * P * H.transpose() + Rk;
      const MatrixXd K = P * H.transpose() * S.inverse();
      x += K * nu;
      x(2) = wrap_angle(x(2));
      P = P - K * S * K.transpose();
    }
    for (int i : fresh) {
      const Eigen::Index m = x.size();
      Mat23 G_R;
      Mat2 G_z;
      const Vec2 f = inverse_observe(config.observation, config.sensor_offset, x.head<3>(),
                                     z.row(i).transpose(), &G_R, &G_z);
      MatrixXd Y = MatrixXd::Zero(m + 2, m);
      Y.topRows(m) = MatrixXd::Identity(m, m);
      Y.bottomLeftCorner<2, 3>() = G_R;
      const Mat2 Ri = R.size() == 1 ? R[0] : R[static_cast<std::size_t>(i)];
      MatrixXd augmented = Y * P * Y.transpose();
      augmented.bottomRightCorner<2, 2>() += G_z * Ri * G_z.transpose();
      P = augmented;
      x.conservativeResize(m + 2);
      x.tail<2>() = f;
      ids.push_back(measured_ids[static_cast<std::size_t>(i)]);
    }
  }
};

struct Scan {
  Vec3 u;
  Mat3 Q;
  MeasurementMatrix z;
  std::vector<Mat2> R;
  std::vector<std::int64_t> ids;
};

// A robot driving circles of radius ~5 m among landmarks on a ring; range–bearing within 6 m.
std::vector<Scan> circle_run(int steps, const SlamConfig& config, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss;
  std::vector<Vec2> landmarks;
  for (int k = 0; k < 8; ++k) {
    const double angle = 2 * M_PI * k / 8;
    landmarks.emplace_back(5 * std::cos(angle) + 0.3 * k, 5 + 5 * std::sin(angle));
  }
  const Vec3 u_true(0.5, 0.0, 0.1);
  const Vec3 u_sigma(0.05, 0.02, 0.01);
  const Vec2 z_sigma(0.05, 0.01);
  Vec3 pose = Vec3::Zero();
  std::vector<Scan> run;
  for (int s = 0; s < steps; ++s) {
    Scan scan;
    pose = compose(pose, u_true);
    scan.u = u_true + Vec3(u_sigma.x() * gauss(rng), u_sigma.y() * gauss(rng), u_sigma.z() * gauss(rng));
    scan.Q = u_sigma.cwiseAbs2().asDiagonal();
    scan.Q(0, 1) = scan.Q(1, 0) = 1e-4;  // correlated odometry exercises every term of G Q G'
    std::vector<Vec2> rows;
    for (std::size_t k = 0; k < landmarks.size(); ++k) {
      const Vec2 z = observe(config.observation, config.sensor_offset, pose, landmarks[k]);
      const double range = config.observation == ObservationModel::RangeBearing ? z.x() : z.norm();
      if (range > 6.0 || range < 0.5) continue;
      rows.push_back(z + Vec2(z_sigma.x() * gauss(rng), z_sigma.y() * gauss(rng)));
      scan.ids.push_back(static_cast<std::int64_t>(k) * 10 + 3);
      scan.R.push_back(z_sigma.cwiseAbs2().asDiagonal() * (1.0 + 0.1 * static_cast<double>(k)));
    }
    scan.z.resize(static_cast<Eigen::Index>(rows.size()), 2);
    for (std::size_t i = 0; i < rows.size(); ++i) scan.z.row(static_cast<Eigen::Index>(i)) = rows[i];
    run.push_back(std::move(scan));
  }
  return run;
}

SlamConfig known_config(ObservationModel observation) {
  SlamConfig config;
  config.association = Association::Known;
  config.observation = observation;
  config.sensor_offset = Vec3(0.4, -0.2, 0.3);
  return config;
}

double max_abs(const MatrixXd& A) { return A.size() ? A.cwiseAbs().maxCoeff() : 0.0; }

class EkfSlamModels : public ::testing::TestWithParam<ObservationModel> {};

TEST_P(EkfSlamModels, MatchesNaiveDenseEkfStepByStep) {
  const SlamConfig config = known_config(GetParam());
  EkfSlam slam(config);
  DenseEkf dense;
  dense.config = config;
  for (const Scan& scan : circle_run(120, config, 1)) {
    slam.predict(scan.u, scan.Q);
    dense.predict(scan.u, scan.Q);
    const auto assigned = slam.update(scan.z, scan.R, &scan.ids);
    dense.update(scan.z, scan.R, scan.ids);
    EXPECT_EQ(assigned, scan.ids);
    const Estimate estimate = slam.estimate();
    ASSERT_EQ(estimate.landmark_ids, dense.ids);
    const double scale = std::max(1.0, max_abs(dense.P));
    EXPECT_LT(max_abs(slam.map().x() - dense.x), 1e-10 * std::max(1.0, max_abs(dense.x)));
    EXPECT_LT(max_abs(estimate.covariance - dense.P), 1e-10 * scale);
  }
}

TEST_P(EkfSlamModels, LongRunKeepsCovarianceSymmetricAndPositiveSemiDefinite) {
  const SlamConfig config = known_config(GetParam());
  EkfSlam slam(config);
  for (const Scan& scan : circle_run(5000, config, 2)) {
    slam.predict(scan.u, scan.Q);
    slam.update(scan.z, scan.R, &scan.ids);
  }
  const MatrixXd P = slam.estimate().covariance;
  EXPECT_EQ(P, P.transpose());  // bitwise: both triangles are written from one
  const VectorXd eigenvalues = Eigen::SelfAdjointEigenSolver<MatrixXd>(P).eigenvalues();
  EXPECT_GE(eigenvalues.minCoeff(), -1e-9 * eigenvalues.cwiseAbs().maxCoeff());
  EXPECT_EQ(slam.stats().steps.size(), 5000u);
}

INSTANTIATE_TEST_SUITE_P(Observation, EkfSlamModels,
                         ::testing::Values(ObservationModel::RangeBearing, ObservationModel::Point));

TEST(EkfSlam, PredictionPropagatesCovarianceWithCentralDifferenceJacobians) {
  const SlamConfig config = known_config(ObservationModel::RangeBearing);
  EkfSlam slam(config);
  const auto run = circle_run(30, config, 3);
  for (const Scan& scan : run) {
    slam.predict(scan.u, scan.Q);
    slam.update(scan.z, scan.R, &scan.ids);
  }
  const Estimate before = slam.estimate();
  const Vec3 u(0.7, -0.2, 0.4);
  const Mat3 Q = Vec3(0.01, 0.02, 0.003).asDiagonal();
  slam.predict(u, Q);
  const Estimate after = slam.estimate();

  const auto motion_of_pose = [&](const VectorXd& pose) -> VectorXd { return compose(pose, u); };
  const auto motion_of_u = [&](const VectorXd& v) -> VectorXd { return compose(before.robot, v); };
  const MatrixXd F_R = testing::numeric_jacobian(motion_of_pose, before.robot, {2});
  const MatrixXd G_R = testing::numeric_jacobian(motion_of_u, u, {2});
  const Eigen::Index n = before.covariance.rows();
  MatrixXd F = MatrixXd::Identity(n, n);
  F.topLeftCorner<3, 3>() = F_R;
  MatrixXd G = MatrixXd::Zero(n, 3);
  G.topRows<3>() = G_R;
  const MatrixXd expected = F * before.covariance * F.transpose() + G * Q * G.transpose();
  EXPECT_LT(max_abs(after.covariance - expected), 1e-7 * max_abs(expected));
  EXPECT_LT((after.robot - compose(before.robot, u)).cwiseAbs().maxCoeff(), 1e-15);
}

// Every rejected call names its argument and leaves the filter bitwise unchanged.
TEST(EkfSlam, BadInputIsRejectedWithoutChangingTheFilter) {
  const SlamConfig config = known_config(ObservationModel::RangeBearing);
  EkfSlam slam(config);
  const auto run = circle_run(10, config, 4);
  for (const Scan& scan : run) {
    slam.predict(scan.u, scan.Q);
    slam.update(scan.z, scan.R, &scan.ids);
  }
  const Scan& good = run.back();
  ASSERT_GE(good.z.rows(), 2);
  const Estimate reference = slam.estimate();
  const std::size_t steps = slam.stats().steps.size();
  const double nan = std::nan("");

  const auto expect_rejected = [&](const std::function<void()>& call, const std::string& needle) {
    try {
      call();
      ADD_FAILURE() << "no exception; expected one mentioning " << needle;
    } catch (const InvalidArgument& error) {
      EXPECT_NE(std::string(error.what()).find(needle), std::string::npos) << error.what();
    }
    const Estimate now = slam.estimate();
    EXPECT_EQ(now.robot, reference.robot);
    EXPECT_EQ(now.landmarks, reference.landmarks);
    EXPECT_EQ(now.landmark_ids, reference.landmark_ids);
    EXPECT_EQ(now.covariance, reference.covariance);
    EXPECT_EQ(slam.stats().steps.size(), steps);
  };

  expect_rejected([&] { slam.predict(Vec3(0.1, nan, 0), good.Q); }, "predict: argument 'u'");
  Mat3 asymmetric = good.Q;
  asymmetric(0, 2) += 1e-3;
  expect_rejected([&] { slam.predict(good.u, asymmetric); }, "argument 'Q' is not symmetric");
  Mat3 indefinite = Vec3(0.1, 0.1, 0.1).asDiagonal();
  indefinite(0, 1) = indefinite(1, 0) = 0.5;
  expect_rejected([&] { slam.predict(good.u, indefinite); }, "argument 'Q' is not positive semi");
  Mat3 nan_Q = good.Q;
  nan_Q(1, 1) = nan;
  expect_rejected([&] { slam.predict(good.u, nan_Q); }, "argument 'Q' contains a non-finite");

  MeasurementMatrix nan_z = good.z;
  nan_z(1, 1) = nan;
  expect_rejected([&] { slam.update(nan_z, good.R, &good.ids); }, "update: argument 'z'[1]");
  MeasurementMatrix negative_range = good.z;
  negative_range(0, 0) = -1.0;
  expect_rejected([&] { slam.update(negative_range, good.R, &good.ids); }, "argument 'z'[0]");
  std::vector<Mat2> not_pd = good.R;
  not_pd[1] << 1.0, 2.0, 2.0, 1.0;
  expect_rejected([&] { slam.update(good.z, not_pd, &good.ids); },
                  "update: argument 'R'[1] is not positive definite");
  std::vector<Mat2> asymmetric_R = good.R;
  asymmetric_R[0](0, 1) += 1e-3;
  expect_rejected([&] { slam.update(good.z, asymmetric_R, &good.ids); }, "argument 'R'[0] is not symmetric");
  std::vector<Mat2> wrong_count(good.R.begin(), good.R.end() - 1);
  if (wrong_count.size() != 1) {
    expect_rejected([&] { slam.update(good.z, wrong_count, &good.ids); }, "argument 'R'");
  }
  expect_rejected([&] { slam.update(good.z, good.R, nullptr); },
                  "argument 'landmark_ids' is required");
  std::vector<std::int64_t> short_ids(good.ids.begin(), good.ids.end() - 1);
  expect_rejected([&] { slam.update(good.z, good.R, &short_ids); }, "argument 'landmark_ids'");
  std::vector<std::int64_t> duplicate_ids = good.ids;
  duplicate_ids[1] = duplicate_ids[0];
  expect_rejected([&] { slam.update(good.z, good.R, &duplicate_ids); },
                  "argument 'landmark_ids'[1]");
  std::vector<std::int64_t> negative_ids = good.ids;
  negative_ids[0] = -7;
  expect_rejected([&] { slam.update(good.z, good.R, &negative_ids); },
                  "argument 'landmark_ids'[0]");
}

TEST(EkfSlam, ZeroHeadingVarianceIsLegal) {
  EkfSlam slam(known_config(ObservationModel::Point));
  slam.predict(Vec3(1, 0, 0.1), Vec3(0.01, 0.01, 0.0).asDiagonal());
  EXPECT_EQ(slam.estimate().covariance(2, 2), 0.0);
}

TEST(EkfSlam, EmptyScansAndMinusOneIdsAreHandled) {
  EkfSlam slam(known_config(ObservationModel::Point));
  slam.predict(Vec3(1, 0, 0), Mat3::Identity() * 0.01);
  const std::vector<std::int64_t> none;
  EXPECT_TRUE(slam.update(MeasurementMatrix(0, 2), {Mat2::Identity()}, &none).empty());
  MeasurementMatrix z(2, 2);
  z << 1, 2, 3, 4;
  const std::vector<std::int64_t> ids{-1, 5};
  EXPECT_EQ(slam.update(z, {Mat2::Identity()}, &ids), (std::vector<std::int64_t>{-1, 5}));
  EXPECT_EQ(slam.map().num_features(), 1);
  EXPECT_EQ(slam.stats().steps.back().rejected, 1);
  EXPECT_EQ(slam.stats().steps.back().new_features, 1);
  EXPECT_EQ(slam.resolve({-1, 5, 9}), (std::vector<std::int64_t>{-1, 5, 9}));
}

// Modes without landmark ids ("nn", "jcbb") refuse them; "known" requires them.
TEST(InputChecks, LandmarkIdsOnlyInKnownMode) {
  MeasurementMatrix z(1, 2);
  z << 2.0, 0.1;
  const std::vector<Mat2> R{Mat2::Identity()};
  const std::vector<std::int64_t> ids{4};
  for (Association mode : {Association::NearestNeighbour, Association::Jcbb}) {
    EXPECT_NO_THROW(check_measurements(z, R, nullptr, ObservationModel::RangeBearing, mode, "update"));
    try {
      check_measurements(z, R, &ids, ObservationModel::RangeBearing, mode, "update");
      ADD_FAILURE() << "ids accepted in mode " << to_string(mode);
    } catch (const InvalidArgument& error) {
      EXPECT_NE(std::string(error.what()).find("update: argument 'landmark_ids' is only accepted"),
                std::string::npos)
          << error.what();
    }
  }
  EXPECT_THROW(check_measurements(z, R, nullptr, ObservationModel::RangeBearing, Association::Known,
                                  "update"),
               InvalidArgument);
}

TEST(InputChecks, SemiDefiniteQWithZeroVarianceAndTinyRoundingPasses) {
  Mat3 Q = Vec3(0.01, 0.02, 0.0).asDiagonal();
  EXPECT_NO_THROW(check_motion(Vec3::Zero(), Q, "predict"));
  Q(2, 2) = -1e-18;  // rounding noise on a zero variance
  EXPECT_NO_THROW(check_motion(Vec3::Zero(), Q, "predict"));
  Q(2, 2) = -1e-6;
  EXPECT_THROW(check_motion(Vec3::Zero(), Q, "predict"), InvalidArgument);
}

TEST(EkfSlam, AssociationModesWithoutIdsAreBuiltAndBadOptionsRefused) {
  SlamConfig config;
  for (Association mode : {Association::Jcbb, Association::NearestNeighbour}) {
    config.association = mode;
    EXPECT_NO_THROW(EkfSlam{config});
  }
  const auto refused = [](SlamConfig bad, const std::string& field) {
    try {
      EkfSlam slam(bad);
      ADD_FAILURE() << field << " accepted";
    } catch (const InvalidArgument& error) {
      EXPECT_NE(std::string(error.what()).find("SlamConfig." + field), std::string::npos) << error.what();
    }
  };
  SlamConfig bad = config;
  bad.jcbb_max_nodes = 0;
  refused(bad, "jcbb_max_nodes");
  bad = config;
  bad.min_sightings = 0;
  refused(bad, "min_sightings");
  bad = config;
  bad.tentative_window = 0;
  refused(bad, "tentative_window");
  bad = config;
  bad.gate_confidence = 1.0;
  refused(bad, "gate_confidence");
}

TEST(EkfSlam, TakeMapRestartsAtTheOrigin) {
  const SlamConfig config = known_config(ObservationModel::RangeBearing);
  EkfSlam slam(config);
  for (const Scan& scan : circle_run(5, config, 5)) {
    slam.predict(scan.u, scan.Q);
    slam.update(scan.z, scan.R, &scan.ids);
  }
  const Estimate before = slam.estimate();
  const GaussianMap taken = slam.take_map();
  EXPECT_EQ(MatrixXd(taken.P()), before.covariance);
  EXPECT_EQ(slam.map().dim(), 3);
  EXPECT_TRUE(slam.map().x().isZero());
  EXPECT_TRUE(slam.map().P().isZero());
  // An id of the old map starts a new feature in the new one.
  MeasurementMatrix z(1, 2);
  z << 2.0, 0.1;
  const std::vector<std::int64_t> ids{before.landmark_ids.front()};
  slam.update(z, {Mat2::Identity() * 0.01}, &ids);
  EXPECT_EQ(slam.map().num_features(), 1);
}

TEST(EkfSlam, RunStepsMatchesStepByStep) {
  const SlamConfig config = known_config(ObservationModel::RangeBearing);
  const auto run = circle_run(50, config, 6);
  EkfSlam stepwise(config), batch(config);
  std::vector<SlamStep> steps;
  for (const Scan& scan : run) {
    stepwise.predict(scan.u, scan.Q);
    stepwise.update(scan.z, scan.R, &scan.ids);
    steps.push_back({scan.u, scan.Q, scan.z, scan.R, scan.ids, true});
  }
  const auto assigned = run_steps(batch, steps);
  ASSERT_EQ(assigned.size(), run.size());
  EXPECT_EQ(assigned.back(), run.back().ids);
  EXPECT_EQ(batch.estimate().covariance, stepwise.estimate().covariance);
  steps[7].Q(0, 0) = -1.0;
  EkfSlam failing(config);
  try {
    run_steps(failing, steps);
    ADD_FAILURE() << "expected InvalidArgument";
  } catch (const InvalidArgument& error) {
    EXPECT_NE(std::string(error.what()).find("run_steps: step 7: predict: argument 'Q'"),
              std::string::npos)
        << error.what();
  }
}

}  // namespace
}  // namespace dcslam
