#pragma once
// Weak joins decided by the next join (docs/data_association.md, "Weak joins decided by the
// next join"; SlamConfig::weak_join_pairings).
//
// A D&C join that pairs few features decides on little evidence, and one wrong pair between
// features seen once bends both maps: the next, larger join then finds its true pairs
// incompatible, and the landmarks of a whole lap end up duplicated. Such a weak join (one with
// a pair of a feature seen once) keeps two more versions of its result: its pairs less those
// with a feature seen once, and none of its pairs. A large join keeps one: its pairs less the
// doubtful ones, those with a rival candidate nearly as close. The next join sees much more of
// the map:
// it runs its association on each combination of its inputs' versions and joins the one with
// the highest score, twice its own pairs plus those of the versions it takes (a tie goes to
// more pairs of its own, then keeps the tighter versions: as made, then less the pairs of
// features seen once). Until then the ids
// of no version are recorded.
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/resumable_work.hpp"
#include "dcslam/joining/join_report.hpp"
#include "dcslam/joining/map_joining.hpp"
#include "dcslam/joining/tentative_features.hpp"

namespace dcslam {

// A large join keeps its version without its doubtful pairs only when at least this share of its
// pairs is doubtful. Below it the version was never taken (Victoria Park, the revisit scenes) but
// was held in memory until the next join decided; 0.1 by measurement (docs/data_association.md,
// "Large joins' doubtful pairs").
inline constexpr double kMinDoubtfulShare = 0.1;

// What a join did to ids: each merged feature of m2 names the feature of m1 it joined
// (from, to); each dropped tentative feature resolves to -1.
struct JoinIds {
  std::vector<std::pair<std::int64_t, std::int64_t>> merged;
  std::vector<std::int64_t> dropped;
  // The pairs as a JoinPairingRecord lists them: (id in m1, id in m2).
  std::vector<std::pair<std::int64_t, std::int64_t>> record_pairs() const;
};
JoinIds join_ids(const MapJoin& join);

// The other versions of a weak join's result: without the pairs that have a feature seen
// once (unless that is all of them), then without any pair.
struct JoinAlternative {
  struct Version {
    std::shared_ptr<const GaussianMap> map;
    std::vector<TentativeFeature> tentative;
    JoinIds ids;
  };
  JoinIds made_ids;  // of the join as made (the version the tree holds)
  std::vector<Version> versions;
  // The ids of version `version`: 0 as made, k > 0 versions[k - 1].
  const JoinIds& ids_of(int version) const {
    return version == 0 ? made_ids : versions[static_cast<std::size_t>(version - 1)].ids;
  }
  // The index its caller gave the weak join (DCSlam: its JoinEvent, or -1 - k for the k-th
  // join of estimate()'s fold), so that the join that decides can correct its record.
  int join_index = 0;
};

// A map of the join tree as the next join takes it.
struct TreeMap {
  std::shared_ptr<const GaussianMap> map;
  // Its features seen once that still wait for a join (tentative_features.hpp).
  std::vector<TentativeFeature> tentative;
  // Set while the decision of the weak join that made it waits for the next join.
  std::shared_ptr<const JoinAlternative> alternative;
};

// What a finished DecidingJoin leaves: the joined map (with its alternative when the join was
// weak) and the ids to record now, oldest first: those of the inputs' versions it took, then
// its own unless its decision waits.
struct DecidedJoin {
  std::shared_ptr<GaussianMap> map;  // a new map, held nowhere else
  std::vector<TentativeFeature> tentative;
  std::shared_ptr<const JoinAlternative> alternative;
  std::vector<JoinIds> settled;
  TreeMap tree_map() const { return TreeMap{map, tentative, alternative}; }
};
// The tentative features of a join's result, from the two versions it joined and the join.
using TentativeOfJoin =
    std::function<std::vector<TentativeFeature>(const TreeMap& first, const TreeMap& second, const MapJoin& join)>;

class DecidingJoin : public ResumableWork<DecidingJoin> {
 public:
  using Pairs = MapJoin::Pairs;
  // The MapJoin of two versions; with `fixed_pairs`, one that imposes those pairs.
  using MakeJoin = std::function<std::unique_ptr<MapJoin>(const TreeMap& first, const TreeMap& second,
                                                          std::shared_ptr<const Pairs> fixed_pairs)>;

