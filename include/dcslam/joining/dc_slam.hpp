#pragma once
// Divide and Conquer SLAM (docs/design.md §5; Paz et al. 2007, Algorithm 2). Local maps are built
// with the sparse-aware EKF, closed at `local_map_features` features, and joined as a binary
// tree in post-order with a stack. Joins run in one of three ways with bitwise the same
// result:
//  - immediate: a join runs as soon as its two inputs exist;
//  - amortized (`amortize`): joins are queued and every step spends a work budget on them, so
//    that each step costs O(n) (the paper's Fig. 3, bottom row);
//  - threaded (`threaded_joins`): a worker thread runs the queued joins while the front end
//    keeps mapping.
//
// Decisions (docs/divide_and_conquer.md): the stack compares map sizes by the number of local
// maps they hold (a binary counter, deterministic whatever the join timing; equal to the
// paper's feature count for exploration), and the amortized budget of a step is
// Σ remaining_work / steps_left over the queued joins, where a join's deadline is half the
// time until its result is next needed.
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "dcslam/core/config.hpp"
#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/joining/join_alternatives.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/join_tree.hpp"
#include "dcslam/joining/map_joining.hpp"
#include "dcslam/joining/online_localisation.hpp"
#include "dcslam/core/slam_filter.hpp"
#include "dcslam/joining/tentative_features.hpp"

namespace dcslam {

// What D&C's final duplicate merge asks of a feature: in how many scans it was seen (summed over
// its local maps and the merges since) and the ids of the features within merge_radius seen in
// one scan with it, once per such scan (EkfSlam::seen_with(); ids as they were then, the merges
// since map them on). Two measurements of one scan come from two landmarks.
struct Sightings {
  int scans = 0;
  std::vector<std::int64_t> seen_with;
};
using SightingsById = std::unordered_map<std::int64_t, Sightings>;

struct JoinEvent {
  int index = 0;         // joins in creation order
  int leaves = 0;        // local maps in the joined map
  std::int64_t step_created = 0;
  std::int64_t step_finished = -1;  // -1 while pending
  JoinReport report;
  JoinPairingRecord pairing;  // empty while pending
};

class DCSlam : public SlamFilter {
 public:
  explicit DCSlam(const SlamConfig& config);
  ~DCSlam() override;
  DCSlam(const DCSlam&) = delete;
  DCSlam& operator=(const DCSlam&) = delete;

  void predict(const Vec3& u, const Mat3& Q) override;
  std::vector<std::int64_t> update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                   const std::vector<std::int64_t>* landmark_ids) override;
  Estimate estimate() const override;
  // A research instrument (JoinOracle in join_options.hpp): every join, the real ones and the
  // estimate's, corrects its association with the truth. Only before the first predict().
  void set_join_oracle(std::shared_ptr<const JoinOracle> oracle);
  Vec3 pose() const override;
  std::vector<std::int64_t> resolve(const std::vector<std::int64_t>& ids) const override;
  const RunStats& stats() const override;

  // The local maps as they closed, then the open one (its robot_id -1), each in its own base
  // frame with the ids it gave its features, and the sealed log of what each was built from:
  // what the re-linearised tree starts from. Kept only with tree_relinearisation > 0 (else
  // empty).
  std::vector<TreeLeaf> tree_leaves() const;
  // Join events so far (pending ones have step_finished == -1).
  std::vector<JoinEvent> joins() const;
  // The stack's shape, bottom first: local maps held by each map, and its feature count
  // (expected count for a pending join: the sum of its inputs).
  std::vector<std::pair<int, std::int64_t>> stack_shape() const;
  // The joins of the last estimate()'s final fold (the stack's maps, top first, each joined
  // with everything after it), as joins() reports the real ones: `index` is the position in the
  // fold, `leaves` the local maps joined so far, both steps the step estimate() was called at.
  // Their `pairing` records what each saw and decided, for diagnosis.
  std::vector<JoinEvent> fold_joins() const;
  // The pending joins the last estimate() computed on the side (or took as an earlier call had
  // computed them), in creation order, each as joins() will report the real join once it runs:
  // `index` is the real join's, `step_finished` the step of the estimate() that computed it.
  std::vector<JoinEvent> side_joins() const;
  // Blocks until every queued join is done (threaded mode) or runs them (other modes).
  void finish_joins();
  const SlamConfig& config() const override { return config_; }
  // The local map being built (base: the robot pose where it started).
  const EkfSlam& local_map() const { return *local_; }

