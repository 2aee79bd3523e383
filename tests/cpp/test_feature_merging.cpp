// impose_equal_features against the dense EKF update with the constraint written out as a
// matrix H (K = P H' (H P H')^-1), and the distance against its definition.
#include <random>
#include <vector>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "dcslam/association/feature_merging.hpp"

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

// Features of a map with independent position errors of sigma 0.05 m, at the given points.
GaussianMap independent_map(const std::vector<Vec2>& points) {
  GaussianMap map;
  for (std::size_t k = 0; k < points.size(); ++k) map.append_feature(points[k], 10 + static_cast<int>(k));
  map.P() = Eigen::MatrixXd::Identity(map.dim(), map.dim()) * 0.05 * 0.05;
  return map;
}

// Two estimates of one landmark (ids 10 and 12) 0.05 m apart, a distinct landmark 1.5 m away,
// and a third pair (13, 14) 0.05 m apart that may not be one (e.g. seen in one scan).
TEST(FeatureMerging, MergesEveryMutuallyUniqueCompatiblePairAndNothingElse) {
  GaussianMap map = independent_map({Vec2(0, 0), Vec2(1.5, 0), Vec2(0.05, 0), Vec2(5, 5), Vec2(5.05, 5)});
  GaussianMap expected = map;
  const double gate = 9.21;
  const MayBeOneLandmark may_be_one = [&map](Eigen::Index a, Eigen::Index b) {
    const auto ia = map.ids()[static_cast<std::size_t>(a)], ib = map.ids()[static_cast<std::size_t>(b)];
    return !((ia == 13 && ib == 14) || (ia == 14 && ib == 13));
  };
  const auto merged = merge_duplicate_features(map, 2.0, gate, 0.0, may_be_one);
  ASSERT_EQ(merged.size(), 1u);
  EXPECT_EQ(merged[0], std::make_pair(std::int64_t{12}, std::int64_t{10}));  // the older id stays
  EXPECT_EQ(map.ids(), (std::vector<std::int64_t>{10, 11, 13, 14}));
  // The merge is the noise-free update f_10 = f_12 (tested above), then f_12 marginalised.
  ASSERT_TRUE(impose_equal_features(expected, 0, 2));
  expected.remove_features({2});
  EXPECT_LT((map.x() - expected.x()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((map.P() - expected.P()).cwiseAbs().maxCoeff(), 1e-12);
}

// A round's merges read and update P's lower triangle and mirror it once (O(n^2) a round, not a
// merge): bitwise what merging one pair at a time with impose_equal_features() gives, P
// mirrored after each. Three pairs merged in one round of a map with a dense covariance.
TEST(FeatureMerging, ARoundsMergesAreBitwiseThoseMadeOneAtATime) {
  GaussianMap map = random_map(10, 11);
  for (Eigen::Index k = 0; k < 5; ++k) map.x().segment<2>(GaussianMap::feature_offset(k)) = Vec2(10.0 * k, 0.0);
  for (Eigen::Index k = 5; k < 8; ++k) {
    map.x().segment<2>(GaussianMap::feature_offset(k)) = map.feature(k - 5) + Vec2(0.1, -0.05 * k);
  }
  for (Eigen::Index k = 8; k < 10; ++k) map.x().segment<2>(GaussianMap::feature_offset(k)) = Vec2(10.0 * k, 30.0);
  GaussianMap expected = map;
  const auto anything = [](Eigen::Index, Eigen::Index) { return true; };
  const auto merged = merge_duplicate_features(map, 1.0, 9.21, 0.0, anything);
  ASSERT_EQ(merged.size(), 3u);
  for (Eigen::Index k = 0; k < 3; ++k) {
    EXPECT_EQ(merged[static_cast<std::size_t>(k)], std::make_pair(std::int64_t{105 + k}, std::int64_t{100 + k}));
    ASSERT_LE(feature_difference_distance_sq(expected, k, k + 5), 9.21);
    ASSERT_TRUE(impose_equal_features(expected, k, k + 5));
  }
  expected.remove_features({5, 6, 7});
  EXPECT_EQ(map.ids(), expected.ids());
  EXPECT_TRUE((map.x().array() == expected.x().array()).all());
  EXPECT_TRUE((map.P().array() == expected.P().array()).all());
}

// join_feature_sigma in the merge's test: 0.4 m apart with sigma 0.05 m each is D^2 = 32, no
// merge; with an independent 0.1 m more on each feature S = 2 (0.05^2 + 0.1^2) I, D^2 = 6.4.
TEST(FeatureMerging, FeatureSigmaWidensTheTestAndNotTheUpdate) {
  const auto anything = [](Eigen::Index, Eigen::Index) { return true; };
  GaussianMap map = independent_map({Vec2(0, 0), Vec2(0.4, 0)});
  EXPECT_NEAR(feature_difference_distance_sq(map, 0, 1), 0.16 / (2 * 0.0025), 1e-9);
  EXPECT_NEAR(feature_difference_distance_sq(map, 0, 1, 0.1), 0.16 / (2 * (0.0025 + 0.01)), 1e-9);
  GaussianMap plain = map;
  EXPECT_TRUE(merge_duplicate_features(plain, 2.0, 9.21, 0.0, anything).empty());
  GaussianMap expected = map;
  const auto merged = merge_duplicate_features(map, 2.0, 9.21, 0.1, anything);
  ASSERT_EQ(merged.size(), 1u);
  // The merge itself is the exact f_10 = f_11 of the map's own covariance, as a join imposes it.
  ASSERT_TRUE(impose_equal_features(expected, 0, 1));
  expected.remove_features({1});
  EXPECT_LT((map.x() - expected.x()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((map.P() - expected.P()).cwiseAbs().maxCoeff(), 1e-12);
}

// A feature with two compatible partners is left alone: no ambiguity is resolved by merging.
TEST(FeatureMerging, AnAmbiguousPairIsNotMerged) {
  GaussianMap map = independent_map({Vec2(0, 0), Vec2(0.05, 0), Vec2(-0.05, 0)});
  const auto merged = merge_duplicate_features(map, 2.0, 9.21, 0.0, [](Eigen::Index, Eigen::Index) { return true; });
  EXPECT_TRUE(merged.empty());
  EXPECT_EQ(map.num_features(), 3);
  // The partner search itself: none (ambiguous) for the middle one, none beyond the radius.
  EXPECT_EQ(merge_partner(map, 0, 2.0, 9.21, 0.0, [](Eigen::Index, Eigen::Index) { return true; }), -1);
  EXPECT_EQ(merge_partner(map, 0, 0.01, 9.21, 0.0, [](Eigen::Index, Eigen::Index) { return true; }), -1);
}

}  // namespace
}  // namespace dcslam
