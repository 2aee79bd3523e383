#include "dcslam/association/jcbb.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <tuple>

#include <Eigen/Cholesky>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();
constexpr double kLogInvTwoPi = -1.8378770664093454836;  // ln(1 / (2 pi)), 2-dof normal

// Lower Cholesky factor of a 2x2 matrix; false unless it is (numerically) positive definite.
bool cholesky2(const Mat2& m, Mat2& lower) {
  if (!(m(0, 0) > 0.0)) return false;
  const double l00 = std::sqrt(m(0, 0));
  const double l10 = 0.5 * (m(1, 0) + m(0, 1)) / l00;
  const double pivot = m(1, 1) - l10 * l10;
  if (!(pivot > 0.0)) return false;
  lower << l00, 0.0, l10, std::sqrt(pivot);
  return true;
}

// L^-1 v for a lower-triangular 2x2 L.
Vec2 forward_solve2(const Mat2& lower, const Vec2& v) {
  const double y0 = v(0) / lower(0, 0);
  return Vec2(y0, (v(1) - lower(1, 0) * y0) / lower(1, 1));
}

void check_candidates(const CandidateLists& candidates) {
  for (const auto& features : candidates) {
    for (int feature : features) {
      if (feature < 0) throw InvalidArgument("candidates: feature indices must be >= 0");
    }
  }
}

}  // namespace

double individual_distance_sq(const PairingModel& model, const Pairing& pairing) {
  Mat2 lower;
  if (!cholesky2(model.covariance(pairing, pairing), lower)) return kInfinity;
  return forward_solve2(lower, model.innovation(pairing)).squaredNorm();
}

Jcbb::Jcbb(const JcbbOptions& options) : options_(options), gate_(options.confidence) {
  if (options.max_nodes < 1) throw InvalidArgument("JcbbOptions.max_nodes must be >= 1");
}

namespace {

void check_likelihood(const CandidateLists& candidates, const JcbbLikelihood& likelihood) {
  const std::size_t m = candidates.size();
  if (likelihood.log_unexplained_density.size() != m || likelihood.log_noise_det.size() != m) {
    throw InvalidArgument("JcbbLikelihood: one log density and one log det per measurement");
  }
}

}  // namespace

JcbbResult Jcbb::solve(const CandidateLists& candidates, const PairingModel& model) {
  return run(candidates, model, nullptr, false);
}

JcbbResult Jcbb::solve(const CandidateLists& candidates, const PairingModel& model,
                       const JcbbLikelihood& likelihood) {
  check_likelihood(candidates, likelihood);
  return run(candidates, model, &likelihood, false);
}

JcbbResult Jcbb::solve_ranked(const CandidateLists& ranked_candidates, const PairingModel& model,
                              const JcbbLikelihood* likelihood) {
  if (likelihood) check_likelihood(ranked_candidates, *likelihood);
  return run(ranked_candidates, model, likelihood, true);
}

JcbbResult Jcbb::best_pairing(const CandidateLists& ranked_candidates, const PairingModel& model,
                              const JcbbLikelihood& likelihood, int measurement,
                              double score_floor) {
  return pairing_above(ranked_candidates, model, likelihood, measurement, score_floor, false);
}

JcbbResult Jcbb::first_pairing_above(const CandidateLists& ranked_candidates, const PairingModel& model,
                                     const JcbbLikelihood& likelihood, int measurement, double score_floor) {
  return pairing_above(ranked_candidates, model, likelihood, measurement, score_floor, true);
}

JcbbResult Jcbb::pairing_above(const CandidateLists& ranked_candidates, const PairingModel& model,
                               const JcbbLikelihood& likelihood, int measurement, double score_floor,
                               bool stop_at_first) {
  check_likelihood(ranked_candidates, likelihood);
  if (measurement < 0 || static_cast<std::size_t>(measurement) >= ranked_candidates.size()) {
    throw InvalidArgument(std::string(stop_at_first ? "Jcbb::first_pairing_above" : "Jcbb::best_pairing") +
                          ": measurement " + std::to_string(measurement) + " is not one of the " +
                          std::to_string(ranked_candidates.size()) + " measurements");
  }
  return run(ranked_candidates, model, &likelihood, true, measurement, score_floor, stop_at_first);
}

