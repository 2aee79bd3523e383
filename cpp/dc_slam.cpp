#include "dcslam/dc_slam.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <unordered_set>

namespace dcslam {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// A copy whose storage fits exactly: local maps keep capacity headroom while they grow,
// finished ones do not need it.
std::shared_ptr<const GaussianMap> compact_copy(const GaussianMap& map) {
  auto copy = std::make_shared<GaussianMap>(GaussianMap::uninitialized(map.dim()));
  copy->x() = map.x();
  copy->P() = map.P();
  copy->ids() = map.ids();
  return copy;
}

// Indices in `map` of the features whose ids are in `ids`.
std::vector<Eigen::Index> feature_indices(const GaussianMap& map,
                                          const std::vector<std::int64_t>& ids) {
  const std::unordered_set<std::int64_t> wanted(ids.begin(), ids.end());
  std::vector<Eigen::Index> indices;
  for (std::size_t k = 0; k < map.ids().size(); ++k) {
    if (wanted.count(map.ids()[k]) != 0) indices.push_back(static_cast<Eigen::Index>(k));
  }
  return indices;
}

// The tentative features of a join's result: m2's, except those merged into an m1 feature
// (seen in both maps, so confirmed). m1's tentative features are either confirmed the same
// way or dropped by the join.
std::vector<std::int64_t> joined_tentative_ids(const std::vector<std::int64_t>& second_tentative,
                                               const MapJoin& join) {
  std::unordered_set<std::int64_t> merged;
  for (const auto& [from, to] : join.merged_ids()) merged.insert(from);
  std::vector<std::int64_t> ids;
  for (std::int64_t id : second_tentative) {
    if (merged.count(id) == 0) ids.push_back(id);
  }
  return ids;
}


}  // namespace

DCSlam::DCSlam(const SlamConfig& config) : config_(config) {
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

JoinOptions DCSlam::join_options(int index) const {
  JoinOptions options;
  options.association = config_.join_association;
  options.gate_confidence = config_.gate_confidence;
  options.rjc_b = config_.rjc_b;
  options.rjc_p_good = config_.rjc_p_good;
  options.rjc_p_fail = config_.rjc_p_fail;
  options.max_iterations = config_.join_iterations;
  // One reproducible stream per join, whatever the order in which joins are run.
  options.seed = config_.seed ^ (0x9E3779B97F4A7C15ULL * static_cast<std::uint64_t>(index + 1));
  return options;
}

void DCSlam::begin_step() {
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
  const auto start = Clock::now();
  local_->predict(u, Q);  // validates first: a bad call changes nothing
  begin_step();
  end_step(seconds_since(start));
}

std::vector<std::int64_t> DCSlam::update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                         const std::vector<std::int64_t>* landmark_ids) {
  const auto start = Clock::now();
  std::vector<std::int64_t> ids = local_->update(z, R, landmark_ids);
  if (stats_.steps.empty()) begin_step();  // measurements at the first pose, before any motion
  const StepStats& local_step = local_->stats().steps.back();
  StepStats& step = stats_.steps.back();
  step.measurements += local_step.measurements;
  step.paired += local_step.paired;
  step.new_features += local_step.new_features;
  step.rejected += local_step.rejected;
  if (local_->map().num_features() >= config_.local_map_features) close_local_map();
  if (config_.amortize && !config_.threaded_joins) run_amortized_budget();
  end_step(seconds_since(start));
  return ids;
}

void DCSlam::close_local_map() {
  {
    // Ids of the tentative features the local map removed as expired resolve to -1 from now on.
    std::lock_guard<std::mutex> lock(mutex_);
    for (std::int64_t id : local_->removed_ids()) merged_into_[id] = -1;
  }
  auto node = std::make_shared<Node>();
  node->map = compact_copy(local_->map());
  // Features seen once stay: a landmark first seen in the map's last steps is seen again by
  // the next map, and the join that meets it keeps the feature only if it matches.
  node->tentative_ids = local_->tentative_ids();
  node->expected_features = node->map->num_features();
  const std::int64_t next_id = local_->next_fresh_id();
  local_ = std::make_unique<EkfSlam>(config_);
  local_->set_next_fresh_id(next_id);
  steps_in_closed_maps_ += local_map_steps_;
  local_map_steps_ = 0;
  ++closed_local_maps_;
  push_and_merge(std::move(node));
  if (!config_.amortize && !config_.threaded_joins) {
    for (const auto& task : queue_) work_on(*task, std::numeric_limits<std::int64_t>::max());
    queue_.clear();
  }
}

