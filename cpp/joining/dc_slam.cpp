#include "dcslam/joining/dc_slam.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <iterator>
#include <limits>
#include <unordered_set>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/feature_merging.hpp"
#include "dcslam/joining/join_tree.hpp"
#include "dcslam/joining/parallel_tasks.hpp"
#include "dcslam/joining/tentative_features.hpp"

namespace dcslam {

namespace {

// Joins of fewer local maps never keep an alternative (SlamConfig::weak_join_pairings): with
// the truth at every larger join D&C's recall on the simulator's revisit scenes is what the
// truth at every join gives, so the joins of two to four local maps do not decide a run
// (docs/data_association.md, "Which joins decide"), and there every join would be weak.
constexpr int kMinWeakJoinLeaves = 8;
// Joins of at least this many local maps keep the costlier versions: a weak join its version
// without any pair, a large join its version without its doubtful pairs. On the revisit scenes
// (20 seeds each) no version without any pair was taken from a join of 8 local maps, where
// Victoria Park's weak joins all are, and each version costs a fill and the next join's
// associations (about 7 % of Victoria Park's join work for the weak joins'); from 32 on,
// loop_both_ways loses a seed's gain.
constexpr int kManyLocalMaps = 16;

// Where the re-linearised tree stops: no mean moved by more than this (m or rad) in a pass.
constexpr double kRelinearisationTolerance = 1e-9;

// estimate()'s fold joins are indexed -1, -2, ... by their position in the fold, apart from
// the real joins' events (JoinAlternative::join_index).
int fold_join_index(std::size_t position) { return -1 - static_cast<int>(position); }
std::size_t fold_position(int join_index) { return static_cast<std::size_t>(-1 - join_index); }

// The local maps' EKF counters that DCSlam's stats add up over all local maps.
constexpr const char* kLocalCounters[] = {"features_merged", "tentative_removed", "jcbb_nodes", "jcbb_bound_hits",
                                         "unexplained_started", "started_beside_tentative"};

double counter(const std::map<std::string, double>& counters, const char* name) {
  const auto found = counters.find(name);
  return found == counters.end() ? 0.0 : found->second;
}

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Thrown by work_on() once the failure is recorded: the front end's callers roll back and
// report it (raise_join_failure()); the worker only stops the join.
struct JoinFailed : InvalidArgument {
  using InvalidArgument::InvalidArgument;
};

// A copy whose storage fits exactly: local maps keep capacity headroom while they grow,
// finished ones do not need it.
std::shared_ptr<const GaussianMap> compact_copy(const GaussianMap& map) {
  auto copy = std::make_shared<GaussianMap>(
      GaussianMap::uninitialized(map.num_features(), map.num_poses()));
  copy->x() = map.x();
  copy->P() = map.P();
  copy->ids() = map.ids();
  copy->pose_ids() = map.pose_ids();
  return copy;
}

// `map` without its past poses: marginalised, since they follow the robot and features in
// the state.
GaussianMap without_past_poses(const GaussianMap& map) {
  GaussianMap out = GaussianMap::uninitialized(map.num_features());
  out.x() = map.x().head(out.dim());
  out.P() = map.P().topLeftCorner(out.dim(), out.dim());
  out.ids() = map.ids();
  return out;
}

}  // namespace

DCSlam::DCSlam(const SlamConfig& config)
    : config_(config), estimate_threads_(estimate_thread_count(config.estimate_threads)) {
  config_.validate();
  local_ = std::make_unique<EkfSlam>(config_);
  if (config_.threaded_joins) worker_ = std::thread([this] { worker_loop(); });
}

DCSlam::~DCSlam() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  work_ready_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void DCSlam::set_join_oracle(std::shared_ptr<const JoinOracle> oracle) {
  if (predictions_ > 0 || steps_ > 0) throw InvalidArgument("set_join_oracle: only before the first predict()");
  join_oracle_ = std::move(oracle);
}

JoinOptions DCSlam::join_options(int index, std::int64_t first_robot_id) const {
  JoinOptions options = join_options_of(config_);
  options.first_robot_id = first_robot_id;
  options.oracle = join_oracle_;
  // One reproducible stream per join, whatever the order in which joins are run.
  options.rjc.seed = config_.seed ^ (0x9E3779B97F4A7C15ULL * static_cast<std::uint64_t>(index + 1));
  return options;
}

void DCSlam::forget_estimate_aliases() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!estimate_aliases_.empty()) estimate_aliases_.clear();
}

void DCSlam::begin_step() {
  std::shared_ptr<const void> leftover;  // freed at the end of this scope, outside the lock
  {
    // One of the finished joins' leftovers a step (complete()).
    std::lock_guard<std::mutex> lock(mutex_);
    if (!released_.empty()) {
      leftover = std::move(released_.front());
      released_.pop_front();
    }
    // A join estimate() computed on the side that has completed since (or was rolled back)
    // cannot be taken again: its map joins the leftovers rather than staying till the next call.
    for (auto it = materialized_.begin(); it != materialized_.end();) {
      const std::shared_ptr<const Node> node = it->node.lock();
      if (node && !node->map) {
        ++it;
        continue;
      }
      released_.push_back(std::move(it->map.map));
      released_.push_back(std::move(it->map.alternative));
      it = materialized_.erase(it);
    }
  }
  stats_.steps.emplace_back();
  ++steps_;
  ++local_map_steps_;
}

void DCSlam::end_step(double seconds) {
  StepStats& step = stats_.steps.back();
  step.seconds += seconds;
  std::int64_t features = local_->map().num_features();
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& node : stack_) features += node->expected_features;
  step.num_features = features;
}

void DCSlam::predict(const Vec3& u, const Mat3& Q) {
  raise_join_failure_if_any();
  const auto start = Clock::now();
  local_->predict(u, Q);  // validates first: a bad call changes nothing
  if (config_.tree_relinearisation > 0) {
    open_log_.u.push_back(u);
    open_log_.Q.push_back(0.5 * (Q + Q.transpose()));  // what the EKF uses
  }
  forget_estimate_aliases();
  ++predictions_;
  begin_step();
  end_step(seconds_since(start));
}

