#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <gtest/gtest.h>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/jcbb.hpp"
#include "admissible_hypotheses.hpp"

namespace dcslam {
namespace {

using testing::direct_distance_sq;
using testing::direct_log_likelihood_ratio;

// A linear-Gaussian scan: state x = [t (2); f_0 (2); ...] with estimate 0 and covariance P,
// measurement i observes A_i (f_j - t) with noise R_i. The true state is a draw from N(0, P),
// so correct pairings are compatible and nearby features are ambiguous.
class LinearScanModel : public PairingModel {
 public:
  Eigen::MatrixXd P;
  std::vector<Vec2> feature_mean;
  std::vector<Mat2> A;
  std::vector<Mat2> R;
  std::vector<Vec2> z;

  Vec2 innovation(const Pairing& p) const override {
    return z[p.measurement] - A[p.measurement] * feature_mean[p.feature];
  }
  Mat2 covariance(const Pairing& a, const Pairing& b) const override {
    const Eigen::Index fa = 2 + 2 * a.feature, fb = 2 + 2 * b.feature;
    const Mat2 relative = block(fa, fb) - block(fa, 0) - block(0, fb) + block(0, 0);
    Mat2 c = A[a.measurement] * relative * A[b.measurement].transpose();
    if (a.measurement == b.measurement) c += R[a.measurement];
    return c;
  }