JcbbResult Jcbb::run(const CandidateLists& candidates, const PairingModel& model,
                     const JcbbLikelihood* likelihood, bool ranked, int paired_measurement,
                     double score_floor, bool stop_at_first) {
  prepare(candidates, model, likelihood, ranked, paired_measurement, score_floor, stop_at_first);
  expand(std::numeric_limits<std::int64_t>::max());
  return result();
}

void Jcbb::start(const CandidateLists& candidates, const PairingModel& model,
                 const JcbbLikelihood* likelihood) {
  if (likelihood) check_likelihood(candidates, *likelihood);
  prepare(candidates, model, likelihood, false);
}

void Jcbb::prepare(const CandidateLists& candidates, const PairingModel& model,
                   const JcbbLikelihood* likelihood, bool ranked, int paired_measurement,
                   double score_floor, bool stop_at_first) {
  check_candidates(candidates);
  paired_measurement_ = paired_measurement;
  stop_at_first_ = stop_at_first;
  model_ = &model;
  likelihood_ = likelihood;
  num_measurements_ = static_cast<int>(candidates.size());
  const int m = num_measurements_;

  // Trying the individually closest candidate first finds a good hypothesis early, so the
  // distance bound starts pruning sooner. Lists already ranked are searched as they are; the
  // solver's own only grow (shrinking would free them).
  ordered_ = ranked ? &candidates : &ordered_candidates_;
  work_ = 0;
  if (!ranked) {
    if (ordered_candidates_.size() < static_cast<std::size_t>(m)) {
      ordered_candidates_.resize(static_cast<std::size_t>(m));
    }
    for (int i = 0; i < m; ++i) {
      ranked_.clear();
      for (int feature : candidates[i]) {
        ranked_.emplace_back(individual_distance_sq(model, Pairing{i, feature}), feature);
      }
      work_ += kPairingCovarianceUnits * static_cast<std::int64_t>(ranked_.size());
      std::stable_sort(ranked_.begin(), ranked_.end(),
                       [](const auto& a, const auto& b) { return a.first < b.first; });
      auto& ordered = ordered_candidates_[static_cast<std::size_t>(i)];
      ordered.clear();
      for (const auto& [distance_sq, feature] : ranked_) ordered.push_back(feature);
    }
  }
  own_slot_begin_.assign(static_cast<std::size_t>(m), 0);
  std::size_t slots = 0;
  for (int i = 0; i < m; ++i) {
    own_slot_begin_[static_cast<std::size_t>(i)] = slots;
    slots += (*ordered_)[static_cast<std::size_t>(i)].size();
  }
  if (own_terms_.size() < slots) own_terms_.resize(slots);
  own_known_.assign(slots, 0);
  int pairable = 0;
  score_bound_from_.assign(static_cast<std::size_t>(m) + 1, 0.0);
  for (int i = m - 1; i >= 0; --i) {
    double bound = 0.0;
    if (!candidates[i].empty()) {
      ++pairable;
      // A measurement can always stay unpaired (gain 0) when the star is allowed; without
      // the star its (possibly negative) gain must be counted, and the bound still holds.
      bound = likelihood ? kLogInvTwoPi - 0.5 * likelihood->log_noise_det[i] -
                               likelihood->log_unexplained_density[i]
                         : 1.0;
      if (star_allowed(i)) bound = std::max(bound, 0.0);
    }
    score_bound_from_[i] = score_bound_from_[i + 1] + bound;
  }

  if (factor_.rows() < 2 * m) {
    factor_.resize(2 * m, 2 * m);
    whitened_.resize(2 * m);
    cross_.resize(2 * m, 2);
  }
  hypothesis_.resize(static_cast<std::size_t>(m));
  best_.clear();
  best_score_ = score_floor;
  // Above the floor, or at it with any D^2: the floor is not a hypothesis to beat on D^2.
  best_distance_sq_ = kInfinity;
  nodes_ = 0;
  bound_hit_ = false;
  frames_.clear();

  const bool feasible =
      options_.allow_star ? paired_measurement < 0 || !candidates[paired_measurement].empty()
                          : pairable == m;
  if (feasible) enter(0, 0, 0.0, 0.0);
}

