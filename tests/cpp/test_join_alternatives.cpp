// DecidingJoin (join_alternatives.hpp) against independent oracles: the plain MapJoin (no
// alternative: bitwise the same), a brute-force count of every combination's pairs (which
// version it takes), and a join by id with the deferred pairs' ids renamed apart (the
// alternative). Joins by id, so that the pairs of each combination are known in advance.
#include <algorithm>
#include <random>
#include <set>

#include <gtest/gtest.h>

#include "dcslam/joining/join_alternatives.hpp"
#include "random_map.hpp"

namespace dcslam {
namespace {

using Index = Eigen::Index;

std::shared_ptr<const GaussianMap> shared_random_map(std::mt19937_64& rng, const std::vector<std::int64_t>& ids) {
  return std::make_shared<const GaussianMap>(random_map(rng, ids));
}

// `count` distinct ids drawn from [0, range).
std::vector<std::int64_t> some_ids(std::mt19937_64& rng, int count, int range) {
  std::vector<std::int64_t> all(static_cast<std::size_t>(range));
  for (int k = 0; k < range; ++k) all[static_cast<std::size_t>(k)] = k;
  std::shuffle(all.begin(), all.end(), rng);
  all.resize(static_cast<std::size_t>(count));
  return all;
}

std::size_t shared_ids(const GaussianMap& a, const GaussianMap& b) {
  const std::set<std::int64_t> first(a.ids().begin(), a.ids().end());
  return static_cast<std::size_t>(
      std::count_if(b.ids().begin(), b.ids().end(), [&](std::int64_t id) { return first.count(id) != 0; }));
}

DecidingJoin::MakeJoin by_id(Index block_columns = kDefaultPanelWidth) {
  return [block_columns](const TreeMap& first, const TreeMap& second, std::shared_ptr<const MapJoin::Pairs> fixed) {
    JoinOptions options;
    options.block_columns = block_columns;
    options.fixed_pairs = std::move(fixed);
    return std::make_unique<MapJoin>(first.map, second.map, options);
  };
}

std::vector<TentativeFeature> none(const TreeMap&, const TreeMap&, const MapJoin&) { return {}; }

void expect_bitwise(const GaussianMap& a, const GaussianMap& b) {
  EXPECT_EQ(a.ids(), b.ids());
  ASSERT_EQ(a.dim(), b.dim());
  EXPECT_TRUE(a.x() == b.x());
  EXPECT_TRUE(a.P() == b.P());
}

// A tree map holding `versions[0]` with the others as its alternative's versions, each with
// `pairs[k]` pairs recorded as a join would have recorded them.
TreeMap with_versions(const std::vector<std::shared_ptr<const GaussianMap>>& versions,
                      const std::vector<std::size_t>& pairs) {
  auto alternative = std::make_shared<JoinAlternative>();
  alternative->made_ids.merged.assign(pairs[0], {1000, 1001});
  for (std::size_t k = 1; k < versions.size(); ++k) {
    JoinAlternative::Version version;
    version.map = versions[k];
    version.ids.merged.assign(pairs[k], {2000 + static_cast<std::int64_t>(k), 2001});
    alternative->versions.push_back(std::move(version));
  }
  return TreeMap{versions[0], {}, std::move(alternative)};
}

TEST(DecidingJoin, WithoutAlternativesItIsThePlainJoinInAnySlices) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 6; ++trial) {
    const auto m1 = shared_random_map(rng, some_ids(rng, 12, 30));
    const auto m2 = shared_random_map(rng, some_ids(rng, 10, 30));
    JoinOptions options;
    options.block_columns = 4;
    const GaussianMap plain = join_maps(*m1, *m2, options);
    DecidingJoin join(TreeMap{m1, {}, nullptr}, TreeMap{m2, {}, nullptr}, by_id(4), 0, true);
    std::uniform_int_distribution<std::int64_t> budget(1, 400);
    while (!join.done()) join.advance(budget(rng));
    EXPECT_EQ(join.first_version_taken(), 0);
    EXPECT_EQ(join.second_version_taken(), 0);
    DecidedJoin decided = join.take_result(none, 0);
    expect_bitwise(*decided.map, plain);
    EXPECT_EQ(decided.alternative, nullptr);
    ASSERT_EQ(decided.settled.size(), 1u);  // its own ids, recorded at once
  }
}