 private:
  friend struct CheckpointAccess;  // checkpoint.cpp saves and restores the state below
  struct JoinTask;
  struct Node {
    int leaves = 1;
    std::int64_t first_leaf = 0;  // the node holds local maps first_leaf .. first_leaf+leaves-1
    std::int64_t expected_features = 0;
    std::int64_t expected_poses = 0;  // past poses (keep_local_map_poses)
    std::int64_t expected_dim() const {
      return GaussianMap::kRobotDim + GaussianMap::kFeatureDim * expected_features +
             GaussianMap::kPoseDim * expected_poses;
    }
    // Id of the node's robot as a past pose: the predict() calls made before its last local
    // map closed.
    std::int64_t robot_id = 0;
    std::shared_ptr<const GaussianMap> map;  // set once complete
    std::vector<TentativeFeature> tentative;  // set with `map`
    // Set with `map` when its join was weak, until the next join decides (join_alternatives.hpp).
    std::shared_ptr<const JoinAlternative> alternative;
    TreeMap tree_map() const { return TreeMap{map, tentative, alternative}; }
    std::shared_ptr<JoinTask> task;          // set while pending
  };
  struct JoinTask {
    int index = 0;
    std::shared_ptr<Node> left, right;
    // The node this join completes. Weak: the node owns the task while the join is pending,
    // and a strong link back would keep joins still queued at destruction alive forever.
    std::weak_ptr<Node> result;
    std::unique_ptr<DecidingJoin> join;
    std::int64_t deadline_step = 0;
    // The budget of every advance() so far: a checkpoint redoes them on load.
    std::vector<std::int64_t> budgets;
  };

