#pragma once
// Exhaustive enumeration of data association hypotheses: the independent oracle for JCBB in
// all its variants (count or likelihood criterion, with or without the star node).
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/association/jcbb.hpp"

namespace dcslam::testing {

// Joint distance of pairings computed from scratch (stacked nu, full S, LDLT).
inline double direct_distance_sq(const std::vector<Pairing>& pairings, const PairingModel& model) {
  const auto k = static_cast<Eigen::Index>(pairings.size());
  Eigen::VectorXd nu(2 * k);
  Eigen::MatrixXd S(2 * k, 2 * k);
  for (Eigen::Index a = 0; a < k; ++a) {
    nu.segment<2>(2 * a) = model.innovation(pairings[a]);
    for (Eigen::Index b = 0; b < k; ++b) {
      S.block<2, 2>(2 * a, 2 * b) = model.covariance(pairings[a], pairings[b]);
    }
  }
  return nu.dot(S.ldlt().solve(nu));
}

// The likelihood criterion's score of pairings computed from scratch: the log-density of
// its stacked innovation under N(0, S_H) (LDLT of the whole S_H) minus sum ln lambda_i.
inline double direct_log_likelihood_ratio(const std::vector<Pairing>& pairings, const PairingModel& model,
                                   const JcbbLikelihood& likelihood) {
  const auto k = static_cast<Eigen::Index>(pairings.size());
  if (k == 0) return 0.0;
  Eigen::VectorXd nu(2 * k);
  Eigen::MatrixXd S(2 * k, 2 * k);
  double unexplained = 0.0;
  for (Eigen::Index a = 0; a < k; ++a) {
    nu.segment<2>(2 * a) = model.innovation(pairings[a]);
    unexplained += likelihood.log_unexplained_density[static_cast<std::size_t>(pairings[a].measurement)];
    for (Eigen::Index b = 0; b < k; ++b) {
      S.block<2, 2>(2 * a, 2 * b) = model.covariance(pairings[a], pairings[b]);
    }
  }
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(S);
  const double log_det = ldlt.vectorD().array().log().sum();
  return -static_cast<double>(k) * std::log(2.0 * M_PI) - 0.5 * log_det - 0.5 * nu.dot(ldlt.solve(nu)) -
         unexplained;
}

namespace detail {

template <typename Visit>
void enumerate_hypotheses(const CandidateLists& candidates, const PairingModel& model, double confidence,
                          bool allow_star, std::size_t measurement, std::vector<Pairing>& hypothesis,
                          std::vector<int>& feature_of, double distance_sq, Visit& visit) {
  if (measurement == candidates.size()) {
    visit(hypothesis, feature_of, distance_sq);
    return;
  }
  for (int feature : candidates[measurement]) {
    const bool used = std::any_of(hypothesis.begin(), hypothesis.end(),
                                  [&](const Pairing& p) { return p.feature == feature; });
    if (used) continue;
    hypothesis.push_back(Pairing{static_cast<int>(measurement), feature});
    const double extended = direct_distance_sq(hypothesis, model);
    if (extended <= chi2_quantile(2 * static_cast<int>(hypothesis.size()), confidence)) {
      feature_of[measurement] = feature;
      enumerate_hypotheses(candidates, model, confidence, allow_star, measurement + 1, hypothesis,
                           feature_of, extended, visit);
      feature_of[measurement] = kStar;
    }
    hypothesis.pop_back();
  }
  if (allow_star) {
    enumerate_hypotheses(candidates, model, confidence, allow_star, measurement + 1, hypothesis,
                         feature_of, distance_sq, visit);
  }
}

}  // namespace detail

// Calls visit(pairings, feature_of, D^2) for every complete assignment (each measurement: one
// of its candidates or, with allow_star, the star node; each feature at most once) whose every
// prefix is jointly compatible at `confidence`, D^2 computed directly. The empty hypothesis
// (D^2 = 0) is visited when allow_star is set.
template <typename Visit>
void for_each_admissible_hypothesis(const CandidateLists& candidates, const PairingModel& model,
                                    double confidence, bool allow_star, Visit visit) {
  std::vector<Pairing> hypothesis;
  std::vector<int> feature_of(candidates.size(), kStar);
  detail::enumerate_hypotheses(candidates, model, confidence, allow_star, 0, hypothesis, feature_of,
                               0.0, visit);
}

}  // namespace dcslam::testing
