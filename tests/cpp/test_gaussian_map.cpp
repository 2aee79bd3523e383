#include <random>

#include <gtest/gtest.h>

#include "dcslam/core/gaussian_map.hpp"

namespace dcslam {
namespace {

// Fills a map with n features and a random symmetric P whose entry (i, j) encodes (i, j).
GaussianMap labelled_map(int n) {
  GaussianMap map;
  for (int k = 0; k < n; ++k) map.append_feature(Vec2(k, -k), 100 + k);
  for (Eigen::Index i = 0; i < map.dim(); ++i) {
    map.x()(i) = i;
    for (Eigen::Index j = 0; j < map.dim(); ++j) map.P()(i, j) = 1000.0 * std::min(i, j) + std::max(i, j);
  }
  return map;
}

TEST(GaussianMap, StartsAsRobotAtOriginWithZeroCovariance) {
  GaussianMap map;
  EXPECT_EQ(map.dim(), 3);
  EXPECT_EQ(map.num_features(), 0);
  EXPECT_TRUE(map.x().isZero());
  EXPECT_TRUE(map.P().isZero());
}

TEST(GaussianMap, GrowthKeepsContentsAndZeroesNewBlocks) {
  GaussianMap map = labelled_map(40);  // crosses the initial capacity several times
  const Eigen::MatrixXd before = map.P();
  map.append_feature(Vec2(7, 8), 999);
  EXPECT_EQ(map.num_features(), 41);
  EXPECT_TRUE(map.P().topLeftCorner(before.rows(), before.cols()).isApprox(before));
  EXPECT_TRUE(map.P().rightCols(2).isZero());
  EXPECT_TRUE(map.P().bottomRows(2).isZero());
  EXPECT_EQ(map.feature(40), Vec2(7, 8));
  EXPECT_EQ(map.ids().back(), 999);
}

TEST(GaussianMap, RemoveFeaturesMatchesSelectingKeptRowsAndColumns) {
  GaussianMap map = labelled_map(12);
  const Eigen::MatrixXd P = map.P();
  const Eigen::VectorXd x = map.x();
  const std::vector<Eigen::Index> removed = {7, 0, 11, 4};
  map.remove_features(removed);
  std::vector<Eigen::Index> keep = {0, 1, 2};
  std::vector<std::int64_t> ids;
  for (int k = 0; k < 12; ++k) {
    if (k == 0 || k == 4 || k == 7 || k == 11) continue;
    keep.push_back(3 + 2 * k);
    keep.push_back(4 + 2 * k);
    ids.push_back(100 + k);
  }
  ASSERT_EQ(map.dim(), static_cast<Eigen::Index>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) {
    EXPECT_EQ(map.x()(i), x(keep[i]));
    for (std::size_t j = 0; j < keep.size(); ++j) EXPECT_EQ(map.P()(i, j), P(keep[i], keep[j]));
  }
  EXPECT_EQ(map.ids(), ids);
}

// Swap-removal equals selecting the kept rows and columns in the order last-into-k.
TEST(GaussianMap, SwapRemoveFeatureMovesTheLastFeatureIntoTheHole) {
  for (int removed : {0, 3, 6}) {
    const GaussianMap original = labelled_map(7);
    GaussianMap map = original;
    EXPECT_EQ(map.swap_remove_feature(removed), removed == 6 ? -1 : 6);
    std::vector<int> source_feature{0, 1, 2, 3, 4, 5};
    if (removed != 6) source_feature[static_cast<std::size_t>(removed)] = 6;
    std::vector<Eigen::Index> source{0, 1, 2};
    for (int f : source_feature) {
      source.push_back(GaussianMap::feature_offset(f));
      source.push_back(GaussianMap::feature_offset(f) + 1);
    }
    ASSERT_EQ(map.dim(), static_cast<Eigen::Index>(source.size()));
    for (Eigen::Index i = 0; i < map.dim(); ++i) {
      EXPECT_EQ(map.x()(i), original.x()(source[static_cast<std::size_t>(i)]));
      for (Eigen::Index j = 0; j < map.dim(); ++j) {
        EXPECT_EQ(map.P()(i, j), original.P()(source[static_cast<std::size_t>(i)], source[static_cast<std::size_t>(j)]))
            << removed << " " << i << " " << j;
      }
    }
    for (std::size_t k = 0; k < source_feature.size(); ++k) {
      EXPECT_EQ(map.ids()[k], 100 + source_feature[k]);
    }
  }
  GaussianMap map = labelled_map(2);
  EXPECT_THROW(map.swap_remove_feature(2), std::exception);
}

// Past poses sit after the features: features keep their offsets, poses are addressed from
// the end; removing features keeps the poses; a map with poses refuses to grow or reorder.
TEST(GaussianMap, PastPosesFollowTheFeatures) {
  GaussianMap map = GaussianMap::uninitialized(4, 2);
  EXPECT_EQ(map.dim(), 3 + 8 + 6);
  EXPECT_EQ(map.num_features(), 4);
  EXPECT_EQ(map.num_poses(), 2);
  EXPECT_EQ(map.pose_offset(0), 11);
  EXPECT_EQ(map.pose_offset(1), 14);
  for (Eigen::Index i = 0; i < map.dim(); ++i) {
    map.x()(i) = i;
    for (Eigen::Index j = 0; j < map.dim(); ++j) map.P()(i, j) = 1000.0 * std::min(i, j) + std::max(i, j);
  }
  map.ids() = {100, 101, 102, 103};
  map.pose_ids() = {7, 9};
  EXPECT_EQ(map.pose(1), Vec3(14, 15, 16));
  const GaussianMap original = map;
  map.remove_features({1, 2});
  EXPECT_EQ(map.num_features(), 2);
  EXPECT_EQ(map.num_poses(), 2);
  EXPECT_EQ(map.pose_ids(), (std::vector<std::int64_t>{7, 9}));
  const std::vector<Eigen::Index> keep = {0, 1, 2, 3, 4, 9, 10, 11, 12, 13, 14, 15, 16};
  ASSERT_EQ(map.dim(), static_cast<Eigen::Index>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) {
    EXPECT_EQ(map.x()(i), original.x()(keep[i]));
    for (std::size_t j = 0; j < keep.size(); ++j) EXPECT_EQ(map.P()(i, j), original.P()(keep[i], keep[j]));
  }
  EXPECT_EQ(map.pose(0), original.pose(0));
  EXPECT_THROW(map.append_feature(Vec2(1, 2), 5), std::exception);
  EXPECT_THROW(map.swap_remove_feature(0), std::exception);
  EXPECT_THROW(map.resize(map.dim() + 2), std::exception);
  EXPECT_THROW(GaussianMap::uninitialized(-1), std::exception);
}

}  // namespace
}  // namespace dcslam