// The paper's Algorithm 2: while the new map is at least as big as the top of the stack, pop
// and join. Joins are only queued here; who runs them depends on the mode.
void DCSlam::push_and_merge(std::shared_ptr<Node> node) {
  std::unique_lock<std::mutex> lock(mutex_);
  const double steps_per_local_map =
      static_cast<double>(steps_in_closed_maps_) / static_cast<double>(closed_local_maps_);
  while (!stack_.empty() && node->leaves >= stack_.back()->leaves) {
    auto task = std::make_shared<JoinTask>();
    task->index = joins_created_++;
    task->left = stack_.back();
    stack_.pop_back();
    task->right = std::move(node);
    auto result = std::make_shared<Node>();
    task->result = result;
    result->leaves = task->left->leaves + task->right->leaves;
    result->expected_features =
        task->left->expected_features + task->right->expected_features;
    result->task = task;
    // The result is next needed when as many local maps again have been closed; finishing
    // within half that time leaves the other half for the joins that will wait on it.
    task->deadline_step =
        steps_ + std::max<std::int64_t>(1, static_cast<std::int64_t>(
                                               0.5 * result->leaves * steps_per_local_map));
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
  stack_.push_back(std::move(node));
  lock.unlock();
  work_ready_.notify_all();
}

void DCSlam::run_amortized_budget() {
  if (queue_.empty()) return;
  double budget = 0.0;
  for (const auto& task : queue_) {
    // A join not started yet: its fill before association (as MapJoin::remaining_work()).
    const auto dim = static_cast<std::int64_t>(3 + 2 * task->result.lock()->expected_features);
    const std::int64_t remaining =
        task->join ? task->join->remaining_work() : dim * (dim + 1) / 2 + 2 * dim;
    budget += static_cast<double>(remaining) /
              static_cast<double>(std::max<std::int64_t>(1, task->deadline_step - steps_));
  }
  auto left = static_cast<std::int64_t>(std::ceil(budget));
  while (left > 0 && !queue_.empty()) {
    JoinTask& task = *queue_.front();
    left -= work_on(task, left);
    if (task.join && !task.join->done()) break;
    queue_.pop_front();
  }
}

std::int64_t DCSlam::work_on(JoinTask& task, std::int64_t budget) {
  if (!task.join) {
    task.join = std::make_unique<MapJoin>(
        task.left->map, task.right->map, join_options(task.index),
        feature_indices(*task.left->map, task.left->tentative_ids));
  }
  const std::int64_t spent = task.join->advance(budget);
  if (task.join->done()) complete(task);
  return spent;
}

void DCSlam::complete(JoinTask& task) {
  auto map = std::make_shared<const GaussianMap>(task.join->take_result());
  std::vector<std::int64_t> tentative = joined_tentative_ids(task.right->tentative_ids, *task.join);
  std::lock_guard<std::mutex> lock(mutex_);
  JoinEvent& event = events_[static_cast<std::size_t>(task.index)];
  event.report = task.join->report();
  event.step_finished = steps_;
  for (const auto& [from, to] : task.join->merged_ids()) {
    if (from != to) merged_into_[from] = to;
  }
  for (std::int64_t id : task.join->dropped_ids()) merged_into_[id] = -1;
  const std::shared_ptr<Node> result = task.result.lock();
  result->tentative_ids = std::move(tentative);
  result->map = std::move(map);
  result->expected_features = result->map->num_features();
  result->task.reset();
  task.left.reset();
  task.right.reset();
}

void DCSlam::worker_loop() {
  for (;;) {
    std::shared_ptr<JoinTask> task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_ready_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      task = queue_.front();
      worker_busy_ = true;
    }
    work_on(*task, std::numeric_limits<std::int64_t>::max());
    {
      std::lock_guard<std::mutex> lock(mutex_);
      queue_.pop_front();
      worker_busy_ = false;
    }
    work_done_.notify_all();
  }
}

