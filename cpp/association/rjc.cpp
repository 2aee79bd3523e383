#include "dcslam/association/rjc.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <tuple>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include <Eigen/Cholesky>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/pairing_exchanges.hpp"

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
  if (options.work_unit < 1) throw InvalidArgument("RjcOptions.work_unit must be >= 1");
  if (options.panel_width < 1) throw InvalidArgument("RjcOptions.panel_width must be >= 1");
}

}  // namespace

int enforce_joint_compatibility(std::vector<int>& feature_of, const PairingModel& model,
                                double confidence, double* joint_distance_sq) {
  JointCompatibilityEnforcement enforcement(feature_of, model, confidence,
                                            RjcOptions().panel_width, RjcOptions().work_unit);
  enforcement.finish();
  if (joint_distance_sq != nullptr) *joint_distance_sq = enforcement.joint_distance_sq();
  return enforcement.removed();
}

int accept_sequentially(const std::vector<Pairing>& order, int seed_size,
                        std::vector<int>& feature_of, const PairingModel& model, double gate) {
  SequentialAcceptance acceptance(order, seed_size, feature_of, model, gate);
  acceptance.finish();
  return acceptance.removed();
}

// The completion tested each pairing against the seed only. Here the pairings are taken again
// in the order the try accepted them (the seed, then by conditional distance), and each must
// pass the individual gate conditioned on all the pairings kept before it, as on JCBB's
// path: nu_a - C_aK S_K^-1 nu_K with C_aa - C_aK S_K^-1 C_Ka. A wrong pairing that the
// seed alone cannot refute is refuted by its neighbours. O(k^3) for k pairings, with the
// factor of S_K grown a block at a time (ConditionedPairingModel).
SequentialAcceptance::SequentialAcceptance(const std::vector<Pairing>& order, int seed_size,
                                           std::vector<int>& feature_of,
                                           const PairingModel& model, double gate, std::int64_t work_unit)
    : order_(order),
      seed_size_(seed_size),
      feature_of_(feature_of),
      gate_(gate),
      work_unit_(work_unit),
      conditioned_(model, static_cast<Eigen::Index>(order.size())) {}

std::int64_t SequentialAcceptance::step_work(std::int64_t kept) {
  return ConditionedPairingModel::condition_work(kept);
}

// A step counts what testing its pairings one at a time would, so that an amortized join's
// schedule does not depend on the panels.
std::int64_t SequentialAcceptance::step(std::int64_t) {
  const std::int64_t kept = conditioned_.kept();
  const Eigen::Index count = ConditionedPairingModel::panel_pairings(
      kept, static_cast<Eigen::Index>(order_.size()) - next_, work_units(work_unit_));
  panel_.assign(order_.begin() + next_, order_.begin() + next_ + count);
  panel_gates_.resize(static_cast<std::size_t>(count));
  for (Eigen::Index p = 0; p < count; ++p) {
    const bool seed = next_ + p < seed_size_;
    panel_gates_[static_cast<std::size_t>(p)] = seed ? std::numeric_limits<double>::infinity() : gate_;
  }
  const std::size_t tested =
      conditioned_.keep_each_within(panel_, panel_gates_, std::max(1, removal_limit_ - removed_), panel_kept_);
  next_ += static_cast<Eigen::Index>(tested);
  std::int64_t work = 0;
  std::int64_t kept_before = kept;
  for (std::size_t p = 0; p < tested; ++p) {
    work += step_work(kept_before);
    if (panel_kept_[p]) {
      ++kept_before;
    } else {
      feature_of_[panel_[p].measurement] = kStar;
      ++removed_;
    }
  }
  return work;
}

double SequentialAcceptance::conditional_distance_sq(const Pairing& pairing) {
  return conditioned_.conditional_distance_sq(pairing);
}

bool SequentialAcceptance::append(const Pairing& pairing) {
  if (!conditioned_.keep_if_within(pairing, gate_)) return false;
  feature_of_[pairing.measurement] = pairing.feature;
  return true;
}

double SequentialAcceptance::joint_distance_sq() const { return conditioned_.joint_distance_sq(); }

// Each pairing left costs its covariances with the kept ones and a triangular solve of their
// factor: about sum over m of (16 m + m^2 / 2) units.
std::int64_t SequentialAcceptance::remaining_work() const {
  const auto left = static_cast<std::int64_t>(order_.size()) - next_;
  return work_left(conditioned_.kept(), left);
}

