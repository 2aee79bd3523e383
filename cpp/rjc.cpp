#include "dcslam/rjc.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <tuple>

#include <Eigen/Cholesky>

#include "dcslam/chi_square.hpp"
#include "dcslam/errors.hpp"

namespace dcslam {

namespace {

// The model seen through a renumbering of measurements: JCBB* runs on the drawn sample as
// measurements 0..b-1.
class SampledModel : public PairingModel {
 public:
  SampledModel(const PairingModel& model, const std::vector<int>& measurement_of)
      : model_(model), measurement_of_(measurement_of) {}
  Vec2 innovation(const Pairing& p) const override { return model_.innovation(original(p)); }
  Mat2 covariance(const Pairing& a, const Pairing& b) const override {
    return model_.covariance(original(a), original(b));
  }

 private:
  Pairing original(const Pairing& p) const {
    return Pairing{measurement_of_[static_cast<std::size_t>(p.measurement)], p.feature};
  }
  const PairingModel& model_;
  const std::vector<int>& measurement_of_;
};

// Uniform integer in [0, n) by rejection, identical on every platform.
std::size_t draw_below(std::mt19937_64& rng, std::size_t n) {
  const std::uint64_t range = static_cast<std::uint64_t>(n);
  const std::uint64_t limit = std::numeric_limits<std::uint64_t>::max() -
                              std::numeric_limits<std::uint64_t>::max() % range;
  std::uint64_t value;
  do {
    value = rng();
  } while (value >= limit);
  return static_cast<std::size_t>(value % range);
}

double tries_needed(double p_good, int b, double p_fail) {
  const double all_good = std::pow(p_good, b);
  if (all_good >= 1.0) return 0.0;
  return std::log(p_fail) / std::log1p(-all_good);
}

void check_options(const RjcOptions& options) {
  if (options.b < 1) throw InvalidArgument("RjcOptions.b must be >= 1");
  if (!(options.p_good > 0.0 && options.p_good < 1.0)) {
    throw InvalidArgument("RjcOptions.p_good must be in (0, 1)");
  }
  if (!(options.p_fail > 0.0 && options.p_fail < 1.0)) {
    throw InvalidArgument("RjcOptions.p_fail must be in (0, 1)");
  }
  if (options.max_tries < 1) throw InvalidArgument("RjcOptions.max_tries must be >= 1");
}

}  // namespace

int enforce_joint_compatibility(std::vector<int>& feature_of, const PairingModel& model,
                                double confidence, double* joint_distance_sq) {
  StackedHypothesis stacked = stack_hypothesis(feature_of, model);
  const std::vector<Pairing>& pairings = stacked.pairings;
  const auto k = static_cast<Eigen::Index>(pairings.size());
  if (joint_distance_sq != nullptr) *joint_distance_sq = 0.0;
  if (k == 0) return 0;
  Eigen::VectorXd& innovation = stacked.innovation;  // entries of removed pairings are zeroed
  Eigen::MatrixXd& information = stacked.covariance;  // becomes S^-1 below
  const Eigen::LLT<Eigen::MatrixXd> cholesky(information);
  if (cholesky.info() != Eigen::Success) {
    throw InvalidArgument("enforce_joint_compatibility: joint covariance not positive definite");
  }
  // Usually the hypothesis passes as it is: then the factor alone decides (k^3 / 3), and the
  // inverse (three times that) is only formed when pairings have to go.
  const double whole_distance_sq = cholesky.matrixL().solve(innovation).squaredNorm();
  if (whole_distance_sq <= chi2_quantile(2 * static_cast<int>(k), confidence)) {
    if (joint_distance_sq != nullptr) *joint_distance_sq = whole_distance_sq;
    return 0;
  }
  information = cholesky.solve(Eigen::MatrixXd::Identity(2 * k, 2 * k));

  // Removing pairing a leaves (S_rr)^-1 = L_rr - L_ra L_aa^-1 L_ar (L = S^-1): the same
  // rank-2 update applied to the whole L also zeroes a's rows and columns, so removed
  // pairings need no compaction. a's share of D^2 is y_a' L_aa^-1 y_a with y = L nu.
  std::vector<bool> active(static_cast<std::size_t>(k), true);
  Eigen::Index remaining = k;
  int removed = 0;
  double distance_sq = 0.0;
  while (remaining > 0) {
    const Eigen::VectorXd weighted = information * innovation;
    distance_sq = innovation.dot(weighted);
    if (distance_sq <= chi2_quantile(2 * static_cast<int>(remaining), confidence)) break;
    Eigen::Index worst = -1;
    double worst_share = -1.0;
    for (Eigen::Index a = 0; a < k; ++a) {
      if (!active[a]) continue;
      const Vec2 y = weighted.segment<2>(2 * a);
      const double share = y.dot(information.block<2, 2>(2 * a, 2 * a).ldlt().solve(y));
      if (share > worst_share) {
        worst_share = share;
        worst = a;
      }
    }
    const Eigen::MatrixXd column = information.middleCols<2>(2 * worst);
    const Mat2 pivot = information.block<2, 2>(2 * worst, 2 * worst);
    information.noalias() -= column * pivot.ldlt().solve(column.transpose());
    information.middleCols<2>(2 * worst).setZero();
    information.middleRows<2>(2 * worst).setZero();
    innovation.segment<2>(2 * worst).setZero();
    active[worst] = false;
    feature_of[pairings[worst].measurement] = kStar;
    --remaining;
    ++removed;
  }
  if (remaining == 0) distance_sq = 0.0;
  if (joint_distance_sq != nullptr) *joint_distance_sq = distance_sq;
  return removed;
}

// The completion tested each pairing against the seed only. Here the pairings are taken again
// in the order the try accepted them (the seed, then by conditional distance), and each must
// pass the individual gate conditioned on all the pairings kept before it, as on JCBB's
// path: nu_a - C_aK S_K^-1 nu_K with C_aa - C_aK S_K^-1 C_Ka. A wrong pairing that the
// seed alone cannot refute is refuted by its neighbours. O(k^3) for k pairings, with the
// factor of S_K grown a block at a time. Returns the number of pairings removed.
int accept_sequentially(const std::vector<Pairing>& order, int seed_size,
                        std::vector<int>& feature_of, const PairingModel& model, double gate) {
  const auto k = static_cast<Eigen::Index>(order.size());
  Eigen::MatrixXd lower = Eigen::MatrixXd::Zero(2 * k, 2 * k);  // factor of S_K, grown
  Eigen::VectorXd whitened(2 * k);
  std::vector<Pairing> kept;
  Eigen::MatrixXd cross(2 * k, 2);
  int removed = 0;
  for (Eigen::Index a = 0; a < k; ++a) {
    const Pairing& pairing = order[static_cast<std::size_t>(a)];
    const auto m = static_cast<Eigen::Index>(kept.size());
    for (Eigen::Index c = 0; c < m; ++c) {
      cross.middleRows<2>(2 * c) = model.covariance(kept[static_cast<std::size_t>(c)], pairing);
    }
    auto cross_kept = cross.topRows(2 * m);
    lower.topLeftCorner(2 * m, 2 * m).triangularView<Eigen::Lower>().solveInPlace(cross_kept);
    const Vec2 innovation = model.innovation(pairing) - cross_kept.transpose() * whitened.head(2 * m);
    const Mat2 covariance = model.covariance(pairing, pairing) - cross_kept.transpose() * cross_kept;
    const Eigen::LLT<Mat2> factor(covariance);
    const bool seed = a < seed_size;
    if (factor.info() != Eigen::Success ||
        (!seed && factor.matrixL().solve(innovation).squaredNorm() > gate)) {
      feature_of[pairing.measurement] = kStar;
      ++removed;
      continue;
    }
    lower.block(2 * m, 0, 2, 2 * m) = cross_kept.transpose();
    lower.block<2, 2>(2 * m, 2 * m) = factor.matrixL();
    whitened.segment<2>(2 * m) = factor.matrixL().solve(innovation);
    kept.push_back(pairing);
  }
  return removed;
}

RjcResult rjc(const CandidateLists& candidates, const PairingModel& model,
              const RjcOptions& options) {
  check_options(options);
  const auto m = candidates.size();
  RjcResult result;
  result.feature_of.assign(m, kStar);

  std::vector<int> overlap;
  for (std::size_t i = 0; i < m; ++i) {
    if (!candidates[i].empty()) overlap.push_back(static_cast<int>(i));
  }
  result.overlap_size = static_cast<int>(overlap.size());
  if (overlap.empty()) return result;

  JcbbOptions jcbb_options;
  jcbb_options.confidence = options.confidence;
  jcbb_options.max_nodes = options.max_nodes_per_try;
  const int b = options.b;
  if (result.overlap_size <= b) {
    const JcbbResult all = jcbb(candidates, model, jcbb_options);
    result.feature_of = all.feature_of;
    result.pairings = all.pairings;
    result.joint_distance_sq = all.joint_distance_sq;
    result.tries = 1;
    return result;
  }

  jcbb_options.allow_star = false;
  Jcbb star_free(jcbb_options);
  const double gate = chi2_quantile(2, options.confidence);
  std::mt19937_64 rng(options.seed);
  std::vector<int> pool = overlap;
  std::vector<int> sample(static_cast<std::size_t>(b));
  CandidateLists sample_candidates(static_cast<std::size_t>(b));
  const SampledModel sampled_model(model, sample);
  std::vector<int> feature_of(m, kStar);
  std::vector<int> used_features;
  std::vector<Pairing> hypothesis;
  std::vector<std::tuple<double, int, int>> conditional;  // (distance^2, measurement, feature)
  Eigen::MatrixXd seed_covariance(2 * b, 2 * b);
  Eigen::VectorXd seed_innovation(2 * b);
  Eigen::MatrixXd cross(2 * b, 2);

  int best_pairings = 0;
  double best_score = std::numeric_limits<double>::infinity();
  std::vector<Pairing> order, best_order;  // pairings in the order the try accepted them
  double p_good = options.p_good;
  double tries_wanted = tries_needed(p_good, b, options.p_fail);
  while (result.tries < tries_wanted && result.tries < options.max_tries) {
    ++result.tries;
    // Partial Fisher–Yates: the first b slots of the pool become a uniform sample.
    for (std::size_t k = 0; k < sample.size(); ++k) {
      std::swap(pool[k], pool[k + draw_below(rng, pool.size() - k)]);
      sample[k] = pool[k];
      sample_candidates[k] = candidates[static_cast<std::size_t>(pool[k])];
    }
    const JcbbResult seed = star_free.solve(sample_candidates, sampled_model);
    if (seed.pairings < b) continue;

    std::fill(feature_of.begin(), feature_of.end(), kStar);
    used_features.clear();
    hypothesis.clear();
    for (int k = 0; k < b; ++k) {
      const Pairing pairing{sample[static_cast<std::size_t>(k)], seed.feature_of[k]};
      hypothesis.push_back(pairing);
      feature_of[pairing.measurement] = pairing.feature;
      used_features.push_back(pairing.feature);
      seed_innovation.segment<2>(2 * k) = model.innovation(pairing);
      for (int c = 0; c <= k; ++c) {
        const Mat2 block = model.covariance(pairing, hypothesis[static_cast<std::size_t>(c)]);
        seed_covariance.block<2, 2>(2 * k, 2 * c) = block;
        seed_covariance.block<2, 2>(2 * c, 2 * k) = block.transpose();
      }
    }
    const Eigen::LLT<Eigen::MatrixXd> seed_factor(seed_covariance);
    if (seed_factor.info() != Eigen::Success) continue;
    const auto lower = seed_factor.matrixL();
    const Eigen::VectorXd whitened = lower.solve(seed_innovation);

    conditional.clear();
    for (int measurement : overlap) {
      if (feature_of[measurement] != kStar) continue;
      for (int feature : candidates[measurement]) {
        if (std::find(used_features.begin(), used_features.end(), feature) != used_features.end()) {
          continue;
        }
        const Pairing pairing{measurement, feature};
        for (std::size_t k = 0; k < hypothesis.size(); ++k) {
          cross.middleRows<2>(2 * static_cast<Eigen::Index>(k)) =
              model.covariance(hypothesis[k], pairing);
        }
        lower.solveInPlace(cross);
        const Vec2 innovation = model.innovation(pairing) - cross.transpose() * whitened;
        const Mat2 covariance = model.covariance(pairing, pairing) - cross.transpose() * cross;
        const Eigen::LLT<Mat2> covariance_factor(covariance);
        if (covariance_factor.info() != Eigen::Success) continue;
        const double distance_sq = covariance_factor.matrixL().solve(innovation).squaredNorm();
        if (distance_sq <= gate) conditional.emplace_back(distance_sq, measurement, feature);
      }
    }
    std::sort(conditional.begin(), conditional.end());
    int pairings = b;
    double score = seed.joint_distance_sq;
    order = hypothesis;
    for (const auto& [distance_sq, measurement, feature] : conditional) {
      if (feature_of[measurement] != kStar) continue;
      if (std::find(used_features.begin(), used_features.end(), feature) != used_features.end()) {
        continue;
      }
      order.push_back(Pairing{measurement, feature});
      feature_of[measurement] = feature;
      used_features.push_back(feature);
      ++pairings;
      score += distance_sq;
    }

    if (pairings > best_pairings || (pairings == best_pairings && score < best_score)) {
      best_pairings = pairings;
      best_score = score;
      result.feature_of = feature_of;
      best_order = order;
    }
    p_good = std::max(p_good, static_cast<double>(best_pairings) / result.overlap_size);
    tries_wanted = tries_needed(p_good, b, options.p_fail);
  }

  result.joint_distance_sq = std::numeric_limits<double>::quiet_NaN();
  if (best_pairings == 0) {
    result.joint_distance_sq = 0.0;
  } else if (options.verify) {
    result.dropped = accept_sequentially(best_order, b, result.feature_of, model, gate);
    result.dropped += enforce_joint_compatibility(result.feature_of, model, options.confidence,
                                                  &result.joint_distance_sq);
  }
  result.pairings = best_pairings - result.dropped;
  return result;
}

}  // namespace dcslam
