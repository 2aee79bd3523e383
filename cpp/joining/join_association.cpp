#include "dcslam/joining/join_association.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <unordered_map>

#include <Eigen/Eigenvalues>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/association/rjc.hpp"

namespace dcslam {

namespace {

using Index = Eigen::Index;

// Confidence of the individual gate that builds the candidate lists. It only prunes: the
// decisions are taken by the joint test (JCBB) or by the gate conditioned on the seed
// hypothesis (RJC), both at options.rjc.confidence. The marginal pair covariance holds the
// uncertainty of the relative pose of the two maps, an error shared by every pair that the
// joint and conditional tests explain away; a true pair whose marginal distance exceeds the
// decision gate is often compatible given the other pairs (e.g. marginal D^2 = 11.9,
// conditional 4.0 on a loop of the batch least-squares test), so pruning at the decision
// confidence would drop it before JCBB or RJC could accept it. Pruning at ten times the
// decision gate's tail keeps those pairs: on the grid loop of test_dc_slam.cpp (paper's noise,
// 10 seeds, 12,680 true pairs) recall rises from 98.9 % to 99.5 % with no wrong pairing.
double candidate_confidence(double gate_confidence) { return 1.0 - 0.1 * (1.0 - gate_confidence); }

// The second search's pruning gate (JoinAssociator::search_again_wider): a thousandth of the
// decision gate's tail, chi2(2) = 23.0 for a confidence of 0.99 (13.8 for the first search).
// On Victoria Park the true pairs of the joins it rescues lie at marginal D^2 of 13-22.
double wide_candidate_confidence(double gate_confidence) { return 1.0 - 0.001 * (1.0 - gate_confidence); }

int pairings_of(const std::vector<int>& feature_of) {
  return static_cast<int>(std::count_if(feature_of.begin(), feature_of.end(), [](int i) { return i != kStar; }));
}

}  // namespace

Vec2 JoinPairingModel::innovation(const Pairing& p) const {
  return frame_.moved_second_feature(p.measurement) - frame_.first_feature(p.feature);
}

Mat2 JoinPairingModel::covariance(const Pairing& a, const Pairing& b) const {
  return with_feature_variance(a, b, frame_.constraint_covariance(a.feature, a.measurement, b.feature, b.measurement));
}

Mat2 JoinPairingModel::with_feature_variance(const Pairing& a, const Pairing& b, Mat2 covariance) const {
  const int shared = (a.feature == b.feature ? 1 : 0) + (a.measurement == b.measurement ? 1 : 0);
  covariance.diagonal().array() += shared * feature_variance_;
  return covariance;
}

void JoinPairingModel::covariances_with(const Pairing* pairings, std::size_t count, const Pairing& b,
                                        CrossColumns cross) const {
  const JoinFrame::ConstraintColumn column = frame_.constraint_column(b.feature, b.measurement);
  for (std::size_t c = 0; c < count; ++c) {
    const Pairing& a = pairings[c];
    cross.middleRows<2>(2 * static_cast<Eigen::Index>(c)) =
        with_feature_variance(a, b, frame_.constraint_covariance(column, a.feature, a.measurement));
  }
}

std::vector<std::pair<Index, Index>> associate_by_id(const GaussianMap& first,
                                                     const GaussianMap& second) {
  std::unordered_map<std::int64_t, Index> index_of;
  index_of.reserve(first.ids().size());
  for (std::size_t i = 0; i < first.ids().size(); ++i) index_of.emplace(first.ids()[i], i);
  std::vector<std::pair<Index, Index>> pairs;
  for (std::size_t j = 0; j < second.ids().size(); ++j) {
    const auto it = index_of.find(second.ids()[j]);
    if (it != index_of.end()) pairs.emplace_back(it->second, static_cast<Index>(j));
  }
  return pairs;
}

JoinAssociationResult associate_maps(const JoinFrame& frame, const JoinOptions& options) {
  JoinAssociator associator(frame, options);
  associator.finish();
  return associator.result();
}

JoinAssociator::JoinAssociator(const JoinFrame& frame, const JoinOptions& options)
    : frame_(frame), options_(options), model_(frame, options.feature_sigma), confidence_(options.rjc.confidence) {}

std::int64_t JoinAssociator::step(std::int64_t budget) {
  switch (stage_) {
    case Stage::Prepare:
      return prepare();
    case Stage::Candidates:
      return candidates_of_next();
    case Stage::Rjc:
      return advance_rjc(budget);
    case Stage::Chunked:
      return advance_chunked(budget);
    case Stage::Jcbb:
      return advance_jcbb();
    case Stage::Done:
      break;
  }
  return 0;
}

// Candidate search radius: a pair (i, j) passes the gate only if |f'_j - f_i| <=
// sqrt(gate) * (sigma_i + sigma_j), with sigma the largest standard deviation of each
// (feature_sigma included: sqrt(a^2 + s^2) <= a + s).
std::int64_t JoinAssociator::prepare() {
  const GaussianMap& m1 = frame_.first();
  const GaussianMap& m2 = frame_.second();
  const Index n1 = m1.num_features(), n2 = m2.num_features();
  if (n1 == 0 || n2 == 0) {
    stage_ = Stage::Done;
    return 1;
  }
  const double pruning_confidence = narrow_ ? wide_candidate_confidence(options_.rjc.confidence)
                                            : candidate_confidence(options_.rjc.confidence);
  pruning_gate_ = chi2_quantile(2, pruning_confidence);
  gate_radius_ = std::sqrt(pruning_gate_);
  for (Index i = 0; i < n1; ++i) sigma_first_ = std::max(sigma_first_, largest_std(frame_.first_first(i, i)));
  sigma_first_ += options_.feature_sigma;
  sigma_second_.resize(static_cast<std::size_t>(n2));
  double typical_radius = 0.0;
  for (Index j = 0; j < n2; ++j) {
    sigma_second_[static_cast<std::size_t>(j)] =
        largest_std(frame_.second_second(j, j)) + options_.feature_sigma;
    typical_radius = std::max(typical_radius, gate_radius_ * (sigma_first_ + sigma_second_[static_cast<std::size_t>(j)]));
  }
  hash_.emplace(std::max(0.5, typical_radius));
  for (Index i = 0; i < n1; ++i) hash_->insert(static_cast<int>(i), m1.feature(i));
  candidates_.resize(static_cast<std::size_t>(n2));
  stage_ = Stage::Candidates;
  return 1 + kPairingCovarianceUnits * static_cast<std::int64_t>(n1 + n2);
}

// The features of m1 near m2's next feature, kept if individually compatible at the pruning
// gate (what individually_compatible() does, one list at a time).
std::int64_t JoinAssociator::candidates_of_next() {
  const Index j = next_second_;
  const double radius = gate_radius_ * (sigma_first_ + sigma_second_[static_cast<std::size_t>(j)]);
  hash_->query(frame_.moved_second_feature(j), radius, nearby_);
  std::sort(nearby_.begin(), nearby_.end());
  std::vector<int>& compatible = candidates_[static_cast<std::size_t>(j)];
  for (int feature : nearby_) {
    if (individual_distance_sq(model_, Pairing{static_cast<int>(j), feature}) <= pruning_gate_) {
      compatible.push_back(feature);
    }
  }
  result_.overlap += compatible.empty() ? 0 : 1;
  candidate_count_ += static_cast<std::int64_t>(compatible.size());
  const std::int64_t work = 4 + kPairingCovarianceUnits * static_cast<std::int64_t>(nearby_.size());
  if (++next_second_ < static_cast<Index>(candidates_.size())) return work;

  hash_.reset();
  // RJC is for large overlaps. On a small one, JCBB with the star node is exact and cheap;
  // and where every RJC try fails (no b-sample of the overlap was all-good: on real data far
  // fewer than p_good of the overlap features have a partner, and on a revisit whose maps
  // overlap widely the second map would otherwise be added whole, every landmark twice), a
  // node-bounded JCBB decides instead.
  const bool small_overlap = result_.overlap <= kRjcMinOverlapSamples * options_.rjc.b;
  if (options_.association == JoinAssociation::Rjc && !small_overlap) {
    RjcOptions rjc_options = options_.rjc;
    if (result_.overlap >= kLargeOverlap) rjc_options.confidence = options_.large_overlap_confidence;
    if (result_.overlap < kRivalMinOverlap) rjc_options.rival_margin = -1;
    confidence_ = rjc_options.confidence;
    auto positions = std::make_shared<std::vector<Vec2>>();
    positions->reserve(candidates_.size());
    for (Index j = 0; j < frame_.second().num_features(); ++j) positions->push_back(frame_.second().feature(j));
    rjc_options.positions = std::move(positions);
    rjc_.emplace(candidates_, model_, rjc_options);
    stage_ = Stage::Rjc;
  } else {
    stage_ = Stage::Jcbb;
  }
  return work;
}

bool JoinAssociator::chunked_wanted() const {
  return options_.chunked_jcbb_min_overlap > 0 && result_.overlap >= options_.chunked_jcbb_min_overlap;
}

ChunkedJcbbOptions JoinAssociator::chunked_options() const {
  ChunkedJcbbOptions options;
  options.confidence = confidence_;
  options.candidate_gate = pruning_gate_;
  return options;
}

std::int64_t JoinAssociator::advance_rjc(std::int64_t budget) {
  const std::int64_t spent = rjc_->advance(budget);
  if (!rjc_->done()) return spent;
  const RjcResult& rjc_result = rjc_->result();
  result_.tries = rjc_result.tries;
  for (const Pairing& pairing : rjc_result.disputed) result_.disputed.emplace_back(pairing.feature, pairing.measurement);
  // With rivals, RJC's hypothesis is what the near alignments agree on: neither the fallback
  // nor chunked JCBB, which would decide between them by count, replaces it.
  const bool rivals = rjc_result.rivals > 0;
  if (rjc_result.pairings == 0 && !rivals) {
    stage_ = Stage::Jcbb;
  } else if (chunked_wanted() && !rivals) {
    ChunkedJcbbOptions options = chunked_options();
    options.to_beat = rjc_result.pairings;
    chunked_.emplace(candidates_, model_, static_cast<int>(frame_.first().num_features()), options);
    stage_ = Stage::Chunked;
    if (chunked_->done()) choose_hypothesis();  // RJC paired the whole overlap
  } else {
    conclude(rjc_result.feature_of);
  }
  return spent;
}

std::int64_t JoinAssociator::advance_chunked(std::int64_t budget) {
  const std::int64_t spent = chunked_->advance(budget);
  if (chunked_->done()) choose_hypothesis();
  return spent;
}

void JoinAssociator::choose_hypothesis() {
  if (chunked_->result().pairings > rjc_->result().pairings) {
    result_.chunked = true;
    conclude(chunked_->result().feature_of);
  } else {
    conclude(rjc_->result().feature_of);
  }
}

// JCBB over the whole overlap: on a small overlap, or where every RJC try failed (then with
// RJC's node bound, so the fallback stays bounded whatever the overlap); in "jcbb" mode by its
// own node bound only. In slices that end at the first node boundary after kJcbbSliceWork, as
// chunked JCBB's: the fallback of a large overlap (a second search's, say: 127 features, 35
// units of work) made a join's step of 0.1 s on Victoria Park when it ran in one step. The
// nodes are visited in the same order however the search is sliced.
std::int64_t JoinAssociator::advance_jcbb() {
  if (!jcbb_) {
    JcbbOptions jcbb_options;
    jcbb_options.confidence = options_.rjc.confidence;
    if (options_.association == JoinAssociation::Rjc) jcbb_options.max_nodes = options_.fallback_jcbb_nodes;
    jcbb_.emplace(jcbb_options);
    jcbb_->start(candidates_, model_);
    return 1 + kPairingCovarianceUnits * candidate_count_;
  }
  const std::int64_t work_before = jcbb_->work_done();
  bool searched = false;
  while (!searched && jcbb_->work_done() - work_before < kJcbbSliceWork) searched = jcbb_->expand(1);
  const std::int64_t work = 1 + jcbb_->work_done() - work_before;
  if (searched) {
    std::vector<int> feature_of = jcbb_->result().feature_of;
    jcbb_.reset();
    conclude(std::move(feature_of));
  }
  return work;
}

bool JoinAssociator::is_candidate(std::size_t second, int first) const {
  const std::vector<int>& candidates = candidates_[second];
  return std::find(candidates.begin(), candidates.end(), first) != candidates.end();
}

std::vector<int> JoinAssociator::oracle_pairing() const {
  const JoinOracle& oracle = *options_.oracle;
  const auto landmark = [&oracle](std::int64_t id) {
    const auto found = oracle.landmark_of.find(id);
    return found == oracle.landmark_of.end() ? std::int64_t{-1} : found->second;
  };
  // A landmark held by several features of each map (duplicates made inside local maps) is
  // paired as many times as both maps allow, its features taken in map order.
  std::unordered_map<std::int64_t, std::vector<int>> unused_of_landmark;
  for (Index i = frame_.first().num_features() - 1; i >= 0; --i) {
    const std::int64_t l = landmark(frame_.first().ids()[static_cast<std::size_t>(i)]);
    if (l >= 0) unused_of_landmark[l].push_back(static_cast<int>(i));  // the first on top
  }
  std::vector<int> truth(static_cast<std::size_t>(frame_.second().num_features()), kStar);
  for (std::size_t j = 0; j < truth.size(); ++j) {
    const auto found = unused_of_landmark.find(landmark(frame_.second().ids()[j]));
    if (found != unused_of_landmark.end() && !found->second.empty()) {
      truth[j] = found->second.back();
      found->second.pop_back();
    }
  }
  return truth;
}

// Research only: O(k^3) in the true pairs k, outside the amortized schedule.
void JoinAssociator::audit_oracle(const std::vector<int>& truth) {
  std::vector<JoinTruthAudit>& audit = result_.truth_audit;
  for (std::size_t j = 0; j < truth.size(); ++j) {
    if (truth[j] == kStar) continue;
    JoinTruthAudit entry;
    entry.first = truth[j];
    entry.second = static_cast<Index>(j);
    entry.distance_sq = individual_distance_sq(model_, Pairing{static_cast<int>(j), truth[j]});
    entry.candidate = is_candidate(j, truth[j]);
    audit.push_back(entry);
  }
  std::vector<std::size_t> by_distance;
  for (std::size_t k = 0; k < audit.size(); ++k) {
    if (audit[k].candidate) by_distance.push_back(k);
  }
  std::sort(by_distance.begin(), by_distance.end(),
            [&audit](std::size_t a, std::size_t b) { return audit[a].distance_sq < audit[b].distance_sq; });
  std::vector<Pairing> order;
  std::vector<int> kept(truth.size(), kStar);
  for (std::size_t k : by_distance) {
    order.push_back(Pairing{static_cast<int>(audit[k].second), static_cast<int>(audit[k].first)});
    kept[static_cast<std::size_t>(audit[k].second)] = static_cast<int>(audit[k].first);
  }
  accept_sequentially(order, 0, kept, model_, chi2_quantile(2, confidence_));
  for (std::size_t k : by_distance) {
    audit[k].consistent = kept[static_cast<std::size_t>(audit[k].second)] != kStar;
  }
}

void JoinAssociator::apply_oracle(const std::vector<int>& truth, std::vector<int>& feature_of) const {
  for (std::size_t j = 0; j < feature_of.size(); ++j) {
    switch (options_.oracle->mode) {
      case JoinOracle::Mode::Truth:
        feature_of[j] = truth[j];
        break;
      case JoinOracle::Mode::AmongCandidates:
        feature_of[j] = is_candidate(j, truth[j]) ? truth[j] : kStar;
        break;
      case JoinOracle::Mode::RemoveWrong:
        if (feature_of[j] != truth[j]) feature_of[j] = kStar;
        break;
      case JoinOracle::Mode::Audit:
        break;
    }
  }
}

// RJC ran (the overlap is not small), paired less than kWideSearchBelowShare of it, and the
// candidate lists are not crowded: the signature of maps whose relative pose is off by more
// than its covariance allows, not of an ambiguous overlap.
bool JoinAssociator::wider_gate_wanted(const std::vector<int>& feature_of) const {
  return !narrow_ && rjc_.has_value() && result_.overlap > 0 &&
         pairings_of(feature_of) < kWideSearchBelowShare * result_.overlap &&
         static_cast<double>(candidate_count_) <= kWideSearchMaxCandidatesPerFeature * result_.overlap;
}

// The first search's result is kept with what conclude() reads if it wins (its candidates
// decide which pairs are doubtful, its confidence the oracle's audit), and the association
// starts again from prepare() at the wide pruning gate.
void JoinAssociator::search_again_wider(std::vector<int> feature_of) {
  narrow_.emplace();
  narrow_->feature_of = std::move(feature_of);
  narrow_->result = std::move(result_);
  narrow_->candidates = std::move(candidates_);
  narrow_->confidence = confidence_;
  result_ = JoinAssociationResult();
  candidates_ = CandidateLists();
  candidate_count_ = 0;
  next_second_ = 0;
  sigma_first_ = 0.0;
  chunked_.reset();
  rjc_.reset();
  confidence_ = options_.rjc.confidence;
  stage_ = Stage::Prepare;
}

void JoinAssociator::conclude(std::vector<int> feature_of) {
  if (wider_gate_wanted(feature_of)) {
    search_again_wider(std::move(feature_of));
    return;
  }
  // The wider search's hypothesis replaces the first one only if it pairs more.
  if (narrow_) {
    const int tries = narrow_->result.tries + result_.tries;
    if (pairings_of(narrow_->feature_of) >= pairings_of(feature_of)) {
      feature_of = std::move(narrow_->feature_of);
      result_ = std::move(narrow_->result);
      candidates_ = std::move(narrow_->candidates);
      confidence_ = narrow_->confidence;
    } else {
      result_.widened = true;
    }
    result_.tries = tries;
  }
  if (options_.oracle) {
    const std::vector<int> truth = oracle_pairing();
    audit_oracle(truth);
    for (std::size_t j = 0; j < feature_of.size(); ++j) {
      if (feature_of[j] != kStar) result_.own_pairs.emplace_back(feature_of[j], static_cast<Index>(j));
    }
    const Index n1 = frame_.first().num_features();
    if (n1 >= options_.oracle->min_first_features && n1 <= options_.oracle->max_first_features) {
      apply_oracle(truth, feature_of);
    }
  }
  for (std::size_t j = 0; j < feature_of.size(); ++j) {
    const int i = feature_of[j];
    if (i != kStar) result_.pairs.emplace_back(i, static_cast<Index>(j));
  }
  mark_doubtful();
  chunked_.reset();
  rjc_.reset();
  candidates_ = CandidateLists();
  stage_ = Stage::Done;
}

// O(candidates): each pair's rivals are the other entries of its m2 feature's list and the
// other lists that hold its m1 feature.
void JoinAssociator::mark_doubtful() {
  std::vector<std::vector<int>> seconds_of(static_cast<std::size_t>(frame_.first().num_features()));
  for (std::size_t j = 0; j < candidates_.size(); ++j) {
    for (int i : candidates_[j]) seconds_of[static_cast<std::size_t>(i)].push_back(static_cast<int>(j));
  }
  result_.doubtful.assign(result_.pairs.size(), 0);
  for (std::size_t k = 0; k < result_.pairs.size(); ++k) {
    const int i = static_cast<int>(result_.pairs[k].first);
    const int j = static_cast<int>(result_.pairs[k].second);
    const double rival_below = individual_distance_sq(model_, Pairing{j, i}) + kDoubtfulPairMargin;
    const auto is_rival = [&](int second, int first) {
      return individual_distance_sq(model_, Pairing{second, first}) < rival_below;
    };
    bool doubtful = false;
    for (int other : candidates_[static_cast<std::size_t>(j)]) doubtful = doubtful || (other != i && is_rival(j, other));
    for (int other : seconds_of[static_cast<std::size_t>(i)]) doubtful = doubtful || (other != j && is_rival(other, i));
    result_.doubtful[k] = doubtful ? 1 : 0;
  }
}

std::int64_t JoinAssociator::expected_overlap() const {
  if (stage_ == Stage::Prepare) return 0;
  if (stage_ != Stage::Candidates) return result_.overlap;
  if (next_second_ == 0) return 0;
  return static_cast<std::int64_t>(result_.overlap) * static_cast<std::int64_t>(candidates_.size()) /
         static_cast<std::int64_t>(next_second_);
}

std::int64_t JoinAssociator::remaining_work() const {
  switch (stage_) {
    case Stage::Prepare:
      return 1 + kPairingCovarianceUnits *
                     static_cast<std::int64_t>(frame_.first().num_features() + 2 * frame_.second().num_features());
    case Stage::Candidates:
      return kPairingCovarianceUnits * static_cast<std::int64_t>(static_cast<Index>(candidates_.size()) - next_second_);
    case Stage::Rjc:
      return rjc_->remaining_work() +
             (chunked_wanted() ? ChunkedJcbb::work_estimate(candidate_count_, result_.overlap, chunked_options().chunk_size) : 0);
    case Stage::Chunked:
      return chunked_->remaining_work();
    case Stage::Jcbb:
      return jcbb_ ? kJcbbSliceWork : 1 + kPairingCovarianceUnits * result_.overlap;
    case Stage::Done:
      break;
  }
  return 0;
}

}  // namespace dcslam