std::int64_t SequentialAcceptance::work_left(std::int64_t kept, std::int64_t left) {
  const std::int64_t m0 = kept, m1 = m0 + left;
  return kPairingCovarianceUnits * left * (m0 + m1) / 2 + (m1 * m1 * m1 - m0 * m0 * m0) / 6 + left;
}

JointCompatibilityEnforcement::JointCompatibilityEnforcement(std::vector<int>& feature_of,
                                                             const PairingModel& model,
                                                             double confidence,
                                                             Eigen::Index panel_width,
                                                             std::int64_t work_unit)
    : feature_of_(feature_of), model_(model), confidence_(confidence), panel_width_(panel_width),
      work_unit_(work_unit), stacked_(feature_of) {
  if (stacked_.pairings.empty()) stage_ = Stage::Done;
}

// S is stacked a block row per step (StackedHypothesis::stack()); it is then factored, and
// usually the hypothesis passes as it is: the factor alone decides (k^3 / 3), and the inverse
// (three times that) is only formed when pairings have to go. Removing pairing a leaves
// (S_rr)^-1 = L_rr - L_ra L_aa^-1 L_ar (L = S^-1): the same rank-2 update applied to the whole
// L also zeroes a's rows and columns, so removed pairings need no compaction. a's share of D^2
// is y_a' L_aa^-1 y_a with y = L nu.
std::int64_t JointCompatibilityEnforcement::step(std::int64_t budget) {
  const std::vector<Pairing>& pairings = stacked_.pairings;
  const auto k = static_cast<Eigen::Index>(pairings.size());
  Eigen::VectorXd& innovation = stacked_.innovation;  // entries of removed pairings are zeroed
  const Eigen::MatrixXd& factor = cholesky_.matrix();
  const auto n = static_cast<std::int64_t>(2 * k);
  switch (stage_) {
    case Stage::Stack: {
      const Eigen::Index a = next_;
      stacked_.stack(a, model_);
      if (++next_ == k) {
        cholesky_ = ResumableCholesky(std::move(stacked_.covariance), panel_width_);
        stage_ = Stage::Factor;
      }
      return kPairingCovarianceUnits * (a + 1);
    }
    case Stage::Factor: {
      const std::int64_t work = cholesky_.step(budget);
      if (cholesky_.failed()) {
        throw InvalidArgument("enforce_joint_compatibility: joint covariance not positive definite");
      }
      if (cholesky_.done()) stage_ = Stage::Test;
      return work;
    }
    case Stage::Test: {
      const double whole_distance_sq =
          factor.triangularView<Eigen::Lower>().solve(innovation).squaredNorm();
      if (whole_distance_sq <= chi2_quantile(2 * static_cast<int>(k), confidence_)) {
        distance_sq_ = whole_distance_sq;
        stage_ = Stage::Done;
      } else {
        information_.resize(2 * k, 2 * k);
        next_ = 0;
        stage_ = Stage::Invert;
      }
      return 1 + work_units(n * n / 2);
    }
    case Stage::Invert: {
      // S^-1 = L^-T L^-1 a block of columns at a time (columns are independent).
      const Eigen::Index width = std::clamp<Eigen::Index>(
          static_cast<Eigen::Index>(work_unit_ / (n * n)), 1, 2 * k);
      const Eigen::Index c = next_, w = std::min(width, 2 * k - c);
      auto columns = information_.middleCols(c, w);
      columns.setZero();
      columns.block(c, 0, w, w).setIdentity();
      factor.triangularView<Eigen::Lower>().solveInPlace(columns);
      factor.triangularView<Eigen::Lower>().transpose().solveInPlace(columns);
      next_ = c + w;
      if (next_ == 2 * k) {
        active_.assign(static_cast<std::size_t>(k), true);
        remaining_ = k;
        stage_ = Stage::Remove;
      }
      return 1 + work_units(n * n * w);
    }
    case Stage::Remove: {
      Eigen::MatrixXd& information = information_;
      const Eigen::VectorXd weighted = information * innovation;
      distance_sq_ = innovation.dot(weighted);
      if (distance_sq_ <= chi2_quantile(2 * static_cast<int>(remaining_), confidence_)) {
        stage_ = Stage::Done;
        return 1 + work_units(n * n);
      }
      Eigen::Index worst = -1;
      double worst_share = -1.0;
      for (Eigen::Index a = 0; a < k; ++a) {
        if (!active_[a]) continue;
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
      active_[worst] = false;
      feature_of_[pairings[worst].measurement] = kStar;
      --remaining_;
      ++removed_;
      if (remaining_ == 0) {
        distance_sq_ = 0.0;
        stage_ = Stage::Done;
      }
      return 1 + work_units(3 * n * n);
    }
    case Stage::Done:
      break;
  }
  return 0;
}

// Until the test, the stacking (k^2 / 2 blocks) and the factor; a failing test adds the inverse
// (n^3 multiply-adds), and each removal 3 n^2.
std::int64_t JointCompatibilityEnforcement::remaining_work() const {
  const auto k = static_cast<std::int64_t>(stacked_.pairings.size()), n = 2 * k;
  switch (stage_) {
    case Stage::Stack:
      return kPairingCovarianceUnits * (k * (k + 1) - next_ * (next_ + 1)) / 2 + work_units(n * n * n / 3);
    case Stage::Factor:
      return cholesky_.remaining_work() + 1;
    case Stage::Test:
      return 1 + work_units(n * n / 2);
    case Stage::Invert:
      return work_units(n * n * (n - next_)) + work_units(remaining_ * 3 * n * n);
    case Stage::Remove:
      return 1 + work_units(remaining_ * 3 * n * n);
    case Stage::Done:
      break;
  }
  return 0;
}

RjcResult rjc(const CandidateLists& candidates, const PairingModel& model,
              const RjcOptions& options) {
  RjcSearch search(candidates, model, options);
  search.finish();
  return search.result();
}

RjcSearch::RjcSearch(const CandidateLists& candidates, const PairingModel& model,
                     const RjcOptions& options)
    : candidates_(candidates), model_(model), options_(options), star_free_([&] {
        check_options(options);
        JcbbOptions jcbb_options;
        jcbb_options.confidence = options.confidence;
        jcbb_options.max_nodes = options.max_nodes_per_try;
        jcbb_options.allow_star = false;
        return jcbb_options;
      }()),
      gate_(chi2_quantile(2, options.confidence)), rng_(options.seed) {}

std::int64_t RjcSearch::step(std::int64_t budget) {
  switch (stage_) {
    case Stage::Start:
      return start();
    case Stage::Seed:
      return seed();
    case Stage::Conditional:
      return conditional_next();
    case Stage::CompleteTry:
      return complete_try();
    case Stage::VerifyTry: {
      // Stopped once its removals leave the try unable to beat (or rival) the best one: the
      // rest of its verification could only remove more.
      SequentialAcceptance& acceptance = *try_verification_->acceptance;
      const std::int64_t work = acceptance.step(budget);
      if (acceptance.done() || !worth_verifying(try_pairings_ - acceptance.removed())) end_of_try();
      return work;
    }
    case Stage::Sequential:
      return verify_next(budget);
    case Stage::Completion:
      return completion_next();
    case Stage::CompletionAdd:
      return completion_add_next();
    case Stage::Joint: {
      const std::int64_t work = joint_->step(budget);
      if (joint_->done()) {
        result_.dropped += joint_->removed();
        result_.joint_distance_sq = joint_->joint_distance_sq();
        result_.pairings = best_verification_->acceptance->kept() - joint_->removed();
        joint_.reset();
        take_verified_hypothesis();
      }
      return work;
    }
    case Stage::Done:
      break;
  }
  return 0;
}

// The overlap; a small one (|O| <= b) is paired by plain JCBB with the star in this step.
std::int64_t RjcSearch::start() {
  const auto m = candidates_.size();
  result_.feature_of.assign(m, kStar);
  std::int64_t candidate_count = 0;
  for (std::size_t i = 0; i < m; ++i) {
    if (!candidates_[i].empty()) overlap_.push_back(static_cast<int>(i));
    candidate_count += static_cast<std::int64_t>(candidates_[i].size());
  }
  result_.overlap_size = static_cast<int>(overlap_.size());
  const int b = options_.b;
  if (overlap_.empty()) {
    stage_ = Stage::Done;
    return 1 + static_cast<std::int64_t>(m);
  }
  if (result_.overlap_size <= b) {
    JcbbOptions jcbb_options = star_free_.options();
    jcbb_options.allow_star = true;
    const JcbbResult all = jcbb(candidates_, model_, jcbb_options);
    result_.feature_of = all.feature_of;
    result_.pairings = all.pairings;
    result_.joint_distance_sq = all.joint_distance_sq;
    result_.tries = 1;
    stage_ = Stage::Done;
    return 1 + static_cast<std::int64_t>(m) +
           kPairingCovarianceUnits * (candidate_count + all.nodes_expanded * b);
  }
  pool_ = overlap_;
  sample_.resize(static_cast<std::size_t>(b));
  sample_candidates_.resize(static_cast<std::size_t>(b));
  feature_of_.assign(m, kStar);
  cross_.resize(2 * b, 2);
  best_pairings_ = 0;
  best_score_ = std::numeric_limits<double>::infinity();
  p_good_ = options_.p_good;
  tries_wanted_ = tries_needed(p_good_, b, options_.p_fail);
  stage_ = Stage::Seed;
  return 1 + static_cast<std::int64_t>(m);
}

// The next try's sample and its seed hypothesis (JCBB* over b measurements, bounded by
// max_nodes_per_try), or the end of the tries.
std::int64_t RjcSearch::seed() {
  std::int64_t work = 0;
  if (constellation_tries_end_ < 0 && !(result_.tries < tries_wanted_ && result_.tries < options_.max_tries)) {
    if (options_.positions == nullptr || best_pairings_ >= kConstellationShare * result_.overlap_size) {
      end_of_tries();
      return 1;
    }
    constellation_tries_end_ = result_.tries + options_.max_tries;
  }
  if (constellation_tries_end_ >= 0 && result_.tries >= constellation_tries_end_) {
    end_of_tries();
    return 1;
  }
  const int b = options_.b;
  ++result_.tries;
  if (constellation_tries_end_ >= 0) {
    work += static_cast<std::int64_t>(overlap_.size());
    if (!draw_constellation()) return work;
  } else {
    draw_uniform_sample();
  }
  const SampledModel sampled_model(model_, sample_);
  const JcbbResult seed = star_free_.solve(sample_candidates_, sampled_model);
  work += kPairingCovarianceUnits * (1 + seed.nodes_expanded) * b;
  if (seed.pairings < b) return work;

  std::fill(feature_of_.begin(), feature_of_.end(), kStar);
  used_features_.clear();
  seed_.pairings.clear();
  for (int k = 0; k < b; ++k) {
    const Pairing pairing{sample_[static_cast<std::size_t>(k)], seed.feature_of[k]};
    seed_.pairings.push_back(pairing);
    feature_of_[pairing.measurement] = pairing.feature;
    used_features_.push_back(pairing.feature);
  }
  seed_.resize();
  for (int k = 0; k < b; ++k) seed_.stack(k, model_);
  const Eigen::LLT<Eigen::MatrixXd> seed_factor(seed_.covariance);
  if (seed_factor.info() != Eigen::Success) return work;
  seed_.covariance = seed_factor.matrixL();
  seed_whitened_ = seed_factor.matrixL().solve(seed_.innovation);
  seed_distance_sq_ = seed.joint_distance_sq;
  conditional_.clear();
  next_overlap_ = 0;
  stage_ = Stage::Conditional;
  return work;
}

// Partial Fisher–Yates: the first b slots of the pool become a uniform sample.
void RjcSearch::draw_uniform_sample() {
  for (std::size_t k = 0; k < sample_.size(); ++k) {
    std::swap(pool_[k], pool_[k + draw_below(rng_, pool_.size() - k)]);
    sample_[k] = pool_[k];
    sample_candidates_[k] = candidates_[static_cast<std::size_t>(pool_[k])];
  }
}

// One measurement of the overlap, uniformly, and its b - 1 nearest ones in the overlap. O(|O|).
bool RjcSearch::draw_constellation() {
  if (overlap_.size() < sample_.size()) return false;
  const int first = overlap_[draw_below(rng_, overlap_.size())];
  const std::vector<Vec2>& positions = *options_.positions;
  nearest_.clear();
  for (int other : overlap_) {
    if (other == first) continue;
    nearest_.emplace_back((positions[static_cast<std::size_t>(other)] - positions[static_cast<std::size_t>(first)]).squaredNorm(), other);
  }
  const auto rest = static_cast<std::ptrdiff_t>(sample_.size() - 1);
  std::partial_sort(nearest_.begin(), nearest_.begin() + rest, nearest_.end());
  sample_[0] = first;
  for (std::ptrdiff_t k = 0; k < rest; ++k) sample_[static_cast<std::size_t>(k + 1)] = nearest_[static_cast<std::size_t>(k)].second;
  for (std::size_t k = 0; k < sample_.size(); ++k) sample_candidates_[k] = candidates_[static_cast<std::size_t>(sample_[k])];
  return true;
}

// One overlap measurement not in the seed: each of its candidates (features not in the seed)
// conditioned on the seed hypothesis H, kept if it passes the 2-dof gate.
std::int64_t RjcSearch::conditional_next() {
  const int measurement = overlap_[next_overlap_];
  std::int64_t work = 1;
  if (feature_of_[measurement] == kStar) {
    const auto lower = seed_.covariance.triangularView<Eigen::Lower>();
    for (int feature : candidates_[measurement]) {
      if (std::find(used_features_.begin(), used_features_.end(), feature) != used_features_.end()) {
        continue;
      }
      const Pairing pairing{measurement, feature};
      for (std::size_t k = 0; k < seed_.pairings.size(); ++k) {
        cross_.middleRows<2>(2 * static_cast<Eigen::Index>(k)) = model_.covariance(seed_.pairings[k], pairing);
      }
      lower.solveInPlace(cross_);
      work += kPairingCovarianceUnits * static_cast<std::int64_t>(seed_.pairings.size() + 1) +
              static_cast<std::int64_t>(cross_.size());
      const Vec2 innovation = model_.innovation(pairing) - cross_.transpose() * seed_whitened_;
      const Mat2 covariance = model_.covariance(pairing, pairing) - cross_.transpose() * cross_;
      const Eigen::LLT<Mat2> covariance_factor(covariance);
      if (covariance_factor.info() != Eigen::Success) continue;
      const double distance_sq = covariance_factor.matrixL().solve(innovation).squaredNorm();
      if (distance_sq <= gate_) conditional_.emplace_back(distance_sq, measurement, feature);
    }
  }
  if (++next_overlap_ == overlap_.size()) stage_ = Stage::CompleteTry;
  return work;
}

// The try's hypothesis: the conditional pairings greedily by distance, each feature used once
// (and with options_.exchange_crossed, crossed pairings exchanged: pairing_exchanges.hpp);
// kept if it beats the best, which may raise p_good and so lower the number of tries.
std::int64_t RjcSearch::complete_try() {
  std::sort(conditional_.begin(), conditional_.end());
  int pairings = options_.b;
  std::vector<int> paired;
  for (const auto& [distance_sq, measurement, feature] : conditional_) {
    if (feature_of_[measurement] != kStar) continue;
    if (std::find(used_features_.begin(), used_features_.end(), feature) != used_features_.end()) {
      continue;
    }
    paired.push_back(measurement);
    feature_of_[measurement] = feature;
    used_features_.push_back(feature);
    ++pairings;
  }
  std::int64_t work = options_.exchange_crossed ? exchange_crossed_pairings(conditional_, paired, feature_of_) : 0;
  // The conditional list holds no measurement of the seed, and each (measurement, feature)
  // once: its entries that are pairings now, in its order, are the try's pairings by distance.
  double score = seed_distance_sq_;
  order_ = seed_.pairings;
  for (const auto& [distance_sq, measurement, feature] : conditional_) {
    if (feature_of_[measurement] != feature) continue;
    order_.push_back(Pairing{measurement, feature});
    score += distance_sq;
  }
  try_pairings_ = pairings;
  try_score_ = score;
  const auto c = static_cast<std::int64_t>(conditional_.size());
  work += 1 + c * (4 + work_units(static_cast<std::int64_t>(used_features_.size()))) +
          work_units(static_cast<std::int64_t>(feature_of_.size()));
  if (options_.verify && pairings > options_.b && worth_verifying(pairings)) {
    // Scored once verified (see rjc()), a pairing per step like the final verification; the
    // kept hypothesis is the try's own, and if it is the best this verification is the final
    // one's (verify_next()). A verification only removes pairings, so a try that cannot beat
    // the best one unverified is not verified at all.
    if (!try_verification_) try_verification_ = std::make_unique<TryVerification>();
    begin_verification(*try_verification_, order_, feature_of_);
    // A panel stops where a pairing at a time would end the try (VerifyTry).
    int removal_limit = 1;
    while (removal_limit <= pairings && worth_verifying(pairings - removal_limit)) ++removal_limit;
    try_verification_->acceptance->stop_after_removals(removal_limit);
    stage_ = Stage::VerifyTry;
  } else {
    end_of_try();
  }
  return work;
}

void RjcSearch::begin_verification(TryVerification& verification, const std::vector<Pairing>& order,
                                   const std::vector<int>& feature_of) const {
  verification.order = order;
  verification.feature_of = feature_of;
  verification.acceptance.emplace(verification.order, options_.b, verification.feature_of, model_, gate_,
                                  options_.work_unit);
}

bool RjcSearch::can_beat_best(int pairings) const {
  return pairings > best_pairings_ || (pairings == best_pairings_ && try_score_ < best_score_);
}

bool RjcSearch::worth_verifying(int pairings) const {
  return can_beat_best(pairings) || (options_.rival_margin >= 0 && pairings >= best_pairings_ - options_.rival_margin);
}

void RjcSearch::end_of_try() {
  const bool verified = try_verification_ && try_verification_->acceptance;
  if (verified) try_pairings_ -= try_verification_->acceptance->removed();
  if (verified && options_.rival_margin >= 0 && try_verification_->acceptance->done()) {
    std::vector<Pairing>& kept = verified_tries_.emplace_back();
    for (const Pairing& pairing : try_verification_->order) {
      if (try_verification_->feature_of[static_cast<std::size_t>(pairing.measurement)] == pairing.feature) {
        kept.push_back(pairing);
      }
    }
  }
  if (can_beat_best(try_pairings_)) {
    best_pairings_ = try_pairings_;
    best_score_ = try_score_;
    result_.feature_of = feature_of_;
    best_order_ = order_;
    if (verified) {
      std::swap(best_verification_, try_verification_);
    } else {
      best_verification_.reset();
    }
  }
  if (try_verification_) try_verification_->acceptance.reset();
  p_good_ = std::max(p_good_, static_cast<double>(best_pairings_) / result_.overlap_size);
  tries_wanted_ = tries_needed(p_good_, options_.b, options_.p_fail);
  stage_ = Stage::Seed;
}

void RjcSearch::end_of_tries() {
  result_.joint_distance_sq = std::numeric_limits<double>::quiet_NaN();
  result_.pairings = best_pairings_;
  if (best_pairings_ == 0) {
    result_.joint_distance_sq = 0.0;
    stage_ = Stage::Done;
  } else if (options_.verify) {
    if (options_.rival_margin >= 0) {
      leave_out_disputed();
      if (stage_ == Stage::Done) return;
    }
    try_verification_.reset();
    verification_replayed_ = best_verification_ != nullptr;
    if (!verification_replayed_) {  // the best try was its seed alone, which no try verifies
      best_verification_ = std::make_unique<TryVerification>();
      begin_verification(*best_verification_, best_order_, result_.feature_of);
    }
    int features = 0;
    for (const auto& list : candidates_) {
      for (int feature : list) features = std::max(features, feature + 1);
    }
    feature_used_.assign(static_cast<std::size_t>(features), 0);
    for (int feature : result_.feature_of) {
      if (feature != kStar) feature_used_[static_cast<std::size_t>(feature)] = 1;
    }
    stage_ = Stage::Sequential;
  } else {
    stage_ = Stage::Done;
  }
}

// The best try's verified hypothesis against every verified try near it in pairings. A try
// agrees with a pairing of its own that the best try makes too, or that passes the gate
// conditioned on all the best try's pairings (a try that paired another part of the same
// alignment: a whole-lap join's tries each pair a part of the overlap); it is a rival when it
// agrees with fewer than kRivalShare of its pairings: another alignment. The best try's
// pairings a rival does not make are disputed. Without disputed pairings nothing changes;
// with them, the rest is verified again (the final verification), in the order the best try
// accepted them. O(k^2) for each pairing of a near try that the best try does not make.
void RjcSearch::leave_out_disputed() {
  if (!best_verification_) {  // the best try was its seed alone: no try verified comes near it
    verified_tries_.clear();
    return;
  }
  const std::vector<int>& best = best_verification_->feature_of;
  SequentialAcceptance& acceptance = *best_verification_->acceptance;
  std::vector<int> consensus = best;
  int best_pairings = 0;
  std::unordered_set<int> best_features;
  for (int feature : best) {
    if (feature == kStar) continue;
    ++best_pairings;
    best_features.insert(feature);
  }
  std::vector<char> shared(best.size());
  for (const std::vector<Pairing>& kept : verified_tries_) {
    if (static_cast<int>(kept.size()) < best_pairings - options_.rival_margin) continue;
    std::fill(shared.begin(), shared.end(), 0);
    int agreeing = 0;
    for (const Pairing& pairing : kept) {
      const auto i = static_cast<std::size_t>(pairing.measurement);
      if (best[i] == pairing.feature) {
        shared[i] = 1;
        ++agreeing;
      } else if (best[i] == kStar && best_features.count(pairing.feature) == 0 &&
                 acceptance.conditional_distance_sq(pairing) <= gate_) {
        ++agreeing;
      }
    }
    if (agreeing >= kRivalShare * static_cast<double>(kept.size())) continue;
    ++result_.rivals;
    for (std::size_t i = 0; i < consensus.size(); ++i) {
      if (consensus[i] != kStar && !shared[i]) {
        result_.disputed.push_back(Pairing{static_cast<int>(i), consensus[i]});
        consensus[i] = kStar;
      }
    }
  }
  verified_tries_.clear();
  if (result_.disputed.empty()) return;
  std::vector<Pairing> order;
  for (const Pairing& pairing : best_order_) {
    if (consensus[static_cast<std::size_t>(pairing.measurement)] == pairing.feature) order.push_back(pairing);
  }
  best_order_ = std::move(order);
  result_.feature_of = std::move(consensus);
  best_verification_.reset();
  best_pairings_ = static_cast<int>(best_order_.size());
  result_.pairings = best_pairings_;
  if (best_pairings_ == 0) {
    result_.joint_distance_sq = 0.0;
    stage_ = Stage::Done;
  }
}

// The final verification's next pairing. When the best try was verified as it was scored, that
// was this same computation on the same pairings, so its result stands and each step only
// counts its work again: an amortized join's schedule (which join finishes at which step, and
// so every estimate) stays that of computing it twice.
std::int64_t RjcSearch::verify_next(std::int64_t budget) {
  TryVerification& verification = *best_verification_;
  SequentialAcceptance& acceptance = *verification.acceptance;
  std::int64_t work = 0;
  bool finished = false;
  if (verification_replayed_) {
    const Pairing& pairing = verification.order[replayed_++];
    work = SequentialAcceptance::step_work(replayed_kept_);
    if (verification.feature_of[static_cast<std::size_t>(pairing.measurement)] != kStar) ++replayed_kept_;
    finished = replayed_ == verification.order.size();
  } else {
    work = acceptance.step(budget);
    finished = acceptance.done();
  }
  if (finished) {
    result_.dropped = acceptance.removed();
    completion_.clear();
    next_completion_ = 0;
    stage_ = Stage::Completion;
  }
  return work;
}

// One overlap measurement left unpaired: its candidates that no kept pairing uses, each
// conditioned on all the kept pairings, collected if they pass the gate.
std::int64_t RjcSearch::completion_next() {
  if (next_completion_ == overlap_.size()) {
    begin_completion_adds();
    return 1;
  }
  const int measurement = overlap_[next_completion_++];
  if (best_verification_->feature_of[static_cast<std::size_t>(measurement)] != kStar) return 1;
  SequentialAcceptance& acceptance = *best_verification_->acceptance;
  const auto k = static_cast<std::int64_t>(acceptance.kept());
  std::int64_t work = 1;
  for (int feature : candidates_[static_cast<std::size_t>(measurement)]) {
    if (feature_used_[static_cast<std::size_t>(feature)]) continue;
    const double distance_sq = acceptance.conditional_distance_sq(Pairing{measurement, feature});
    work += kPairingCovarianceUnits * (k + 1) + k * k / 2;
    if (distance_sq <= gate_) completion_.emplace_back(distance_sq, measurement, feature);
  }
  return work;
}

// Keeps the unambiguous candidates (see kCompletionMargin), nearest first.
void RjcSearch::begin_completion_adds() {
  std::sort(completion_.begin(), completion_.end());
  // completion_ is sorted, so the first entry of a measurement or feature is its nearest.
  std::unordered_map<int, double> nearest_of_measurement, nearest_of_feature;
  std::unordered_map<int, double> runner_up_of_measurement, runner_up_of_feature;
  const auto note = [](std::unordered_map<int, double>& nearest, std::unordered_map<int, double>& runner_up,
                       int key, double distance_sq) {
    if (nearest.emplace(key, distance_sq).second) return;
    runner_up.emplace(key, distance_sq);
  };
  for (const auto& [distance_sq, measurement, feature] : completion_) {
    note(nearest_of_measurement, runner_up_of_measurement, measurement, distance_sq);
    note(nearest_of_feature, runner_up_of_feature, feature, distance_sq);
  }
  const auto unambiguous = [](const std::unordered_map<int, double>& nearest,
                              const std::unordered_map<int, double>& runner_up, int key, double distance_sq) {
    if (nearest.at(key) != distance_sq) return false;
    const auto second = runner_up.find(key);
    return second == runner_up.end() || second->second - distance_sq >= kCompletionMargin;
  };
  std::vector<std::tuple<double, int, int>> kept;
  for (const auto& entry : completion_) {
    const auto& [distance_sq, measurement, feature] = entry;
    if (unambiguous(nearest_of_measurement, runner_up_of_measurement, measurement, distance_sq) &&
        unambiguous(nearest_of_feature, runner_up_of_feature, feature, distance_sq)) {
      kept.push_back(entry);
    }
  }
  completion_ = std::move(kept);
  next_completion_ = 0;
  stage_ = Stage::CompletionAdd;
}

// Adds the next unambiguous candidate if it still passes the gate conditioned on all the
// pairings kept so far, those the completion added included.
std::int64_t RjcSearch::completion_add_next() {
  if (next_completion_ == completion_.size()) {
    end_of_verification();
    return 1;
  }
  const auto [distance_sq, measurement, feature] = completion_[next_completion_++];
  SequentialAcceptance& acceptance = *best_verification_->acceptance;
  const auto k = static_cast<std::int64_t>(acceptance.kept());
  if (acceptance.append(Pairing{measurement, feature})) {
    feature_used_[static_cast<std::size_t>(feature)] = 1;
    ++result_.completed;
  }
  return kPairingCovarianceUnits * (k + 1) + k * k / 2;
}

// The joint test of everything kept: usually passed as it is (the sequential factor already
// holds the kept pairings' D^2, and S need not be stacked and factored again).
void RjcSearch::end_of_verification() {
  const SequentialAcceptance& acceptance = *best_verification_->acceptance;
  const int kept = acceptance.kept();
  const double distance_sq = acceptance.joint_distance_sq();
  if (kept == 0 || distance_sq <= chi2_quantile(2 * kept, options_.confidence)) {
    result_.joint_distance_sq = distance_sq;
    result_.pairings = kept;
    take_verified_hypothesis();
  } else {
    joint_.emplace(best_verification_->feature_of, model_, options_.confidence, options_.panel_width,
                   options_.work_unit);
    stage_ = Stage::Joint;
  }
}

void RjcSearch::take_verified_hypothesis() {
  result_.feature_of = std::move(best_verification_->feature_of);
  best_verification_.reset();
  stage_ = Stage::Done;
}

// One try: its seed and the conditional test of every overlap candidate against b pairings.
std::int64_t RjcSearch::try_cost() const {
  std::int64_t candidate_count = 0;
  for (int measurement : overlap_) {
    candidate_count += static_cast<std::int64_t>(candidates_[static_cast<std::size_t>(measurement)].size());
  }
  const std::int64_t b = options_.b;
  const auto k = static_cast<std::int64_t>(overlap_.size());
  const std::int64_t verification = options_.verify ? kPairingCovarianceUnits * k * k / 2 + k * k * k / 6 : 0;
  return candidate_count * (kPairingCovarianceUnits * (b + 1) + 4 * b) + kPairingCovarianceUnits * b * b +
         verification;
}

// Before the tries end, the tries still wanted plus a verification of the whole overlap; then
// the verification's own estimate.
std::int64_t RjcSearch::remaining_work() const {
  const auto k = static_cast<std::int64_t>(overlap_.size());
  const std::int64_t verification = options_.verify ? k * k * k / 2 : 0;
  switch (stage_) {
    case Stage::Start:
      return static_cast<std::int64_t>(candidates_.size());
    case Stage::Seed:
    case Stage::Conditional:
    case Stage::VerifyTry:
    case Stage::CompleteTry: {
      const double tries_left =
          constellation_tries_end_ >= 0
              ? static_cast<double>(constellation_tries_end_ - result_.tries)
              : std::max(0.0, std::min(tries_wanted_, static_cast<double>(options_.max_tries)) - result_.tries);
      return static_cast<std::int64_t>(std::ceil(tries_left)) * try_cost() + verification;
    }
    case Stage::Sequential: {
      // With the completion (about one more pass) and the joint stage, which only runs should
      // the kept pairings fail the test. A replayed verification counts what running it would.
      const auto replay_left = static_cast<std::int64_t>(best_verification_->order.size() - replayed_);
      const std::int64_t left = verification_replayed_
                                    ? SequentialAcceptance::work_left(replayed_kept_, replay_left)
                                    : best_verification_->acceptance->remaining_work();
      return 2 * left + k * k * k / 3;
    }
    case Stage::Completion:
    case Stage::CompletionAdd: {
      const std::size_t left = (stage_ == Stage::Completion ? overlap_.size() : completion_.size()) - next_completion_;
      return static_cast<std::int64_t>(left) * (kPairingCovarianceUnits * (k + 1) + k * k / 2) + 1 + k * k * k / 3;
    }
    case Stage::Joint:
      return joint_->remaining_work();
    case Stage::Done:
      break;
  }
  return 0;
}

}  // namespace dcslam
