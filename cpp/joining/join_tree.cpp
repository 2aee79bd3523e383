#include "dcslam/joining/join_tree.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "dcslam/association/feature_merging.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/joining/parallel_tasks.hpp"

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

// Gauss–Newton steps of the first point's boundaries (BoundaryFit); they usually stop earlier,
// when no boundary moves by more than 1e-12.
constexpr int kBoundarySteps = 10;
// Halvings of a pass's step before the line search gives up (2^-20 of the step).
constexpr int kLineSearchHalvings = 20;

// Two features of one local map that estimate()'s duplicate merge made one landmark carry one
// id once relabelled. The batch problem has one landmark for both; the local map's Gaussian
// conditioned on f_a = f_b (and f_b marginalised) is that local map's part of it.
// `distance_sq` gains each merge's D^2 (what imposing it adds to the least-squares objective).
std::shared_ptr<const GaussianMap> with_repeated_ids_merged(std::shared_ptr<const GaussianMap> map,
                                                            double& distance_sq) {
  std::unordered_map<std::int64_t, Index> first_of;
  std::vector<std::pair<Index, Index>> repeats;
  for (Index k = 0; k < map->num_features(); ++k) {
    const auto [found, inserted] = first_of.emplace(map->ids()[static_cast<std::size_t>(k)], k);
    if (!inserted) repeats.emplace_back(found->second, k);
  }
  if (repeats.empty()) return map;
  auto merged = std::make_shared<GaussianMap>(*map);
  std::vector<Index> dropped;
  for (const auto& [kept, repeat] : repeats) {
    distance_sq += feature_difference_distance_sq(*merged, kept, repeat);
    if (!impose_equal_features(*merged, kept, repeat)) {
      throw std::logic_error("JoinTree::relinearise: two features of one local map merged into " +
                             std::to_string(map->ids()[static_cast<std::size_t>(kept)]) +
                             " have a difference of zero covariance");
    }
    dropped.push_back(repeat);
  }
  merged->remove_features(dropped);
  return merged;
}

// The angle equal to `angle` modulo 2π that is nearest to `reference`: JoinFrame takes the
// difference between a prior heading and the heading it is linearised at.
double nearest_turn(double angle, double reference) { return reference + wrap_angle(angle - reference); }

// x_{from, to}: the pose `to` seen from the pose `from`.
Vec3 between(const Vec3& from, const Vec3& to) { return compose(invert(from), to); }