 private:
  Mat2 block(Eigen::Index row, Eigen::Index col) const { return P.block<2, 2>(row, col); }
};

struct Problem {
  LinearScanModel model;
  CandidateLists candidates;
};

Problem random_problem(std::mt19937_64& rng, int max_measurements) {
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  Problem problem;
  LinearScanModel& model = problem.model;
  const int n = 3 + static_cast<int>(uniform(rng) * 5);
  const Eigen::Index dim = 2 + 2 * n;
  Eigen::MatrixXd factor(dim, dim);
  for (Eigen::Index i = 0; i < dim; ++i) {
    for (Eigen::Index j = 0; j < dim; ++j) factor(i, j) = normal(rng);
  }
  // Random correlations and sparse structure: some state entries barely uncertain.
  for (Eigen::Index i = 0; i < dim; ++i) factor.row(i) *= (uniform(rng) < 0.2 ? 0.05 : 0.2);
  model.P = factor * factor.transpose() + 0.001 * Eigen::MatrixXd::Identity(dim, dim);
  const Eigen::VectorXd truth = model.P.llt().matrixL() * Eigen::VectorXd::NullaryExpr(
                                                              dim, [&]() { return normal(rng); });
  for (int j = 0; j < n; ++j) {
    model.feature_mean.emplace_back(2.0 * uniform(rng), 2.0 * uniform(rng));
  }

  const int m = 1 + static_cast<int>(uniform(rng) * max_measurements);
  std::vector<int> features(n);
  for (int j = 0; j < n; ++j) features[j] = j;
  std::shuffle(features.begin(), features.end(), rng);
  for (int i = 0; i < m; ++i) {
    const double angle = 0.3 * normal(rng);
    Mat2 a;
    a << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
    model.A.push_back(a * (1.0 + 0.2 * normal(rng)));
    const double sigma = 0.02 + 0.1 * uniform(rng);
    model.R.push_back(sigma * sigma * Mat2::Identity());
    const Vec2 noise(sigma * normal(rng), sigma * normal(rng));
    const bool spurious = i >= n || uniform(rng) < 0.15;
    if (spurious) {
      model.z.push_back(Vec2(2.0 * uniform(rng), 2.0 * uniform(rng)));
    } else {
      const int j = features[i];
      const Vec2 f = model.feature_mean[j] + truth.segment<2>(2 + 2 * j) - truth.head<2>();
      model.z.push_back(model.A.back() * f + noise);
    }
    std::vector<int> list;
    for (int j = 0; j < n; ++j) {
      if (uniform(rng) < 0.45 || (!spurious && j == features[i] && uniform(rng) < 0.9)) {
        list.push_back(j);
      }
    }
    std::shuffle(list.begin(), list.end(), rng);
    list.resize(std::min<std::size_t>(list.size(), 3));
    problem.candidates.push_back(list);
  }
  return problem;
}

struct Exhaustive {
  int pairings = -1;
  double distance_sq = 0.0;
  double runner_up_distance_sq = std::numeric_limits<double>::infinity();
  std::vector<int> feature_of;
};

// Best of every admissible assignment: most pairings, then lowest D^2 (runner-up kept to
// tell a unique best from a tie).
Exhaustive exhaustive(const Problem& problem, double confidence, bool allow_star) {
  Exhaustive best;
  testing::for_each_admissible_hypothesis(
      problem.candidates, problem.model, confidence, allow_star,
      [&best](const std::vector<Pairing>& hypothesis, const std::vector<int>& feature_of, double distance_sq) {
        const int pairings = static_cast<int>(hypothesis.size());
        if (pairings > best.pairings) {
          best = Exhaustive{pairings, distance_sq, std::numeric_limits<double>::infinity(), feature_of};
        } else if (pairings == best.pairings) {
          if (distance_sq < best.distance_sq) {
            best.runner_up_distance_sq = best.distance_sq;
            best.distance_sq = distance_sq;
            best.feature_of = feature_of;
          } else {
            best.runner_up_distance_sq = std::min(best.runner_up_distance_sq, distance_sq);
          }
        }
      });
  return best;
}

int count_pairings(const std::vector<int>& feature_of) {
  return static_cast<int>(std::count_if(feature_of.begin(), feature_of.end(),
                                        [](int f) { return f != kStar; }));
}

void expect_matches_exhaustive(bool allow_star, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  int unique_checked = 0;
  int nontrivial = 0;
  for (int trial = 0; trial < 400; ++trial) {
    const Problem problem = random_problem(rng, 6);
    const double confidence = trial % 3 == 0 ? 0.95 : 0.99;
    JcbbOptions options;
    options.confidence = confidence;
    options.allow_star = allow_star;
    const JcbbResult result = jcbb(problem.candidates, problem.model, options);
    const Exhaustive reference = exhaustive(problem, confidence, allow_star);
    ASSERT_FALSE(result.bound_hit);
    ASSERT_EQ(result.pairings, count_pairings(result.feature_of));
    if (reference.pairings < 0) {  // JCBB*: nothing pairs every measurement
      ASSERT_EQ(result.pairings, 0) << "trial " << trial;
      ASSERT_TRUE(std::all_of(result.feature_of.begin(), result.feature_of.end(),
                              [](int f) { return f == kStar; }));
      continue;
    }
    nontrivial += reference.pairings > 1;
    ASSERT_EQ(result.pairings, reference.pairings) << "trial " << trial;
    ASSERT_NEAR(result.joint_distance_sq, reference.distance_sq,
                1e-9 * std::max(1.0, reference.distance_sq))
        << "trial " << trial;
    ASSERT_NEAR(joint_distance_sq(result.feature_of, problem.model), result.joint_distance_sq,
                1e-9 * std::max(1.0, reference.distance_sq));
    if (reference.runner_up_distance_sq - reference.distance_sq > 1e-7) {
      ASSERT_EQ(result.feature_of, reference.feature_of) << "trial " << trial;
      ++unique_checked;
    }
  }
  EXPECT_GT(unique_checked, 100);
  EXPECT_GT(nontrivial, 100);
}

TEST(Jcbb, MatchesExhaustiveSearch) { expect_matches_exhaustive(true, 11); }

TEST(Jcbb, StarFreeVariantMatchesExhaustiveSearch) { expect_matches_exhaustive(false, 12); }

struct LikelihoodBest {
  double score = -std::numeric_limits<double>::infinity();
  double distance_sq = 0.0;
  double runner_up_score = -std::numeric_limits<double>::infinity();
  std::vector<int> feature_of;
};

// Every admissible assignment, ranked by the directly computed score.
LikelihoodBest exhaustive_likelihood(const Problem& problem, const JcbbLikelihood& likelihood,
                                     double confidence, bool allow_star) {
  LikelihoodBest best;
  testing::for_each_admissible_hypothesis(
      problem.candidates, problem.model, confidence, allow_star,
      [&](const std::vector<Pairing>& hypothesis, const std::vector<int>& feature_of, double distance_sq) {
        const double score = direct_log_likelihood_ratio(hypothesis, problem.model, likelihood);
        if (score > best.score) {
          best.runner_up_score = best.score;
          best.score = score;
          best.distance_sq = distance_sq;
          best.feature_of = feature_of;
        } else {
          best.runner_up_score = std::max(best.runner_up_score, score);
        }
      });
  return best;
}

// Densities spread so that the criterion sometimes declines pairings "most pairings" takes;
// ln det R_i bounds every conditional covariance of the linear model from below.
JcbbLikelihood random_likelihood(std::mt19937_64& rng, const Problem& problem) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  JcbbLikelihood likelihood;
  for (const Mat2& R : problem.model.R) {
    likelihood.log_unexplained_density.push_back(-6.0 + 7.0 * uniform(rng));
    likelihood.log_noise_det.push_back(std::log(R.determinant()));
  }
  return likelihood;
}

void expect_likelihood_matches_exhaustive(bool allow_star, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  int unique_checked = 0, fewer_than_most_pairings = 0;
  for (int trial = 0; trial < 400; ++trial) {
    const Problem problem = random_problem(rng, 6);
    const JcbbLikelihood likelihood = random_likelihood(rng, problem);
    JcbbOptions options;
    options.allow_star = allow_star;
    Jcbb solver(options);
    const JcbbResult result = solver.solve(problem.candidates, problem.model, likelihood);
    ASSERT_FALSE(result.bound_hit);
    ASSERT_EQ(result.pairings, count_pairings(result.feature_of));
    const LikelihoodBest reference = exhaustive_likelihood(problem, likelihood, options.confidence, allow_star);
    if (reference.feature_of.empty()) {  // JCBB*: nothing pairs every measurement
      ASSERT_EQ(result.pairings, 0) << "trial " << trial;
      continue;
    }
    const double found = direct_log_likelihood_ratio(stack_hypothesis(result.feature_of, problem.model).pairings,
                                                     problem.model, likelihood);
    ASSERT_NEAR(found, reference.score, 1e-8 * std::max(1.0, std::abs(reference.score))) << "trial " << trial;
    if (reference.score - reference.runner_up_score > 1e-7) {
      ASSERT_EQ(result.feature_of, reference.feature_of) << "trial " << trial;
      ++unique_checked;
    }
    fewer_than_most_pairings += result.pairings < solver.solve(problem.candidates, problem.model).pairings;
  }
  EXPECT_GT(unique_checked, 200);
  if (allow_star) {
    EXPECT_GT(fewer_than_most_pairings, 20);  // the two criteria do differ
  }
}

TEST(Jcbb, LikelihoodCriterionMatchesExhaustiveSearch) { expect_likelihood_matches_exhaustive(true, 21); }

TEST(Jcbb, LikelihoodCriterionStarFreeVariantMatchesExhaustiveSearch) {
  expect_likelihood_matches_exhaustive(false, 22);
}

// The problem's candidate lists in order of increasing individual distance, as a caller that
// gated them hands them to solve_ranked() and best_pairing().
CandidateLists ranked_candidates(const Problem& problem) {
  CandidateLists ranked = problem.candidates;
  for (std::size_t i = 0; i < ranked.size(); ++i) {
    std::stable_sort(ranked[i].begin(), ranked[i].end(), [&](int a, int b) {
      const int measurement = static_cast<int>(i);
      return individual_distance_sq(problem.model, Pairing{measurement, a}) <
             individual_distance_sq(problem.model, Pairing{measurement, b});
    });
  }
  return ranked;
}

// best_pairing(i, floor): the most likely admissible hypothesis among those that pair
// measurement i, as exhaustive enumeration finds it, and nothing when the floor is above it.
// The result's score is the criterion's value of the hypothesis it returns.
// first_pairing_above(i, floor): some such hypothesis above the floor exactly when there is one.
TEST(Jcbb, BestAndFirstPairingMatchExhaustiveSearch) {
  std::mt19937_64 rng(24);
  Jcbb solver;
  int checked = 0, unpaired_by_best = 0, first_checked = 0, first_cheaper = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const Problem problem = random_problem(rng, 5);
    const JcbbLikelihood likelihood = random_likelihood(rng, problem);
    const CandidateLists ranked = ranked_candidates(problem);
    const JcbbResult best = solver.solve_ranked(ranked, problem.model, &likelihood);
    ASSERT_NEAR(best.score,
                direct_log_likelihood_ratio(stack_hypothesis(best.feature_of, problem.model).pairings,
                                            problem.model, likelihood),
                1e-8 * std::max(1.0, std::abs(best.score)));
    for (int i = 0; i < static_cast<int>(ranked.size()); ++i) {
      double reference = -std::numeric_limits<double>::infinity();
      testing::for_each_admissible_hypothesis(
          problem.candidates, problem.model, 0.99, true,
          [&](const std::vector<Pairing>& hypothesis, const std::vector<int>& feature_of, double) {
            if (feature_of[static_cast<std::size_t>(i)] == kStar) return;
            reference = std::max(reference, direct_log_likelihood_ratio(hypothesis, problem.model, likelihood));
          });
      const double unbounded = -std::numeric_limits<double>::infinity();
      const JcbbResult rival = solver.best_pairing(ranked, problem.model, likelihood, i, unbounded);
      ASSERT_FALSE(rival.bound_hit);
      if (!std::isfinite(reference)) {  // no candidate, or none jointly admissible with i paired
        ASSERT_EQ(rival.pairings, 0) << "trial " << trial << " measurement " << i;
        continue;
      }
      ASSERT_NE(rival.feature_of[static_cast<std::size_t>(i)], kStar) << "trial " << trial;
      const double tolerance = 1e-8 * std::max(1.0, std::abs(reference));
      ASSERT_NEAR(rival.score, reference, tolerance) << "trial " << trial << " measurement " << i;
      ASSERT_NEAR(direct_log_likelihood_ratio(stack_hypothesis(rival.feature_of, problem.model).pairings,
                                              problem.model, likelihood),
                  reference, tolerance);
      ASSERT_LE(rival.score, best.score + tolerance);
      EXPECT_EQ(solver.best_pairing(ranked, problem.model, likelihood, i, reference + 1e-6).pairings, 0);
      const JcbbResult below = solver.best_pairing(ranked, problem.model, likelihood, i, reference - 1e-6);
      EXPECT_EQ(below.feature_of, rival.feature_of);
      // Cut by the floor, the search visits no more nodes than without it.
      EXPECT_LE(below.nodes_expanded, rival.nodes_expanded);
      // Stopped at the first hypothesis above the floor: one exists exactly when the best is
      // above it, and what it returns is a hypothesis that pairs i and scores above the floor.
      for (const double floor : {unbounded, reference - 1.0, reference - 1e-6, reference + 1e-6}) {
        const JcbbResult best_above = solver.best_pairing(ranked, problem.model, likelihood, i, floor);
        const JcbbResult first = solver.first_pairing_above(ranked, problem.model, likelihood, i, floor);
        ASSERT_FALSE(first.bound_hit);
        ASSERT_EQ(first.pairings > 0, best_above.pairings > 0) << "trial " << trial << " measurement " << i;
        EXPECT_LE(first.nodes_expanded, best_above.nodes_expanded);
        if (first.pairings == 0) continue;
        ASSERT_NE(first.feature_of[static_cast<std::size_t>(i)], kStar);
        const double score = direct_log_likelihood_ratio(stack_hypothesis(first.feature_of, problem.model).pairings,
                                                         problem.model, likelihood);
        EXPECT_NEAR(first.score, score, tolerance);
        EXPECT_GT(score, floor - tolerance);
        EXPECT_LE(score, reference + tolerance);
        ++first_checked;
        if (first.nodes_expanded < best_above.nodes_expanded) ++first_cheaper;
      }
      ++checked;
      unpaired_by_best += best.feature_of[static_cast<std::size_t>(i)] == kStar;
    }
  }
  EXPECT_GT(checked, 500);
  EXPECT_GT(unpaired_by_best, 50);  // the case the EKF asks about
  EXPECT_GT(first_checked, 1500);
  EXPECT_GT(first_cheaper, 100);  // the search does stop early
  EXPECT_THROW(solver.best_pairing({{}, {}}, LinearScanModel(), JcbbLikelihood{{0.0, 0.0}, {0.0, 0.0}}, 2, 0.0),
               InvalidArgument);
  EXPECT_THROW(solver.first_pairing_above({{}, {}}, LinearScanModel(), JcbbLikelihood{{0.0, 0.0}, {0.0, 0.0}}, -1, 0.0),
               InvalidArgument);
}

