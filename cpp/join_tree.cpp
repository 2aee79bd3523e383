#include "dcslam/join_tree.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "dcslam/geometry.hpp"

namespace dcslam {

using Index = Eigen::Index;

void JoinTree::add_leaf(TreeLeaf leaf) { leaves_.push_back(std::move(leaf)); }

void JoinTree::add_join(const TreeSpan& left, const TreeSpan& right) {
  left_leaves_[{left.first_leaf, left.leaves + right.leaves}] = left.leaves;
}

std::int64_t JoinTree::left_leaves(const TreeSpan& node) const {
  const auto found = left_leaves_.find({node.first_leaf, node.leaves});
  if (found == left_leaves_.end()) {
    throw std::logic_error("JoinTree: no join made the node of local maps " +
                           std::to_string(node.first_leaf) + ".." + std::to_string(node.last_leaf()));
  }
  return found->second;
}

namespace {

// The angle equal to `angle` modulo 2π that is nearest to `reference`: JoinFrame takes the
// difference between a prior heading and the heading it is linearised at.
double nearest_turn(double angle, double reference) { return reference + wrap_angle(angle - reference); }

// x_{from, to}: the pose `to` seen from the pose `from`.
Vec3 between(const Vec3& from, const Vec3& to) { return compose(invert(from), to); }

// The means a pass linearises at (the previous pass's result), by feature and pose id.
class GlobalEstimate {
 public:
  explicit GlobalEstimate(const GaussianMap& map) : robot_(map.robot()) {
    for (Index k = 0; k < map.num_features(); ++k) features_[map.ids()[static_cast<std::size_t>(k)]] = map.feature(k);
    for (Index q = 0; q < map.num_poses(); ++q) poses_[map.pose_ids()[static_cast<std::size_t>(q)]] = map.pose(q);
  }
  void set_pose(std::int64_t id, const Vec3& pose) { poses_[id] = pose; }
  bool has_pose(std::int64_t id) const { return poses_.count(id) != 0; }
  void set_feature(std::int64_t id, const Vec2& feature) { features_[id] = feature; }
  const Vec3& robot() const { return robot_; }
  const Vec2* feature(std::int64_t id) const {
    const auto found = features_.find(id);
    return found == features_.end() ? nullptr : &found->second;
  }
  Vec3 pose(std::int64_t id) const {
    const auto found = poses_.find(id);
    if (found == poses_.end()) throw std::logic_error("JoinTree: no boundary pose " + std::to_string(id));
    return found->second;
  }

 private:
  Vec3 robot_;
  std::unordered_map<std::int64_t, Vec2> features_;
  std::unordered_map<std::int64_t, Vec3> poses_;
};

// The largest change of a mean between two results of the tree (features and poses by id,
// those both hold).
double largest_change(const GaussianMap& before, const GaussianMap& after) {
  const GlobalEstimate old(before);
  double change = (after.robot().head<2>() - old.robot().head<2>()).cwiseAbs().maxCoeff();
  change = std::max(change, std::abs(wrap_angle(after.robot().z() - old.robot().z())));
  for (Index k = 0; k < after.num_features(); ++k) {
    const Vec2* previous = old.feature(after.ids()[static_cast<std::size_t>(k)]);
    if (previous != nullptr) change = std::max(change, (after.feature(k) - *previous).cwiseAbs().maxCoeff());
  }
  for (Index q = 0; q < after.num_poses(); ++q) {
    const std::int64_t id = after.pose_ids()[static_cast<std::size_t>(q)];
    if (!old.has_pose(id)) continue;  // the tree's own map keeps no boundary unless asked to
    const Vec3 previous = old.pose(id);
    change = std::max(change, (after.pose(q).head<2>() - previous.head<2>()).cwiseAbs().maxCoeff());
    change = std::max(change, std::abs(wrap_angle(after.pose(q).z() - previous.z())));
  }
  return change;
}

// The base pose, in the global frame, that puts the features of `local` (in its own base frame)
// nearest to where `global` has them: the 2D rigid least-squares fit. False with fewer than
// two of them in `global`.
bool fit_base(const GaussianMap& local, const GlobalEstimate& global, Vec3& base) {
  std::vector<std::pair<Vec2, Vec2>> matches;  // (local, global)
  for (Index k = 0; k < local.num_features(); ++k) {
    const Vec2* position = global.feature(local.ids()[static_cast<std::size_t>(k)]);
    if (position != nullptr) matches.emplace_back(local.feature(k), *position);
  }
  if (matches.size() < 2) return false;
  Vec2 local_mean = Vec2::Zero(), global_mean = Vec2::Zero();
  for (const auto& [p, q] : matches) {
    local_mean += p;
    global_mean += q;
  }
  local_mean /= static_cast<double>(matches.size());
  global_mean /= static_cast<double>(matches.size());
  double dot = 0.0, cross = 0.0;
  for (const auto& [p, q] : matches) {
    const Vec2 a = p - local_mean, b = q - global_mean;
    dot += a.dot(b);
    cross += a.x() * b.y() - a.y() * b.x();
  }
  const double heading = std::atan2(cross, dot);
  const double c = std::cos(heading), s = std::sin(heading);
  Mat2 rotation;
  rotation << c, -s, s, c;
  base.head<2>() = global_mean - rotation * local_mean;
  base.z() = heading;
  return true;
}

struct BuiltNode {
  std::shared_ptr<const GaussianMap> map;
  std::vector<TentativeFeature> tentative;
};

// One pass over the tree: every join redone from the leaves, ⊕ linearised at `point`, or,
// without one, where each join's inputs put it, with the join's own Gauss–Newton steps (the
// tree as it ran).
class TreePass {
 public:
  TreePass(const JoinTree& tree, const std::vector<BuiltNode>& leaves,
           std::shared_ptr<const GaussianMap> current, const JoinOptions& options,
           const GlobalEstimate* point)
      : tree_(tree), leaves_(leaves), current_(std::move(current)), options_(options), point_(point) {}