// The means a pass linearises at (the previous pass's result), by feature and pose id.
class GlobalEstimate {
 public:
  // Without `with_poses`, the map's past poses are left out.
  explicit GlobalEstimate(const GaussianMap& map, bool with_poses = true) : robot_(map.robot()) {
    for (Index k = 0; k < map.num_features(); ++k) features_[map.ids()[static_cast<std::size_t>(k)]] = map.feature(k);
    if (!with_poses) return;
    for (Index q = 0; q < map.num_poses(); ++q) poses_[map.pose_ids()[static_cast<std::size_t>(q)]] = map.pose(q);
  }
  void set_pose(std::int64_t id, const Vec3& pose) { poses_[id] = pose; }
  bool has_pose(std::int64_t id) const { return poses_.count(id) != 0; }
  const Vec3& robot() const { return robot_; }
  // This estimate moved a fraction `alpha` of the way to `to`, element by element (headings
  // along the shorter turn); elements only `to` holds are taken from it.
  GlobalEstimate toward(const GlobalEstimate& to, double alpha) const {
    if (alpha == 1.0) return to;  // the full step: the pass's own means, bit for bit
    GlobalEstimate moved = to;
    moved.robot_ = blend(robot_, to.robot_, alpha);
    for (auto& [id, position] : moved.features_) {
      const auto found = features_.find(id);
      if (found != features_.end()) position = found->second + alpha * (position - found->second);
    }
    for (auto& [id, pose] : moved.poses_) {
      const auto found = poses_.find(id);
      if (found != poses_.end()) pose = blend(found->second, pose, alpha);
    }
    return moved;
  }
  // Writes these means into `map`'s robot, features and past poses (by id; all must be here).
  void set_means(GaussianMap& map) const {
    map.x().head<3>() = robot_;
    for (Index k = 0; k < map.num_features(); ++k) {
      map.x().segment<2>(GaussianMap::feature_offset(k)) = *feature(map.ids()[static_cast<std::size_t>(k)]);
    }
    for (Index q = 0; q < map.num_poses(); ++q) map.x().segment<3>(map.pose_offset(q)) = pose(map.pose_ids()[static_cast<std::size_t>(q)]);
  }
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
  static Vec3 blend(const Vec3& from, const Vec3& to, double alpha) {
    Vec3 step = to - from;
    step.z() = wrap_angle(step.z());
    Vec3 moved = from + alpha * step;
    moved.z() = wrap_angle(moved.z());
    return moved;
  }

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

// The local-map boundaries B_1..B_L that best explain the local maps given the map's features
// and robot held fixed: Gauss–Newton over the boundaries alone. Local map k (the open one
// last) measures [⊖B_k ⊕ B_{k+1}; ⊖B_k ⊕ F_i] (B_0 the origin; the open map's robot the
// map's), so the normal equations are block-tridiagonal in the boundaries and each step is
// O(L) (block Thomas elimination) after O(p^3) per local map for its information matrix. At
// the optimum of the whole problem this gives the optimum's own boundaries, so a pass
// linearised there stays there (the linear case stays exact, a two-map tree at its join).
class BoundaryFit {
 public:
  // Each local map's information matrix on up to `threads` threads.
  BoundaryFit(const std::vector<const GaussianMap*>& maps, const GlobalEstimate& point, int threads)
      : information_(maps.size()), means_(maps.size()), features_(maps.size()) {
    run_for_each(maps.size(), threads, [&](std::size_t k) { add_map(k, *maps[k], point); });
  }

  // Up to `steps` Gauss–Newton steps from `boundaries` (B_1..B_L), the open map's robot fixed.
  void solve(std::vector<Vec3>& boundaries, const Vec3& robot, int steps) const {
    const std::size_t L = boundaries.size();
    for (int step = 0; step < steps; ++step) {
      std::vector<Mat3> diagonal(L, Mat3::Zero()), upper(L, Mat3::Zero());
      std::vector<Vec3> gradient(L, Vec3::Zero());
      for (std::size_t k = 0; k <= L; ++k) {
        const Vec3 base = k == 0 ? Vec3::Zero() : boundaries[k - 1];
        const Vec3 end = k == L ? robot : boundaries[k];
        const Eigen::VectorXd& z = means_[k];
        const auto n = z.size();
        Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, 6);  // d h / d [B_k, B_{k+1}]
        Eigen::VectorXd error(n);
        Mat3 J_inverse, J_first, J_second;
        const Vec3 inverse = invert(base, &J_inverse);
        const Vec3 between = compose(inverse, end, &J_first, &J_second);
        error.head<3>() = z.head<3>() - between;
        error(2) = wrap_angle(error(2));
        J.block<3, 3>(0, 0) = J_first * J_inverse;
        J.block<3, 3>(0, 3) = J_second;
        for (std::size_t i = 0; i < features_[k].size(); ++i) {
          Mat23 J_base;
          const Index row = 3 + 2 * static_cast<Index>(i);
          error.segment<2>(row) = z.segment<2>(row) - inverse_transform_point(base, features_[k][i], &J_base);
          J.block<2, 3>(row, 0) = J_base;
        }
        const Eigen::MatrixXd weighted = information_[k] * J;  // Λ J
        const Eigen::Matrix<double, 6, 6> normal = J.transpose() * weighted;
        const Eigen::Matrix<double, 6, 1> rhs = weighted.transpose() * error;
        if (k > 0) {
          diagonal[k - 1] += normal.block<3, 3>(0, 0);
          gradient[k - 1] += rhs.head<3>();
        }
        if (k < L) {
          diagonal[k] += normal.block<3, 3>(3, 3);
          gradient[k] += rhs.tail<3>();
          if (k > 0) upper[k - 1] += normal.block<3, 3>(0, 3);
        }
      }
      // Block Thomas: eliminate forwards, substitute backwards.
      for (std::size_t j = 1; j < L; ++j) {
        const Mat3 factor = upper[j - 1].transpose() * diagonal[j - 1].inverse();
        diagonal[j] -= factor * upper[j - 1];
        gradient[j] -= factor * gradient[j - 1];
      }
      std::vector<Vec3> delta(L);
      double largest = 0.0;
      for (std::size_t j = L; j-- > 0;) {
        const Vec3 rhs = j + 1 < L ? Vec3(gradient[j] - upper[j] * delta[j + 1]) : gradient[j];
        delta[j] = diagonal[j].inverse() * rhs;
        largest = std::max(largest, delta[j].cwiseAbs().maxCoeff());
      }
      for (std::size_t j = 0; j < L; ++j) boundaries[j] += delta[j];
      if (!(largest > 1e-12)) break;
    }
  }

