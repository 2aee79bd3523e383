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

// A tree map holding `made` with an alternative version `alternative` (its ids as a join
// would have recorded them: `merged` pairs for each version).
TreeMap with_alternative(std::shared_ptr<const GaussianMap> made, std::size_t made_pairs,
                         std::shared_ptr<const GaussianMap> alternative, std::size_t alternative_pairs) {
  auto alt = std::make_shared<JoinAlternative>();
  alt->made_ids.merged.assign(made_pairs, {1000, 1001});
  alt->map = std::move(alternative);
  alt->ids.merged.assign(alternative_pairs, {2000, 2001});
  return TreeMap{std::move(made), {}, std::move(alt)};
}

TEST(DecidingJoin, WithoutAlternativesItIsThePlainJoinInAnySlices) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 6; ++trial) {
    const auto m1 = shared_random_map(rng, some_ids(rng, 12, 30));
    const auto m2 = shared_random_map(rng, some_ids(rng, 10, 30));
    JoinOptions options;
    options.block_columns = 4;
    const GaussianMap plain = join_maps(*m1, *m2, options);
    DecidingJoin join(TreeMap{m1, {}, nullptr}, TreeMap{m2, {}, nullptr}, by_id(4), 0);
    std::uniform_int_distribution<std::int64_t> budget(1, 400);
    while (!join.done()) join.advance(budget(rng));
    EXPECT_FALSE(join.took_first_alternative() || join.took_second_alternative());
    DecidedJoin decided = join.take_result(none);
    expect_bitwise(*decided.map, plain);
    EXPECT_EQ(decided.alternative, nullptr);
    ASSERT_EQ(decided.settled.size(), 1u);  // its own ids, recorded at once
  }
}

TEST(DecidingJoin, TakesTheCombinationWithTheMostPairsInAll) {
  std::mt19937_64 rng(11);
  int took_an_alternative = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const auto first_made = shared_random_map(rng, some_ids(rng, 10, 24));
    const auto first_alt = shared_random_map(rng, some_ids(rng, 11, 24));
    const auto second_made = shared_random_map(rng, some_ids(rng, 9, 24));
    const auto second_alt = shared_random_map(rng, some_ids(rng, 10, 24));
    std::uniform_int_distribution<std::size_t> pairs(0, 6);
    const std::size_t pairs_first_made = pairs(rng), pairs_first_alt = pairs(rng);
    const std::size_t pairs_second_made = pairs(rng), pairs_second_alt = pairs(rng);
    const TreeMap first = with_alternative(first_made, pairs_first_made, first_alt, pairs_first_alt);
    const TreeMap second = with_alternative(second_made, pairs_second_made, second_alt, pairs_second_alt);
    // Brute force, the versions as made first and a tie keeping the earlier combination.
    std::size_t best_total = 0;
    bool best_first = false, best_second = false, any = false;
    for (const bool a : {false, true}) {
      for (const bool b : {false, true}) {
        const std::size_t total = shared_ids(a ? *first_alt : *first_made, b ? *second_alt : *second_made) +
                                  (a ? pairs_first_alt : pairs_first_made) + (b ? pairs_second_alt : pairs_second_made);
        if (!any || total > best_total) {
          best_total = total;
          best_first = a;
          best_second = b;
          any = true;
        }
      }
    }
    DecidingJoin join(first, second, by_id(), 0);
    join.finish();
    EXPECT_EQ(join.took_first_alternative(), best_first) << "trial " << trial;
    EXPECT_EQ(join.took_second_alternative(), best_second) << "trial " << trial;
    EXPECT_EQ(join.report().alternatives_taken, (best_first ? 1 : 0) + (best_second ? 1 : 0));
    took_an_alternative += best_first || best_second ? 1 : 0;
    DecidedJoin decided = join.take_result(none);
    expect_bitwise(*decided.map, join_maps(best_first ? *first_alt : *first_made,
                                           best_second ? *second_alt : *second_made, JoinOptions()));
    // The ids of both inputs' chosen versions, then its own.
    ASSERT_EQ(decided.settled.size(), 3u);
    EXPECT_EQ(decided.settled[0].merged.size(), best_first ? pairs_first_alt : pairs_first_made);
    EXPECT_EQ(decided.settled[1].merged.size(), best_second ? pairs_second_alt : pairs_second_made);
  }
  EXPECT_GT(took_an_alternative, 5);  // the cases are not all decided one way
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

  DecidingJoin strong(first, second, by_id(), 3);  // 4 pairs: more than 3, not weak
  strong.finish();
  EXPECT_EQ(strong.take_result(none).alternative, nullptr);

  DecidingJoin weak(first, second, by_id(), 4);
  weak.finish();
  EXPECT_EQ(weak.report().deferred_pairings, 2);
  DecidedJoin decided = weak.take_result(none);
  expect_bitwise(*decided.map, join_maps(*m1, *m2, JoinOptions()));
  EXPECT_TRUE(decided.settled.empty());  // its decision waits
  ASSERT_NE(decided.alternative, nullptr);
  EXPECT_EQ(decided.alternative->made_ids.merged.size(), 4u);
  // Oracle: the join by id with the second map's 5 and 8 renamed, so that only 3 and 7 pair.
  GaussianMap renamed = *m2;
  for (std::int64_t& id : renamed.ids()) id = id == 5 ? 105 : id == 8 ? 108 : id;
  const GaussianMap oracle = join_maps(*m1, renamed, JoinOptions());
  const GaussianMap& alternative = *decided.alternative->map;
  ASSERT_EQ(alternative.dim(), oracle.dim());
  EXPECT_TRUE(alternative.x() == oracle.x());
  EXPECT_TRUE(alternative.P() == oracle.P());
  std::vector<std::int64_t> expected_ids = oracle.ids();
  for (std::int64_t& id : expected_ids) id = id == 105 ? 5 : id == 108 ? 8 : id;
  EXPECT_EQ(alternative.ids(), expected_ids);
  const std::set<std::pair<std::int64_t, std::int64_t>> merged(decided.alternative->ids.merged.begin(),
                                                               decided.alternative->ids.merged.end());
  EXPECT_EQ(merged, (std::set<std::pair<std::int64_t, std::int64_t>>{{3, 3}, {7, 7}}));
}

}  // namespace
}  // namespace dcslam
