#pragma once
// The sparse-aware EKF SLAM of docs/design.md §3: one stochastic map (x, P) in the frame of the
// first pose, predicted and updated in O(n) per step except the one O(n^2) covariance update,
// done as a single symmetric rank-k update. It is both the baseline filter (dcslam.EkfSlam)
// and the builder of DCSlam's local maps.
#include <chrono>
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"
#include "dcslam/association/ekf_association.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/slam_filter.hpp"

namespace dcslam {

class EkfSlam : public SlamFilter {
 public:
  using Index = Eigen::Index;

  // Outcome of data association for one measurement: a feature index (>= 0) or one of these.
  static constexpr Index kNewFeature = dcslam::kNewFeature;
  static constexpr Index kRejected = dcslam::kRejected;

  // Validates the config (InvalidArgument naming the field).
  explicit EkfSlam(const SlamConfig& config);

  void predict(const Vec3& u, const Mat3& Q) override;
  std::vector<std::int64_t> update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                   const std::vector<std::int64_t>* landmark_ids) override;
  Estimate estimate() const override;
  Vec3 pose() const override { return map_.robot(); }
  // The id of a feature merged into another as its duplicate gives the other's id (followed to
  // the feature holding it now); ids of removed tentative features (and -1) give -1.
  std::vector<std::int64_t> resolve(const std::vector<std::int64_t>& ids) const override;
  const RunStats& stats() const override { return stats_; }

  const SlamConfig& config() const override { return config_; }
  const GaussianMap& map() const { return map_; }
  // Removes every tentative feature now. Does nothing when the policy is off ("known" mode or
  // min_sightings = 1). O(n) per removed feature.
  void prune_tentative();
  // A tentative feature's sightings in this filter: its id and the steps (predicts so far) it
  // was first and last seen, which its expiry is judged by. Not dcslam::TentativeFeature
  // (joining/tentative_features.hpp), which D&C makes of it when it closes the local map: there
  // the filter's steps mean nothing any more, and what counts is which neighbouring local
  // maps' joins the feature still waits for.
  struct TentativeTrack {
    std::int64_t id = 0;
    std::int64_t first_seen_step = 0;
    std::int64_t last_seen_step = 0;
  };
  // The features that are tentative now (empty when the policy is off). O(n).
  std::vector<TentativeTrack> tentative_features() const;
  // Tentative features first seen at a step <= `step` never expire (prune_tentative() still
  // removes them). D&C: a landmark seen once at the start of a local map may have been seen
  // at the end of the previous one, and only the join of the two can tell.
  void keep_tentative_first_seen_until(std::int64_t step) { keep_until_step_ = step; }
  // Predicts so far.
  std::int64_t steps() const { return step_; }
  // Ids of the features removed so far by the spurious-measurement policy.
  const std::unordered_set<std::int64_t>& removed_ids() const { return removed_ids_; }
  // Duplicated features merged so far: merged id -> the id of the feature it was merged into.
  const IdAliases& merged_ids() const { return merged_into_; }
  // Ids of the features within merge_radius seen in one scan with feature k, once per such scan
  // (ids as they were then: merged_ids() maps those merged since; a pair's scans are listed on
  // either feature, up to final_merge_shared_scans + 1). Recorded in modes "nn"/"jcbb" only.
  const std::vector<std::int64_t>& seen_with(Index k) const { return tracks_[static_cast<std::size_t>(k)].seen_with; }
  // The scans in which feature k was paired (or started), its merged duplicates' included.
  int sightings(Index k) const { return tracks_[static_cast<std::size_t>(k)].sightings; }

  // Hands the map over (D&C closing a local map) and restarts this filter as a fresh one at
  // the origin of a new base frame. Stats and the fresh-id counter carry on.
  GaussianMap take_map();

  // Ids given to features started in modes without landmark ids ("nn", "jcbb"). D&C shares
  // one id space across local maps by passing the counter from one filter to the next.
  std::int64_t next_fresh_id() const { return next_fresh_id_; }
  void set_next_fresh_id(std::int64_t id) { next_fresh_id_ = id; }

 private:
  friend struct CheckpointAccess;  // checkpoint.cpp saves and restores the state below
  // Fills pairing_ (one entry per measurement: feature index, kNewFeature, kRejected or
  // kNewFeatureOnProbation). The seam for data association: "known" looks ids up; "nn"/"jcbb" run EkfAssociation.
  void associate(const MeasurementsRef& z, const ScanNoise& R,
                 const std::vector<std::int64_t>* landmark_ids);
  void associate_known(const std::vector<std::int64_t>& landmark_ids);

