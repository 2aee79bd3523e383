#include "dcslam/joining/join_alternatives.hpp"

#include <algorithm>
#include <limits>
#include <unordered_set>
#include <vector>

#include "dcslam/joining/parallel_tasks.hpp"

namespace dcslam {

JoinIds join_ids(const MapJoin& join) { return JoinIds{join.merged_ids(), join.dropped_ids()}; }

std::vector<std::pair<std::int64_t, std::int64_t>> JoinIds::record_pairs() const {
  std::vector<std::pair<std::int64_t, std::int64_t>> pairs;
  pairs.reserve(merged.size());
  for (const auto& [from, to] : merged) pairs.emplace_back(to, from);
  return pairs;
}

namespace {

int num_versions(const TreeMap& map) {
  return 1 + (map.alternative ? static_cast<int>(map.alternative->versions.size()) : 0);
}

TreeMap version_of(const TreeMap& map, int version) {
  if (version == 0) return map;
  const JoinAlternative::Version& alternative = map.alternative->versions[static_cast<std::size_t>(version - 1)];
  return TreeMap{alternative.map, alternative.tentative, nullptr};
}

// Pairs a version stands for: those of the join that made it, as made or without the ones
// that version leaves out.
std::int64_t version_pairs(const TreeMap& map, int version) {
  return map.alternative ? static_cast<std::int64_t>(map.alternative->ids_of(version).merged.size()) : 0;
}

}  // namespace

DecidingJoin::DecidingJoin(TreeMap first, TreeMap second, MakeJoin make_join, int weak_pairings,
                           bool spans_many_maps)
    : first_(std::move(first)), second_(std::move(second)), make_join_(std::move(make_join)),
      weak_pairings_(weak_pairings), spans_many_maps_(spans_many_maps) {
  // The versions as made first: a tie keeps them.
  for (int first_version = 0; first_version < num_versions(first_); ++first_version) {
    for (int second_version = 0; second_version < num_versions(second_); ++second_version) {
      candidates_.push_back(Candidate{first_version, second_version, nullptr});
    }
  }
  for (Candidate& candidate : candidates_) {
    candidate.join = make_join_(version_of(first_, candidate.first_version),
                                version_of(second_, candidate.second_version), nullptr);
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
      if (chosen_->done()) start_alternatives();
      return spent;
    }
    case Phase::Alternative: {
      const std::int64_t spent = alternatives_.back()->step(budget);
      if (alternatives_.back()->done()) start_next_alternative();
      return spent;
    }
    case Phase::Done:
      break;
  }
  return 0;
}

void DecidingJoin::associate(int threads) {
  constexpr std::int64_t kWhole = std::numeric_limits<std::int64_t>::max();
  if (phase_ == Phase::Choose && threads > 1 && candidates_.size() > 1) {
    run_for_each(candidates_.size(), threads, [&](std::size_t k) {
      MapJoin& join = *candidates_[k].join;
      while (!join.associated()) join.step(kWhole);
    });
    choose();
  }
  while (!associated()) step(kWhole);
}

void DecidingJoin::finish(int threads) {
  associate(threads);
  while (!done()) {
    if (phase_ == Phase::Join) {
      chosen_->finish(threads);
      start_alternatives();
    } else {
      alternatives_.back()->finish(threads);
      start_next_alternative();
    }
  }
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
      return alternatives_.back()->remaining_work();
    case Phase::Done:
      break;
  }
  return 0;
}

// A pair an input's version keeps counts half a pair this join makes of its own. A right pair
// dropped leaves its landmark in the map twice, which costs this join none of its own pairs
// (each of its features pairs one of the copies); a wrong pair kept bends the map and costs
// this join its own pairs. So a version with fewer pairs is taken when this join gains more
// than half the pairs it drops: long_revisits seed 0's 32-leaf join that made 6 of its 25
// pairs wrong, whose version without any pair let the next join make 17 more of its own
// (docs/data_association.md, "Own pairs count twice"). At a tie the combination with more
// pairs of this join's own wins, this join's own evidence (long_revisits seed 3: two weak
// joins, either's pairs bending the next join against the other's, tied at 667; the versions'
// order kept the one with 3 wrong pairs of 25; "Crossed pairings exchanged").
void DecidingJoin::choose() {
  std::size_t best = 0;
  std::int64_t best_score = -1;
  std::size_t best_own = 0;
  for (std::size_t k = 0; k < candidates_.size(); ++k) {
    const Candidate& candidate = candidates_[k];
    const std::size_t own = candidate.join->pairs().size();
    const std::int64_t score = 2 * static_cast<std::int64_t>(own) + version_pairs(first_, candidate.first_version) +
                               version_pairs(second_, candidate.second_version);
    if (score > best_score || (score == best_score && own > best_own)) {
      best_score = score;
      best_own = own;
      best = k;
    }
  }
  for (std::size_t k = 0; k < candidates_.size(); ++k) {
    if (k == best) continue;
    discarded_work_units_ += candidates_[k].join->report().work_units;
    discarded_seconds_ += candidates_[k].join->report().seconds_total;
    discarded_association_seconds_ += candidates_[k].join->report().seconds_association;
  }
  took_first_ = candidates_[best].first_version;
  took_second_ = candidates_[best].second_version;
  first_version_ = version_of(first_, took_first_);
  second_version_ = version_of(second_, took_second_);
  chosen_ = std::move(candidates_[best].join);
  candidates_.clear();
  phase_ = chosen_->done() ? Phase::Done : Phase::Join;
  if (phase_ == Phase::Done) start_alternatives();
}