std::vector<std::int64_t> DCSlam::update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                         const std::vector<std::int64_t>* landmark_ids) {
  raise_join_failure_if_any();
  const auto start = Clock::now();
  // An update that closes the local map and so queues a join keeps the local map as it was
  // for the restore point. A closure needs as many features as local_map_features after the
  // update, and an update adds at most one feature per measurement: the copy (O(p^2) of the
  // local map's p) is only made on the last updates of a local map.
  before_update_.local.reset();
  if (local_->map().num_features() + z.rows() >= config_.local_map_features && !stack_.empty() &&
      stack_.back()->leaves == 1) {
    before_update_.local = std::make_unique<EkfSlam>(*local_);
    before_update_.local_map_steps = local_map_steps_;
    before_update_.steps = steps_;
    before_update_.stats_steps = stats_.steps.size();
    before_update_.last_step = stats_.steps.empty() ? StepStats() : stats_.steps.back();
    before_update_.open_log_measurements = open_log_.measurements.size();
  }
  std::vector<std::int64_t> ids = local_->update(z, R, landmark_ids);
  if (config_.tree_relinearisation > 0) {
    // The measurements the EKF used (a rejected one gets -1), at the local map's current pose.
    const auto pose = static_cast<std::int64_t>(open_log_.u.size());
    for (std::size_t i = 0; i < ids.size(); ++i) {
      if (ids[i] == -1) continue;
      const Mat2& covariance = R.size() == 1 ? R[0] : R[i];
      open_log_.measurements.push_back(LeafMeasurement{z.row(static_cast<Eigen::Index>(i)).transpose(),
                                                       0.5 * (covariance + covariance.transpose()), ids[i], pose});
    }
  }
  forget_estimate_aliases();
  if (stats_.steps.empty()) begin_step();  // measurements at the first pose, before any motion
  const StepStats& local_step = local_->stats().steps.back();
  StepStats& step = stats_.steps.back();
  step.measurements += local_step.measurements;
  step.paired += local_step.paired;
  step.new_features += local_step.new_features;
  step.rejected += local_step.rejected;
  step.association_seconds += local_step.association_seconds;
  try {
    if (local_->map().num_features() >= config_.local_map_features) close_local_map();
    if (config_.amortize && !config_.threaded_joins) run_amortized_budget();
    if (!joins_immediate()) advance_localisation();
  } catch (const JoinFailed&) {
    std::unique_lock<std::mutex> lock(mutex_);
    raise_join_failure(lock);
  }
  end_step(seconds_since(start));
  return ids;
}

namespace {

void record_sightings(const EkfSlam& local, SightingsById& sightings) {
  const auto& ids = local.map().ids();
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const auto index = static_cast<Eigen::Index>(k);
    sightings[ids[k]] = Sightings{local.sightings(index), local.seen_with(index)};
  }
}

}  // namespace

void DCSlam::close_local_map() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (before_update_.local) take_restore_point();
  }
  {
    // Ids of the tentative features the local map removed as expired resolve to -1 from now on.
    std::lock_guard<std::mutex> lock(mutex_);
    for (std::int64_t id : local_->removed_ids()) add_alias(merged_into_, id, -1);
    // Each merged id straight to where the local map's chain of merges ends: add_alias() drops
    // the alias of the id it points to, so copying a chain a -> b -> c link by link would lose
    // b -> c whenever the hash map gave a -> b last.
    for (const auto& [from, to] : local_->merged_ids()) {
      add_alias(merged_into_, from, follow_aliases(local_->merged_ids(), to));
    }
    for (const char* name : kLocalCounters) closed_maps_counters_[name] += counter(local_->stats().counters, name);
    record_sightings(*local_, sightings_);
  }
  auto node = std::make_shared<Node>();
  node->map = compact_copy(local_->map());
  // Features seen once stay until the joins with the neighbouring local maps (the previous
  // one, for those first seen in this map's first steps; the next one, for those still
  // unexpired), and are kept only if matched there: the EKF's min_sightings rule across maps.
  const std::int64_t leaf = closed_local_maps_;
  const std::int64_t window = config_.tentative_window;
  const std::int64_t steps = local_->steps();
  for (const auto& feature : local_->tentative_features()) {
    node->tentative.push_back(TentativeFeature{
        feature.id, leaf, leaf > 0 && feature.first_seen_step <= window,
        steps - feature.last_seen_step <= window});
  }
  node->first_leaf = leaf;
  node->robot_id = predictions_;
  node->expected_features = node->map->num_features();
  const std::int64_t next_id = local_->next_fresh_id();
  const IdAliases local_merges = local_->merged_ids();
  local_ = std::make_unique<EkfSlam>(config_);
  local_->set_next_fresh_id(next_id);
  local_->keep_tentative_first_seen_until(window);
  const std::int64_t closed_steps = local_map_steps_;
  steps_in_closed_maps_ += local_map_steps_;
  local_map_steps_ = 0;
  ++closed_local_maps_;
  if (config_.tree_relinearisation > 0) {
    tree_.add_leaf(TreeLeaf{node->map, node->tentative, node->robot_id,
                            std::make_shared<const LeafLog>(seal_leaf_log(open_log_, *node->map, local_merges))});
    open_log_ = LeafLog();
  }
  if (config_.online_localisation_sigma) begin_localisation(*node, closed_steps);
  push_and_merge(std::move(node));
  if (joins_immediate()) {
    const auto tasks = queue_;  // a failing join empties queue_ (record_join_failure())
    for (const auto& task : tasks) work_on(*task, std::numeric_limits<std::int64_t>::max());
    queue_.clear();
  }
}

std::shared_ptr<DCSlam::Node> DCSlam::copy_pending(const std::shared_ptr<Node>& node) const {
  if (node->map) return node;
  auto copy = std::make_shared<Node>(*node);
  auto task = std::make_shared<JoinTask>();
  task->index = node->task->index;
  task->deadline_step = node->task->deadline_step;
  // The worker writes a running join's budgets without the lock, and runs a join in one go.
  if (!config_.threaded_joins) task->budgets = node->task->budgets;
  task->left = copy_pending(node->task->left);
  task->right = copy_pending(node->task->right);
  task->result = copy;
  copy->task = std::move(task);
  return copy;
}

void DCSlam::take_restore_point() {
  RestorePoint point;
  point.local = std::move(before_update_.local);
  point.local_map_steps = before_update_.local_map_steps;
  point.steps = before_update_.steps;
  point.stats_steps = before_update_.stats_steps;
  point.last_step = before_update_.last_step;
  point.predictions = predictions_;
  point.closed_local_maps = closed_local_maps_;
  point.steps_in_closed_maps = steps_in_closed_maps_;
  point.localised_base = localised_base_;
  point.online_localisations = online_localisations_;
  point.localisation = pending_localisation();
  point.first_join = joins_created_;
  // The joins push_and_merge() will queue for the new local map (one leaf).
  int leaves = 1;
  for (auto it = stack_.rbegin(); it != stack_.rend() && leaves >= (*it)->leaves; ++it) {
    leaves += (*it)->leaves;
    ++point.incomplete;
  }
  point.joins_created = point.first_join + point.incomplete;
  for (const auto& node : stack_) point.stack.push_back(copy_pending(node));
  for (const auto& task : queue_) {
    point.queue.push_back(task->index);
    point.pending_events.push_back(events_[static_cast<std::size_t>(task->index)]);
  }
  point.merged_into = merged_into_;
  point.sightings = sightings_;
  point.closed_maps_counters = closed_maps_counters_;
  if (config_.tree_relinearisation > 0) {
    point.tree = tree_;
    point.open_log = open_log_;
    point.open_log.measurements.resize(before_update_.open_log_measurements);
  }
  restore_points_.push_back(std::move(point));
}

