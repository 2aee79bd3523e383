#include <cmath>
#include <random>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/observation.hpp"
#include "numeric_jacobian.hpp"
#include "print_parameters.hpp"

namespace dcslam {
namespace {

using testing::numeric_jacobian;
constexpr double kPi = 3.14159265358979323846;
constexpr double kJacobianTol = 1e-6;

class GeometryTest : public ::testing::Test {
 protected:
  std::mt19937_64 rng{42};
  double uniform(double lo, double hi) { return std::uniform_real_distribution<>(lo, hi)(rng); }
  // Headings are drawn both uniformly and within 1e-3 of ±pi, where wrapping bites.
  double heading(int i) {
    if (i % 3 == 0) return (i % 2 ? kPi : -kPi) - std::copysign(uniform(0, 1e-3), i % 2 ? 1 : -1);
    return uniform(-kPi, kPi);
  }
  Vec3 pose(int i) { return {uniform(-20, 20), uniform(-20, 20), heading(i)}; }
  Vec2 point() { return {uniform(-20, 20), uniform(-20, 20)}; }
};

TEST_F(GeometryTest, WrapAngleRange) {
  EXPECT_DOUBLE_EQ(wrap_angle(kPi), kPi);
  EXPECT_DOUBLE_EQ(wrap_angle(-kPi), kPi);
  EXPECT_NEAR(wrap_angle(3 * kPi + 0.1), -kPi + 0.1, 1e-12);
  for (int i = 0; i < 1000; ++i) {
    const double a = uniform(-100, 100);
    const double w = wrap_angle(a);
    EXPECT_GT(w, -kPi);
    EXPECT_LE(w, kPi);
    EXPECT_NEAR(std::cos(w), std::cos(a), 1e-9);
    EXPECT_NEAR(std::sin(w), std::sin(a), 1e-9);
  }
}

TEST_F(GeometryTest, ComposeJacobiansMatchCentralDifferences) {
  for (int i = 0; i < 300; ++i) {
    const Vec3 a = pose(i), b = pose(i + 1);
    Mat3 J_a, J_b;
    compose(a, b, &J_a, &J_b);
    const auto fa = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd { return compose(v, b); };
    const auto fb = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd { return compose(a, v); };
    EXPECT_LT((J_a - numeric_jacobian(fa, a, {2})).cwiseAbs().maxCoeff(), kJacobianTol);
    EXPECT_LT((J_b - numeric_jacobian(fb, b, {2})).cwiseAbs().maxCoeff(), kJacobianTol);
  }
}

TEST_F(GeometryTest, InvertJacobianMatchesCentralDifferences) {
  for (int i = 0; i < 300; ++i) {
    const Vec3 a = pose(i);
    Mat3 J;
    invert(a, &J);
    const auto f = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd { return invert(v); };
    EXPECT_LT((J - numeric_jacobian(f, a, {2})).cwiseAbs().maxCoeff(), kJacobianTol);
  }
}

TEST_F(GeometryTest, ComposeInvertRoundTrips) {
  for (int i = 0; i < 300; ++i) {
    const Vec3 a = pose(i), b = pose(i + 1);
    EXPECT_LT(compose(a, invert(a)).norm(), 1e-12);
    EXPECT_LT(compose(invert(a), a).norm(), 1e-12);
    const Vec3 back = compose(invert(a), compose(a, b));
    EXPECT_NEAR(back.x(), b.x(), 1e-9);
    EXPECT_NEAR(back.y(), b.y(), 1e-9);
    EXPECT_NEAR(wrap_angle(back.z() - b.z()), 0.0, 1e-12);
    const Vec2 p = point();
    EXPECT_LT((inverse_transform_point(a, transform_point(a, p)) - p).norm(), 1e-9);
  }
}

TEST_F(GeometryTest, PointTransformJacobiansMatchCentralDifferences) {
  for (int i = 0; i < 300; ++i) {
    const Vec3 a = pose(i);
    const Vec2 p = point();
    Mat23 J_a;
    Mat2 J_p;
    transform_point(a, p, &J_a, &J_p);
    EXPECT_LT((J_a - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                       return transform_point(v, p);
                     }, a)).cwiseAbs().maxCoeff(), kJacobianTol);
    EXPECT_LT((J_p - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                       return transform_point(a, v);
                     }, p)).cwiseAbs().maxCoeff(), kJacobianTol);
    inverse_transform_point(a, p, &J_a, &J_p);
    EXPECT_LT((J_a - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                       return inverse_transform_point(v, p);
                     }, a)).cwiseAbs().maxCoeff(), kJacobianTol);
    EXPECT_LT((J_p - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                       return inverse_transform_point(a, v);
                     }, p)).cwiseAbs().maxCoeff(), kJacobianTol);
  }
}