TEST(Jcbb, LikelihoodCriterionNeedsOneDensityPerMeasurement) {
  LinearScanModel model;
  JcbbLikelihood likelihood;
  likelihood.log_unexplained_density = {0.0};
  likelihood.log_noise_det = {0.0, 0.0};
  Jcbb solver;
  EXPECT_THROW(solver.solve({{}, {}}, model, likelihood), InvalidArgument);
}

TEST(Jcbb, NodeBoundReturnsAnAdmissibleHypothesis) {
  std::mt19937_64 rng(5);
  int bounded = 0;
  for (int trial = 0; trial < 50; ++trial) {
    Problem problem = random_problem(rng, 8);
    JcbbOptions options;
    options.max_nodes = 4;
    const JcbbResult result = jcbb(problem.candidates, problem.model, options);
    if (!result.bound_hit) continue;
    ++bounded;
    EXPECT_EQ(result.nodes_expanded, 4);
    EXPECT_EQ(result.pairings, count_pairings(result.feature_of));
    const double direct = joint_distance_sq(result.feature_of, problem.model);
    EXPECT_NEAR(direct, result.joint_distance_sq, 1e-9 * std::max(1.0, direct));
    if (result.pairings > 0) {
      EXPECT_LE(direct, chi2_quantile(2 * result.pairings, options.confidence));
    }
    const JcbbResult full = jcbb(problem.candidates, problem.model);
    EXPECT_FALSE(full.bound_hit);
    EXPECT_GE(full.pairings, result.pairings);
    EXPECT_GT(full.nodes_expanded, 4);
  }
  EXPECT_GT(bounded, 20);
}