void DCSlam::roll_back(RestorePoint point) {
  local_ = std::move(point.local);
  local_map_steps_ = point.local_map_steps;
  steps_ = point.steps;
  predictions_ = point.predictions;
  closed_local_maps_ = point.closed_local_maps;
  steps_in_closed_maps_ = point.steps_in_closed_maps;
  localised_base_ = point.localised_base;
  online_localisations_ = point.online_localisations;
  resume_localisation(std::move(point.localisation));
  joins_created_ = point.first_join;
  stats_.steps.resize(point.stats_steps);
  if (!stats_.steps.empty()) stats_.steps.back() = point.last_step;
  stack_ = std::move(point.stack);
  events_.resize(static_cast<std::size_t>(point.first_join));
  for (JoinEvent& event : point.pending_events) events_[static_cast<std::size_t>(event.index)] = std::move(event);
  merged_into_ = std::move(point.merged_into);
  sightings_ = std::move(point.sightings);
  closed_maps_counters_ = std::move(point.closed_maps_counters);
  if (config_.tree_relinearisation > 0) {
    tree_ = std::move(point.tree);
    open_log_ = std::move(point.open_log);
  }
  estimate_aliases_.clear();  // as after any update: resolve() follows the joins done
  std::map<int, std::shared_ptr<JoinTask>> tasks;
  const std::function<void(const std::shared_ptr<Node>&)> collect = [&](const std::shared_ptr<Node>& node) {
    if (!node->task) return;
    tasks[node->task->index] = node->task;
    collect(node->task->left);
    collect(node->task->right);
  };
  for (const auto& node : stack_) collect(node);
  queue_.clear();
  for (const int index : point.queue) queue_.push_back(tasks.at(index));
}

// The paper's Algorithm 2: while the new map is at least as big as the top of the stack, pop
// and join. Joins are only queued here; who runs them depends on the mode.
void DCSlam::push_and_merge(std::shared_ptr<Node> node) {
  std::unique_lock<std::mutex> lock(mutex_);
  const double steps_per_local_map =
      static_cast<double>(steps_in_closed_maps_) / static_cast<double>(closed_local_maps_);
  std::vector<std::shared_ptr<JoinTask>> chain;  // joins created now, each waiting on the last
  while (!stack_.empty() && node->leaves >= stack_.back()->leaves) {
    auto task = std::make_shared<JoinTask>();
    task->index = joins_created_++;
    task->left = stack_.back();
    stack_.pop_back();
    task->right = std::move(node);
    if (config_.tree_relinearisation > 0) {
      tree_.add_join(TreeSpan{task->left->first_leaf, task->left->leaves},
                     TreeSpan{task->right->first_leaf, task->right->leaves});
    }
    auto result = std::make_shared<Node>();
    task->result = result;
    result->leaves = task->left->leaves + task->right->leaves;
    result->first_leaf = task->left->first_leaf;
    result->robot_id = task->right->robot_id;
    result->expected_features =
        task->left->expected_features + task->right->expected_features;
    result->expected_poses = task->left->expected_poses + task->right->expected_poses +
                             (config_.keep_local_map_poses ? 1 : 0);
    result->task = task;
    // The result is next needed when as many local maps again have been closed; finishing
    // within half that time leaves the other half for the joins that will wait on it.
    task->deadline_step =
        steps_ + std::max<std::int64_t>(1, static_cast<std::int64_t>(
                                               0.5 * result->leaves * steps_per_local_map));
    chain.push_back(task);
    JoinEvent event;
    event.index = task->index;
    event.leaves = result->leaves;
    event.step_created = steps_;
    // Sizes as known now (a pending input counts its inputs' sum); exact once finished.
    event.report.features_first = task->left->expected_features;
    event.report.features_second = task->right->expected_features;
    events_.push_back(event);
    queue_.push_back(task);
    node = std::move(result);
  }
  // A chain's joins run one after the other, and the last one, the biggest, only starts when
  // the one before it is done: the window up to the last deadline is shared among them in
  // proportion to their fills (dim^2; r is unknown yet), instead of the last join getting
  // only what its predecessors' own deadlines leave (a few ms a step for the snail's
  // 128-leaf join, squeezed into its last 120 steps).
  if (chain.size() > 1) {
    const auto fill = [](const JoinTask& task) {
      const auto dim = static_cast<double>(task.result.lock()->expected_dim());
      return dim * dim;
    };
    double total = 0.0;
    for (const auto& task : chain) total += fill(*task);
    const auto window = static_cast<double>(chain.back()->deadline_step - steps_);
    double done = 0.0;
    for (std::size_t k = 0; k + 1 < chain.size(); ++k) {
      done += fill(*chain[k]);
      chain[k]->deadline_step = std::min(
          chain[k]->deadline_step,
          steps_ + std::max<std::int64_t>(1, static_cast<std::int64_t>(window * done / total)));
    }
  }
  stack_.push_back(std::move(node));
  lock.unlock();
  work_ready_.notify_all();
}

void DCSlam::run_amortized_budget() {
  if (queue_.empty()) return;
  double budget = 0.0;
  for (const auto& task : queue_) {
    // A join not started yet: a low guess, one unit a cell of its output's lower triangle and
    // two a row; once the join exists, MapJoin::remaining_work() counts all its phases. Its
    // count before the first step (with the assembly, the solve and the association
    // besides) is not used here: it raises these budgets and so moves every
    // amortized run's schedule (which join finishes at which step, and the online poses).
    const std::int64_t dim = task->result.lock()->expected_dim();
    const std::int64_t remaining =
        task->join ? task->join->remaining_work() : dim * (dim + 1) / 2 + 2 * dim;
    budget += static_cast<double>(remaining) /
              static_cast<double>(std::max<std::int64_t>(1, task->deadline_step - steps_));
  }
  auto left = static_cast<std::int64_t>(std::ceil(budget));
  while (left > 0 && !queue_.empty()) {
    // Earliest deadline first among the joins whose inputs exist: a small join queued behind a
    // large independent one is done first, so the large one runs at the pace of its own
    // deadline rather than at the sum of everyone's. The queue's order is post-order, so its
    // front is always ready.
    auto next = queue_.begin();
    for (auto it = queue_.begin(); it != queue_.end(); ++it) {
      const JoinTask& task = **it;
      if (task.left->map && task.right->map && task.deadline_step < (*next)->deadline_step) next = it;
    }
    JoinTask& task = **next;
    left -= work_on(task, left);
    if (task.join && !task.join->done()) break;
    queue_.erase(next);
  }
}

std::int64_t DCSlam::work_on(JoinTask& task, std::int64_t budget) {
  try {
    if (!task.join) {
      task.join = make_join(task.left->tree_map(), task.right->tree_map(), *task.left, *task.right, task.index);
    }
    task.budgets.push_back(budget);
    const std::int64_t spent = task.join->advance(budget);
    if (task.join->done()) complete(task);
    return spent;
  } catch (const std::exception& error) {
    record_join_failure(task, error);
    throw JoinFailed(error.what());
  }
}

void DCSlam::record_join_failure(const JoinTask& task, const std::exception& error) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (join_failure_.empty()) {
    const JoinEvent& event = events_[static_cast<std::size_t>(task.index)];
    join_failure_ = "DCSlam: join " + std::to_string(task.index) + " (" + std::to_string(event.leaves) +
                    " local maps, queued at step " + std::to_string(event.step_created) +
                    ") failed: " + error.what();
    failed_join_ = task.index;
  }
  queue_.clear();  // the joins after it need its result
}

void DCSlam::raise_join_failure_if_any() {
  std::unique_lock<std::mutex> lock(mutex_);
  if (!join_failure_.empty()) raise_join_failure(lock);
}