// The combination taken has the most of: twice the join's own pairs plus the pairs its inputs'
// versions keep, a tie going to the one with more own pairs (DecidingJoin::choose()).
TEST(DecidingJoin, TakesTheCombinationWhoseOwnPairsCountTwiceTheVersionsPairs) {
  std::mt19937_64 rng(11);
  int took_an_alternative = 0, took_a_second_version = 0, ties_to_more_own = 0;
  for (int trial = 0; trial < 60; ++trial) {
    // Each input: as made and one or two other versions.
    std::uniform_int_distribution<int> other_versions(1, 2);
    std::uniform_int_distribution<int> size(8, 11);
    std::uniform_int_distribution<std::size_t> some_pairs(0, 6);
    std::vector<std::shared_ptr<const GaussianMap>> firsts, seconds;
    std::vector<std::size_t> first_pairs, second_pairs;
    for (int k = other_versions(rng); k >= 0; --k) {
      firsts.push_back(shared_random_map(rng, some_ids(rng, size(rng), 24)));
      first_pairs.push_back(some_pairs(rng));
    }
    for (int k = other_versions(rng); k >= 0; --k) {
      seconds.push_back(shared_random_map(rng, some_ids(rng, size(rng), 24)));
      second_pairs.push_back(some_pairs(rng));
    }
    // Brute force, the versions in order (as made first); a tie goes to more own pairs, then
    // to the earlier.
    std::size_t best_total = 0, best_own = 0, best_first = 0, best_second = 0;
    for (std::size_t a = 0; a < firsts.size(); ++a) {
      for (std::size_t b = 0; b < seconds.size(); ++b) {
        const std::size_t own = shared_ids(*firsts[a], *seconds[b]);
        const std::size_t total = 2 * own + first_pairs[a] + second_pairs[b];
        if (a + b > 0 && total == best_total && own > best_own) ++ties_to_more_own;
        if ((a == 0 && b == 0) || total > best_total || (total == best_total && own > best_own)) {
          best_total = total;
          best_own = own;
          best_first = a;
          best_second = b;
        }
      }
    }
    DecidingJoin join(with_versions(firsts, first_pairs), with_versions(seconds, second_pairs), by_id(), 0, true);
    join.finish();
    EXPECT_EQ(join.first_version_taken(), static_cast<int>(best_first)) << "trial " << trial;
    EXPECT_EQ(join.second_version_taken(), static_cast<int>(best_second)) << "trial " << trial;
    EXPECT_EQ(join.report().alternatives_taken, (best_first > 0 ? 1 : 0) + (best_second > 0 ? 1 : 0));
    // The associations of the combinations not chosen are the join's time too (every input has
    // two versions or more, so some combination was discarded).
    EXPECT_GT(join.report().seconds_association, join.join().report().seconds_association);
    EXPECT_LE(join.report().seconds_association, join.report().seconds_total);
    took_an_alternative += best_first > 0 || best_second > 0 ? 1 : 0;
    took_a_second_version += best_first == 2 || best_second == 2 ? 1 : 0;
    DecidedJoin decided = join.take_result(none, 0);
    expect_bitwise(*decided.map, join_maps(*firsts[best_first], *seconds[best_second], JoinOptions()));
    // The ids of both inputs' chosen versions, then its own.
    ASSERT_EQ(decided.settled.size(), 3u);
    EXPECT_EQ(decided.settled[0].merged.size(), first_pairs[best_first]);
    EXPECT_EQ(decided.settled[1].merged.size(), second_pairs[best_second]);
  }
  // The cases are not all decided one way.
  EXPECT_GT(took_an_alternative, 10);
  EXPECT_GT(took_a_second_version, 5);
  EXPECT_GT(ties_to_more_own, 0);
}

