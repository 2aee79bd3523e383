// impose_equal_features against the dense EKF update with the constraint written out as a
// matrix H (K = P H' (H P H')^-1), and the distance against its definition.
#include <random>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "dcslam/feature_merging.hpp"

namespace dcslam {
namespace {

GaussianMap random_map(int features, unsigned seed) {
  std::mt19937 engine(seed);
  std::normal_distribution<double> normal;
  GaussianMap map;
  for (int k = 0; k < features; ++k) map.append_feature(Vec2(normal(engine), normal(engine)), 100 + k);
  const Eigen::Index n = map.dim();
  Eigen::MatrixXd A(n, n);
  for (Eigen::Index i = 0; i < n; ++i)
    for (Eigen::Index j = 0; j < n; ++j) A(i, j) = normal(engine);
  map.P() = A * A.transpose() / static_cast<double>(n) + 0.1 * Eigen::MatrixXd::Identity(n, n);
  for (Eigen::Index i = 0; i < n; ++i) map.x()(i) = normal(engine);
  return map;
}

Eigen::MatrixXd constraint_rows(Eigen::Index n, Eigen::Index a, Eigen::Index b) {
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(2, n);
  H.block<2, 2>(0, GaussianMap::feature_offset(a)).setIdentity();
  H.block<2, 2>(0, GaussianMap::feature_offset(b)) = -Eigen::Matrix2d::Identity();
  return H;
}

TEST(FeatureMerging, DistanceIsTheMahalanobisDistanceOfTheDifference) {
  const GaussianMap map = random_map(6, 1);
  const Eigen::MatrixXd H = constraint_rows(map.dim(), 1, 4);
  const Eigen::Vector2d d = H * map.x();
  const Eigen::Matrix2d S = H * map.P() * H.transpose();
  EXPECT_NEAR(feature_difference_distance_sq(map, 1, 4), d.dot(S.inverse() * d), 1e-10);
}

TEST(FeatureMerging, ImposeEqualFeaturesIsTheDenseNoiseFreeUpdate) {
  for (unsigned seed = 0; seed < 5; ++seed) {
    GaussianMap map = random_map(7, seed);
    const Eigen::Index a = 2, b = 5;
    const Eigen::MatrixXd P = map.P();
    const Eigen::VectorXd x = map.x();
    const Eigen::MatrixXd H = constraint_rows(map.dim(), a, b);
    const Eigen::MatrixXd K = P * H.transpose() * (H * P * H.transpose()).inverse();
    Eigen::VectorXd x_expected = x - K * (H * x);
    x_expected(2) = wrap_angle(x_expected(2));
    const Eigen::MatrixXd P_expected = P - K * H * P;

    ASSERT_TRUE(impose_equal_features(map, a, b));
    EXPECT_LT((map.x() - x_expected).cwiseAbs().maxCoeff(), 1e-10) << "seed " << seed;
    EXPECT_LT((map.P() - P_expected).cwiseAbs().maxCoeff(), 1e-10) << "seed " << seed;
    EXPECT_EQ((map.P() - map.P().transpose()).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LT((map.feature(a) - map.feature(b)).norm(), 1e-10);
  }
}

TEST(FeatureMerging, FeaturesAlreadyOneAreLeftAlone) {
  GaussianMap map = random_map(3, 7);
  // Make feature 2 an exact copy of feature 0: their difference has zero covariance.
  const Eigen::Index o0 = GaussianMap::feature_offset(0), o2 = GaussianMap::feature_offset(2);
  map.x().segment<2>(o2) = map.x().segment<2>(o0);
  Eigen::MatrixXd P = map.P();
  P.middleRows<2>(o2) = P.middleRows<2>(o0);
  P.middleCols<2>(o2) = P.middleCols<2>(o0);
  map.P() = P;
  const Eigen::VectorXd x = map.x();
  EXPECT_TRUE(std::isinf(feature_difference_distance_sq(map, 0, 2)));
  EXPECT_FALSE(impose_equal_features(map, 0, 2));
  EXPECT_EQ(map.x(), x);
}

}  // namespace
}  // namespace dcslam