void DCSlam::finish_joins() {
  if (config_.threaded_joins) {
    std::unique_lock<std::mutex> lock(mutex_);
    work_done_.wait(lock, [this] { return queue_.empty() && !worker_busy_; });
    return;
  }
  while (!queue_.empty()) {
    work_on(*queue_.front(), std::numeric_limits<std::int64_t>::max());
    queue_.pop_front();
  }
}

DCSlam::NodeMap DCSlam::materialize(const std::shared_ptr<Node>& node) const {
  std::shared_ptr<Node> left, right;
  int index = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (node->map) return NodeMap{node->map, node->tentative_ids};
    left = node->task->left;
    right = node->task->right;
    index = node->task->index;
  }
  // Same inputs and options as the real join: the same result, computed on the side.
  NodeMap first = materialize(left);
  NodeMap second = materialize(right);
  MapJoin join(first.map, second.map, join_options(index),
               feature_indices(*first.map, first.tentative_ids));
  join.finish();
  return NodeMap{std::make_shared<const GaussianMap>(join.take_result()),
                 joined_tentative_ids(second.tentative_ids, join)};
}

Estimate DCSlam::estimate() const {
  std::vector<std::shared_ptr<Node>> stack;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stack = stack_;
  }
  auto joined = std::make_shared<GaussianMap>(*compact_copy(local_->map()));
  // Join everything on the stack, top first, as Algorithm 2 does at the end of the run.
  // Tentative features all stay, as in the EKF's estimate: the maps after them may not have
  // had their chance to confirm them yet (and resolve() still points at them).
  for (auto it = stack.rbegin(); it != stack.rend(); ++it) {
    const int index = -1 - static_cast<int>(it - stack.rbegin());
    NodeMap first = materialize(*it);
    MapJoin join(first.map, std::move(joined), join_options(index));
    join.finish();  // releases its inputs: at most the inputs and the result are alive
    joined = std::make_shared<GaussianMap>(join.take_result());
  }
  // Means and ids first: release_covariance() moves P out without a copy and empties the map.
  Estimate estimate = to_estimate(*joined, Eigen::MatrixXd());
  estimate.covariance = joined->release_covariance();
  return estimate;
}

Vec3 DCSlam::node_robot(const Node& node) const {
  if (node.map) return node.map->robot();
  return compose(node_robot(*node.task->left), node_robot(*node.task->right));
}

Vec3 DCSlam::pose() const {
  Vec3 pose = Vec3::Zero();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& node : stack_) pose = compose(pose, node_robot(*node));
  }
  return compose(pose, local_->map().robot());
}

std::vector<std::int64_t> DCSlam::resolve(const std::vector<std::int64_t>& ids) const {
  std::vector<std::int64_t> resolved_local = local_->resolve(ids);
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::int64_t> resolved;
  resolved.reserve(ids.size());
  for (std::int64_t id : resolved_local) {
    for (auto it = merged_into_.find(id); it != merged_into_.end(); it = merged_into_.find(id)) {
      id = it->second;
    }
    resolved.push_back(id);
  }
  return resolved;
}

const RunStats& DCSlam::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::int64_t finished = 0;
  for (const JoinEvent& event : events_) finished += event.step_finished >= 0 ? 1 : 0;
  stats_.counters["local_maps_closed"] = static_cast<double>(closed_local_maps_);
  stats_.counters["joins_created"] = static_cast<double>(events_.size());
  stats_.counters["joins_finished"] = static_cast<double>(finished);
  stats_.counters["stack_depth"] = static_cast<double>(stack_.size());
  return stats_;
}

std::vector<JoinEvent> DCSlam::joins() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return events_;
}

std::vector<std::pair<int, std::int64_t>> DCSlam::stack_shape() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::pair<int, std::int64_t>> shape;
  for (const auto& node : stack_) shape.emplace_back(node->leaves, node->expected_features);
  return shape;
}

}  // namespace dcslam
