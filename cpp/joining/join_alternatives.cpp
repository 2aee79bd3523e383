#include "dcslam/joining/join_alternatives.hpp"

#include <algorithm>
#include <unordered_set>

namespace dcslam {

JoinIds join_ids(const MapJoin& join) { return JoinIds{join.merged_ids(), join.dropped_ids()}; }

namespace {

TreeMap alternative_version(const TreeMap& map) {
  return TreeMap{map.alternative->map, map.alternative->tentative, nullptr};
}

// Pairs a version stands for: those of the join that made it, as made or without the deferred
// ones.
std::int64_t version_pairs(const TreeMap& map, bool alternative) {
  if (!map.alternative) return 0;
  return static_cast<std::int64_t>(alternative ? map.alternative->ids.merged.size()
                                               : map.alternative->made_ids.merged.size());
}

}  // namespace

DecidingJoin::DecidingJoin(TreeMap first, TreeMap second, MakeJoin make_join, int weak_pairings)
    : first_(std::move(first)), second_(std::move(second)), make_join_(std::move(make_join)),
      weak_pairings_(weak_pairings) {
  // The versions as made first: a tie keeps them.
  for (const bool first_alternative : {false, true}) {
    if (first_alternative && !first_.alternative) continue;
    for (const bool second_alternative : {false, true}) {
      if (second_alternative && !second_.alternative) continue;
      candidates_.push_back(Candidate{first_alternative, second_alternative, nullptr});
    }
  }
  for (Candidate& candidate : candidates_) {
    candidate.join = make_join_(candidate.first_alternative ? alternative_version(first_) : first_,
                                candidate.second_alternative ? alternative_version(second_) : second_, nullptr);
  }
  // Nothing to decide: the join runs exactly as a plain MapJoin would.
  if (candidates_.size() == 1) choose();
}

DecidingJoin::~DecidingJoin() = default;

std::int64_t DecidingJoin::step(std::int64_t budget) {
  switch (phase_) {
    case Phase::Choose: {
      const auto open = std::find_if(candidates_.begin(), candidates_.end(),
                                     [](const Candidate& candidate) { return !candidate.join->associated(); });
      const std::int64_t spent = open->join->step(budget);
      if (std::none_of(candidates_.begin(), candidates_.end(),
                       [](const Candidate& candidate) { return !candidate.join->associated(); })) {
        choose();
      }
      return spent;
    }
    case Phase::Join: {
      const std::int64_t spent = chosen_->step(budget);
      if (chosen_->done()) start_alternative();
      return spent;
    }
    case Phase::Alternative: {
      const std::int64_t spent = alternative_->step(budget);
      if (alternative_->done()) phase_ = Phase::Done;
      return spent;
    }
    case Phase::Done:
      break;
  }
  return 0;
}

std::int64_t DecidingJoin::remaining_work() const {
  switch (phase_) {
    case Phase::Choose: {
      // Every candidate as if it were joined: an upper bound, exact for the chosen one.
      std::int64_t work = 0;
      for (const Candidate& candidate : candidates_) work += candidate.join->remaining_work();
      return work;
    }
    case Phase::Join:
      return chosen_->remaining_work();
    case Phase::Alternative:
      return alternative_->remaining_work();
    case Phase::Done:
      break;
  }
  return 0;
}

void DecidingJoin::choose() {
  std::size_t best = 0;
  std::int64_t best_pairs = -1;
  for (std::size_t k = 0; k < candidates_.size(); ++k) {
    const Candidate& candidate = candidates_[k];
    const std::int64_t pairs = static_cast<std::int64_t>(candidate.join->pairs().size()) +
                               version_pairs(first_, candidate.first_alternative) +
                               version_pairs(second_, candidate.second_alternative);
    if (pairs > best_pairs) {
      best_pairs = pairs;
      best = k;
    }
  }
  for (std::size_t k = 0; k < candidates_.size(); ++k) {
    if (k == best) continue;
    discarded_work_units_ += candidates_[k].join->report().work_units;
    discarded_seconds_ += candidates_[k].join->report().seconds_total;
  }
  took_first_ = candidates_[best].first_alternative;
  took_second_ = candidates_[best].second_alternative;
  first_version_ = took_first_ ? alternative_version(first_) : first_;
  second_version_ = took_second_ ? alternative_version(second_) : second_;
  chosen_ = std::move(candidates_[best].join);
  candidates_.clear();
  phase_ = chosen_->done() ? Phase::Done : Phase::Join;
  if (phase_ == Phase::Done) start_alternative();
}

void DecidingJoin::start_alternative() {
  phase_ = Phase::Done;
  const Pairs& pairs = chosen_->pairs();
  if (weak_pairings_ <= 0 || pairs.empty() || static_cast<int>(pairs.size()) > weak_pairings_) return;
  std::unordered_set<std::int64_t> seen_once;
  for (const TreeMap* version : {&first_version_, &second_version_}) {
    for (const TentativeFeature& feature : version->tentative) seen_once.insert(feature.id);
  }
  const auto& first_ids = first_version_.map->ids();
  const auto& second_ids = second_version_.map->ids();
  auto kept = std::make_shared<Pairs>();
  for (const auto& [i, j] : pairs) {
    if (seen_once.count(first_ids[static_cast<std::size_t>(i)]) == 0 &&
        seen_once.count(second_ids[static_cast<std::size_t>(j)]) == 0) {
      kept->emplace_back(i, j);
    }
  }
  if (kept->size() == pairs.size()) return;
  deferred_pairs_ = static_cast<int>(pairs.size() - kept->size());
  alternative_ = make_join_(first_version_, second_version_, std::move(kept));
  phase_ = alternative_->done() ? Phase::Done : Phase::Alternative;
}

JoinReport DecidingJoin::report() const {
  JoinReport report = chosen_->report();
  report.work_units += discarded_work_units_ + (alternative_ ? alternative_->report().work_units : 0);
  report.seconds_total += discarded_seconds_ + (alternative_ ? alternative_->report().seconds_total : 0.0);
  report.deferred_pairings = deferred_pairs_;
  report.alternatives_taken = (took_first_ ? 1 : 0) + (took_second_ ? 1 : 0);
  return report;
}

DecidedJoin DecidingJoin::take_result(const TentativeOfJoin& tentative_of) {
  DecidedJoin decided;
  for (const auto& [input, took] : {std::pair<const TreeMap*, bool>{&first_, took_first_},
                                    std::pair<const TreeMap*, bool>{&second_, took_second_}}) {
    if (input->alternative) decided.settled.push_back(took ? input->alternative->ids : input->alternative->made_ids);
  }
  const JoinIds made_ids = join_ids(*chosen_);
  decided.tentative = tentative_of(first_version_, second_version_, *chosen_);
  decided.map = std::make_shared<GaussianMap>(chosen_->take_result());
  if (alternative_) {
    auto alternative = std::make_shared<JoinAlternative>();
    alternative->made_ids = made_ids;
    alternative->ids = join_ids(*alternative_);
    alternative->tentative = tentative_of(first_version_, second_version_, *alternative_);
    alternative->map = std::make_shared<const GaussianMap>(alternative_->take_result());
    decided.alternative = std::move(alternative);
  } else {
    decided.settled.push_back(made_ids);
  }
  first_ = second_ = first_version_ = second_version_ = TreeMap{};
  return decided;
}

}  // namespace dcslam