void DCSlam::raise_join_failure(std::unique_lock<std::mutex>& lock) {
  // Threaded: the worker may still be leaving the failed join; it takes no other one.
  work_done_.wait(lock, [this] { return !worker_busy_; });
  const auto point = std::find_if(restore_points_.begin(), restore_points_.end(), [this](const RestorePoint& p) {
    return p.first_join <= failed_join_ && failed_join_ < p.joins_created;
  });
  if (point == restore_points_.end()) {
    // Restore points are not saved in checkpoints: the failure stays, and every call raises it.
    throw InvalidArgument(join_failure_ +
                          "; this filter cannot go on (it was resumed from a checkpoint saved while the join was "
                          "pending, and a checkpoint keeps no restore point)");
  }
  const std::string message =
      join_failure_ + "; the filter is back at its state before the update() that queued the join (step " +
      std::to_string(events_[static_cast<std::size_t>(failed_join_)].step_created) +
      "): that update and every call after it are undone";
  RestorePoint restore = std::move(*point);
  // The restore points taken after it belong to the state undone.
  restore_points_.erase(point, restore_points_.end());
  roll_back(std::move(restore));
  join_failure_.clear();
  failed_join_ = -1;
  lock.unlock();
  if (!config_.threaded_joins) {
    // The work the pending joins had done, redone with the budgets they had been given (as a
    // checkpoint's load does): it ran before without failing, and stops short of their end.
    for (const auto& task : queue_) {
      const std::vector<std::int64_t> budgets = std::move(task->budgets);
      task->budgets.clear();
      for (const std::int64_t budget : budgets) work_on(*task, budget);
    }
  }
  work_ready_.notify_all();
  throw InvalidArgument(message);
}

std::unique_ptr<DecidingJoin> DCSlam::make_join(const TreeMap& first, const TreeMap& second, const Node& left,
                                                const Node& right, int index) const {
  const std::int64_t first_leaf = left.first_leaf;
  const std::int64_t last_leaf = right.first_leaf + right.leaves - 1;
  auto make = [options = join_options(index, left.robot_id), first_leaf, last_leaf](
                  const TreeMap& a, const TreeMap& b, std::shared_ptr<const MapJoin::Pairs> fixed_pairs) {
    JoinOptions join_options = options;
    join_options.fixed_pairs = std::move(fixed_pairs);
    return std::make_unique<MapJoin>(a.map, b.map, std::move(join_options),
                                     last_chance(*a.map, a.tentative, first_leaf, last_leaf),
                                     last_chance(*b.map, b.tentative, first_leaf, last_leaf));
  };
  return std::make_unique<DecidingJoin>(first, second, std::move(make),
                                        weak_pairings(left.leaves + right.leaves >= kMinWeakJoinLeaves),
                                        left.leaves + right.leaves >= kManyLocalMaps);
}

int DCSlam::weak_pairings(bool may_be_weak) const {
  // Pairs by the caller's ids are not a decision to revisit.
  return may_be_weak && config_.join_association != JoinAssociation::Known ? config_.weak_join_pairings : 0;
}

TentativeOfJoin DCSlam::tentative_of(const Node& left, const Node& right) {
  return [first_leaf = left.first_leaf, last_leaf = right.first_leaf + right.leaves - 1](
             const TreeMap& first, const TreeMap& second, const MapJoin& join) {
    return joined_tentative(first.tentative, second.tentative, join, first_leaf, last_leaf);
  };
}

namespace {

// A merged feature was seen in the scans of both, with what either was seen with.
void merge_sightings(SightingsById& sightings, std::int64_t from, std::int64_t to) {
  if (from == to) return;
  const auto source = sightings.find(from);
  if (source == sightings.end()) return;
  Sightings& target = sightings[to];
  target.scans += source->second.scans;
  target.seen_with.insert(target.seen_with.end(), source->second.seen_with.begin(), source->second.seen_with.end());
  sightings.erase(from);
}

// What a join did to ids: each merged one now names the feature it joined; dropped ones, -1.
void record_ids(const JoinIds& ids, IdAliases& aliases, SightingsById& sightings) {
  for (const auto& [from, to] : ids.merged) {
    add_alias(aliases, from, to);
    merge_sightings(sightings, from, to);
  }
  for (std::int64_t id : ids.dropped) {
    add_alias(aliases, id, -1);
    sightings.erase(id);
  }
}

}  // namespace

void DCSlam::complete(JoinTask& task) {
  const JoinReport report = task.join->report();
  DecidedJoin decided = task.join->take_result(tentative_of(*task.left, *task.right), task.index);
  std::lock_guard<std::mutex> lock(mutex_);
  JoinEvent& event = events_[static_cast<std::size_t>(task.index)];
  event.report = report;
  event.pairing = task.join->join().pairing_record();
  // A weak input's record lists the pairs of the version this join took.
  for (const auto& [input, version] :
       {std::pair<const Node*, int>{task.left.get(), task.join->first_version_taken()},
        std::pair<const Node*, int>{task.right.get(), task.join->second_version_taken()}}) {
    if (version > 0) {
      const JoinAlternative& alternative = *input->alternative;
      events_[static_cast<std::size_t>(alternative.join_index)].pairing.pairs =
          alternative.ids_of(version).record_pairs();
    }
  }
  event.step_finished = steps_;
  for (const JoinIds& ids : decided.settled) record_ids(ids, merged_into_, sightings_);
  const std::shared_ptr<Node> result = task.result.lock();
  event.pairing.merged = merge_after_join(result->leaves, decided, merged_into_, sightings_);
  result->tentative = std::move(decided.tentative);
  result->map = std::move(decided.map);
  result->alternative = std::move(decided.alternative);
  result->expected_features = result->map->num_features();
  result->expected_poses = result->map->num_poses();
  result->task.reset();
  // What the join no longer needs is freed one piece a step from the next one on
  // (begin_step()): freeing it all here (its inputs, its own matrices, the restore point) took
  // about 1.1 ms on Victoria Park's largest join, most of the worst step, one munmap a block.
  released_.push_back(std::move(task.left));
  released_.push_back(std::move(task.right));
  released_.push_back(std::shared_ptr<DecidingJoin>(std::move(task.join)));
  // The restore point of the update that queued the join is kept until all of its joins are.
  for (auto point = restore_points_.begin(); point != restore_points_.end(); ++point) {
    if (point->first_join <= task.index && task.index < point->joins_created) {
      if (--point->incomplete == 0) {
        released_.push_back(std::make_shared<RestorePoint>(std::move(*point)));
        restore_points_.erase(point);
      }
      break;
    }
  }
}

void DCSlam::worker_loop() {
  for (;;) {
    std::shared_ptr<JoinTask> task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_ready_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      if (!join_failure_.empty()) {
        // Joins queued after a failure may need the failed join's result: none of them runs.
        queue_.clear();
        work_done_.notify_all();
        continue;
      }
      task = queue_.front();
      worker_busy_ = true;
    }
    try {
      work_on(*task, std::numeric_limits<std::int64_t>::max());
    } catch (const std::exception&) {
      // Recorded by work_on(), which emptied the queue; the caller's next call raises it.
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!queue_.empty() && queue_.front() == task) queue_.pop_front();
      worker_busy_ = false;
    }
    work_done_.notify_all();
  }
}

void DCSlam::finish_joins() {
  raise_join_failure_if_any();
  if (config_.threaded_joins) {
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_done_.wait(lock, [this] { return queue_.empty() && !worker_busy_; });
    }
    raise_join_failure_if_any();
    return;
  }
  try {
    while (!queue_.empty()) {
      work_on(*queue_.front(), std::numeric_limits<std::int64_t>::max());
      queue_.pop_front();
    }
  } catch (const JoinFailed&) {
    std::unique_lock<std::mutex> lock(mutex_);
    raise_join_failure(lock);
  }
}