JcbbResult Jcbb::result() {
  JcbbResult result;
  result.feature_of.assign(static_cast<std::size_t>(num_measurements_), kStar);
  for (const Pairing& pairing : best_) result.feature_of[pairing.measurement] = pairing.feature;
  result.pairings = static_cast<int>(best_.size());
  result.joint_distance_sq = best_.empty() ? 0.0 : best_distance_sq_;
  result.score = best_.empty() ? 0.0 : best_score_;
  result.nodes_expanded = nodes_;
  result.bound_hit = bound_hit_;
  ordered_ = nullptr;
  model_ = nullptr;
  likelihood_ = nullptr;
  return result;
}

bool Jcbb::can_improve(double score_upper_bound, double distance_sq_lower_bound) const {
  return score_upper_bound > best_score_ ||
         (score_upper_bound == best_score_ && distance_sq_lower_bound < best_distance_sq_);
}

bool Jcbb::feature_in_use(int depth, int feature) const {
  for (int t = 0; t < depth; ++t) {
    if (hypothesis_[t].feature == feature) return true;
  }
  return false;
}

void Jcbb::record(int depth, double distance_sq, double score) {
  best_.assign(hypothesis_.begin(), hypothesis_.begin() + depth);
  best_score_ = score;
  best_distance_sq_ = distance_sq;
}

void Jcbb::enter(int measurement, int depth, double distance_sq, double score) {
  if (nodes_ >= options_.max_nodes) {
    bound_hit_ = true;
    frames_.clear();
    return;
  }
  ++nodes_;
  // With the star allowed every node is a complete hypothesis (the rest unpaired), once the
  // measurement that must be paired is behind it, so it is recorded here; that also gives the
  // bounded search a useful answer.
  const bool complete = measurement == num_measurements_;
  if ((complete || (options_.allow_star && measurement > paired_measurement_)) &&
      can_improve(score, distance_sq)) {
    record(depth, distance_sq, score);
    if (stop_at_first_) {
      frames_.clear();
      return;
    }
  }
  if (!complete) frames_.push_back(Frame{measurement, depth, distance_sq, score, 0, false});
}

// Depth first, a node's candidates in rank order and then the star, as the recursion
//   visit(node): for each candidate c that extends it within the bounds, visit(child c);
//                then visit(star child) if it can still improve
// would; the path is kept in frames_ so that the search can stop after any node.
bool Jcbb::expand(std::int64_t nodes) {
  const std::int64_t stop_at =
      nodes_ > std::numeric_limits<std::int64_t>::max() - nodes ? std::numeric_limits<std::int64_t>::max()
                                                                 : nodes_ + nodes;
  while (!frames_.empty()) {
    if (nodes_ >= stop_at) return false;
    Frame& frame = frames_.back();
    const std::vector<int>& features = (*ordered_)[static_cast<std::size_t>(frame.measurement)];
    const double bound_after = frame.score + score_bound_from_[frame.measurement + 1];
    if (frame.next < features.size()) {
      const int feature = features[frame.next++];
      // Re-checked per candidate: the best may have improved inside the previous subtree.
      if (!can_improve(frame.score + score_bound_from_[frame.measurement], frame.distance_sq)) {
        frame.next = features.size();
        continue;
      }
      if (feature_in_use(frame.depth, feature)) continue;
      const Pairing pairing{frame.measurement, feature};
      const std::size_t slot = own_slot_begin_[static_cast<std::size_t>(frame.measurement)] + frame.next - 1;
      double extended_distance_sq = frame.distance_sq;
      double gain = 0.0;
      if (!extend(frame.depth, pairing, slot, extended_distance_sq, gain)) continue;
      if (!can_improve(bound_after + gain, extended_distance_sq)) continue;
      hypothesis_[frame.depth] = pairing;
      enter(frame.measurement + 1, frame.depth + 1, extended_distance_sq, frame.score + gain);
      continue;
    }
    if (!frame.star_tried) {
      frame.star_tried = true;
      if (star_allowed(frame.measurement) && can_improve(bound_after, frame.distance_sq)) {
        enter(frame.measurement + 1, frame.depth, frame.distance_sq, frame.score);
      }
      continue;
    }
    frames_.pop_back();
  }
  return true;
}

