#include <algorithm>
#include <limits>
#include <map>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/spatial_hash.hpp"

namespace dcslam {
namespace {

std::vector<int> brute_force_disc(const std::map<int, Vec2>& items, const Vec2& center,
                                  double radius) {
  std::vector<int> ids;
  for (const auto& [id, p] : items) {
    if ((p - center).squaredNorm() <= radius * radius) ids.push_back(id);
  }
  return ids;
}

std::vector<int> brute_force_box(const std::map<int, Vec2>& items, const Vec2& lo,
                                 const Vec2& hi) {
  std::vector<int> ids;
  for (const auto& [id, p] : items) {
    if (lo.x() <= p.x() && p.x() <= hi.x() && lo.y() <= p.y() && p.y() <= hi.y()) {
      ids.push_back(id);
    }
  }
  return ids;
}

std::vector<int> sorted(std::vector<int> ids) {
  std::sort(ids.begin(), ids.end());
  return ids;
}

TEST(SpatialHash, RandomInsertMoveRemoveMatchesBruteForce) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> coordinate(-50.0, 50.0);
  std::uniform_real_distribution<double> radius_of(0.0, 12.0);
  std::uniform_int_distribution<int> operation(0, 9);
  SpatialHash hash(2.5);
  std::map<int, Vec2> reference;
  std::vector<int> found;
  int next_id = -20;  // negative ids are valid too
  for (int step = 0; step < 4000; ++step) {
    const int op = operation(rng);
    if (op < 4 || reference.empty()) {
      const Vec2 p(coordinate(rng), coordinate(rng));
      hash.insert(next_id, p);
      reference[next_id++] = p;
    } else if (op < 6) {
      auto it = std::next(reference.begin(),
                          std::uniform_int_distribution<long>(0, reference.size() - 1)(rng));
      // Half the moves stay close, so some keep their cell.
      const Vec2 p = op == 4 ? Vec2(coordinate(rng), coordinate(rng))
                             : Vec2(it->second + Vec2(0.3 * radius_of(rng) / 12.0, -0.1));
      hash.move(it->first, p);
      it->second = p;
    } else if (op < 7) {
      auto it = std::next(reference.begin(),
                          std::uniform_int_distribution<long>(0, reference.size() - 1)(rng));
      hash.remove(it->first);
      reference.erase(it);
    } else {
      const Vec2 center(coordinate(rng) * 1.2, coordinate(rng) * 1.2);
      const double radius = radius_of(rng);
      hash.query(center, radius, found);
      ASSERT_EQ(sorted(found), brute_force_disc(reference, center, radius)) << "step " << step;
      const Vec2 lo(coordinate(rng), coordinate(rng));
      const Vec2 hi = lo + Vec2(radius_of(rng), 2.0 * radius_of(rng));
      hash.query_box(lo, hi, found);
      ASSERT_EQ(sorted(found), brute_force_box(reference, lo, hi)) << "step " << step;
    }
    ASSERT_EQ(hash.size(), reference.size());
  }
  for (const auto& [id, p] : reference) {
    ASSERT_TRUE(hash.contains(id));
    ASSERT_EQ(hash.position(id), p);
  }
}

TEST(SpatialHash, QueryIsInclusiveOnTheCircleAndCellBorders) {
  SpatialHash hash(1.0);
  hash.insert(0, Vec2(1.0, 0.0));   // on a cell border
  hash.insert(1, Vec2(-1.0, 0.0));  // on the circle, negative side
  hash.insert(2, Vec2(0.0, 1.0000001));
  std::vector<int> found;
  hash.query(Vec2(0.0, 0.0), 1.0, found);
  EXPECT_EQ(sorted(found), (std::vector<int>{0, 1}));
  hash.query(Vec2(0.0, 0.0), -1.0, found);
  EXPECT_TRUE(found.empty());
  hash.query_box(Vec2(-1.0, 0.0), Vec2(1.0, 0.0), found);
  EXPECT_EQ(sorted(found), (std::vector<int>{0, 1}));
}

TEST(SpatialHash, HugeQueriesAndFarPointsFallBackToScanningOccupiedCells) {
  SpatialHash hash(0.5);
  hash.insert(3, Vec2(1e12, -1e12));  // beyond the int32 cell range: clamped
  hash.insert(4, Vec2(0.2, 0.3));
  hash.insert(5, Vec2(-3e11, 7.0));
  std::vector<int> found;
  hash.query(Vec2(0.0, 0.0), std::numeric_limits<double>::infinity(), found);
  EXPECT_EQ(sorted(found), (std::vector<int>{3, 4, 5}));
  hash.query(Vec2(1e12, -1e12), 1.0, found);
  EXPECT_EQ(found, (std::vector<int>{3}));
  hash.query(Vec2(0.0, 0.0), 1e6, found);
  EXPECT_EQ(found, (std::vector<int>{4}));
}

TEST(SpatialHash, RejectsBadArguments) {
  EXPECT_THROW(SpatialHash(0.0), InvalidArgument);
  EXPECT_THROW(SpatialHash(std::numeric_limits<double>::quiet_NaN()), InvalidArgument);
  SpatialHash hash(1.0);
  hash.insert(1, Vec2(0.0, 0.0));
  EXPECT_THROW(hash.insert(1, Vec2(2.0, 0.0)), InvalidArgument);
  EXPECT_THROW(hash.insert(2, Vec2(std::numeric_limits<double>::infinity(), 0.0)),
               InvalidArgument);
  EXPECT_THROW(hash.move(9, Vec2(0.0, 0.0)), InvalidArgument);
  EXPECT_THROW(hash.remove(9), InvalidArgument);
  EXPECT_THROW(hash.position(9), InvalidArgument);
  hash.remove(1);
  EXPECT_EQ(hash.size(), 0u);
  hash.insert(1, Vec2(5.0, 5.0));  // a removed id can come back
  EXPECT_EQ(hash.position(1), Vec2(5.0, 5.0));
}

}  // namespace
}  // namespace dcslam