std::shared_ptr<DCSlam::FrozenNode> DCSlam::freeze(const std::shared_ptr<Node>& node) const {
  auto frozen = std::make_shared<FrozenNode>();
  frozen->node = node;
  if (node->map) {
    frozen->map = node->tree_map();
  } else {
    frozen->left = freeze(node->task->left);
    frozen->right = freeze(node->task->right);
    frozen->index = node->task->index;
    frozen->step_created = events_[static_cast<std::size_t>(frozen->index)].step_created;
  }
  return frozen;
}

TreeMap DCSlam::materialize(const FrozenNode& node, std::vector<JoinIds>& settled, SettledIds& ids,
                            std::vector<JoinEvent>& side_joins) const {
  if (node.map.map) return node.map;
  // Same inputs and options as the real join: the same result, computed on the side.
  const TreeMap first = materialize(*node.left, settled, ids, side_joins);
  const TreeMap second = materialize(*node.right, settled, ids, side_joins);
  ++estimate_pending_joins_;
  for (MaterializedJoin& made : materialized_) {
    if (made.node.lock() != node.node) continue;
    for (const JoinIds& join_ids : made.settled) record_ids(join_ids, ids.aliases, ids.sightings);
    settled.insert(settled.end(), made.settled.begin(), made.settled.end());
    side_joins.push_back(made.event);
    ++estimate_pending_joins_reused_;
    return made.map;
  }
  const Node& left = *node.left->node;
  const Node& right = *node.right->node;
  const std::unique_ptr<DecidingJoin> join = make_join(first, second, left, right, node.index);
  try {
    join->finish(estimate_threads_);
  } catch (const std::exception& error) {
    // The real join fails the same way when it runs, and rolls the filter back then.
    throw InvalidArgument("DCSlam::estimate: pending join " + std::to_string(node.index) + " (queued at step " +
                          std::to_string(node.step_created) + ") fails: " + error.what() +
                          "; the filter is unchanged until it runs that join (finish_joins() runs it now)");
  }
  const JoinReport report = join->report();
  DecidedJoin decided = join->take_result(tentative_of(left, right), node.index);
  MaterializedJoin made{node.node, TreeMap(), decided.settled, JoinEvent()};
  for (const JoinIds& join_ids : decided.settled) record_ids(join_ids, ids.aliases, ids.sightings);
  JoinIds merges;
  merges.merged = merge_after_join(left.leaves + right.leaves, decided, ids.aliases, ids.sightings);
  made.event.index = node.index;
  made.event.leaves = left.leaves + right.leaves;
  made.event.step_created = node.step_created;
  made.event.step_finished = steps_;
  made.event.report = report;
  made.event.pairing = join->join().pairing_record();
  made.event.pairing.merged = merges.merged;
  if (!merges.merged.empty()) made.settled.push_back(std::move(merges));
  settled.insert(settled.end(), made.settled.begin(), made.settled.end());
  made.map = decided.tree_map();
  side_joins.push_back(made.event);
  materialized_.push_back(std::move(made));
  return materialized_.back().map;
}

std::vector<std::pair<std::int64_t, std::int64_t>> DCSlam::merge_after_join(int leaves, DecidedJoin& decided,
                                                                            IdAliases& aliases,
                                                                            SightingsById& sightings) const {
  // A small join's unpaired duplicates would otherwise meet every larger join twice. A weak
  // join's versions wait for the next join, which compares them as they were made.
  if (leaves > config_.join_merge_max_leaves || decided.alternative) return {};
  return merge_duplicates(
      *decided.map, aliases, sightings, [&](std::int64_t id) { return follow_aliases(aliases, id); },
      decided.tentative);
}

std::shared_ptr<JoinAssociationMemo> DCSlam::FoldAssociations::memo(const std::shared_ptr<const GaussianMap>& first,
                                                                    const std::shared_ptr<const GaussianMap>& second,
                                                                    std::size_t position) {
  std::lock_guard<std::mutex> lock(mutex_);
  // A map no longer alive cannot be joined again, and its address may be another map's now.
  entries_.erase(std::remove_if(entries_.begin(), entries_.end(),
                                [](const Entry& entry) { return entry.first.expired() || entry.second.expired(); }),
                 entries_.end());
  for (const Entry& entry : entries_) {
    if (entry.position == position && entry.first.lock() == first && entry.second.lock() == second) {
      return entry.memo;
    }
  }
  entries_.push_back(Entry{first, second, position, std::make_shared<JoinAssociationMemo>()});
  return entries_.back().memo;
}

DCSlam::FoldState DCSlam::fold(FoldState state, const std::vector<FoldInput>& inputs, std::size_t position,
                               FoldAssociations& associations, bool comparing_versions, std::size_t end) const {
  const std::size_t stop = std::min(end, inputs.size());
  for (; position < stop; ++position) {
    const FoldInput& input = inputs[position];
    for (const JoinIds& ids : input.settled) record_ids(ids, state.aliases, state.sightings);
    JoinOptions options = join_options(fold_join_index(position), input.robot_id);
    // The fold's last join decides what no later join can: it commits only to what RJC's rival
    // hypotheses agree on (SlamConfig::join_rival_margin).
    if (position + 1 == inputs.size()) options.rjc.rival_margin = config_.join_rival_margin.value_or(-1);
    auto make = [options = std::move(options), &associations, position](
                    const TreeMap& first, const TreeMap& second, std::shared_ptr<const MapJoin::Pairs> fixed_pairs) {
      JoinOptions join_options = options;
      if (!fixed_pairs) join_options.association_memo = associations.memo(first.map, second.map, position);
      join_options.fixed_pairs = std::move(fixed_pairs);
      return std::make_unique<MapJoin>(first.map, second.map, std::move(join_options));
    };
    const bool last = position + 1 == stop;
    const bool associate_only = last && comparing_versions;
    const std::shared_ptr<const JoinAlternative> previous_alternative = state.joined.alternative;
    state.result.reset();  // the join holds its input as long as it needs it
    auto join = std::make_shared<DecidingJoin>(input.map, std::move(state.joined), std::move(make),
                                               weak_pairings(!last), /*spans_many_maps=*/true);
    // At most the inputs and the result are alive.
    run_fold_join(*join, inputs, position, associate_only, estimate_threads_);
    JoinEvent event;
    event.index = static_cast<int>(position);
    event.step_created = event.step_finished = steps_;
    event.pairing = join->join().pairing_record();
    state.joins.push_back(std::move(event));
    // A weak fold join's record lists the pairs of the version this one took (a real join's
    // record is corrected only when a real join decides).
    if (join->second_version_taken() > 0) {
      const JoinAlternative& alternative = *previous_alternative;
      state.joins[fold_position(alternative.join_index)].pairing.pairs =
          alternative.ids_of(join->second_version_taken()).record_pairs();
    }
    if (associate_only) {
      state.last_join = std::move(join);
      return state;
    }
    take_fold_join(state, *join, inputs, position);
    // A weak fold join of fewer local maps is decided by the next join, as a real one would be
    // weak only from kMinWeakJoinLeaves on.
    if (!state.joined.alternative || state.leaves < kMinWeakJoinLeaves) continue;
    if (!comparing_versions) return decide_by_rest_of_fold(std::move(state), inputs, position + 1, associations);
    // Taken as made while an earlier weak join's versions are compared; decided by the rest of
    // the fold once that one is, from the snapshot (decide_by_rest_of_fold()).
    if (!state.after_first_weak) {
      state.after_first_weak = std::make_shared<const FoldState>(state);
      state.after_first_weak_position = position + 1;
    }
    const std::shared_ptr<const JoinAlternative> alternative = std::move(state.joined.alternative);
    record_ids(alternative->ids_of(0), state.aliases, state.sightings);
  }
  return state;
}