void PairingModel::covariances_with(const Pairing* pairings, std::size_t count, const Pairing& b,
                                    CrossColumns cross) const {
  for (std::size_t c = 0; c < count; ++c) cross.middleRows<2>(2 * static_cast<Eigen::Index>(c)) = covariance(pairings[c], b);
}

const Jcbb::OwnTerms& Jcbb::own_terms(std::size_t slot, const Pairing& pairing) {
  OwnTerms& terms = own_terms_[slot];
  if (!own_known_[slot]) {
    terms.covariance = model_->covariance(pairing, pairing);
    terms.innovation = model_->innovation(pairing);
    own_known_[slot] = 1;
  }
  return terms;
}

bool Jcbb::extend(int depth, const Pairing& pairing, std::size_t slot, double& distance_sq, double& score_gain) {
  // Appending pairing a to H: with C_Ha = cov(nu_H, nu_a) and X = L^-1 C_Ha, the new factor
  // row is [X', chol(C_aa - X'X)] and the new whitened entry chol(..)^-1 (nu_a - X' w_H).
  const int rows = 2 * depth;
  work_ += kPairingCovarianceUnits * (depth + 1) + depth * depth / 2;
  // Hypotheses hold a handful of pairings: plain loops beat Eigen's blocked triangular solve
  // and products, whose set-up dominates at these sizes.
  const OwnTerms& own = own_terms(slot, pairing);
  Mat2 schur = own.covariance;
  Vec2 residual = own.innovation;
  model_->covariances_with(hypothesis_.data(), static_cast<std::size_t>(depth), pairing, cross_.topRows(rows));
  for (int r = 0; r < rows; ++r) {
    double x0 = cross_(r, 0), x1 = cross_(r, 1);
    for (int c = 0; c < r; ++c) {
      const double l = factor_(r, c);
      x0 -= l * cross_(c, 0);
      x1 -= l * cross_(c, 1);
    }
    const double inverse_pivot = 1.0 / factor_(r, r);
    x0 *= inverse_pivot;
    x1 *= inverse_pivot;
    cross_(r, 0) = x0;
    cross_(r, 1) = x1;
    schur(0, 0) -= x0 * x0;
    schur(0, 1) -= x0 * x1;
    schur(1, 0) -= x1 * x0;
    schur(1, 1) -= x1 * x1;
    residual(0) -= x0 * whitened_(r);
    residual(1) -= x1 * whitened_(r);
  }
  Mat2 block;
  if (!cholesky2(schur, block)) return false;
  const Vec2 whitened = forward_solve2(block, residual);
  const double extended = distance_sq + whitened.squaredNorm();
  if (!(extended <= gate_.threshold(2 * (depth + 1)))) return false;
  factor_.block(rows, 0, 2, rows) = cross_.topRows(rows).transpose();
  factor_.block<2, 2>(rows, rows) = block;
  whitened_.segment<2>(rows) = whitened;
  distance_sq = extended;
  if (likelihood_) {
    // ln N(nu_a|H; 0, S_a|H) with S_a|H = block block' (the Schur complement).
    const auto i = static_cast<std::size_t>(pairing.measurement);
    score_gain = kLogInvTwoPi - std::log(block(0, 0) * block(1, 1)) - 0.5 * whitened.squaredNorm() -
                 likelihood_->log_unexplained_density[i];
  } else {
    score_gain = 1.0;
  }
  return true;
}