 private:
  // Local map k's rows measured: the robot (the open map's too) and the features the map
  // holds; the others (tentative features dropped later) are marginalised out of the local map.
  void add_map(std::size_t k, const GaussianMap& map, const GlobalEstimate& point) {
    std::vector<Index> rows = {0, 1, 2};
    std::vector<Vec2> features;
    for (Index j = 0; j < map.num_features(); ++j) {
      const Vec2* global = point.feature(map.ids()[static_cast<std::size_t>(j)]);
      if (global == nullptr) continue;
      rows.push_back(GaussianMap::feature_offset(j));
      rows.push_back(GaussianMap::feature_offset(j) + 1);
      features.push_back(*global);
    }
    const auto n = static_cast<Index>(rows.size());
    Eigen::MatrixXd covariance(n, n);
    Eigen::VectorXd mean(n);
    for (Index a = 0; a < n; ++a) {
      mean(a) = map.x()(rows[static_cast<std::size_t>(a)]);
      for (Index b = 0; b < n; ++b) covariance(a, b) = map.P()(rows[static_cast<std::size_t>(a)], rows[static_cast<std::size_t>(b)]);
    }
    // A zero variance (a known heading, a map just opened) is a constraint: a tiny floor
    // keeps the information finite and weights it as one.
    const double floor = 1e-12 * std::max(1.0, covariance.diagonal().cwiseAbs().maxCoeff());
    covariance.diagonal().array() += floor;
    information_[k] = covariance.ldlt().solve(Eigen::MatrixXd::Identity(n, n));
    means_[k] = std::move(mean);
    features_[k] = std::move(features);
  }

  std::vector<Eigen::MatrixXd> information_;
  std::vector<Eigen::VectorXd> means_;
  std::vector<std::vector<Vec2>> features_;
};

struct BuiltNode {
  std::shared_ptr<const GaussianMap> map;
  std::vector<TentativeFeature> tentative;
  // In a pass: the minimum of the node's linearised least-squares problem, summed over its
  // leaves' filters and its joins' constraints (the prediction-error decomposition).
  double distance_sq = 0.0;
};

// The leaves (the open local map last) at a global estimate: their intermediate poses fitted
// (kept from one fit to the next as its start) and the batch objective, and the leaves rebuilt
// from their logs (leaf_relinearisation.hpp).
class LeafRebuilder {
 public:
  // `maps`: the leaves' maps, ids relabelled to the final ids; `logs`: theirs, sealed;
  // `robot_ids`: the pose id of each closed leaf's robot.
  LeafRebuilder(std::vector<const GaussianMap*> maps, std::vector<const LeafLog*> logs,
                std::vector<std::int64_t> robot_ids, const LeafModel& model)
      : maps_(std::move(maps)), logs_(std::move(logs)), robot_ids_(std::move(robot_ids)), model_(model),
        poses_(maps_.size()) {
    for (const LeafLog* log : logs_) weights_.push_back(leaf_weights(*log));
  }