  // DCSlam::estimate()'s fold: each node of the stack, top first, joined with everything after it.
  GaussianMap fold(const std::vector<TreeSpan>& stack) const {
    if (stack.empty()) return *current_;
    std::shared_ptr<const GaussianMap> joined = current_;
    for (auto node = stack.rbegin();; ++node) {
      const BuiltNode first = build(*node);
      MapJoin join(first.map, joined, options_for(*node, tree_.num_leaves(), *first.map, *joined));
      join.finish();
      GaussianMap result = join.take_result();
      if (node + 1 == stack.rend()) return result;
      joined = std::make_shared<const GaussianMap>(std::move(result));
    }
  }

 private:
  BuiltNode build(const TreeSpan& node) const {
    if (node.leaves == 1) return leaves_[static_cast<std::size_t>(node.first_leaf)];
    const std::int64_t left_count = tree_.left_leaves(node);
    const TreeSpan left{node.first_leaf, left_count};
    const TreeSpan right{node.first_leaf + left_count, node.leaves - left_count};
    const BuiltNode first = build(left);
    const BuiltNode second = build(right);
    MapJoin join(first.map, second.map, options_for(left, right.last_leaf(), *first.map, *second.map),
                 last_chance(*first.map, first.tentative, node.first_leaf, node.last_leaf()),
                 last_chance(*second.map, second.tentative, node.first_leaf, node.last_leaf()));
    join.finish();
    BuiltNode built;
    built.map = std::make_shared<const GaussianMap>(join.take_result());
    built.tentative = joined_tentative(first.tentative, second.tentative, join, node.first_leaf, node.last_leaf());
    return built;
  }

  // Pose of the base of the node starting at `first_leaf`, and of the robot of the node ending
  // at `last_leaf` (num_leaves(): the open local map), in the global frame.
  Vec3 base_pose(std::int64_t first_leaf) const {
    return first_leaf == 0 ? Vec3::Zero() : point_->pose(tree_.leaf(first_leaf - 1).robot_id);
  }
  Vec3 robot_pose(std::int64_t last_leaf) const {
    return last_leaf == tree_.num_leaves() ? point_->robot() : point_->pose(tree_.leaf(last_leaf).robot_id);
  }