void DCSlam::run_fold_join(DecidingJoin& join, const std::vector<FoldInput>& inputs, std::size_t position,
                           bool associate_only, int threads) {
  try {
    join.associate(threads);
    if (!associate_only) join.finish(threads);
  } catch (const std::exception& error) {
    throw InvalidArgument("DCSlam::estimate: the join of the stack's map " +
                          std::to_string(inputs.size() - 1 - position) + " with the maps after it failed: " +
                          error.what() + "; the filter is unchanged");
  }
}

void DCSlam::take_fold_join(FoldState& state, DecidingJoin& join, const std::vector<FoldInput>& inputs,
                            std::size_t position) const {
  JoinEvent& event = state.joins[position];
  event.report = join.report();
  DecidedJoin decided = join.take_result(
      [](const TreeMap& first, const TreeMap& second, const MapJoin& made) {
        return unmatched_tentative(first.tentative, second.tentative, made);
      },
      fold_join_index(position));
  for (const JoinIds& ids : decided.settled) record_ids(ids, state.aliases, state.sightings);
  state.joined = decided.tree_map();
  state.result = std::move(decided.map);
  state.leaves += inputs[position].leaves;
  event.leaves = static_cast<int>(state.leaves);
}

void DCSlam::make_last_fold_join(FoldState& state, const std::vector<FoldInput>& inputs) const {
  const std::shared_ptr<DecidingJoin> join = std::move(state.last_join);
  const std::size_t position = inputs.size() - 1;
  run_fold_join(*join, inputs, position, /*associate_only=*/false, estimate_threads_);
  take_fold_join(state, *join, inputs, position);
}

DCSlam::FoldState DCSlam::decide_by_rest_of_fold(FoldState state, const std::vector<FoldInput>& inputs,
                                                 std::size_t position, FoldAssociations& associations) const {
  // Why not the next join alone: its pairs can favour a version whose wrong pairs make the
  // join after it fail (loop_both_ways seed 2: two wrong pairs of fourteen, both with clutter
  // seen once, and the last fold join then finds 88 of its 189 true pairs as candidates).
  const std::shared_ptr<const JoinAlternative> alternative = std::move(state.joined.alternative);
  const std::size_t weak = position - 1;  // the weak join's record
  const auto start_of = [&](int version) {
    FoldState start = state;
    if (version > 0) {
      const JoinAlternative::Version& taken = alternative->versions[static_cast<std::size_t>(version - 1)];
      start.joined = TreeMap{taken.map, taken.tentative, nullptr};
      start.joins[weak].pairing.pairs = alternative->ids_of(version).record_pairs();
    }
    record_ids(alternative->ids_of(version), start.aliases, start.sightings);
    return start;
  };
  // A version that does not let the next fold join make more pairs of its own than the join as
  // made does not change what that join can pair, so the rest of the fold would only count the
  // pairs it left out: it is not carried through (the rest of the fold is most of estimate()'s
  // work on a loop closed in the fold). The next join's association is kept for the fold after.
  // The versions are carried through side by side (estimate_threads), each fold on its own
  // maps; a batch of as many as there are threads at a time, so that no more folds' maps are
  // alive at once than run at once (one and the best so far with a single thread).
  std::vector<int> compared{0};
  const int versions = static_cast<int>(alternative->versions.size());
  if (position + 1 < inputs.size()) {
    std::vector<std::size_t> next_pairs(static_cast<std::size_t>(versions + 1));
    run_for_each(next_pairs.size(), estimate_threads_, [&](std::size_t version) {
      const FoldState next = fold(start_of(static_cast<int>(version)), inputs, position, associations,
                                  /*comparing_versions=*/true, position + 1);
      next_pairs[version] = next.joins[position].pairing.pairs.size();
    });
    for (int version = 1; version <= versions; ++version) {
      if (next_pairs[static_cast<std::size_t>(version)] > next_pairs[0]) compared.push_back(version);
    }
    if (compared.size() == 1) return fold(start_of(0), inputs, position, associations);
  } else {
    for (int version = 1; version <= versions; ++version) compared.push_back(version);
  }
  FoldState best;
  std::size_t best_pairs = 0;
  const auto batch_size = static_cast<std::size_t>(estimate_threads_);
  for (std::size_t begin = 0; begin < compared.size(); begin += batch_size) {
    const std::size_t end = std::min(compared.size(), begin + batch_size);
    std::vector<FoldState> rests(end - begin);
    run_for_each(rests.size(), estimate_threads_, [&](std::size_t k) {
      rests[k] = fold(start_of(compared[begin + k]), inputs, position, associations, /*comparing_versions=*/true);
    });
    for (std::size_t k = begin; k < end; ++k) {
      FoldState& rest = rests[k - begin];
      std::size_t pairs = 0;
      for (std::size_t j = weak; j < rest.joins.size(); ++j) pairs += rest.joins[j].pairing.pairs.size();
      if (k == 0 || pairs > best_pairs) {
        best = std::move(rest);
        best_pairs = pairs;
      }
    }
  }
  if (!best.after_first_weak) {
    make_last_fold_join(best, inputs);
    return best;
  }
  // The fold from the best version would make best's joins again up to its first later weak
  // join, and decide that one by the rest from the same state.
  FoldState from = *best.after_first_weak;
  const std::size_t next = best.after_first_weak_position;
  best = FoldState{};
  return decide_by_rest_of_fold(std::move(from), inputs, next, associations);
}

std::vector<std::pair<std::int64_t, std::int64_t>> DCSlam::merge_duplicates(
    GaussianMap& map, IdAliases& aliases, SightingsById& sightings,
    const std::function<std::int64_t(std::int64_t)>& as_named, const std::vector<TentativeFeature>& left_out) const {
  if (!(config_.merge_radius > 0.0) || config_.association == Association::Known) return {};
  const auto& ids = map.ids();
  std::unordered_set<std::int64_t> tentative;
  for (const TentativeFeature& feature : left_out) tentative.insert(feature.id);
  const auto listed = [&](std::int64_t id, std::int64_t other) -> std::int64_t {
    const auto found = sightings.find(id);
    if (found == sightings.end()) return 0;
    const std::vector<std::int64_t>& seen_with = found->second.seen_with;
    return std::count_if(seen_with.begin(), seen_with.end(),
                         [&](std::int64_t seen) { return as_named(seen) == other; });
  };
  const auto scans = [&](std::int64_t id) -> std::int64_t {
    const auto found = sightings.find(id);
    return found == sightings.end() ? 0 : found->second.scans;
  };
  // Two features paired in one scan are two landmarks, unless one of the scan's pairings was
  // wrong (a clutter point or a neighbour): a few shared scans are allowed when each feature
  // was also seen without the other. Two distinct landmarks close enough to pass the test are
  // seen together whenever both are seen, so the less seen one has no scan of its own.
  const std::int64_t shared_allowed = config_.final_merge_shared_scans;
  const auto may_be_one = [&](Eigen::Index a, Eigen::Index b) {
    const std::int64_t id_a = ids[static_cast<std::size_t>(a)], id_b = ids[static_cast<std::size_t>(b)];
    // A feature seen once may still be confirmed (or dropped) by a later join.
    if (tentative.count(id_a) > 0 || tentative.count(id_b) > 0) return false;
    const std::int64_t shared = listed(id_a, id_b) + listed(id_b, id_a);
    return shared == 0 || (shared <= shared_allowed && scans(id_a) > shared && scans(id_b) > shared);
  };
  // Each feature of a local map carries the error a join models (join_feature_sigma), two of
  // one local map as much as two of different ones: the local EKF's own merge, which has no
  // such term, may have declined a pair this test accepts.
  const double gate = chi2_quantile(2, config_.final_merge_confidence.value_or(config_.gate_confidence));
  // Each merge recorded as it is made: a merged feature's scans and seen-with list go to the one
  // it is kept as, which the next round's partners are tested against (two sightings of one
  // scan would otherwise meet in one feature unnoticed).
  return merge_duplicate_features(map, config_.merge_radius, gate, config_.join_feature_sigma, may_be_one,
                                  [&](std::int64_t from, std::int64_t to) {
                                    add_alias(aliases, from, to);
                                    merge_sightings(sightings, from, to);
                                  });
}