  // Fits every leaf's intermediate poses at `point`, the leaves side by side on up to `threads`
  // threads; returns the batch objective there, summed in the leaves' order whatever the threads.
  double fit(const GlobalEstimate& point, int threads) {
    std::vector<double> objectives(maps_.size());
    run_for_each(maps_.size(), threads, [&](std::size_t k) {
      objectives[k] = fit_leaf_poses(*logs_[k], weights_[k], leaf_point(k, point), model_, poses_[k]);
    });
    double total = 0.0;
    for (const double objective : objectives) total += objective;
    return total;
  }

  // Every leaf rebuilt at `point`, with the poses of the last fit() (at `point`), and the sum
  // of its filter's normalised innovations squared (rebuild_leaf()).
  std::vector<std::pair<std::shared_ptr<const GaussianMap>, double>> rebuild(const GlobalEstimate& point,
                                                                             int threads) const {
    std::vector<std::pair<std::shared_ptr<const GaussianMap>, double>> rebuilt(maps_.size());
    run_for_each(maps_.size(), threads, [&](std::size_t k) {
      rebuilt[k].first = std::make_shared<const GaussianMap>(
          rebuild_leaf(*maps_[k], *logs_[k], leaf_point(k, point), poses_[k], model_, &rebuilt[k].second));
    });
    return rebuilt;
  }

 private:
  // Leaf k's end pose and features where `point` puts them, in its base frame.
  LeafPoint leaf_point(std::size_t k, const GlobalEstimate& point) const {
    const Vec3 base = k == 0 ? Vec3::Zero() : point.pose(robot_ids_[k - 1]);
    LeafPoint leaf;
    leaf.end = between(base, k == robot_ids_.size() ? point.robot() : point.pose(robot_ids_[k]));
    const GaussianMap& map = *maps_[k];
    leaf.features.resize(static_cast<std::size_t>(map.num_features()));
    for (Index j = 0; j < map.num_features(); ++j) {
      const Vec2* global = point.feature(map.ids()[static_cast<std::size_t>(j)]);
      if (global != nullptr) leaf.features[static_cast<std::size_t>(j)] = inverse_transform_point(base, *global);
    }
    return leaf;
  }

  std::vector<const GaussianMap*> maps_;
  std::vector<const LeafLog*> logs_;
  std::vector<LeafWeights> weights_;
  std::vector<std::int64_t> robot_ids_;
  LeafModel model_;
  std::vector<std::vector<Vec3>> poses_;
};


// One pass over the tree: every join redone from the leaves, ⊕ linearised at `point`.
class TreePass {
 public:
  // The joins of disjoint subtrees are independent: they run side by side on up to `threads`
  // threads (estimate_threads), each on its own maps, with the same results on any number.
  TreePass(const JoinTree& tree, const std::vector<BuiltNode>& leaves, BuiltNode current,
           const JoinOptions& options, const GlobalEstimate& point, int threads)
      : tree_(tree), leaves_(leaves), current_(std::move(current)), options_(options), point_(point),
        threads_(threads) {}

  // DCSlam::estimate()'s fold: each node of the stack, top first, joined with everything after
  // it. The stack's nodes are built first, side by side; then the fold's joins, in order.
  // `distance_sq`: the minimum of the whole linearised problem (BuiltNode::distance_sq).
  GaussianMap fold(const std::vector<TreeSpan>& stack, double& distance_sq) const {
    distance_sq = current_.distance_sq;
    if (stack.empty()) return *current_.map;
    std::vector<BuiltNode> built(stack.size());
    run_for_each(stack.size(), threads_, [&](std::size_t k) { built[k] = build(stack[k]); });
    std::shared_ptr<const GaussianMap> joined = current_.map;
    for (std::size_t k = stack.size() - 1;; --k) {
      const std::shared_ptr<const GaussianMap> first = std::move(built[k].map);
      MapJoin join(first, joined, options_for(stack[k], tree_.num_leaves(), *first, *joined));
      join.finish(threads_);
      distance_sq += built[k].distance_sq + join.report().constraint_distance_sq;
      GaussianMap result = join.take_result();
      if (k == 0) return result;
      joined = std::make_shared<const GaussianMap>(std::move(result));
    }
  }