  // The join of node `left` (map `first`) with the map `second` of the leaves after it up to
  // `second_last_leaf`: pairs by id, R1 kept, ⊕ linearised at the global point if there is one.
  JoinOptions options_for(const TreeSpan& left, std::int64_t second_last_leaf, const GaussianMap& first,
                          const GaussianMap& second) const {
    JoinOptions options = options_;
    options.association = JoinAssociation::Known;
    options.oracle = nullptr;
    options.keep_first_robot = true;
    options.first_robot_id = tree_.leaf(left.last_leaf()).robot_id;
    if (point_ == nullptr) return options;
    // R1 in m1's base, and m2's elements in m2's base (R1), where the global point puts them.
    const Vec3 first_robot = robot_pose(left.last_leaf());
    auto linearisation = std::make_shared<JoinLinearisation>();
    linearisation->first_robot = between(base_pose(left.first_leaf), first_robot);
    linearisation->first_robot.z() = nearest_turn(linearisation->first_robot.z(), first.robot().z());
    Eigen::VectorXd& x = linearisation->second_x;
    x = second.x();
    const auto set_pose = [&](Index offset, const Vec3& global) {
      Vec3 local = between(first_robot, global);
      local.z() = nearest_turn(local.z(), x(offset + 2));
      x.segment<3>(offset) = local;
    };
    set_pose(0, robot_pose(second_last_leaf));
    for (Index j = 0; j < second.num_features(); ++j) {
      // A feature the result does not hold (a tentative one dropped later) stays at its own
      // mean: it is marginalised out unconstrained, so where ⊕ is linearised for it does not
      // change the other elements.
      const Vec2* global = point_->feature(second.ids()[static_cast<std::size_t>(j)]);
      if (global != nullptr) x.segment<2>(GaussianMap::feature_offset(j)) = inverse_transform_point(first_robot, *global);
    }
    for (Index q = 0; q < second.num_poses(); ++q) {
      set_pose(second.pose_offset(q), point_->pose(second.pose_ids()[static_cast<std::size_t>(q)]));
    }
    options.linearisation = std::move(linearisation);
    return options;
  }

  const JoinTree& tree_;
  const std::vector<BuiltNode>& leaves_;
  std::shared_ptr<const GaussianMap> current_;
  JoinOptions options_;
  const GlobalEstimate* point_;
};

}  // namespace

GaussianMap JoinTree::relinearise(const std::vector<TreeSpan>& stack, const GaussianMap& current,
                                  const std::function<std::int64_t(std::int64_t)>& final_id,
                                  const GaussianMap& start, const JoinOptions& options, int max_passes,
                                  double tolerance, RelinearisationReport* report) const {
  if (max_passes < 1) throw std::logic_error("JoinTree::relinearise: max_passes must be >= 1");
  const auto relabel = [&](std::int64_t id) {
    const std::int64_t resolved = final_id(id);
    return resolved < 0 ? id : resolved;
  };
  const auto relabelled = [&](const GaussianMap& map) {
    auto copy = std::make_shared<GaussianMap>(map);
    for (std::int64_t& id : copy->ids()) id = relabel(id);
    return std::shared_ptr<const GaussianMap>(std::move(copy));
  };
  std::vector<BuiltNode> leaves;
  leaves.reserve(leaves_.size());
  for (const TreeLeaf& leaf : leaves_) {
    BuiltNode built{relabelled(*leaf.map), leaf.tentative};
    for (TentativeFeature& feature : built.tentative) feature.id = relabel(feature.id);
    leaves.push_back(std::move(built));
  }
  const std::shared_ptr<const GaussianMap> open_map = relabelled(current);

  // The first point: the map as the tree made it, with each local-map boundary it does not
  // hold fitted to it (or, for a local map with fewer than two mapped features, the previous
  // boundary moved by the previous local map's robot).
  GlobalEstimate point(start);
  Vec3 boundary = Vec3::Zero();
  for (std::int64_t k = 1; k <= num_leaves(); ++k) {
    const std::int64_t id = leaf(k - 1).robot_id;
    if (!point.has_pose(id)) {
      const GaussianMap& next_map = k < num_leaves() ? *leaves[static_cast<std::size_t>(k)].map : *open_map;
      Vec3 fitted;
      point.set_pose(id, fit_base(next_map, point, fitted)
                             ? fitted
                             : compose(boundary, leaves[static_cast<std::size_t>(k - 1)].map->robot()));
    }
    boundary = point.pose(id);
  }
  // Features the map no longer holds (tentative ones dropped at a join) where their local map puts them.
  for (std::int64_t k = 0; k <= num_leaves(); ++k) {
    const GaussianMap& map = k < num_leaves() ? *leaves[static_cast<std::size_t>(k)].map : *open_map;
    const Vec3 base = k == 0 ? Vec3::Zero() : point.pose(leaf(k - 1).robot_id);
    for (Index j = 0; j < map.num_features(); ++j) {
      const std::int64_t id = map.ids()[static_cast<std::size_t>(j)];
      if (point.feature(id) == nullptr) point.set_feature(id, transform_point(base, map.feature(j)));
    }
  }

  RelinearisationReport done;
  GaussianMap result;
  for (int pass = 0; pass < max_passes; ++pass) {
    GaussianMap next = TreePass(*this, leaves, open_map, options, &point).fold(stack);
    done.last_step = largest_change(pass == 0 ? start : result, next);
    ++done.passes;
    result = std::move(next);
    if (done.last_step <= tolerance || pass + 1 == max_passes) break;
    point = GlobalEstimate(result);
  }
  if (report != nullptr) *report = done;
  return result;
}

}  // namespace dcslam