TEST(DecidingJoin, AWeakJoinsAlternativeLeavesOutThePairsOfFeaturesSeenOnce) {
  std::mt19937_64 rng(5);
  const std::vector<std::int64_t> first_ids = {1, 2, 3, 4, 5, 6, 7, 8};
  const std::vector<std::int64_t> second_ids = {20, 3, 21, 5, 22, 7, 8};  // shares 3, 5, 7, 8
  const auto m1 = shared_random_map(rng, first_ids);
  const auto m2 = shared_random_map(rng, second_ids);
  // 5 was seen once in the first map, 8 once in the second: their pairs are deferred.
  const TreeMap first{m1, {TentativeFeature{5, 0, false, false}}, nullptr};
  const TreeMap second{m2, {TentativeFeature{8, 1, false, false}}, nullptr};

  DecidingJoin strong(first, second, by_id(), 3, true);  // 4 pairs: more than 3, not weak
  strong.finish();
  EXPECT_EQ(strong.take_result(none, 0).alternative, nullptr);

  DecidingJoin weak(first, second, by_id(), 4, true);
  weak.finish();
  EXPECT_EQ(weak.report().deferred_pairings, 4);
  DecidedJoin decided = weak.take_result(none, 0);
  expect_bitwise(*decided.map, join_maps(*m1, *m2, JoinOptions()));
  EXPECT_TRUE(decided.settled.empty());  // its decision waits
  ASSERT_NE(decided.alternative, nullptr);
  EXPECT_EQ(decided.alternative->made_ids.merged.size(), 4u);
  ASSERT_EQ(decided.alternative->versions.size(), 2u);
  // Oracles: the join by id with some of the second map's ids renamed apart: 5 and 8, so that
  // only 3 and 7 pair; then all four, so that nothing pairs.
  const std::vector<std::set<std::int64_t>> renamed_apart = {{5, 8}, {3, 5, 7, 8}};
  const std::vector<std::set<std::pair<std::int64_t, std::int64_t>>> expected_merged = {{{3, 3}, {7, 7}}, {}};
  for (std::size_t v = 0; v < 2; ++v) {
    const JoinAlternative::Version& version = decided.alternative->versions[v];
    GaussianMap renamed = *m2;
    for (std::int64_t& id : renamed.ids()) id = renamed_apart[v].count(id) ? id + 100 : id;
    const GaussianMap oracle = join_maps(*m1, renamed, JoinOptions());
    const GaussianMap& alternative = *version.map;
    ASSERT_EQ(alternative.dim(), oracle.dim());
    EXPECT_TRUE(alternative.x() == oracle.x());
    EXPECT_TRUE(alternative.P() == oracle.P());
    std::vector<std::int64_t> expected_ids = oracle.ids();
    for (std::int64_t& id : expected_ids) id = renamed_apart[v].count(id - 100) ? id - 100 : id;
    EXPECT_EQ(alternative.ids(), expected_ids);
    const std::set<std::pair<std::int64_t, std::int64_t>> merged(version.ids.merged.begin(), version.ids.merged.end());
    EXPECT_EQ(merged, expected_merged[v]);
  }
  // A join too small for the version without any pair keeps the other one only.
  DecidingJoin small(first, second, by_id(), 4, /*spans_many_maps=*/false);
  small.finish();
  EXPECT_EQ(small.report().deferred_pairings, 2);
  const DecidedJoin small_decided = small.take_result(none, 0);
  ASSERT_NE(small_decided.alternative, nullptr);
  ASSERT_EQ(small_decided.alternative->versions.size(), 1u);
  EXPECT_EQ(small_decided.alternative->versions[0].ids.merged.size(), 2u);
}

TEST(DecidingJoin, WhenEveryPairHasAFeatureSeenOnceTheOnlyOtherVersionHasNoPair) {
  std::mt19937_64 rng(6);
  const auto m1 = shared_random_map(rng, {1, 2, 3, 4, 5});
  const auto m2 = shared_random_map(rng, {3, 5, 9});
  const TreeMap first{m1, {TentativeFeature{3, 0, false, false}}, nullptr};
  const TreeMap second{m2, {TentativeFeature{5, 1, false, false}}, nullptr};
  DecidingJoin weak(first, second, by_id(), 30, /*spans_many_maps=*/false);
  weak.finish();
  EXPECT_EQ(weak.report().deferred_pairings, 2);
  DecidedJoin decided = weak.take_result(none, 0);
  ASSERT_NE(decided.alternative, nullptr);
  ASSERT_EQ(decided.alternative->versions.size(), 1u);
  const JoinAlternative::Version& version = decided.alternative->versions[0];
  EXPECT_TRUE(version.ids.merged.empty());
  EXPECT_EQ(version.map->num_features(), 8);
  // A join without any pair stacks the two maps: the oracle renames the second map's ids apart.
  GaussianMap renamed = *m2;
  for (std::int64_t& id : renamed.ids()) id += 100;
  const GaussianMap oracle = join_maps(*m1, renamed, JoinOptions());
  EXPECT_TRUE(version.map->x() == oracle.x());
  EXPECT_TRUE(version.map->P() == oracle.P());
}

}  // namespace
}  // namespace dcslam