  // Neither amortized nor threaded: every join runs at the closure that queues it.
  bool joins_immediate() const { return !config_.amortize && !config_.threaded_joins; }
  void close_local_map();
  void push_and_merge(std::shared_ptr<Node> node);
  void run_amortized_budget();
  // Advances `task` by up to `budget`; returns work done. Completes the node when finished.
  std::int64_t work_on(JoinTask& task, std::int64_t budget);
  // A join that threw (a covariance that is not positive definite, say) leaves its task half
  // done and the tree without its result: the failure is recorded and named (the first one
  // stays), on whichever thread the join ran, instead of escaping a worker thread (which ends
  // the process); work_on() then throws JoinFailed.
  void record_join_failure(const JoinTask& task, const std::exception& error);
  // Reports a recorded failure, if any, to the caller (InvalidArgument): the filter is first
  // put back as it was before the update() that queued the failed join (its restore point),
  // so that it goes on from there. Every public call starts with it: a failure on the worker
  // reaches the caller at the next call. const in estimate() and pose() only in name: see
  // dc_slam.cpp.
  void raise_join_failure_if_any();
  [[noreturn]] void raise_join_failure(std::unique_lock<std::mutex>& lock);
  // A localisation under way (amortized or threaded joins spread it over the steps after its
  // closure), as what redoes it: its inputs and the budget of every advance so far.
  struct PendingLocalisation {
    LocalisationInputs inputs;
    std::int64_t deadline_step = 0;
    std::vector<std::int64_t> budgets;
  };
  // What an update() that closes the local map and queues joins changes, as it was before:
  // the local map before the update and everything the closure and its joins touch. Kept
  // until every join the closure queued is complete (cheap when nothing fails: the stack's
  // maps are shared, not copied; see docs/design.md, "A failed join").
  struct RestorePoint {
    int first_join = 0;     // the joins the closure queued: first_join .. joins_created - 1
    int joins_created = 0;  // of the filter, after the closure
    int incomplete = 0;     // of those joins
    std::unique_ptr<EkfSlam> local;
    std::int64_t local_map_steps = 0, steps = 0, predictions = 0, closed_local_maps = 0, steps_in_closed_maps = 0;
    std::size_t stats_steps = 0;
    StepStats last_step;  // stats_.steps.back() before the update, when stats_steps > 0
    std::vector<std::shared_ptr<Node>> stack;  // pending nodes as copies (copy_pending())
    std::vector<int> queue;                    // indices of the queued joins
    std::vector<JoinEvent> pending_events;     // of the pending joins, as they were
    IdAliases merged_into;
    SightingsById sightings;
    std::map<std::string, double> closed_maps_counters;
    JoinTree tree;
    LeafLog open_log;  // of the local map before the update
    std::optional<Vec3> localised_base;
    std::int64_t online_localisations = 0;
    std::optional<PendingLocalisation> localisation;
  };
  // The local map before an update that may close it (update()); moved into the restore point
  // if it does, else dropped by the next update.
  struct BeforeUpdate {
    std::unique_ptr<EkfSlam> local;
    std::int64_t local_map_steps = 0, steps = 0;
    std::size_t stats_steps = 0;
    StepStats last_step;
    std::size_t open_log_measurements = 0;  // open_log_'s measurements before the update
  };
  // A pending node and its join, copied down to its complete inputs (which never change
  // again, so they are shared); the copy's join has not started (its budgets are kept outside
  // threaded mode, to be redone as a checkpoint redoes them). mutex_ held.
  std::shared_ptr<Node> copy_pending(const std::shared_ptr<Node>& node) const;
  void take_restore_point();  // at the start of close_local_map(); mutex_ held
  void roll_back(RestorePoint point);  // mutex_ held, the worker idle
  void complete(JoinTask& task);
  void worker_loop();
  // The localisation of `closed` (not yet on the stack) against the stack's oldest complete
  // map (SlamConfig::online_localisation_sigma); nullopt when the stack is empty.
  std::optional<LocalisationInputs> localisation_inputs(const Node& closed) const;
  JoinOptions localisation_options(std::uint64_t seed) const;  // a localisation's, RJC's stream `seed`
  // At a closure: the localisation under way finished (it places the closed map's base), then
  // `closed`'s started, run at once with immediate joins and spread over the next
  // max(1, closed_steps / 2) steps otherwise, the base carried from the last one meanwhile.
  void begin_localisation(const Node& closed, std::int64_t closed_steps);
  void advance_localisation();  // each update(), amortized or threaded
  void take_localisation();     // localisation_ done: its result is the open map's base
  std::optional<PendingLocalisation> pending_localisation() const;
  void resume_localisation(std::optional<PendingLocalisation> pending);  // redoes its budgets
  // Options of join `index`, whose first map's robot has pose id `first_robot_id`.
  JoinOptions join_options(int index, std::int64_t first_robot_id) const;
  // The join of two adjacent nodes' maps (or of versions of them), with the tentative features
  // whose last chance it is; weak, it keeps an alternative when its result spans
  // kMinWeakJoinLeaves local maps or more.
  std::unique_ptr<DecidingJoin> make_join(const TreeMap& first, const TreeMap& second, const Node& left,
                                          const Node& right, int index) const;
  // DecidingJoin's weak_pairings for a join that may be weak by its place in the tree.
  int weak_pairings(bool may_be_weak) const;
  // The tentative features of the join of `left` and `right` (joined_tentative()).
  static TentativeOfJoin tentative_of(const Node& left, const Node& right);
  // A node as it stood when estimate() began: its map if complete, else the inputs of its
  // pending join. A join the worker completes during the estimate must not be seen: its
  // merges would be missing from the leaf sets estimate() copied at the start.
  struct FrozenNode {
    std::shared_ptr<Node> node;  // for its fixed fields (leaves, robot id)
    TreeMap map;                 // map.map null while pending
    std::shared_ptr<FrozenNode> left, right;
    int index = 0;
    std::int64_t step_created = 0;  // of the pending join
  };
  std::shared_ptr<FrozenNode> freeze(const std::shared_ptr<Node>& node) const;  // mutex_ held
  // Ids as the joins left them: merged_into_ and the sightings, then what each pending join
  // computed on the side did, for the merges after those joins (complete()'s).
  struct SettledIds {
    IdAliases aliases;
    SightingsById sightings;
  };
  // The map of a frozen node, computing pending joins on copies (never touching the real
  // tasks) as complete() finishes them, the merges after small joins included; what those
  // joins did to ids is appended to `settled`, oldest first, and recorded in `ids`. A pending
  // join computed by an earlier estimate() is taken from materialized_.
  // Each pending join it computes or takes is reported in `side_joins`.
  TreeMap materialize(const FrozenNode& node, std::vector<JoinIds>& settled, SettledIds& ids,
                      std::vector<JoinEvent>& side_joins) const;
  // A pending join as estimate() computed it on the side: its result and what it did to ids
  // (its own joins' JoinIds, then its merges; not its inputs'). Its inputs never change while
  // it is pending, and an input that completes meanwhile is bitwise the map computed on the
  // side, so the next estimate() takes it as it is while the join is still pending. That is
  // most of a call's cost on a revisit while a large join is spread over the steps.
  // `event` reports it as complete() will report the real join, but step_finished is the step
  // of the estimate() that computed it.
  struct MaterializedJoin {
    std::weak_ptr<const Node> node;
    TreeMap map;
    std::vector<JoinIds> settled;
    JoinEvent event;
  };
  // complete()'s merge after a join that spans `leaves` local maps, on its result `decided`
  // (nothing when the join is larger than join_merge_max_leaves or keeps a version for the
  // next join); records the merges in `aliases` and `sightings` and returns them.
  std::vector<std::pair<std::int64_t, std::int64_t>> merge_after_join(int leaves, DecidedJoin& decided,
                                                                      IdAliases& aliases,
                                                                      SightingsById& sightings) const;
  // A map of the stack as estimate()'s fold takes it: materialized, with the ids its pending
  // joins settled, and its robot's pose id.
  struct FoldInput {
    TreeMap map;
    std::vector<JoinIds> settled;
    std::int64_t robot_id = 0;
    std::int64_t leaves = 0;
  };
  // The fold as far as it has gone: the maps folded so far (with the alternative of a weak fold
  // join while its decision waits), what the fold did to ids, and its joins' records.
  struct FoldState {
    TreeMap joined;
    std::shared_ptr<GaussianMap> result;  // joined's map as the last fold join made it, mutable
    IdAliases aliases;
    SightingsById sightings;
    std::vector<JoinEvent> joins;  // by position; report and leaves are set when the join is made
    std::int64_t leaves = 1;  // local maps folded, the open one included
    // Set when a fold comparing versions took a later weak fold join (of kMinWeakJoinLeaves
    // local maps or more) as made: the state just after the first such join, its alternative
    // kept, and the position after it. decide_by_rest_of_fold() goes on from it to decide that
    // join, instead of making the joins before it again.
    std::shared_ptr<const FoldState> after_first_weak;
    std::size_t after_first_weak_position = 0;
    // The last fold join, associated but not made, in a fold comparing versions
    // (make_last_fold_join() makes it): versions compared by their pairs need only its pairs.
    std::shared_ptr<DecidingJoin> last_join;
  };
  // The associations of estimate()'s fold joins (JoinAssociationMemo), by their maps and
  // position: comparing a weak fold join's versions makes some joins again on the same maps
  // (the runs of a later weak join's versions start where the best run of the earlier one
  // took it as made).
  class FoldAssociations {
   public:
    // The memo of the fold join at `position` of these maps: empty the first time.
    std::shared_ptr<JoinAssociationMemo> memo(const std::shared_ptr<const GaussianMap>& first,
                                              const std::shared_ptr<const GaussianMap>& second,
                                              std::size_t position);