 private:
  BuiltNode build(const TreeSpan& node) const {
    if (node.leaves == 1) return leaves_[static_cast<std::size_t>(node.first_leaf)];
    const std::int64_t left_count = tree_.left_leaves(node);
    const TreeSpan left{node.first_leaf, left_count};
    const TreeSpan right{node.first_leaf + left_count, node.leaves - left_count};
    BuiltNode first, second;
    run_tasks({[&] { first = build(left); }, [&] { second = build(right); }}, threads_);
    MapJoin join(first.map, second.map, options_for(left, right.last_leaf(), *first.map, *second.map),
                 last_chance(*first.map, first.tentative, node.first_leaf, node.last_leaf()),
                 last_chance(*second.map, second.tentative, node.first_leaf, node.last_leaf()));
    join.finish(threads_);
    BuiltNode built;
    built.distance_sq = first.distance_sq + second.distance_sq + join.report().constraint_distance_sq;
    built.map = std::make_shared<const GaussianMap>(join.take_result());
    built.tentative = joined_tentative(first.tentative, second.tentative, join, node.first_leaf, node.last_leaf());
    return built;
  }

  // Pose of the base of the node starting at `first_leaf`, and of the robot of the node ending
  // at `last_leaf` (num_leaves(): the open local map), in the global frame.
  Vec3 base_pose(std::int64_t first_leaf) const {
    return first_leaf == 0 ? Vec3::Zero() : point_.pose(tree_.leaf(first_leaf - 1).robot_id);
  }
  Vec3 robot_pose(std::int64_t last_leaf) const {
    return last_leaf == tree_.num_leaves() ? point_.robot() : point_.pose(tree_.leaf(last_leaf).robot_id);
  }

  // The join of node `left` (map `first`) with the map `second` of the leaves after it up to
  // `second_last_leaf`: pairs by id, R1 kept, ⊕ linearised at the global point.
  JoinOptions options_for(const TreeSpan& left, std::int64_t second_last_leaf, const GaussianMap& first,
                          const GaussianMap& second) const {
    JoinOptions options = options_;
    options.association = JoinAssociation::Known;
    options.oracle = nullptr;
    options.keep_first_robot = true;
    options.first_robot_id = tree_.leaf(left.last_leaf()).robot_id;
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
      const Vec2* global = point_.feature(second.ids()[static_cast<std::size_t>(j)]);
      if (global != nullptr) x.segment<2>(GaussianMap::feature_offset(j)) = inverse_transform_point(first_robot, *global);
    }
    for (Index q = 0; q < second.num_poses(); ++q) {
      set_pose(second.pose_offset(q), point_.pose(second.pose_ids()[static_cast<std::size_t>(q)]));
    }
    options.linearisation = std::move(linearisation);
    return options;
  }

  const JoinTree& tree_;
  const std::vector<BuiltNode>& leaves_;
  BuiltNode current_;
  JoinOptions options_;
  const GlobalEstimate& point_;
  int threads_;
};

}  // namespace

