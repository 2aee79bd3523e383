// Chunked JCBB (chunked_jcbb.hpp) and the model it conditions (conditioned_model.hpp), against
// oracles computed densely: the Schur complement of the stacked hypothesis, the chain rule of
// the joint distance, plain JCBB on one chunk, and the truth of the grid join.
#include <algorithm>
#include <limits>
#include <vector>

#include <Eigen/Cholesky>
#include <gtest/gtest.h>

#include "dcslam/association/chunked_jcbb.hpp"
#include "dcslam/association/conditioned_model.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "grid_join.hpp"

namespace dcslam {
namespace {

std::vector<Pairing> true_pairings(const JoinProblem& problem) {
  std::vector<Pairing> pairings;
  for (std::size_t j = 0; j < problem.truth.size(); ++j) {
    if (problem.truth[j] != kStar) pairings.push_back(Pairing{static_cast<int>(j), problem.truth[j]});
  }
  return pairings;
}

// D^2 of pairings given as feature_of (the stacked hypothesis, O(k^3)), or +inf.
double dense_distance_sq(const std::vector<Pairing>& pairings, int measurements, const PairingModel& model) {
  std::vector<int> feature_of(static_cast<std::size_t>(measurements), kStar);
  for (const Pairing& p : pairings) feature_of[static_cast<std::size_t>(p.measurement)] = p.feature;
  return joint_distance_sq(feature_of, model);
}

TEST(ConditionedPairingModel, IsTheSchurComplementOfTheStackedHypothesis) {
  const JoinProblem problem = grid_join(3, 0, 6, 3, 9);
  const std::vector<Pairing> truth = true_pairings(problem);
  ASSERT_GE(truth.size(), 12u);
  const std::vector<Pairing> kept(truth.begin(), truth.begin() + 8);
  ConditionedPairingModel conditioned(problem.model);
  for (const Pairing& p : kept) ASSERT_TRUE(conditioned.keep_if_within(p, std::numeric_limits<double>::infinity()));
  ASSERT_EQ(conditioned.kept(), 8);
  const Eigen::Index k = 2 * static_cast<Eigen::Index>(kept.size());
  Eigen::MatrixXd s(k, k);
  Eigen::VectorXd nu(k);
  for (std::size_t a = 0; a < kept.size(); ++a) {
    nu.segment<2>(2 * static_cast<Eigen::Index>(a)) = problem.model.innovation(kept[a]);
    for (std::size_t b = 0; b < kept.size(); ++b) {
      s.block<2, 2>(2 * static_cast<Eigen::Index>(a), 2 * static_cast<Eigen::Index>(b)) =
          problem.model.covariance(kept[a], kept[b]);
    }
  }
  const Eigen::LDLT<Eigen::MatrixXd> s_factor(s);
  EXPECT_NEAR(conditioned.joint_distance_sq(), nu.dot(s_factor.solve(nu)), 1e-9);
  const auto cross = [&](const Pairing& a) {
    Eigen::MatrixXd c(k, 2);
    for (std::size_t m = 0; m < kept.size(); ++m) c.middleRows<2>(2 * static_cast<Eigen::Index>(m)) = problem.model.covariance(kept[m], a);
    return c;
  };
  // Pairings of other measurements, true and wrong, each conditioned and against each other.
  std::vector<Pairing> others(truth.begin() + 8, truth.end());
  others.push_back(Pairing{truth[9].measurement, truth[10].feature});
  for (const Pairing& a : others) {
    const Eigen::MatrixXd c_a = cross(a);
    const Vec2 expected_nu = problem.model.innovation(a) - c_a.transpose() * s_factor.solve(nu);
    EXPECT_LT((conditioned.innovation(a) - expected_nu).norm(), 1e-9);
    for (const Pairing& b : others) {
      if (b.measurement == a.measurement && b.feature != a.feature) continue;
      const Mat2 expected = problem.model.covariance(a, b) - c_a.transpose() * s_factor.solve(cross(b));
      EXPECT_LT((conditioned.covariance(a, b) - expected).norm(), 1e-9 * (1.0 + expected.norm()));
    }
  }
  // The chain rule: a's distance given K is D^2(K + a) - D^2(K).
  const int measurements = static_cast<int>(problem.truth.size());
  for (const Pairing& a : others) {
    std::vector<Pairing> with_a = kept;
    with_a.push_back(a);
    const double expected = dense_distance_sq(with_a, measurements, problem.model) -
                            dense_distance_sq(kept, measurements, problem.model);
    EXPECT_NEAR(individual_distance_sq(conditioned, a), expected, 1e-7 * (1.0 + expected));
    EXPECT_NEAR(conditioned.conditional_distance_sq(a), expected, 1e-7 * (1.0 + expected));
  }
}

// prepare() solves for several pairings at once what each would solve alone: the same values,
// whether none, some or all of them were cached before, and nothing to do with none kept.
TEST(ConditionedPairingModel, PreparedPairingsAreConditionedAsOneByOne) {
  const JoinProblem problem = grid_join(3, 0, 6, 3, 9);
  const std::vector<Pairing> truth = true_pairings(problem);
  ASSERT_GE(truth.size(), 14u);
  std::vector<Pairing> others(truth.begin() + 8, truth.end());
  others.push_back(Pairing{truth[9].measurement, truth[10].feature});
  ConditionedPairingModel one_by_one(problem.model);
  ConditionedPairingModel prepared(problem.model);
  prepared.prepare(others);  // nothing kept yet: the base model's values
  for (const Pairing& a : others) EXPECT_EQ(prepared.innovation(a), problem.model.innovation(a));
  for (std::size_t k = 0; k < 8; ++k) {
    ASSERT_TRUE(one_by_one.keep_if_within(truth[k], std::numeric_limits<double>::infinity()));
    ASSERT_TRUE(prepared.keep_if_within(truth[k], std::numeric_limits<double>::infinity()));
  }
  (void)prepared.innovation(others[1]);  // one of them cached alone first
  prepared.prepare(others);
  prepared.prepare(others);  // all cached: nothing to do
  for (const Pairing& a : others) {
    const Vec2 expected_nu = one_by_one.innovation(a);
    EXPECT_LE((prepared.innovation(a) - expected_nu).norm(), 1e-12 * (1.0 + expected_nu.norm()));
    for (const Pairing& b : others) {
      const Mat2 expected = one_by_one.covariance(a, b);
      EXPECT_LE((prepared.covariance(a, b) - expected).norm(), 1e-12 * (1.0 + expected.norm()));
    }
    EXPECT_NEAR(individual_distance_sq(prepared, a), individual_distance_sq(one_by_one, a), 1e-10);
  }
}

// keep_each_within() decides as keep_if_within() one by one and leaves the same factor: panels
// with nothing kept yet and with many kept, seeds (an infinite gate), wrong pairings first,
// inside and last in a panel, and a panel of which nothing is kept.
TEST(ConditionedPairingModel, KeepEachWithinIsKeepIfWithinOneByOne) {
  const JoinProblem problem = grid_join(11, 0, 10, 0, 10);
  std::vector<Pairing> order = true_pairings(problem);
  ASSERT_GE(order.size(), 60u);
  const int spurious = static_cast<int>(problem.truth.size()) - 1;
  std::vector<double> gates(order.size(), chi2_quantile(2, 0.99));
  std::fill(gates.begin(), gates.begin() + 3, std::numeric_limits<double>::infinity());
  for (std::size_t at : {9u, 16u, 31u, 40u, 41u, 42u, 52u}) {
    order[at].feature = (order[at].feature + 7) % (problem.model.first_size - 2);  // a wrong feature
  }
  order.insert(order.begin() + 12, Pairing{spurious, 5 * 6 + 0});
  gates.insert(gates.begin() + 12, chi2_quantile(2, 0.99));
  const std::vector<std::size_t> panel_ends{3, 9, 10, 17, 40, 43, 53, order.size()};

  ConditionedPairingModel one_by_one(problem.model);
  std::vector<char> expected(order.size());
  for (std::size_t a = 0; a < order.size(); ++a) expected[a] = one_by_one.keep_if_within(order[a], gates[a]);
  ConditionedPairingModel in_panels(problem.model);
  std::vector<char> decided;
  std::size_t begin = 0;
  int rejected_panels = 0;
  for (std::size_t end : panel_ends) {
    const std::vector<Pairing> panel(order.begin() + begin, order.begin() + end);
    const std::vector<double> panel_gates(gates.begin() + begin, gates.begin() + end);
    std::vector<char> kept;
    ASSERT_EQ(in_panels.keep_each_within(panel, panel_gates, std::numeric_limits<int>::max(), kept), panel.size());
    ASSERT_EQ(kept.size(), panel.size());
    rejected_panels += std::count(kept.begin(), kept.end(), 0) > 0;
    decided.insert(decided.end(), kept.begin(), kept.end());
    begin = end;
  }
  EXPECT_EQ(decided, expected);
  EXPECT_GE(std::count(expected.begin(), expected.end(), 0), 6);
  EXPECT_GE(rejected_panels, 4);
  ASSERT_EQ(in_panels.kept(), one_by_one.kept());
  EXPECT_NEAR(in_panels.joint_distance_sq(), one_by_one.joint_distance_sq(), 1e-9 * one_by_one.joint_distance_sq());
  // The factor both left: every rejected pairing's distance conditioned on all kept ones.
  for (std::size_t a = 0; a < order.size(); ++a) {
    if (expected[a]) continue;
    const double distance = one_by_one.conditional_distance_sq(order[a]);
    EXPECT_NEAR(in_panels.conditional_distance_sq(order[a]), distance, 1e-9 * (1.0 + distance));
  }
  // Told to stop at the second refusal, a panel tests up to that one and keeps what it kept
  // before it.
  ConditionedPairingModel stopped(problem.model);
  std::vector<char> kept;
  const std::size_t tested = stopped.keep_each_within(order, gates, 2, kept);
  std::size_t second_refusal = 0;
  for (int refusals = 0; refusals < 2; ++second_refusal) refusals += expected[second_refusal] == 0;
  ASSERT_EQ(tested, second_refusal);
  EXPECT_EQ(kept, std::vector<char>(expected.begin(), expected.begin() + static_cast<std::ptrdiff_t>(tested)));
  EXPECT_EQ(stopped.kept(), std::count(kept.begin(), kept.end(), 1));
}

ChunkedJcbbResult run_chunked(const JoinProblem& problem, const ChunkedJcbbOptions& options) {
  const int features = static_cast<int>(problem.model.first_size);
  ChunkedJcbb chunked(problem.candidates, problem.model, features, options);
  chunked.finish();
  return chunked.result();
}

TEST(ChunkedJcbb, OneChunkIsJcbb) {
  for (std::uint64_t seed : {1, 2, 3}) {
    const JoinProblem problem = grid_join(seed, 0, 6, 3, 9);
    // A bound no search here reaches: a search cut short depends on how many nodes the lists
    // of measurements without candidates cost, which one chunk leaves out.
    ChunkedJcbbOptions options;
    options.chunk_size = static_cast<int>(problem.candidates.size());
    options.candidate_gate = std::numeric_limits<double>::infinity();
    options.max_nodes = 10000000;
    JcbbOptions jcbb_options;
    jcbb_options.confidence = options.confidence;
    jcbb_options.max_nodes = options.max_nodes;
    const JcbbResult expected = jcbb(problem.candidates, problem.model, jcbb_options);
    ASSERT_FALSE(expected.bound_hit);
    const ChunkedJcbbResult result = run_chunked(problem, options);
    EXPECT_EQ(result.feature_of, expected.feature_of) << "seed " << seed;
    EXPECT_EQ(result.feature_of, problem.truth);
    EXPECT_EQ(result.pairings, expected.pairings);
    EXPECT_EQ(result.chunks, 1);
    EXPECT_EQ(result.bound_hits, 0);
  }
}

// Chunks of one measurement: each takes its nearest unused candidate conditioned on every
// pairing before it, if that passes both the candidate gate and the 2-dof decision gate. The
// oracle computes each conditional distance by the chain rule on dense stacked hypotheses.
TEST(ChunkedJcbb, ChunksOfOneAreNearestNeighbourConditionedOnTheEarlierPairings) {
  for (std::uint64_t seed : {4, 5}) {
    const JoinProblem problem = grid_join(seed, 0, 6, 3, 9);
    ChunkedJcbbOptions options;
    options.chunk_size = 1;
    options.candidate_gate = chi2_quantile(2, 0.999);
    const double gate = std::min(options.candidate_gate, chi2_quantile(2, options.confidence));
    const int measurements = static_cast<int>(problem.candidates.size());
    std::vector<Pairing> kept;
    std::vector<int> expected(problem.candidates.size(), kStar);
    std::vector<char> used(static_cast<std::size_t>(problem.model.first_size), 0);
    for (int j = 0; j < measurements; ++j) {
      const double before = dense_distance_sq(kept, measurements, problem.model);
      double best = gate;
      int best_feature = kStar;
      for (int i : problem.candidates[static_cast<std::size_t>(j)]) {
        if (used[static_cast<std::size_t>(i)]) continue;
        std::vector<Pairing> with = kept;
        with.push_back(Pairing{j, i});
        const double distance_sq = dense_distance_sq(with, measurements, problem.model) - before;
        if (distance_sq <= best) {
          best = distance_sq;
          best_feature = i;
        }
      }
      if (best_feature == kStar) continue;
      kept.push_back(Pairing{j, best_feature});
      used[static_cast<std::size_t>(best_feature)] = 1;
      expected[static_cast<std::size_t>(j)] = best_feature;
    }
    const ChunkedJcbbResult result = run_chunked(problem, options);
    EXPECT_EQ(result.feature_of, expected) << "seed " << seed;
    EXPECT_EQ(result.pairings, static_cast<int>(kept.size()));
  }
}

TEST(ChunkedJcbb, ResumedInSlicesGivesTheSameResult) {
  const JoinProblem problem = grid_join(2, 0, 6, 3, 9);
  ChunkedJcbbOptions options;
  options.chunk_size = 5;
  options.candidate_gate = chi2_quantile(2, 0.999);
  const ChunkedJcbbResult whole = run_chunked(problem, options);
  ChunkedJcbb sliced(problem.candidates, problem.model, problem.model.first_size, options);
  int steps = 0;
  std::int64_t previous_estimate = sliced.remaining_work();
  EXPECT_GT(previous_estimate, 0);
  while (!sliced.done()) {
    EXPECT_GT(sliced.advance(1), 0);
    ++steps;
  }
  EXPECT_EQ(sliced.remaining_work(), 0);
  EXPECT_GT(steps, static_cast<int>(problem.candidates.size()));
  EXPECT_EQ(sliced.result().feature_of, whole.feature_of);
  EXPECT_EQ(sliced.result().chunks, whole.chunks);
}

// A chunk's JCBB runs over several steps when its search exceeds the work unit, so that an
// amortized join's step stays short; the result is the same as with the search in one step.
TEST(ChunkedJcbb, AChunksSearchIsSlicedByTheWorkUnit) {
  const JoinProblem problem = grid_join(2, 0, 6, 3, 9);
  ChunkedJcbbOptions options;
  options.chunk_size = 8;
  options.candidate_gate = chi2_quantile(2, 0.999);
  const auto count_steps = [&](std::int64_t work_unit, ChunkedJcbbResult& result) {
    options.work_unit = work_unit;
    ChunkedJcbb chunked(problem.candidates, problem.model, problem.model.first_size, options);
    int steps = 0;
    while (!chunked.done()) {
      chunked.advance(1);
      ++steps;
    }
    result = chunked.result();
    return steps;
  };
  ChunkedJcbbResult coarse, fine;
  const int coarse_steps = count_steps(std::int64_t{1} << 40, coarse);
  const int fine_steps = count_steps(1, fine);
  ASSERT_GT(coarse.chunks, 0);
  EXPECT_GT(fine_steps, coarse_steps + coarse.chunks);
  EXPECT_EQ(fine.feature_of, coarse.feature_of);
  EXPECT_EQ(fine.pairings, coarse.pairings);
  EXPECT_EQ(fine.chunks, coarse.chunks);
}

// to_beat only stops a search that can no longer pair more: one that ends above it runs as
// without it, one that cannot reach it stops early.
TEST(ChunkedJcbb, StopsOnlyWhereItCanNoLongerBeatTheOtherHypothesis) {
  for (std::uint64_t seed : {2, 4}) {
    const JoinProblem problem = grid_join(seed, 0, 6, 3, 9);
    ChunkedJcbbOptions options;
    options.chunk_size = 4;
    options.candidate_gate = chi2_quantile(2, 0.999);
    const ChunkedJcbbResult full = run_chunked(problem, options);
    ASSERT_GT(full.pairings, 4);
    options.to_beat = full.pairings - 1;
    const ChunkedJcbbResult beaten = run_chunked(problem, options);
    EXPECT_FALSE(beaten.abandoned);
    EXPECT_EQ(beaten.feature_of, full.feature_of);
    options.to_beat = full.pairings;
    const ChunkedJcbbResult tied = run_chunked(problem, options);
    EXPECT_LE(tied.pairings, full.pairings);
    EXPECT_LE(tied.chunks, full.chunks);
    options.to_beat = static_cast<int>(problem.candidates.size());  // more than the overlap
    const ChunkedJcbbResult hopeless = run_chunked(problem, options);
    EXPECT_TRUE(hopeless.abandoned);
    EXPECT_EQ(hopeless.chunks, 0);
  }
}

TEST(ChunkedJcbb, RejectsAnEmptyChunk) {
  const JoinProblem problem = grid_join(2, 0, 6, 3, 9);
  ChunkedJcbbOptions options;
  options.chunk_size = 0;
  EXPECT_THROW(ChunkedJcbb(problem.candidates, problem.model, problem.model.first_size, options), InvalidArgument);
}

}  // namespace
}  // namespace dcslam