// estimate() and pose() report a failure the worker found, as every call does, and rolling
// back is part of reporting it: a DCSlam is never const in itself (only the filter interface's
// const calls see it so), so the cast changes nothing that was meant to stay.
Estimate DCSlam::estimate() const {
  const_cast<DCSlam*>(this)->raise_join_failure_if_any();
  std::vector<std::shared_ptr<FrozenNode>> stack;
  SightingsById sightings;
  IdAliases merged;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& node : stack_) stack.push_back(freeze(node));
    sightings = sightings_;
    merged = merged_into_;
  }
  FoldState state;
  state.result = std::make_shared<GaussianMap>(*compact_copy(local_->map()));
  state.joined.map = state.result;
  // The open local map's features seen once, for the fold's weak joins.
  for (const auto& track : local_->tentative_features()) {
    state.joined.tentative.push_back(TentativeFeature{track.id, closed_local_maps_, false, false});
  }
  record_sightings(*local_, sightings);
  state.sightings = std::move(sightings);
  // Join everything on the stack, top first, as Algorithm 2 does at the end of the run.
  // Tentative features all stay, as in the EKF's estimate: the maps after them may not have
  // had their chance to confirm them yet (and resolve() still points at them). A weak join of
  // the fold is decided by the rest of the fold; the last one's result is final.
  std::vector<FoldInput> inputs;
  SettledIds settled_ids{merged, state.sightings};
  std::vector<JoinEvent> side_joins;
  for (auto it = stack.rbegin(); it != stack.rend(); ++it) {
    FoldInput input;
    input.map = materialize(**it, input.settled, settled_ids, side_joins);
    input.robot_id = (*it)->node->robot_id;
    input.leaves = (*it)->node->leaves;
    inputs.push_back(std::move(input));
  }
  FoldAssociations associations;
  state = fold(std::move(state), inputs, 0, associations);
  inputs.clear();
  IdAliases& aliases = state.aliases;
  std::shared_ptr<GaussianMap> joined = std::move(state.result);
  state.joined = TreeMap();
  // The duplicates the joins left, pairs no join could decide (docs/data_association.md). A
  // listed id as the map names it: the open local map's own merges are not in `merged` yet.
  merge_duplicates(
      *joined, aliases, state.sightings,
      [&](std::int64_t id) {
        return follow_aliases(aliases, follow_aliases(merged, follow_aliases(local_->merged_ids(), id)));
      },
      {});
  if (config_.tree_relinearisation > 0 && !stack.empty()) {
    // The same pairs, every join redone from the local maps and re-linearised (join_tree.hpp).
    std::vector<TreeSpan> spans;
    for (const auto& frozen : stack) spans.push_back(TreeSpan{frozen->node->first_leaf, frozen->node->leaves});
    const auto final_id = [&](std::int64_t id) { return follow_aliases(aliases, follow_aliases(merged, id)); };
    RelinearisationReport report;
    const LeafLog open_log = seal_leaf_log(open_log_, local_->map(), local_->merged_ids());
    GaussianMap root = tree_.relinearise(spans, *compact_copy(local_->map()), open_log, final_id, *joined,
                                         join_options(0, 0), LeafModel{config_.observation, config_.sensor_offset},
                                         config_.tree_relinearisation, kRelinearisationTolerance,
                                         config_.tree_relinearisation_tolerance, estimate_threads_, &report);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      relinearisation_ = report;
    }
    joined = std::make_shared<GaussianMap>(config_.keep_local_map_poses ? std::move(root) : without_past_poses(root));
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    estimate_aliases_ = std::move(aliases);
    fold_joins_ = std::move(state.joins);
    std::sort(side_joins.begin(), side_joins.end(),
              [](const JoinEvent& a, const JoinEvent& b) { return a.index < b.index; });
    side_joins_ = std::move(side_joins);
  }
  // Means and ids first: release_covariance() moves P out without a copy and empties the map.
  Estimate estimate = to_estimate(*joined, Eigen::MatrixXd());
  estimate.covariance = joined->release_covariance();
  return estimate;
}

// RJC's tries for a localisation (a join's: RjcOptions::max_tries, 100). A closed local map
// is small: at 100, one on Victoria Park (s = 10 m) took 3 ms, over 4x D&C's worst step
// without it; at 20, 1 ms, with the same online poses (docs/divide_and_conquer.md, "The online
// pose on places seen again").
namespace {
constexpr int kLocalisationMaxTries = 20;
}  // namespace

// The oldest complete map is the leftmost leaf of the stack's tree of pending joins; the
// chain between it and `closed` is every complete map after it, in order, as pose() composes
// them. Each map's robot is independent of the others', as their data are.
std::optional<LocalisationInputs> DCSlam::localisation_inputs(const Node& closed) const {
  std::vector<std::shared_ptr<const GaussianMap>> chain;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const std::function<void(const Node&)> collect = [&](const Node& node) {
      if (node.map) {
        chain.push_back(node.map);
        return;
      }
      collect(*node.task->left);
      collect(*node.task->right);
    };
    for (const auto& node : stack_) collect(*node);
  }
  if (chain.empty()) return std::nullopt;
  LocalisationInputs inputs;
  inputs.oldest = chain.front();
  for (std::size_t k = 1; k < chain.size(); ++k) {
    inputs.between.push_back(PoseLink{chain[k]->robot(), chain[k]->P().topLeftCorner<3, 3>()});
  }
  inputs.newest = closed.map;
  const std::vector<std::int64_t>& ids = closed.map->ids();
  for (const TentativeFeature& feature : closed.tentative) {
    const auto at = std::find(ids.begin(), ids.end(), feature.id);
    if (at != ids.end()) inputs.left_out.push_back(at - ids.begin());
  }
  inputs.max_sigma = *config_.online_localisation_sigma;
  // A stream of its own, apart from every join's (join_options()).
  inputs.options =
      localisation_options(config_.seed ^ (0xD1B54A32D192ED03ULL * static_cast<std::uint64_t>(closed_local_maps_)));
  return inputs;
}

