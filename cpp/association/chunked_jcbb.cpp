#include "dcslam/association/chunked_jcbb.hpp"

#include <algorithm>
#include <limits>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

JcbbOptions chunk_jcbb_options(const ChunkedJcbbOptions& options) {
  JcbbOptions jcbb_options;
  jcbb_options.confidence = options.confidence;
  jcbb_options.max_nodes = options.max_nodes;
  return jcbb_options;
}

}  // namespace

ChunkedJcbb::ChunkModel::ChunkModel(const ConditionedPairingModel& conditioned, const std::vector<int>& measurements,
                                    const CandidateLists& candidates)
    : conditioned_(conditioned),
      candidates_(candidates),
      block_work_(ConditionedPairingModel::condition_work(0) + conditioned.kept()) {
  for (std::size_t m = 0; m < candidates.size(); ++m) {
    first_slot_.push_back(pairings_.size());
    for (int feature : candidates[m]) pairings_.push_back(Pairing{measurements[m], feature});
  }
  innovations_.reserve(pairings_.size());
  for (const Pairing& pairing : pairings_) innovations_.push_back(conditioned.innovation(pairing));
}

std::size_t ChunkedJcbb::ChunkModel::slot(const Pairing& pairing) const {
  const std::vector<int>& list = candidates_[static_cast<std::size_t>(pairing.measurement)];
  const auto position = std::find(list.begin(), list.end(), pairing.feature) - list.begin();
  return first_slot_[static_cast<std::size_t>(pairing.measurement)] + static_cast<std::size_t>(position);
}

Vec2 ChunkedJcbb::ChunkModel::innovation(const Pairing& pairing) const { return innovations_[slot(pairing)]; }

// Each block is computed with the later slot first and transposed for the other order, so a
// block is the same whichever order the search asks in.
Mat2 ChunkedJcbb::ChunkModel::covariance(const Pairing& a, const Pairing& b) const {
  const std::size_t slot_a = slot(a), slot_b = slot(b);
  const std::size_t later = std::max(slot_a, slot_b), earlier = std::min(slot_a, slot_b);
  const std::uint64_t key = (static_cast<std::uint64_t>(later) << 32) | earlier;
  auto found = blocks_.find(key);
  if (found == blocks_.end()) {
    work_ += block_work_;
    found = blocks_.emplace(key, conditioned_.covariance(pairings_[later], pairings_[earlier])).first;
  }
  return slot_a >= slot_b ? found->second : Mat2(found->second.transpose());
}

ChunkedJcbb::ChunkedJcbb(const CandidateLists& candidates, const PairingModel& model, int num_features,
                         const ChunkedJcbbOptions& options)
    : candidates_(candidates),
      options_(options),
      conditioned_(model),
      jcbb_(chunk_jcbb_options(options)),
      feature_used_(static_cast<std::size_t>(std::max(0, num_features)), 0) {
  if (options.chunk_size < 1) throw InvalidArgument("ChunkedJcbb: chunk_size must be at least 1");
  result_.feature_of.assign(candidates.size(), kStar);
  for (const auto& list : candidates) {
    candidates_left_ += static_cast<std::int64_t>(list.size());
    overlap_ += list.empty() ? 0 : 1;
  }
  overlap_left_ = overlap_;
  if (candidates.empty()) stage_ = Stage::Done;
  next_chunk();
}

std::int64_t ChunkedJcbb::step(std::int64_t) {
  switch (stage_) {
    case Stage::Gate:
      return gate_next();
    case Stage::Start:
      return start_chunk();
    case Stage::Search:
      return search_chunk();
    case Stage::Keep:
      return keep_next();
    case Stage::Done:
      break;
  }
  return 0;
}

// A measurement's candidates are solved (w_a) with those of the measurements after it that the
// chunk will gate before it can close, as many as one panel holds: the factor is read once for
// them all, and they stay cached until the chunk's pairings are kept.
std::int64_t ChunkedJcbb::gate_next() {
  const auto open_pairings = [&](std::size_t measurement, std::vector<Pairing>& open) {
    for (int feature : candidates_[measurement]) {
      if (!feature_used_[static_cast<std::size_t>(feature)]) {
        open.push_back(Pairing{static_cast<int>(measurement), feature});
      }
    }
  };
  const int measurement = static_cast<int>(next_);
  const std::vector<int>& list = candidates_[next_++];
  candidates_left_ -= static_cast<std::int64_t>(list.size());
  overlap_left_ -= list.empty() ? 0 : 1;
  std::vector<Pairing> open;
  open_pairings(static_cast<std::size_t>(measurement), open);
  std::size_t solved = 0;
  if (!open.empty() && !conditioned_.prepared(open.front())) {
    const Eigen::Index panel = ConditionedPairingModel::panel_pairings(
        conditioned_.kept(), ConditionedPairingModel::kMaxPanelPairings, options_.work_unit);
    panel_ = open;
    const std::size_t gated_before_close = static_cast<std::size_t>(options_.chunk_size) - chunk_.size();
    const std::size_t end = std::min(candidates_.size(), static_cast<std::size_t>(measurement) + gated_before_close);
    for (std::size_t later = next_; later < end && static_cast<Eigen::Index>(panel_.size()) < panel; ++later) {
      open_pairings(later, panel_);
    }
    solved = conditioned_.prepare(panel_);
  }
  std::vector<int> gated;
  for (const Pairing& pairing : open) {
    if (individual_distance_sq(conditioned_, pairing) <= options_.candidate_gate) {
      gated.push_back(pairing.feature);
    }
  }
  if (!gated.empty()) {
    chunk_.push_back(measurement);
    chunk_candidates_.push_back(std::move(gated));
  }
  const bool last = next_ == candidates_.size();
  if (static_cast<int>(chunk_.size()) == options_.chunk_size || last) {
    stage_ = !chunk_.empty() ? Stage::Start : Stage::Done;
  }
  return 1 + static_cast<std::int64_t>(solved) * ConditionedPairingModel::condition_work(conditioned_.kept()) +
         static_cast<std::int64_t>(list.size()) * kPairingCovarianceUnits;
}

