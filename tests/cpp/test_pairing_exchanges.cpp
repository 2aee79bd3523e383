#include <algorithm>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "dcslam/association/jcbb.hpp"
#include "dcslam/association/pairing_exchanges.hpp"

namespace dcslam {
namespace {

using Scored = std::vector<std::tuple<double, int, int>>;

double distance_of(const Scored& scored, int measurement, int feature) {
  for (const auto& [d, m, f] : scored) {
    if (m == measurement && f == feature) return d;
  }
  return -1.0;  // not a candidate
}

double sum_of(const Scored& scored, const std::vector<int>& movable, const std::vector<int>& feature_of) {
  double sum = 0.0;
  for (int m : movable) sum += distance_of(scored, m, feature_of[static_cast<std::size_t>(m)]);
  return sum;
}

// Greedy by distance, each feature once: what an RJC try does before the exchanges.
std::vector<int> greedy(const Scored& scored, int measurements, std::vector<int>& paired) {
  std::vector<int> feature_of(static_cast<std::size_t>(measurements), kStar);
  std::set<int> used;
  for (const auto& [d, m, f] : scored) {
    if (feature_of[static_cast<std::size_t>(m)] != kStar || used.count(f) != 0) continue;
    feature_of[static_cast<std::size_t>(m)] = f;
    used.insert(f);
    paired.push_back(m);
  }
  return feature_of;
}

// Two landmarks 0.1 m apart, each a feature in both maps: the nearest single pair (m1, f0)
// takes the feature m0 needed, and m1 is left with f1 far off. The exchange gives each
// measurement its own feature.
TEST(PairingExchanges, UndoesTheCrossingOfTwoCloseLandmarks) {
  Scored scored{{0.1, 1, 0}, {0.3, 0, 0}, {0.4, 1, 1}, {3.0, 0, 1}};
  std::vector<int> paired;
  std::vector<int> feature_of = greedy(scored, 2, paired);
  ASSERT_EQ(feature_of, (std::vector<int>{1, 0}));
  exchange_crossed_pairings(scored, paired, feature_of);
  EXPECT_EQ(feature_of, (std::vector<int>{0, 1}));
  EXPECT_DOUBLE_EQ(sum_of(scored, paired, feature_of), 0.7);
}

// The exchange needs both crossed pairs to be candidates: without (m0, f1) nothing moves.
TEST(PairingExchanges, ExchangesOnlyIntoCandidatePairs) {
  Scored scored{{0.1, 1, 0}, {0.3, 0, 0}, {0.4, 1, 1}};
  std::vector<int> feature_of{0, 1};  // what a try may hold when m0 came first
  const std::vector<int> before = feature_of;
  exchange_crossed_pairings(scored, {0, 1}, feature_of);
  EXPECT_EQ(feature_of, before);
}

// Random candidate lists against a brute force over every two pairings: afterwards no
// exchange of two movable pairings lowers their sum, the paired measurements and the used
// features are those of the start, every pairing is a candidate, and the sum did not rise.
// Measurements outside `movable` keep their features.
TEST(PairingExchanges, LeavesNoImprovingExchangeOnRandomLists) {
  std::mt19937_64 rng(7);
  int exchanged_runs = 0;
  for (int run = 0; run < 300; ++run) {
    const int measurements = 3 + static_cast<int>(rng() % 10);
    const int features = measurements + static_cast<int>(rng() % 4);
    std::uniform_real_distribution<double> distance(0.0, 9.0);
    Scored scored;
    for (int m = 0; m < measurements; ++m) {
      for (int f = 0; f < features; ++f) {
        if (rng() % 3 == 0) scored.emplace_back(distance(rng), m, f);
      }
    }
    std::sort(scored.begin(), scored.end());
    std::vector<int> paired;
    std::vector<int> feature_of = greedy(scored, measurements, paired);
    // The first paired measurement stands for the seed: paired, but not movable.
    if (paired.empty()) continue;
    const std::vector<int> movable(paired.begin() + 1, paired.end());
    const std::vector<int> start = feature_of;
    exchange_crossed_pairings(scored, movable, feature_of, 1000);
    exchanged_runs += feature_of != start;
    EXPECT_EQ(feature_of[static_cast<std::size_t>(paired[0])], start[static_cast<std::size_t>(paired[0])]);
    std::multiset<int> used_before, used_after;
    for (int m = 0; m < measurements; ++m) {
      EXPECT_EQ(feature_of[static_cast<std::size_t>(m)] == kStar, start[static_cast<std::size_t>(m)] == kStar);
      if (start[static_cast<std::size_t>(m)] != kStar) used_before.insert(start[static_cast<std::size_t>(m)]);
      if (feature_of[static_cast<std::size_t>(m)] != kStar) used_after.insert(feature_of[static_cast<std::size_t>(m)]);
    }
    EXPECT_EQ(used_after, used_before);
    for (int m : movable) EXPECT_GE(distance_of(scored, m, feature_of[static_cast<std::size_t>(m)]), 0.0);
    EXPECT_LE(sum_of(scored, movable, feature_of), sum_of(scored, movable, start) + 1e-12);
    for (int a : movable) {
      for (int b : movable) {
        if (a >= b) continue;
        const int fa = feature_of[static_cast<std::size_t>(a)], fb = feature_of[static_cast<std::size_t>(b)];
        const double ab = distance_of(scored, a, fb), ba = distance_of(scored, b, fa);
        if (ab < 0.0 || ba < 0.0) continue;
        EXPECT_GE(ab + ba, distance_of(scored, a, fa) + distance_of(scored, b, fb)) << "run " << run;
      }
    }
  }
  EXPECT_GT(exchanged_runs, 20);  // the lists do cross
}

}  // namespace
}  // namespace dcslam