   private:
    struct Entry {
      std::weak_ptr<const GaussianMap> first, second;
      std::size_t position = 0;
      std::shared_ptr<JoinAssociationMemo> memo;
    };
    std::mutex mutex_;  // the versions of a weak fold join are folded side by side
    std::vector<Entry> entries_;
  };
  // Folds `inputs` (the stack, top first) from `position` on into `state`: each weak fold join
  // of kMinWeakJoinLeaves local maps or more is decided by the rest of the fold
  // (decide_by_rest_of_fold()), the smaller ones by the next fold join, as a real join is.
  // `comparing_versions`: the fold of one version of a weak fold join, compared by its pairs:
  // the later weak joins of kMinWeakJoinLeaves local maps or more are taken as made (the state
  // after the first kept in after_first_weak), and the last fold join is only associated
  // (FoldState::last_join).
  // `end`: the fold stops before that position (its last join, then, is the one before it).
  FoldState fold(FoldState state, const std::vector<FoldInput>& inputs, std::size_t position,
                 FoldAssociations& associations, bool comparing_versions = false,
                 std::size_t end = static_cast<std::size_t>(-1)) const;
  // Runs the fold join at `position` to its end, or with `associate_only` until its pairs are
  // known, its candidate versions associated on up to `threads` threads; a failure names the
  // stack's map.
  static void run_fold_join(DecidingJoin& join, const std::vector<FoldInput>& inputs, std::size_t position,
                            bool associate_only, int threads);
  // Makes the fold join at `position` (run by run_fold_join()) and folds its result into `state`.
  void take_fold_join(FoldState& state, DecidingJoin& join, const std::vector<FoldInput>& inputs,
                      std::size_t position) const;
  // Makes `state.last_join`, left associated by fold().
  void make_last_fold_join(FoldState& state, const std::vector<FoldInput>& inputs) const;
  // `state` ends with a weak fold join whose decision waits: carries each of its versions
  // through the rest of the fold (each later weak join of kMinWeakJoinLeaves local maps or
  // more taken as made, the smaller ones decided by their next join) and keeps the
  // one that makes the most pairs over the weak join and every fold join after it (a tie keeps
  // the tighter version); the fold then goes on from that version, deciding the later weak
  // joins the same way (docs/data_association.md, "The final fold decides by the rest of the
  // fold"). A looser version is carried through only if the next fold join makes more pairs
  // of its own with it than with the join as made.
  FoldState decide_by_rest_of_fold(FoldState state, const std::vector<FoldInput>& inputs, std::size_t position,
                                   FoldAssociations& associations) const;
  // Merges the duplicates the joins left in `map` as the EKF merges its own (each the other's
  // only compatible feature within merge_radius, seen together in at most
  // final_merge_shared_scans scans), the test with join_feature_sigma as at a join and at
  // final_merge_confidence. `as_named` names an id of `sightings`' lists as `map` does (after
  // the merges made since the list was recorded); the features listed in `left_out` (still
  // tentative) are not merged. Records the merges in `aliases` and `sightings` and returns them,
  // (id merged, id kept). Off with merge_radius 0 or known association.
  std::vector<std::pair<std::int64_t, std::int64_t>> merge_duplicates(
      GaussianMap& map, IdAliases& aliases, SightingsById& sightings,
      const std::function<std::int64_t(std::int64_t)>& as_named, const std::vector<TentativeFeature>& left_out) const;
  // Follows merged_into_, then the last estimate()'s aliases while they are current.
  std::int64_t resolve_one(std::int64_t id) const;
  Vec3 node_robot(const Node& node) const;
  void begin_step();
  void end_step(double seconds);
  void forget_estimate_aliases();