TEST(Jcbb, SolverReusesBuffersAcrossProblemsOfDifferentSize) {
  std::mt19937_64 rng(9);
  Jcbb solver;
  for (int trial = 0; trial < 60; ++trial) {
    const Problem problem = random_problem(rng, trial % 2 == 0 ? 6 : 2);
    const JcbbResult reused = solver.solve(problem.candidates, problem.model);
    const JcbbResult fresh = jcbb(problem.candidates, problem.model);
    ASSERT_EQ(reused.feature_of, fresh.feature_of);
    ASSERT_EQ(reused.nodes_expanded, fresh.nodes_expanded);
  }
}

// A caller that gated the candidates has their individual distances: handing the lists over
// ranked must give what the solver's own ranking gives, with either criterion, and the
// exhaustive search's answer.
TEST(Jcbb, RankedCandidatesGiveTheSameResult) {
  std::mt19937_64 rng(23);
  Jcbb solver;
  int compared = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const Problem problem = random_problem(rng, trial % 2 == 0 ? 6 : 3);
    const CandidateLists ranked = ranked_candidates(problem);
    const JcbbResult own = jcbb(problem.candidates, problem.model);
    const JcbbResult given = solver.solve_ranked(ranked, problem.model);
    ASSERT_EQ(given.feature_of, own.feature_of) << "trial " << trial;
    ASSERT_EQ(given.nodes_expanded, own.nodes_expanded) << "trial " << trial;
    ASSERT_EQ(given.pairings, exhaustive(problem, 0.99, true).pairings) << "trial " << trial;
    JcbbLikelihood likelihood;
    for (std::size_t i = 0; i < ranked.size(); ++i) {
      likelihood.log_unexplained_density.push_back(-3.0);
      likelihood.log_noise_det.push_back(-4.0);
    }
    Jcbb fresh;
    const JcbbResult own_likelihood = fresh.solve(problem.candidates, problem.model, likelihood);
    const JcbbResult given_likelihood = solver.solve_ranked(ranked, problem.model, &likelihood);
    ASSERT_EQ(given_likelihood.feature_of, own_likelihood.feature_of) << "trial " << trial;
    compared += own.pairings > 1;
  }
  EXPECT_GT(compared, 50);
}

