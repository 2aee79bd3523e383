#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/association/rjc.hpp"
#include "dcslam/core/spatial_hash.hpp"
#include "grid_join.hpp"

namespace dcslam {
namespace {

int count_pairings(const std::vector<int>& feature_of) {
  return static_cast<int>(std::count_if(feature_of.begin(), feature_of.end(),
                                        [](int f) { return f != kStar; }));
}

TEST(Rjc, FindsTheTruePairingWhereNearestNeighbourFails) {
  const JoinProblem problem = grid_join(1, 0, 6, 3, 9);
  const std::vector<int> nn = nearest_neighbour(problem.candidates, problem.model, 0.99);
  int nn_wrong = 0;
  for (std::size_t j = 0; j < nn.size(); ++j) {
    nn_wrong += nn[j] != kStar && nn[j] != problem.truth[j];
  }
  EXPECT_GE(nn_wrong, 10);  // the layout is ambiguous for individual compatibility

  const RjcResult result = rjc(problem.candidates, problem.model);
  EXPECT_EQ(result.feature_of, problem.truth);
  EXPECT_EQ(result.pairings, 18);
  EXPECT_EQ(result.dropped, 0);
  EXPECT_GT(result.overlap_size, 18);  // spurious features and grid neighbours are in O
  EXPECT_GE(result.tries, 5);
  EXPECT_LE(result.tries, 9);
  EXPECT_NEAR(result.joint_distance_sq, joint_distance_sq(result.feature_of, problem.model), 1e-8);
}

TEST(Rjc, FindsTheTruePairingForManySeeds) {
  const JoinProblem problem = grid_join(2, 0, 6, 3, 9);
  RjcOptions options;
  options.p_fail = 1e-4;
  for (std::uint64_t seed = 0; seed < 20; ++seed) {
    options.seed = seed;
    EXPECT_EQ(rjc(problem.candidates, problem.model, options).feature_of, problem.truth)
        << "seed " << seed;
  }
}

TEST(Rjc, WithoutVerificationReportsNoJointDistance) {
  const JoinProblem problem = grid_join(9, 0, 6, 3, 9);
  RjcOptions options;
  options.verify = false;
  const RjcResult result = rjc(problem.candidates, problem.model, options);
  EXPECT_EQ(result.feature_of, problem.truth);
  EXPECT_EQ(result.dropped, 0);
  EXPECT_TRUE(std::isnan(result.joint_distance_sq));
}

TEST(Rjc, SameSeedSameResult) {
  const JoinProblem problem = grid_join(3, 0, 6, 3, 9);
  RjcOptions options;
  options.seed = 42;
  const RjcResult a = rjc(problem.candidates, problem.model, options);
  const RjcResult b = rjc(problem.candidates, problem.model, options);
  EXPECT_EQ(a.feature_of, b.feature_of);
  EXPECT_EQ(a.tries, b.tries);
  EXPECT_EQ(a.joint_distance_sq, b.joint_distance_sq);
}

TEST(Rjc, NoOverlapPairsNothing) {
  const JoinProblem problem = grid_join(4, 0, 6, 3, 9, 100.0);
  const RjcResult result = rjc(problem.candidates, problem.model);
  EXPECT_EQ(result.overlap_size, 0);
  EXPECT_EQ(result.pairings, 0);
  EXPECT_EQ(result.tries, 0);
  EXPECT_EQ(count_pairings(result.feature_of), 0);
}

TEST(Rjc, WholeMapOverlapping) {
  const JoinProblem problem = grid_join(5, 0, 6, 0, 6);
  const RjcResult result = rjc(problem.candidates, problem.model);
  EXPECT_EQ(result.feature_of, problem.truth);
  EXPECT_EQ(result.pairings, 36);
}

TEST(Rjc, SmallOverlapRunsPlainJcbb) {
  JoinProblem problem = grid_join(6, 0, 6, 3, 9);
  // Keep the candidates of three true features only.
  for (std::size_t j = 0; j < problem.candidates.size(); ++j) {
    if (j != 0 && j != 7 && j != 14) problem.candidates[j].clear();
  }
  const RjcResult result = rjc(problem.candidates, problem.model);
  const JcbbResult direct = jcbb(problem.candidates, problem.model);
  EXPECT_EQ(result.overlap_size, 3);
  EXPECT_EQ(result.tries, 1);
  EXPECT_EQ(result.feature_of, direct.feature_of);
  EXPECT_EQ(result.pairings, direct.pairings);
}

// RjcSearch spread over many calls (one step each, or a few units of work each) is rjc() at
// once, bitwise: the same draws, tries, pairings and D^2.
TEST(Rjc, ResumedInSlicesGivesBitwiseTheSameResult) {
  const JoinProblem problem = grid_join(7, 0, 6, 3, 9);
  RjcOptions options;
  options.seed = 5;
  const RjcResult at_once = rjc(problem.candidates, problem.model, options);
  ASSERT_GT(at_once.tries, 1);
  for (std::int64_t budget : {1, 7, 300}) {
    RjcSearch search(problem.candidates, problem.model, options);
    int calls = 0;
    while (!search.done()) {
      EXPECT_GT(search.advance(budget), 0);
      ++calls;
    }
    EXPECT_GT(calls, at_once.tries) << "budget " << budget;
    const RjcResult& sliced = search.result();
    EXPECT_EQ(sliced.feature_of, at_once.feature_of);
    EXPECT_EQ(sliced.tries, at_once.tries);
    EXPECT_EQ(sliced.pairings, at_once.pairings);
    EXPECT_EQ(sliced.dropped, at_once.dropped);
    EXPECT_EQ(sliced.joint_distance_sq, at_once.joint_distance_sq);
    EXPECT_EQ(search.remaining_work(), 0);
  }
}

TEST(Rjc, VerificationDropsTheInconsistentPairing) {
  const JoinProblem problem = grid_join(7, 0, 6, 3, 9);
  std::vector<int> feature_of = problem.truth;
  // Pair the second map's spurious feature at cell centre (5.5, 0.5) with grid point (5, 0).
  const std::size_t spurious = feature_of.size() - 1;
  feature_of[spurious] = 5 * 6 + 0;
  ASSERT_GT(joint_distance_sq(feature_of, problem.model), chi2_quantile(2 * 19, 0.99));
  double distance_sq = 0.0;
  EXPECT_EQ(enforce_joint_compatibility(feature_of, problem.model, 0.99, &distance_sq), 1);
  EXPECT_EQ(feature_of, problem.truth);
  EXPECT_NEAR(distance_sq, joint_distance_sq(problem.truth, problem.model), 1e-8);
  // Removal through S^-1 formed a column at a time and S factored in one-column panels: the
  // same decision.
  std::vector<int> sliced = problem.truth;
  sliced[spurious] = 5 * 6 + 0;
  JointCompatibilityEnforcement enforcement(sliced, problem.model, 0.99, 1, 1);
  int steps = 0;
  while (!enforcement.done()) {
    enforcement.advance(1);
    ++steps;
  }
  EXPECT_GT(steps, static_cast<int>(problem.truth.size()));
  EXPECT_EQ(enforcement.removed(), 1);
  EXPECT_EQ(sliced, problem.truth);
  EXPECT_NEAR(enforcement.joint_distance_sq(), distance_sq, 1e-8);
  // A compatible hypothesis is left as it is, with its own D^2.
  EXPECT_EQ(enforce_joint_compatibility(feature_of, problem.model, 0.99, &distance_sq), 0);
  EXPECT_EQ(feature_of, problem.truth);
  EXPECT_NEAR(distance_sq, joint_distance_sq(problem.truth, problem.model), 1e-8);
}

// Each pairing after the seed is kept only if compatible given every pairing kept before it:
// checked against the chain rule, D^2(K + a) - D^2(K) being a's conditional distance given K.
TEST(Rjc, SequentialAcceptanceKeepsThePairingsCompatibleWithAllEarlierOnes) {
  const JoinProblem problem = grid_join(7, 0, 6, 3, 9);
  std::vector<Pairing> order;
  for (std::size_t j = 0; j < problem.truth.size(); ++j) {
    if (problem.truth[j] != kStar) order.push_back(Pairing{static_cast<int>(j), problem.truth[j]});
  }
  // Two wrong pairings among the true ones: a spurious feature of the second map with a grid
  // point nearby, and a true feature with its +y neighbour's partner instead of its own.
  const int spurious = static_cast<int>(problem.truth.size()) - 1;
  order.insert(order.begin() + 6, Pairing{spurious, 5 * 6 + 0});
  const Pairing shifted{order[9].measurement, order[9].feature + 1};
  order[9] = shifted;
  std::vector<int> feature_of(problem.truth.size(), kStar);
  for (const Pairing& pairing : order) feature_of[pairing.measurement] = pairing.feature;

  const double gate = chi2_quantile(2, 0.99);
  std::vector<int> expected(problem.truth.size(), kStar);
  int expected_removed = 0;
  for (std::size_t a = 0; a < order.size(); ++a) {
    std::vector<int> with = expected;
    with[order[a].measurement] = order[a].feature;
    const double conditional = joint_distance_sq(with, problem.model) - joint_distance_sq(expected, problem.model);
    if (a < 4 || conditional <= gate) {
      expected = with;
    } else {
      ++expected_removed;
    }
  }
  std::vector<int> sequential = feature_of;
  SequentialAcceptance acceptance(order, 4, sequential, problem.model, gate);
  acceptance.finish();
  EXPECT_EQ(accept_sequentially(order, 4, feature_of, problem.model, gate), expected_removed);
  EXPECT_EQ(feature_of, expected);
  EXPECT_EQ(sequential, expected);
  // Its factor holds the joint D^2 of what it kept (what RJC's joint test reads from it).
  EXPECT_NEAR(acceptance.joint_distance_sq(), joint_distance_sq(expected, problem.model),
              1e-9 * joint_distance_sq(expected, problem.model));
  // Both wrong pairings go, every true one stays.
  EXPECT_EQ(expected_removed, 2);
  EXPECT_EQ(feature_of[spurious], kStar);
  EXPECT_EQ(feature_of[shifted.measurement], kStar);
}

// The completion's two primitives against the chain rule: a's distance conditioned on all
// the kept pairings is D^2(K + a) - D^2(K); append() keeps a pairing only if it passes the gate.
TEST(Rjc, CompletionTestsAPairingAgainstAllKeptOnes) {
  const JoinProblem problem = grid_join(7, 0, 6, 3, 9);
  std::vector<Pairing> order;
  std::vector<Pairing> left_out;
  for (std::size_t j = 0; j < problem.truth.size(); ++j) {
    if (problem.truth[j] == kStar) continue;
    (j % 5 == 2 ? left_out : order).push_back(Pairing{static_cast<int>(j), problem.truth[j]});
  }
  ASSERT_GE(left_out.size(), 2u);
  std::vector<int> feature_of(problem.truth.size(), kStar);
  for (const Pairing& pairing : order) feature_of[pairing.measurement] = pairing.feature;
  const double gate = chi2_quantile(2, 0.99);
  SequentialAcceptance acceptance(order, 4, feature_of, problem.model, gate);
  acceptance.finish();
  ASSERT_EQ(acceptance.removed(), 0);
  for (const Pairing& pairing : left_out) {
    std::vector<int> with = feature_of;
    with[pairing.measurement] = pairing.feature;
    const double expected = joint_distance_sq(with, problem.model) - joint_distance_sq(feature_of, problem.model);
    EXPECT_NEAR(acceptance.conditional_distance_sq(pairing), expected, 1e-8 * (1.0 + expected));
    ASSERT_LE(expected, gate);
    EXPECT_TRUE(acceptance.append(pairing));
    EXPECT_EQ(feature_of[pairing.measurement], pairing.feature);
    EXPECT_NEAR(acceptance.joint_distance_sq(), joint_distance_sq(feature_of, problem.model),
                1e-8 * joint_distance_sq(feature_of, problem.model));
  }
  EXPECT_EQ(acceptance.kept(), static_cast<int>(order.size() + left_out.size()));
  // A spurious feature of the second map paired with a grid point: refused, nothing changes.
  const int spurious = static_cast<int>(problem.truth.size()) - 1;
  std::vector<int> with = feature_of;
  with[spurious] = 5 * 6 + 0;
  ASSERT_GT(joint_distance_sq(with, problem.model) - joint_distance_sq(feature_of, problem.model), gate);
  const std::vector<int> before = feature_of;
  EXPECT_FALSE(acceptance.append(Pairing{spurious, 5 * 6 + 0}));
  EXPECT_EQ(feature_of, before);
}

// On other draws of the grid, with the completion: no wrong pairing, most true ones found,
// the result jointly compatible and its D^2 the one recomputed from scratch.
TEST(Rjc, WithTheCompletionEveryPairingIsTrueAndTheResultJointlyCompatible) {
  int found = 0, true_pairs = 0;
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    const JoinProblem problem = grid_join(seed, 0, 6, 3, 9);
    RjcOptions options;
    options.seed = seed;
    const RjcResult result = rjc(problem.candidates, problem.model, options);
    for (std::size_t j = 0; j < result.feature_of.size(); ++j) {
      if (result.feature_of[j] != kStar) {
        EXPECT_EQ(result.feature_of[j], problem.truth[j]) << "seed " << seed;
      }
    }
    found += result.pairings;
    true_pairs += count_pairings(problem.truth);
    EXPECT_EQ(result.pairings, count_pairings(result.feature_of));
    EXPECT_LE(result.joint_distance_sq, chi2_quantile(2 * result.pairings, 0.99));
    EXPECT_NEAR(result.joint_distance_sq, joint_distance_sq(result.feature_of, problem.model),
                1e-8 * (1.0 + result.joint_distance_sq));
  }
  EXPECT_GE(found, true_pairs * 9 / 10);
}

// Constellation tries (RjcOptions.positions, the second map's features where its map puts
// them): a second map of 8 columns of which only 2 overlap the first. Every pairing returned
// is true, on every seed, and the tries include the constellation phase where the uniform
// tries verified under half of the overlap.
TEST(Rjc, WithPositionsEveryPairingIsTrue) {
  int constellation_runs = 0;
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    const JoinProblem problem = grid_join(seed, 0, 6, 4, 12);
    auto positions = std::make_shared<std::vector<Vec2>>();
    const int n1 = problem.model.first_size;
    for (std::size_t j = 0; j < problem.truth.size(); ++j) {
      positions->push_back(problem.model.x.segment<2>(2 * (n1 + static_cast<int>(j))));
    }
    RjcOptions options;
    options.seed = seed;
    options.positions = positions;
    const RjcResult result = rjc(problem.candidates, problem.model, options);
    for (std::size_t j = 0; j < result.feature_of.size(); ++j) {
      if (result.feature_of[j] != kStar) {
        EXPECT_EQ(result.feature_of[j], problem.truth[j]) << "seed " << seed;
      }
    }
    EXPECT_GT(result.pairings, 0) << "seed " << seed;
    constellation_runs += result.tries > 9 ? 1 : 0;
  }
  EXPECT_GT(constellation_runs, 0);
}

TEST(Rjc, RejectsBadOptions) {
  const JoinProblem problem = grid_join(8, 0, 6, 3, 9);
  RjcOptions options;
  options.b = 0;
  EXPECT_THROW(rjc(problem.candidates, problem.model, options), InvalidArgument);
  options = RjcOptions();
  options.p_good = 1.0;
  EXPECT_THROW(rjc(problem.candidates, problem.model, options), InvalidArgument);
}

}  // namespace
}  // namespace dcslam