  SlamConfig config_;
  const int estimate_threads_;  // config_.estimate_threads resolved (estimate_thread_count())
  std::unique_ptr<EkfSlam> local_;
  std::int64_t local_map_steps_ = 0;
  // Written by the front end's every step, read by a join worker when a join completes.
  std::atomic<std::int64_t> steps_{0};
  std::int64_t predictions_ = 0;
  std::int64_t closed_local_maps_ = 0;
  std::int64_t steps_in_closed_maps_ = 0;
  int joins_created_ = 0;
  // The open local map's base in the global frame, from the last localisation (carried from
  // the one before while it is under way); unset: pose() composes the stack's maps.
  std::optional<Vec3> localised_base_;
  std::int64_t online_localisations_ = 0;
  std::unique_ptr<MapLocalisation> localisation_;  // under way
  std::int64_t localisation_deadline_ = 0;
  std::vector<std::int64_t> localisation_budgets_;

  mutable std::mutex mutex_;  // guards the stack, tasks, events and aliases (threaded mode)
  std::condition_variable work_ready_, work_done_;
  std::vector<std::shared_ptr<Node>> stack_;
  std::deque<std::shared_ptr<JoinTask>> queue_;
  std::vector<JoinEvent> events_;
  IdAliases merged_into_;
  SightingsById sightings_;  // of the features of the closed local maps and of the joins done
  std::shared_ptr<const JoinOracle> join_oracle_;
  JoinTree tree_;  // with tree_relinearisation > 0; front end only
  // What the open local map was built from (tree_relinearisation > 0; front end only): each
  // predict()'s u, Q and each measurement update() used, with the id it gave.
  LeafLog open_log_;
  // Counters of the closed local maps' filters (see kLocalCounters in dc_slam.cpp).
  std::map<std::string, double> closed_maps_counters_;
  // The merges of the joins the last estimate() made on copies: resolve() follows them until
  // the next predict() or update(), so that ids resolve to that estimate's landmarks.
  mutable IdAliases estimate_aliases_;
  mutable std::vector<JoinEvent> fold_joins_;  // of the last estimate()
  mutable std::vector<JoinEvent> side_joins_;  // of the last estimate()
  // The pending joins estimate() computed on the side, until the first step after they
  // complete (begin_step()); front end only.
  mutable std::vector<MaterializedJoin> materialized_;
  mutable std::int64_t estimate_pending_joins_ = 0, estimate_pending_joins_reused_ = 0;
  bool stopping_ = false;
  bool worker_busy_ = false;
  // Gauss–Newton passes of the last estimate()'s re-linearised tree, and its last step.
  mutable RelinearisationReport relinearisation_;  // guarded by mutex_
  std::string join_failure_;  // empty unless a join failed (record_join_failure())
  int failed_join_ = -1;      // its index
  // Oldest first; guarded by mutex_ (complete() releases them on the worker).
  std::deque<RestorePoint> restore_points_;
  BeforeUpdate before_update_;  // front end only
  // Finished joins' inputs, matrices and restore points, freed one a step (begin_step());
  // guarded by mutex_.
  std::deque<std::shared_ptr<const void>> released_;
  std::thread worker_;

  mutable RunStats stats_;  // counters are refreshed by stats()
};

}  // namespace dcslam
