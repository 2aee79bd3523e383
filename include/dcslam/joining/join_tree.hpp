#pragma once
// D&C's tree of joins, kept so that every join can be redone from the local maps
// (docs/divide_and_conquer.md, "Re-linearised joins").
//
// A join linearises ⊕ where its two inputs put the robot and the second map's elements, and
// each local map's EKF linearised its own odometry and measurements where it stood. A subtree
// mapped without the rest drifts, and a later join can only correct it linearly. Here the
// leaves (each local map as it closed, with the log of what its EKF was built from:
// leaf_relinearisation.hpp) and the tree's shape are kept, and relinearise() redoes every
// join from the leaves at one global estimate: each leaf rebuilt from its own measurements
// linearised there (rebuild_leaf()), each join's ⊕ linearised there. Every join is exact in
// the linear-Gaussian case, so such a pass solves the full SLAM least-squares problem (every
// pose and landmark; the intermediate poses marginalised leaf by leaf) linearised at that
// estimate: one Gauss–Newton step, taken through D&C's own tree so that the result keeps the
// full covariance. A line search on the batch objective damps the step, so no pass raises it;
// repeated passes converge to the batch optimum of the run's own associations.
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/joining/leaf_relinearisation.hpp"
#include "dcslam/joining/map_joining.hpp"
#include "dcslam/joining/tentative_features.hpp"

namespace dcslam {

struct TreeLeaf {
  std::shared_ptr<const GaussianMap> map;  // as it closed: base frame, feature ids
  std::vector<TentativeFeature> tentative;
  std::int64_t robot_id = 0;  // pose id of its robot, the next leaf's base
  // What its EKF was built from, sealed against `map` (seal_leaf_log()).
  std::shared_ptr<const LeafLog> log;
};

// A node of the tree: the leaves first_leaf .. first_leaf + leaves - 1.
struct TreeSpan {
  std::int64_t first_leaf = 0;
  std::int64_t leaves = 1;
  std::int64_t last_leaf() const { return first_leaf + leaves - 1; }
};

struct RelinearisationReport {
  int passes = 0;          // Gauss–Newton passes through the tree
  double last_step = 0.0;  // largest change of a mean in the last pass (m or rad)
  // The batch objective (sum of squared whitened residuals) at the first point and at the end.
  double first_objective = 0.0;
  double objective = 0.0;
  // The last pass's linearised problem at its minimum (the sum of its leaves' normalised
  // innovations squared and its joins' h' S^-1 h): the objective it predicted for its step.
  double predicted_objective = 0.0;
  int halvings = 0;  // step halvings of the line search, over all passes
};

class JoinTree {
 public:
  void add_leaf(TreeLeaf leaf);
  // A join of the adjacent nodes `left` and `right` (right.first_leaf = left's last + 1).
  void add_join(const TreeSpan& left, const TreeSpan& right);
  std::int64_t num_leaves() const { return static_cast<std::int64_t>(leaves_.size()); }
  const TreeLeaf& leaf(std::int64_t k) const { return leaves_[static_cast<std::size_t>(k)]; }
  // Local maps in the left input of the join that made `node`.
  std::int64_t left_leaves(const TreeSpan& node) const;
  // Every join: (first_leaf, leaves) of the node it made -> local maps in its left input.
  const std::map<std::pair<std::int64_t, std::int64_t>, std::int64_t>& joins() const { return left_leaves_; }

  // The map that DCSlam::estimate() folds from the nodes `stack` (bottom first, covering the
  // leaves in order) and `current` (the open local map, based at the last leaf's robot, built
  // from `open_log`, sealed), with every leaf rebuilt and every join redone at the previous
  // pass's result, until no mean moves by more than `tolerance` (m or rad) or `max_passes`
  // (>= 1) passes are done. The first pass linearises at `start`, the map as the tree made it
  // (ids as `final_id` gives them), with each local-map boundary placed where its local map's
  // features fit `start` best (whether `start` holds the boundaries or not).
  //
  // Each pass is a Gauss–Newton step of the batch problem; its means are then taken a
  // fraction 1, 1/2, 1/4, ... of the way from the point it linearised at, the first that does
  // not raise the batch objective (the covariance is the pass's). With `objective_tolerance`
  // > 0, a pass taken whole also ends the passes when its objective differs from the minimum
  // of the problem it linearised (the sum of its leaves' normalised innovations squared and
  // its joins' h' S^-1 h: the prediction-error decomposition) by at most that much: the
  // linearisation's error over the step, which measures what another pass could still gain.
  // The joins pair features by `final_id` (each leaf feature's id once every merge of the run
  // is followed: the joins', the fold's and the duplicate merge's; ids it maps to -1, dropped
  // tentative features, keep their own), so the pairs are those the run decided, each made at
  // the lowest join where its two features meet. `options` gives the constraint update's settings; association,
  // linearisation and the past poses are set here. The result keeps every local-map boundary
  // as a past pose (the linearisation points need them). The leaves' fits and rebuilds and the
  // joins of disjoint subtrees run side by side on up to `threads` threads (>= 1), with the
  // same result on any number.
  GaussianMap relinearise(const std::vector<TreeSpan>& stack, const GaussianMap& current, const LeafLog& open_log,
                          const std::function<std::int64_t(std::int64_t)>& final_id,
                          const GaussianMap& start, const JoinOptions& options, const LeafModel& model,
                          int max_passes, double tolerance, double objective_tolerance, int threads,
                          RelinearisationReport* report = nullptr) const;

 private:
  std::vector<TreeLeaf> leaves_;
  // (first_leaf, leaves) of each joined node -> local maps in its left input.
  std::map<std::pair<std::int64_t, std::int64_t>, std::int64_t> left_leaves_;
};

}  // namespace dcslam