// start/expand/result visits the nodes solve() visits, in its order, however the search is
// sliced: bitwise the same hypothesis, D^2 and node count, with either criterion, with and
// without the star, and when the node bound cuts the search.
TEST(Jcbb, SearchInSlicesEqualsTheWholeSearch) {
  std::mt19937_64 rng(31);
  int sliced_searches = 0;
  for (int trial = 0; trial < 120; ++trial) {
    const Problem problem = random_problem(rng, trial % 3 == 0 ? 8 : 6);
    const JcbbLikelihood likelihood = random_likelihood(rng, problem);
    JcbbOptions options;
    options.allow_star = trial % 4 != 1;
    options.max_nodes = trial % 5 == 2 ? 7 : 100000;
    for (const JcbbLikelihood* criterion : {static_cast<const JcbbLikelihood*>(nullptr), &likelihood}) {
      Jcbb whole_solver(options);
      const JcbbResult whole = criterion ? whole_solver.solve(problem.candidates, problem.model, *criterion)
                                         : whole_solver.solve(problem.candidates, problem.model);
      for (const std::int64_t slice : {1, 3}) {
        Jcbb solver(options);
        solver.start(problem.candidates, problem.model, criterion);
        int slices = 1;
        while (!solver.expand(slice)) {
          ++slices;
          ASSERT_LT(slices, 1000000);
        }
        const JcbbResult sliced = solver.result();
        ASSERT_EQ(sliced.feature_of, whole.feature_of) << "trial " << trial;
        ASSERT_EQ(sliced.joint_distance_sq, whole.joint_distance_sq) << "trial " << trial;
        ASSERT_EQ(sliced.nodes_expanded, whole.nodes_expanded) << "trial " << trial;
        ASSERT_EQ(sliced.bound_hit, whole.bound_hit) << "trial " << trial;
        ASSERT_GE(slices, whole.nodes_expanded / slice) << "trial " << trial;
        sliced_searches += slices > 1;
      }
    }
  }
  EXPECT_GT(sliced_searches, 300);
}