std::int64_t ChunkedJcbb::start_chunk() {
  chunk_model_.emplace(conditioned_, chunk_, chunk_candidates_);
  jcbb_.start(chunk_candidates_, *chunk_model_);
  stage_ = Stage::Search;
  return 1 + chunk_work();
}

// A slice of the search ends at the first node boundary after options.work_unit: it depends on
// the search alone, not on the budget, so the slicing is the same in every run.
std::int64_t ChunkedJcbb::search_chunk() {
  const std::int64_t work_before = chunk_work();
  bool searched = false;
  while (!searched && chunk_work() - work_before < options_.work_unit) searched = jcbb_.expand(1);
  const std::int64_t work = 1 + chunk_work() - work_before;
  if (!searched) return work;
  const JcbbResult solved = jcbb_.result();
  chunk_model_.reset();
  ++result_.chunks;
  result_.bound_hits += solved.bound_hit ? 1 : 0;
  accepted_.clear();
  for (std::size_t k = 0; k < chunk_.size(); ++k) {
    if (solved.feature_of[k] != kStar) accepted_.push_back(Pairing{chunk_[k], solved.feature_of[k]});
  }
  next_kept_ = 0;
  stage_ = Stage::Keep;
  if (accepted_.empty()) keep_next();  // nothing to keep: on to the next chunk
  return work;
}

// The chunk's pairings join the conditioning set a panel at a time (each conditional covariance
// is positive definite in exact arithmetic, the chunk's JCBB having factored it; one that is
// not in floating point is left unpaired).
std::int64_t ChunkedJcbb::keep_next() {
  std::int64_t work = 1;
  if (next_kept_ < accepted_.size()) {
    std::int64_t kept = conditioned_.kept();
    const Eigen::Index count = ConditionedPairingModel::panel_pairings(
        kept, static_cast<Eigen::Index>(accepted_.size() - next_kept_), options_.work_unit);
    panel_.assign(accepted_.begin() + static_cast<std::ptrdiff_t>(next_kept_),
                  accepted_.begin() + static_cast<std::ptrdiff_t>(next_kept_) + count);
    panel_gates_.assign(panel_.size(), std::numeric_limits<double>::infinity());
    conditioned_.keep_each_within(panel_, panel_gates_, std::numeric_limits<int>::max(), panel_kept_);
    next_kept_ += panel_.size();
    for (std::size_t p = 0; p < panel_.size(); ++p) {
      work += ConditionedPairingModel::condition_work(kept);
      if (!panel_kept_[p]) continue;
      ++kept;
      feature_used_[static_cast<std::size_t>(panel_[p].feature)] = 1;
      result_.feature_of[static_cast<std::size_t>(panel_[p].measurement)] = panel_[p].feature;
      ++result_.pairings;
    }
  }
  if (next_kept_ == accepted_.size()) {
    chunk_.clear();
    chunk_candidates_.clear();
    next_chunk();
  }
  return work;
}

void ChunkedJcbb::next_chunk() {
  if (stage_ == Stage::Done) return;
  if (options_.to_beat >= 0 && result_.pairings + overlap_left_ <= options_.to_beat) {
    result_.abandoned = true;
    stage_ = Stage::Done;
    return;
  }
  stage_ = next_ == candidates_.size() ? Stage::Done : Stage::Gate;
}

std::int64_t ChunkedJcbb::remaining_work() const {
  if (stage_ == Stage::Done) return 0;
  const std::int64_t left_to_keep = std::max<std::int64_t>(0, overlap_ - conditioned_.kept());
  return work(candidates_left_, left_to_keep, overlap_, options_.chunk_size);
}

std::int64_t ChunkedJcbb::work_estimate(std::int64_t candidates, std::int64_t overlap, int chunk_size) {
  return work(candidates, overlap, overlap, chunk_size);
}

// Each candidate gated and each pairing kept against about the whole overlap, and each
// chunk's JCBB at a node per measurement.
std::int64_t ChunkedJcbb::work(std::int64_t candidates, std::int64_t to_keep, std::int64_t overlap, int chunk_size) {
  const std::int64_t per_pairing = ConditionedPairingModel::condition_work(overlap);
  const std::int64_t chunks = 1 + to_keep / std::max(1, chunk_size);
  return (candidates + to_keep) * per_pairing + chunks * kPairingCovarianceUnits * chunk_size;
}

}  // namespace dcslam