GaussianMap JoinTree::relinearise(const std::vector<TreeSpan>& stack, const GaussianMap& current,
                                  const LeafLog& open_log, const std::function<std::int64_t(std::int64_t)>& final_id,
                                  const GaussianMap& start, const JoinOptions& options, const LeafModel& model,
                                  int max_passes, double tolerance, double objective_tolerance, int threads,
                                  RelinearisationReport* report) const {
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

  // The first point: the map as the tree made it, with the local-map boundaries that best
  // explain the local maps given that map (BoundaryFit), started from each local map's rigid
  // fit to the map (or, with fewer than two mapped features, the previous boundary moved by
  // the previous local map's robot). Computed also where the map holds the boundaries
  // (keep_local_map_poses), so that asking for them does not move the map.
  GlobalEstimate point(start, false);
  std::vector<const GaussianMap*> maps;
  for (const BuiltNode& leaf : leaves) maps.push_back(leaf.map.get());
  maps.push_back(open_map.get());
  std::vector<std::int64_t> boundary_ids;
  std::vector<Vec3> boundaries;
  Vec3 boundary = Vec3::Zero();
  for (std::int64_t k = 1; k <= num_leaves(); ++k) {
    Vec3 fitted;
    const Vec3 moved = compose(boundary, maps[static_cast<std::size_t>(k - 1)]->robot());
    boundary = fit_base(*maps[static_cast<std::size_t>(k)], point, fitted) ? fitted : moved;
    boundaries.push_back(boundary);
    boundary_ids.push_back(leaf(k - 1).robot_id);
  }
  BoundaryFit(maps, point, threads).solve(boundaries, start.robot(), kBoundarySteps);
  // A heading no noise has touched (zero variance in every local map so far: odometry with a
  // known heading) is known exactly, and the covariance the pass computes depends on it to
  // first order: it is set exactly rather than fitted (to ~1e-10 rad under the fit's floor).
  double heading = 0.0;
  for (std::size_t j = 0; j < boundaries.size() && maps[j]->P()(2, 2) == 0.0; ++j) {
    heading += maps[j]->robot().z();
    boundaries[j].z() = nearest_turn(heading, boundaries[j].z());
  }
  for (std::size_t j = 0; j < boundaries.size(); ++j) point.set_pose(boundary_ids[j], boundaries[j]);

  std::vector<const LeafLog*> logs;
  std::vector<std::int64_t> robot_ids;
  for (const TreeLeaf& kept : leaves_) {
    if (!kept.log) throw std::logic_error("JoinTree::relinearise: a local map kept without its log");
    logs.push_back(kept.log.get());
    robot_ids.push_back(kept.robot_id);
  }
  logs.push_back(&open_log);
  LeafRebuilder rebuilder(maps, std::move(logs), std::move(robot_ids), model);

  RelinearisationReport done;
  double objective = rebuilder.fit(point, threads);
  done.first_objective = objective;
  GaussianMap result;
  for (int pass = 0; pass < max_passes; ++pass) {
    const auto rebuilt = rebuilder.rebuild(point, threads);
    std::vector<BuiltNode> pass_leaves;
    pass_leaves.reserve(rebuilt.size());
    for (std::size_t k = 0; k < rebuilt.size(); ++k) {
      BuiltNode& leaf = pass_leaves.emplace_back();
      leaf.distance_sq = rebuilt[k].second;
      leaf.map = with_repeated_ids_merged(rebuilt[k].first, leaf.distance_sq);
      if (k < leaves.size()) leaf.tentative = leaves[k].tentative;
    }
    BuiltNode open_leaf = std::move(pass_leaves.back());
    pass_leaves.pop_back();
    double predicted = 0.0;
    GaussianMap next = TreePass(*this, pass_leaves, std::move(open_leaf), options, point, threads).fold(stack, predicted);
    done.predicted_objective = predicted;
    // The line search: the Gauss–Newton step is taken whole where it lowers the batch
    // objective (always, near the optimum), else halved until it does. Each try refits the
    // intermediate poses, O(steps + measurements), next to the pass's O(n^2) joins.
    const GlobalEstimate proposed(next);
    bool lowered = false;
    double alpha = 1.0;
    for (int halving = 0; halving <= kLineSearchHalvings && !lowered; ++halving) {
      GlobalEstimate candidate = point.toward(proposed, alpha);
      const double value = rebuilder.fit(candidate, threads);
      if (value <= objective * (1.0 + 1e-12)) {
        lowered = true;
        objective = value;
        point = std::move(candidate);
      } else {
        ++done.halvings;
        alpha *= 0.5;
      }
    }
    // No fraction of the step lowers the objective: the point is its minimum to rounding,
    // and the result keeps its means.
    if (!lowered) point = point.toward(proposed, 0.0);
    point.set_means(next);
    done.last_step = largest_change(pass == 0 ? start : result, next);
    ++done.passes;
    result = std::move(next);
    // Taken whole, the step's departure from its linearised problem estimates what another
    // pass could gain (docs/divide_and_conquer.md, "When the passes stop").
    const bool close_enough = objective_tolerance > 0.0 && lowered && alpha == 1.0 &&
                              std::abs(objective - predicted) <= objective_tolerance;
    if (!lowered || done.last_step <= tolerance || close_enough) break;
  }
  done.objective = objective;
  if (report != nullptr) *report = done;
  return result;
}

}  // namespace dcslam