TEST_F(GeometryTest, LargestStdIsTheSquareRootOfTheLargestEigenvalue) {
  for (int i = 0; i < 300; ++i) {
    Mat2 A;
    A << uniform(-2, 2), uniform(-2, 2), uniform(-2, 2), uniform(-2, 2);
    const Mat2 covariance = A * A.transpose() + (i % 5 == 0 ? 0.0 : 1e-3) * Mat2::Identity();
    const double expected =
        std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Mat2>(covariance).eigenvalues().maxCoeff()));
    EXPECT_NEAR(largest_std(covariance), expected, 1e-9 * std::max(1.0, expected));
  }
}

class ObservationTest : public GeometryTest, public ::testing::WithParamInterface<ObservationModel> {};

TEST_P(ObservationTest, JacobiansMatchCentralDifferences) {
  const ObservationModel model = GetParam();
  const std::vector<int> angle_rows =
      model == ObservationModel::RangeBearing ? std::vector<int>{1} : std::vector<int>{};
  for (int i = 0; i < 300; ++i) {
    const Vec3 robot = pose(i);
    const Vec3 offset{uniform(-4, 4), uniform(-1, 1), heading(i + 1)};
    // A feature 1..15 m from the sensor, in any direction (bearings near ±pi included).
    const Vec2 local = uniform(1, 15) * Vec2(std::cos(heading(i + 2)), std::sin(heading(i + 2)));
    const Vec2 feature = transform_point(compose(robot, offset), local);
    Mat23 J_robot;
    Mat2 J_feature;
    const Vec2 z = observe(model, offset, robot, feature, &J_robot, &J_feature);
    EXPECT_LT((J_robot - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                           return observe(model, offset, v, feature);
                         }, robot, angle_rows)).cwiseAbs().maxCoeff(), kJacobianTol);
    EXPECT_LT((J_feature - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                             return observe(model, offset, robot, v);
                           }, feature, angle_rows)).cwiseAbs().maxCoeff(), kJacobianTol);
    Mat23 G_robot;
    Mat2 G_z;
    const Vec2 back = inverse_observe(model, offset, robot, z, &G_robot, &G_z);
    EXPECT_LT((back - feature).norm(), 1e-9);
    EXPECT_LT((G_robot - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                          return inverse_observe(model, offset, v, z);
                        }, robot)).cwiseAbs().maxCoeff(), kJacobianTol);
    EXPECT_LT((G_z - numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
                      return inverse_observe(model, offset, robot, v);
                    }, z)).cwiseAbs().maxCoeff(), kJacobianTol);
  }
}

TEST_P(ObservationTest, InnovationWrapsBearingOnly) {
  const Vec2 nu = innovation(GetParam(), Vec2(5.0, kPi - 0.01), Vec2(4.0, -kPi + 0.01));
  EXPECT_NEAR(nu.x(), 1.0, 1e-12);
  if (GetParam() == ObservationModel::RangeBearing) {
    EXPECT_NEAR(nu.y(), -0.02, 1e-12);
  } else {
    EXPECT_NEAR(nu.y(), 2 * kPi - 0.02, 1e-12);
  }
}

INSTANTIATE_TEST_SUITE_P(Models, ObservationTest,
                         ::testing::Values(ObservationModel::RangeBearing, ObservationModel::Point));

TEST(ObservationModelNames, UnknownNameRaisesNamingField) {
  try {
    parse_observation_model("bearing_only", "SlamConfig.observation");
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("SlamConfig.observation"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("bearing_only"), std::string::npos);
  }
}

}  // namespace
}  // namespace dcslam