void DecidingJoin::start_alternatives() {
  phase_ = Phase::Done;
  const Pairs& pairs = chosen_->pairs();
  if (weak_pairings_ <= 0 || pairs.empty()) return;
  if (static_cast<int>(pairs.size()) > weak_pairings_) {
    if (spans_many_maps_) start_version_without_doubtful_pairs();
    return;
  }
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
  // The versions, in order: without the pairs that have a feature seen once (unless that is
  // all of them), then without any pair. The pairs without such a feature can be wrong too,
  // and only the version without any pair lets the next join show it; the tighter version,
  // tried before it, keeps it from winning by the chance pairs a looser map collects where
  // only the pairs of features seen once were wrong.
  if (!kept->empty()) alternative_pairs_.push_back(std::move(kept));
  if (spans_many_maps_ || alternative_pairs_.empty()) {
    alternative_pairs_.push_back(std::make_shared<const Pairs>());
  }
  deferred_pairs_ = static_cast<int>(pairs.size() - alternative_pairs_.back()->size());
  start_next_alternative();
}

// A large join's doubtful pairs (a rival candidate nearly as close) are where it is most often
// wrong, and a wrong pair imposed exactly bends both maps: the next join then finds the true
// pairs of whole laps incompatible. Without them, the next join shows which was right.
void DecidingJoin::start_version_without_doubtful_pairs() {
  const Pairs& pairs = chosen_->pairs();
  const std::vector<char>& doubtful = chosen_->doubtful();
  auto kept = std::make_shared<Pairs>();
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    if (!doubtful[k]) kept->push_back(pairs[k]);
  }
  const std::size_t doubtful_count = pairs.size() - kept->size();
  if (kept->empty() ||
      static_cast<double>(doubtful_count) < kMinDoubtfulShare * static_cast<double>(pairs.size())) {
    return;
  }
  deferred_pairs_ = static_cast<int>(doubtful_count);
  alternative_pairs_.push_back(std::move(kept));
  start_next_alternative();
}

void DecidingJoin::start_next_alternative() {
  phase_ = Phase::Done;
  if (alternatives_.size() == alternative_pairs_.size()) return;
  alternatives_.push_back(make_join_(first_version_, second_version_, alternative_pairs_[alternatives_.size()]));
  phase_ = Phase::Alternative;
  if (alternatives_.back()->done()) start_next_alternative();
}

JoinReport DecidingJoin::report() const {
  JoinReport report = chosen_->report();
  report.work_units += discarded_work_units_;
  report.seconds_total += discarded_seconds_;
  report.seconds_association += discarded_association_seconds_;
  for (const auto& alternative : alternatives_) {
    report.work_units += alternative->report().work_units;
    report.seconds_total += alternative->report().seconds_total;
    report.seconds_association += alternative->report().seconds_association;
  }
  report.deferred_pairings = deferred_pairs_;
  report.alternatives_taken = (took_first_ > 0 ? 1 : 0) + (took_second_ > 0 ? 1 : 0);
  return report;
}

DecidedJoin DecidingJoin::take_result(const TentativeOfJoin& tentative_of, int join_index) {
  DecidedJoin decided;
  for (const auto& [input, took] : {std::pair<const TreeMap*, int>{&first_, took_first_},
                                    std::pair<const TreeMap*, int>{&second_, took_second_}}) {
    if (input->alternative) decided.settled.push_back(input->alternative->ids_of(took));
  }
  const JoinIds made_ids = join_ids(*chosen_);
  decided.tentative = tentative_of(first_version_, second_version_, *chosen_);
  decided.map = std::make_shared<GaussianMap>(chosen_->take_result());
  if (!alternatives_.empty()) {
    auto alternative = std::make_shared<JoinAlternative>();
    alternative->made_ids = made_ids;
    alternative->join_index = join_index;
    for (std::size_t k = 0; k < alternatives_.size(); ++k) {
      MapJoin& join = *alternatives_[k];
      JoinAlternative::Version version;
      version.ids = join_ids(join);
      version.tentative = tentative_of(first_version_, second_version_, join);
      version.map = std::make_shared<const GaussianMap>(join.take_result());
      alternative->versions.push_back(std::move(version));
    }
    decided.alternative = std::move(alternative);
  } else {
    decided.settled.push_back(made_ids);
  }
  first_ = second_ = first_version_ = second_version_ = TreeMap{};
  return decided;
}

}  // namespace dcslam
