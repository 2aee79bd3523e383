#pragma once
// D&C's online pose localised against its oldest map (docs/divide_and_conquer.md, "The online
// pose on places seen again"). The online pose composes the robots of the stack's maps, each in
// the frame of the one before, so it learns that the robot is back in a mapped place only when
// the joins reach that place's map: on Victoria Park it ends 9.7 m from the full estimate's
// robot. When a local map closes, its features are paired with the oldest map's (the join
// association, as if the two maps were joined through the chain of maps between them), and
// the local map's end pose is conditioned on those pairs: a robot-only join, O(p^3 + n) for a
// local map of p features against a map of n. The maps stay as they are; only the pose the
// next local map starts from is moved.
#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/resumable_work.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/join_frame.hpp"
#include "dcslam/joining/join_options.hpp"

namespace dcslam {

// A relative pose and its covariance: one map of the chain between the oldest map and the
// newest, its robot in its own base frame.
struct PoseLink {
  Vec3 mean = Vec3::Zero();
  Mat3 covariance = Mat3::Zero();
};

struct LocalisedPose {
  Vec3 pose = Vec3::Zero();  // newest's robot in oldest's base frame
  int pairs = 0;             // the pairs it was conditioned on
};

// One localisation's inputs, all fixed when its local map closes: kept to redo it from the
// start (a restore point, a checkpoint).
struct LocalisationInputs {
  std::shared_ptr<const GaussianMap> oldest;
  std::vector<PoseLink> between;
  std::shared_ptr<const GaussianMap> newest;
  std::vector<Eigen::Index> left_out;
  double max_sigma = 0.0;
  JoinOptions options;
};

// The pose of `newest`'s robot in `oldest`'s base frame, where newest's base sits at oldest's
// robot ⊕ between[0] ⊕ ... ⊕ between[k-1], conditioned on the pairs that the join association
// (`options`; by id in "known" mode) finds between oldest's features and newest's (the features
// listed in `left_out`, such as tentative ones, take no part). The three parts are independent,
// as the maps of a D&C stack are. The chain is linearised at its means (as a join is, once).
// nullopt, the pose left to the chain, when newest's robot moved through the chain has a
// position standard deviation (largest_std) above `max_sigma` [m], where the association
// would be a loop closure at large uncertainty (the joins' work), or when fewer than 5 pairs
// are found.
//
// Resumable (resumable_work.hpp), so that an amortized D&C spreads it over the steps after the
// close as it spreads a join: the first step moves newest through the chain, the association
// advances a slice a step (its own work units), the last step conditions the robot. The result
// is the same however the work is sliced.
class MapLocalisation : public ResumableWork<MapLocalisation> {
 public:
  explicit MapLocalisation(LocalisationInputs inputs);
  MapLocalisation(const MapLocalisation&) = delete;
  MapLocalisation& operator=(const MapLocalisation&) = delete;

  std::int64_t step(std::int64_t budget);
  bool done() const { return stage_ == Stage::Done; }
  // Before the association has started, the move, its preparation and the conditioning of
  // every kept feature; then the association's own estimate and the conditioning.
  std::int64_t remaining_work() const;
  // Valid once done().
  const std::optional<LocalisedPose>& result() const { return result_; }
  const LocalisationInputs& inputs() const { return inputs_; }

 private:
  enum class Stage { Move, Associate, Condition, Done };
  void move();
  void condition(const std::vector<std::pair<Eigen::Index, Eigen::Index>>& pairs);

  LocalisationInputs inputs_;
  Stage stage_ = Stage::Move;
  std::unique_ptr<GaussianMap> moved_;  // the frame and the association refer to it
  std::unique_ptr<JoinFrame> frame_;
  std::unique_ptr<JoinAssociator> associator_;
  std::optional<LocalisedPose> result_;
};

// MapLocalisation run at once.
std::optional<LocalisedPose> localise_against(const GaussianMap& oldest, const std::vector<PoseLink>& between,
                                              const GaussianMap& newest, const std::vector<Eigen::Index>& left_out,
                                              double max_sigma, const JoinOptions& options);

}  // namespace dcslam