  // `weak_pairings`: the join keeps an alternative when it makes at most this many pairs and
  // some of them have a feature seen once (listed as tentative by either version it joins);
  // 0: never, its result is final (a large join's too). `spans_many_maps`: the join spans 16
  // local maps or more (or is one of estimate()'s fold): a weak join's alternative then includes
  // the version without any pair (it always does when every pair has a feature seen once), and
  // a large join (more than `weak_pairings` pairs) keeps its version without its doubtful pairs
  // (MapJoin::doubtful()), when at least kMinDoubtfulShare of its pairs are doubtful but not
  // all of them.
  DecidingJoin(TreeMap first, TreeMap second, MakeJoin make_join, int weak_pairings, bool spans_many_maps);
  ~DecidingJoin();
  DecidingJoin(const DecidingJoin&) = delete;
  DecidingJoin& operator=(const DecidingJoin&) = delete;

  // ResumableWork: a step is one step of a candidate's association, of the chosen join or of
  // the alternative.
  std::int64_t step(std::int64_t budget);
  bool done() const { return phase_ == Phase::Done; }
  // The chosen join's pairs are known (join().pairs(), its pairing record): what a caller
  // that compares joins by their pairs needs, before the costlier rest (the fill).
  bool associated() const { return phase_ != Phase::Choose && chosen_->associated(); }
  // Steps until associated(); finish() then makes the rest, the same steps as without this.
  // `threads` > 1: the candidates' associations run side by side (run_tasks()), each the same
  // steps as one after the other, so the choice and the join are the same.
  void associate(int threads = 1);
  using ResumableWork<DecidingJoin>::finish;
  // Runs to completion as finish() does, with associate(threads) and each join's fill on up to
  // `threads` threads (MapJoin::finish(threads)): the same choice, result and work.
  void finish(int threads);
  std::int64_t remaining_work() const;

  // Valid once done(). The versions joined:
  const TreeMap& first() const { return first_version_; }
  const TreeMap& second() const { return second_version_; }
  // The version of each input taken: 0 as made, k > 0 its alternative's versions[k - 1].
  int first_version_taken() const { return took_first_; }
  int second_version_taken() const { return took_second_; }
  // The chosen join.
  MapJoin& join() { return *chosen_; }
  const MapJoin& join() const { return *chosen_; }
  // The chosen join's report, with the work and time of the candidates not chosen and of the
  // alternative added, and the decision's own counts.
  JoinReport report() const;
  // The joined map and the ids it settles; `join_index` names the join to its caller
  // (JoinAlternative::join_index). Leaves the join empty (and its inputs released).
  DecidedJoin take_result(const TentativeOfJoin& tentative_of, int join_index);

 private:
  enum class Phase { Choose, Join, Alternative, Done };
  struct Candidate {
    int first_version = 0, second_version = 0;
    std::unique_ptr<MapJoin> join;
  };
  void choose();
  void start_alternatives();
  void start_version_without_doubtful_pairs();
  void start_next_alternative();

  TreeMap first_, second_;
  MakeJoin make_join_;
  int weak_pairings_;
  bool spans_many_maps_;
  Phase phase_ = Phase::Choose;
  std::vector<Candidate> candidates_;
  std::unique_ptr<MapJoin> chosen_;
  // The pairs each version of a weak join's alternative imposes, and their joins (the one
  // under way last).
  std::vector<std::shared_ptr<const Pairs>> alternative_pairs_;
  std::vector<std::unique_ptr<MapJoin>> alternatives_;
  TreeMap first_version_, second_version_;
  int took_first_ = 0, took_second_ = 0;
  int deferred_pairs_ = 0;
  std::int64_t discarded_work_units_ = 0;
  double discarded_seconds_ = 0.0;
  double discarded_association_seconds_ = 0.0;
};

}  // namespace dcslam