JcbbResult jcbb(const CandidateLists& candidates, const PairingModel& model,
                const JcbbOptions& options) {
  Jcbb solver(options);
  return solver.solve(candidates, model);
}

CandidateLists individually_compatible(const CandidateLists& candidates,
                                       const PairingModel& model, double confidence) {
  check_candidates(candidates);
  const double gate = chi2_quantile(2, confidence);
  CandidateLists compatible(candidates.size());
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    for (int feature : candidates[i]) {
      if (individual_distance_sq(model, Pairing{static_cast<int>(i), feature}) <= gate) {
        compatible[i].push_back(feature);
      }
    }
  }
  return compatible;
}

std::vector<int> nearest_neighbour(const CandidateLists& candidates, const PairingModel& model,
                                   double confidence) {
  check_candidates(candidates);
  const double gate = chi2_quantile(2, confidence);
  std::vector<std::tuple<double, int, int>> ranked;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const int measurement = static_cast<int>(i);
    for (int feature : candidates[i]) {
      const double distance_sq = individual_distance_sq(model, Pairing{measurement, feature});
      if (distance_sq <= gate) ranked.emplace_back(distance_sq, measurement, feature);
    }
  }
  std::sort(ranked.begin(), ranked.end());
  std::vector<int> feature_of(candidates.size(), kStar);
  std::vector<int> used_features;
  for (const auto& [distance_sq, measurement, feature] : ranked) {
    if (feature_of[measurement] != kStar) continue;
    if (std::find(used_features.begin(), used_features.end(), feature) != used_features.end()) {
      continue;
    }
    feature_of[measurement] = feature;
    used_features.push_back(feature);
  }
  return feature_of;
}

StackedHypothesis::StackedHypothesis(const std::vector<int>& feature_of) {
  for (std::size_t i = 0; i < feature_of.size(); ++i) {
    if (feature_of[i] != kStar) pairings.push_back(Pairing{static_cast<int>(i), feature_of[i]});
  }
  resize();
}

void StackedHypothesis::resize() {
  const auto k = static_cast<Eigen::Index>(pairings.size());
  innovation.resize(2 * k);
  covariance.resize(2 * k, 2 * k);
}

void StackedHypothesis::stack(Eigen::Index a, const PairingModel& model) {
  const Pairing& pairing = pairings[static_cast<std::size_t>(a)];
  innovation.segment<2>(2 * a) = model.innovation(pairing);
  for (Eigen::Index b = 0; b <= a; ++b) {
    const Mat2 block = model.covariance(pairing, pairings[static_cast<std::size_t>(b)]);
    covariance.block<2, 2>(2 * a, 2 * b) = block;
    covariance.block<2, 2>(2 * b, 2 * a) = block.transpose();
  }
}

StackedHypothesis stack_hypothesis(const std::vector<int>& feature_of, const PairingModel& model) {
  StackedHypothesis stacked(feature_of);
  for (Eigen::Index a = 0; a < static_cast<Eigen::Index>(stacked.pairings.size()); ++a) {
    stacked.stack(a, model);
  }
  return stacked;
}

double joint_distance_sq(const std::vector<int>& feature_of, const PairingModel& model) {
  const StackedHypothesis stacked = stack_hypothesis(feature_of, model);
  if (stacked.pairings.empty()) return 0.0;
  const Eigen::LLT<Eigen::MatrixXd> cholesky(stacked.covariance);
  if (cholesky.info() != Eigen::Success) return kInfinity;
  return cholesky.matrixL().solve(stacked.innovation).squaredNorm();
}

}  // namespace dcslam