TEST(Jcbb, EmptyAndUnpairableInputs) {
  LinearScanModel model;
  EXPECT_EQ(jcbb({}, model).pairings, 0);
  const JcbbResult none = jcbb({{}, {}}, model);
  EXPECT_EQ(none.feature_of, (std::vector<int>{kStar, kStar}));
  EXPECT_THROW(jcbb({{-2}}, model), InvalidArgument);
  JcbbOptions options;
  options.max_nodes = 0;
  EXPECT_THROW(Jcbb{options}, InvalidArgument);
}

// Greedy nearest neighbour written the slow way: repeatedly take the globally closest
// compatible pair among unused measurements and features.
std::vector<int> brute_force_nearest_neighbour(const Problem& problem, double confidence) {
  const double gate = chi2_quantile(2, confidence);
  const std::size_t m = problem.candidates.size();
  std::vector<int> feature_of(m, kStar);
  std::vector<int> used;
  for (;;) {
    double closest = std::numeric_limits<double>::infinity();
    Pairing chosen{-1, -1};
    for (std::size_t i = 0; i < m; ++i) {
      if (feature_of[i] != kStar) continue;
      for (int j : problem.candidates[i]) {
        if (std::find(used.begin(), used.end(), j) != used.end()) continue;
        const Pairing p{static_cast<int>(i), j};
        const double d = direct_distance_sq({p}, problem.model);
        if (d <= gate && d < closest) {
          closest = d;
          chosen = p;
        }
      }
    }
    if (chosen.measurement < 0) return feature_of;
    feature_of[chosen.measurement] = chosen.feature;
    used.push_back(chosen.feature);
  }
}

TEST(NearestNeighbour, MatchesBruteForceAndIndividualCompatibilityFilters) {
  std::mt19937_64 rng(21);
  for (int trial = 0; trial < 300; ++trial) {
    const Problem problem = random_problem(rng, 6);
    ASSERT_EQ(nearest_neighbour(problem.candidates, problem.model, 0.99),
              brute_force_nearest_neighbour(problem, 0.99))
        << "trial " << trial;
    const CandidateLists compatible =
        individually_compatible(problem.candidates, problem.model, 0.95);
    for (std::size_t i = 0; i < problem.candidates.size(); ++i) {
      std::vector<int> expected;
      for (int j : problem.candidates[i]) {
        if (direct_distance_sq({Pairing{static_cast<int>(i), j}}, problem.model) <=
            chi2_quantile(2, 0.95)) {
          expected.push_back(j);
        }
      }
      ASSERT_EQ(compatible[i], expected);
    }
  }
}

}  // namespace
}  // namespace dcslam