JoinOptions DCSlam::localisation_options(std::uint64_t seed) const {
  JoinOptions options = join_options_of(config_);
  options.rjc.seed = seed;
  options.rjc.max_tries = kLocalisationMaxTries;
  return options;
}

void DCSlam::begin_localisation(const Node& closed, std::int64_t closed_steps) {
  if (localisation_) {
    localisation_->finish();
    take_localisation();
  }
  const std::optional<Vec3> carried =
      localised_base_ ? std::optional<Vec3>(compose(*localised_base_, closed.map->robot())) : std::nullopt;
  std::optional<LocalisationInputs> inputs = localisation_inputs(closed);
  if (!inputs) {
    localised_base_.reset();
    return;
  }
  localisation_ = std::make_unique<MapLocalisation>(std::move(*inputs));
  localisation_budgets_.clear();
  if (joins_immediate()) {
    localisation_->finish();
    take_localisation();
    return;
  }
  localised_base_ = carried;
  localisation_deadline_ = steps_ + std::max<std::int64_t>(1, closed_steps / 2);
}

void DCSlam::advance_localisation() {
  if (!localisation_) return;
  const std::int64_t steps_left = std::max<std::int64_t>(1, localisation_deadline_ - steps_);
  const std::int64_t remaining = localisation_->remaining_work();
  const std::int64_t budget = std::max<std::int64_t>(1, (remaining + steps_left - 1) / steps_left);
  localisation_budgets_.push_back(budget);
  localisation_->advance(budget);
  if (localisation_->done()) take_localisation();
}

void DCSlam::take_localisation() {
  const std::optional<LocalisedPose>& result = localisation_->result();
  localised_base_ = result ? std::optional<Vec3>(result->pose) : std::nullopt;
  online_localisations_ += result ? 1 : 0;
  localisation_.reset();
  localisation_budgets_.clear();
}

std::optional<DCSlam::PendingLocalisation> DCSlam::pending_localisation() const {
  if (!localisation_) return std::nullopt;
  return PendingLocalisation{localisation_->inputs(), localisation_deadline_, localisation_budgets_};
}

void DCSlam::resume_localisation(std::optional<PendingLocalisation> pending) {
  localisation_.reset();
  localisation_budgets_.clear();
  if (!pending) return;
  localisation_ = std::make_unique<MapLocalisation>(std::move(pending->inputs));
  localisation_deadline_ = pending->deadline_step;
  localisation_budgets_ = std::move(pending->budgets);
  for (const std::int64_t budget : localisation_budgets_) localisation_->advance(budget);
}

Vec3 DCSlam::node_robot(const Node& node) const {
  if (node.map) return node.map->robot();
  return compose(node_robot(*node.task->left), node_robot(*node.task->right));
}

Vec3 DCSlam::pose() const {
  const_cast<DCSlam*>(this)->raise_join_failure_if_any();  // see estimate()
  Vec3 pose = Vec3::Zero();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // Once the joins have put the closed map and the oldest one into one map, the chain holds
    // what the localisation knew and more.
    const bool joined_since = stack_.size() == 1 && stack_.front()->map;
    if (localised_base_ && !joined_since) return compose(*localised_base_, local_->map().robot());
    for (const auto& node : stack_) pose = compose(pose, node_robot(*node));
  }
  return compose(pose, local_->map().robot());
}

std::vector<std::int64_t> DCSlam::resolve(const std::vector<std::int64_t>& ids) const {
  std::vector<std::int64_t> resolved_local = local_->resolve(ids);
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::int64_t> resolved;
  resolved.reserve(ids.size());
  for (std::int64_t id : resolved_local) resolved.push_back(resolve_one(id));
  return resolved;
}

std::int64_t DCSlam::resolve_one(std::int64_t id) const {
  // The real joins' merges first; the estimate's joins take the maps they left.
  for (const IdAliases* aliases : std::array<const IdAliases*, 2>{&merged_into_, &estimate_aliases_}) {
    id = follow_aliases(*aliases, id);
  }
  return id;
}

const RunStats& DCSlam::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::int64_t finished = 0;
  for (const JoinEvent& event : events_) finished += event.step_finished >= 0 ? 1 : 0;
  stats_.counters["local_maps_closed"] = static_cast<double>(closed_local_maps_);
  stats_.counters["joins_created"] = static_cast<double>(events_.size());
  stats_.counters["joins_finished"] = static_cast<double>(finished);
  stats_.counters["stack_depth"] = static_cast<double>(stack_.size());
  stats_.counters["online_localisations"] = static_cast<double>(online_localisations_);
  stats_.counters["localisation_under_way"] = localisation_ ? 1.0 : 0.0;
  stats_.counters["estimate_pending_joins"] = static_cast<double>(estimate_pending_joins_);
  stats_.counters["estimate_pending_joins_reused"] = static_cast<double>(estimate_pending_joins_reused_);
  // The real joins' decisions left to the next join (join_alternatives.hpp): weak joins', large
  // joins' doubtful pairs; the final fold's are not counted.
  double weak_joins = 0.0, doubtful_joins = 0.0, alternatives_taken = 0.0;
  for (const JoinEvent& event : events_) {
    if (event.report.deferred_pairings > 0) {
      (event.report.pairings > config_.weak_join_pairings ? doubtful_joins : weak_joins) += 1.0;
    }
    alternatives_taken += event.report.alternatives_taken;
  }
  stats_.counters["weak_joins"] = weak_joins;
  stats_.counters["doubtful_joins"] = doubtful_joins;
  stats_.counters["alternatives_taken"] = alternatives_taken;
  if (config_.tree_relinearisation > 0) {
    stats_.counters["relinearisation_passes"] = relinearisation_.passes;
    stats_.counters["relinearisation_last_step"] = relinearisation_.last_step;
    stats_.counters["relinearisation_first_objective"] = relinearisation_.first_objective;
    stats_.counters["relinearisation_objective"] = relinearisation_.objective;
    stats_.counters["relinearisation_predicted_objective"] = relinearisation_.predicted_objective;
    stats_.counters["relinearisation_halvings"] = relinearisation_.halvings;
  }
  for (const char* name : kLocalCounters) {
    stats_.counters[name] = counter(local_->stats().counters, name) + counter(closed_maps_counters_, name);
  }
  return stats_;
}

std::vector<TreeLeaf> DCSlam::tree_leaves() const {
  if (config_.tree_relinearisation == 0) return {};
  std::vector<TreeLeaf> leaves;
  for (std::int64_t k = 0; k < tree_.num_leaves(); ++k) leaves.push_back(tree_.leaf(k));
  leaves.push_back(TreeLeaf{compact_copy(local_->map()), {}, -1,
                            std::make_shared<const LeafLog>(seal_leaf_log(open_log_, local_->map(), local_->merged_ids()))});
  return leaves;
}

std::vector<JoinEvent> DCSlam::joins() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return events_;
}

std::vector<JoinEvent> DCSlam::fold_joins() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return fold_joins_;
}

std::vector<JoinEvent> DCSlam::side_joins() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return side_joins_;
}

std::vector<std::pair<int, std::int64_t>> DCSlam::stack_shape() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::pair<int, std::int64_t>> shape;
  for (const auto& node : stack_) shape.emplace_back(node->leaves, node->expected_features);
  return shape;
}

}  // namespace dcslam