  // Joint EKF update with the measurements paired in pairing_.
  void update_paired(const MeasurementsRef& z, const ScanNoise& R);
  // Appends measurement z (noise R, symmetric) as a feature initialised from the current robot;
  // returns its index.
  Index add_feature(const Vec2& z, const Mat2& R, std::int64_t id);
  // The spurious-measurement policy (docs/data_association.md) applies in this filter.
  bool tentative_policy() const;
  // Removes the tentative features for which `expired` holds, in O(n) each.
  template <typename Expired>
  void remove_tentative(Expired expired);
  // Deletes feature k's rows and columns and its track (the last feature moves into slot k);
  // returns the slot the moved feature came from, or -1.
  Index remove_feature(Index k);
  // Duplicated features (docs/data_association.md): records which of the scan's features
  // were seen together, then merges each of them with its duplicate, if it has one. Only in
  // modes "nn"/"jcbb" with merge_radius > 0 (update() checks).
  void record_seen_together(const std::vector<Index>& touched);
  void merge_duplicates(const std::vector<Index>& touched);
  // The one feature that feature k may be merged with (see SlamConfig::merge_radius), or -1.
  Index merge_partner(Index k) const;
  // The scans in which features a and b were both paired, as recorded (record_seen_together).
  std::int64_t shared_scans(Index a, Index b) const;
  void ensure_workspace(Index rows, Index measurement_rows);
  StepStats& current_step();
  void finish_timing(std::chrono::steady_clock::time_point start);

  SlamConfig config_;
  GaussianMap map_;
  std::unordered_map<std::int64_t, Index> index_of_id_;
  std::int64_t next_fresh_id_ = 0;
  RunStats stats_;
  std::optional<EkfAssociation> association_;  // "nn" and "jcbb" only

  // Per feature (state order): how often it has been seen (its first sighting not counted when
  // it was started on probation, SlamConfig::new_feature_beside_tentative: a close call) and the
  // step it was last seen in.
  struct Track {
    int sightings = 0;
    std::int64_t first_seen_step = 0;
    std::int64_t last_seen_step = 0;
    // Ids of the features within merge_radius that were seen in one scan with this one, an id
    // once per such scan (a pair's scans listed on either of the two, up to
    // final_merge_shared_scans + 1): two measurements of one scan come from two landmarks, so
    // the map's own merges never merge such a pair.
    std::vector<std::int64_t> seen_with;
  };
  std::vector<Track> tracks_;
  std::vector<std::uint8_t> tentative_flags_;  // per feature, for the association; reused
  std::int64_t step_ = 0;  // predicts so far
  std::int64_t keep_until_step_ = -1;
  std::unordered_set<std::int64_t> removed_ids_;
  IdAliases merged_into_;
  double merge_gate_ = 0.0;  // chi2(2, gate_confidence)
  std::vector<Index> touched_;

  // Workspaces kept across steps so that the hot path does not allocate; they only grow.
  std::vector<Index> pairing_;
  std::vector<Index> paired_measurements_;
  Eigen::MatrixXd PHt_;         // P H' (n x 2k), becomes W = P H' L^-T in place
  Eigen::MatrixXd S_;           // innovation covariance (2k x 2k), becomes its Cholesky factor
  Eigen::VectorXd innovation_;  // nu (2k), becomes L^-1 nu in place
  std::vector<Mat23> H_robot_;
  std::vector<Mat2> H_feature_;
  ScanNoise noise_;  // this scan's R, normalised once where update() begins
};

// One step of a recorded run: the predict input, then the scan (ids only in "known" mode).
struct SlamStep {
  Vec3 u = Vec3::Zero();
  Mat3 Q = Mat3::Zero();
  MeasurementMatrix z;
  std::vector<Mat2> R;
  std::vector<std::int64_t> landmark_ids;
  bool has_landmark_ids = false;
};

// Runs a whole sequence (predict + update per step) in one call, for benchmarks. Returns the
// ids of every update. Stops at the first invalid step, throwing InvalidArgument that names
// the step; earlier steps stay applied.
std::vector<std::vector<std::int64_t>> run_steps(SlamFilter& filter,
                                                 const std::vector<SlamStep>& steps);

}  // namespace dcslam
