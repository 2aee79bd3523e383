#pragma once
// Data association of one scan against an EKF map (docs/design.md §3.4; docs/data_association.md,
// "Association inside the EKF"): candidates from a spatial hash of the feature means, the
// 2-dof individual compatibility gate, then nearest neighbour or JCBB over an EKF
// PairingModel whose every covariance block costs O(1).
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/config.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/slam_filter.hpp"
#include "dcslam/core/spatial_hash.hpp"

namespace dcslam {

// Outcome of data association for one measurement: a feature index (>= 0) or one of these.
inline constexpr Eigen::Index kNewFeature = -1;
inline constexpr Eigen::Index kRejected = -2;
// A new feature on probation (SlamConfig::new_feature_beside_tentative): the measurement was
// compatible with tentative features only, and left unpaired.
inline constexpr Eigen::Index kNewFeatureOnProbation = -3;

// Pairing (i, j) = measurement i explained by feature j of `map`. With H_a = [H_R 0 .. H_f ..]
// the Jacobian of h(x_R, f_j) at the means:
//   innovation(a)    = z_i - h(x_R, f_j)   (bearing wrapped)
//   covariance(a, b) = H_a P H_b' + (i == k ? R_i : 0)
// read from the blocks P_RR, P_Rj, P_Rl, P_jl only. The predictions of a feature must be
// prepared (prepare()) before a pairing with it is asked for.
class EkfPairingModel : public PairingModel {
 public:
  using Index = Eigen::Index;

  // Forgets the prepared features; the references must outlive the model's use.
  void reset(const GaussianMap& map, ObservationModel observation, const Vec3& sensor_offset,
             const MeasurementsRef& z, const ScanNoise& R);
  // Computes h(x_R, f_j) and its Jacobians once; O(1), idempotent.
  void prepare(int feature);

  Vec2 innovation(const Pairing& pairing) const override;
  Mat2 covariance(const Pairing& a, const Pairing& b) const override;

  struct Prediction {
    Vec2 z_hat;
    Mat23 H_robot;
    Mat2 H_feature;
  };
  // The prediction of a prepared feature, else nullptr. Valid until the next reset(); the
  // filter's update reuses them, as the map has not moved since the association.
  const Prediction* find_prediction(int feature) const;

 private:
  // The index of a prepared feature's prediction; throws if it is not prepared.
  int slot(int feature) const;
  const Prediction& prediction(int feature) const;
  const Mat2& noise(int measurement) const;
  // H_a P H_b' of two prepared features, kept for the scan while at most kCachedSlots features
  // are prepared: JCBB's nodes and the rival searches ask for the same blocks again and again.
  Mat2 feature_covariance(int feature_a, int feature_b) const;
  void compute_feature_covariance(int feature_a, int feature_b, Mat2& C) const;
  static constexpr int kCachedSlots = 256;  // a 2 MB table at most

  const GaussianMap* map_ = nullptr;
  ObservationModel observation_ = ObservationModel::RangeBearing;
  Vec3 sensor_offset_ = Vec3::Zero();
  MeasurementMatrix z_;  // a copy: the caller's view may not outlive reset()
  ScanNoise R_;  // a copy, like z_
  std::vector<int> slot_of_feature_;     // -1 = not prepared; only prepared entries are reset
  std::vector<int> prepared_features_;
  std::vector<Prediction> predictions_;
  // feature_covariance()'s blocks by (slot of a, slot of b), `cached_slots_` a side; `known_`
  // marks those computed since reset().
  mutable std::vector<Mat2> covariance_cache_;
  mutable std::vector<std::uint8_t> known_;
  mutable int cached_slots_ = 0;
};

// Upper bound on |g(x_R, z) - f_j| over every feature j whose pairing with z passes a 2-dof
// gate of threshold `gate` (docs/data_association.md derives it), where
//   sigma_position = sqrt(lambda_max(P_R,xy)), sigma_heading = sqrt(P_R,phiphi),
//   sigma_feature  >= sqrt(lambda_max(P_jj)) for every feature.
// +inf when no finite bound exists (the Cartesian model with a very uncertain heading).
double candidate_radius(ObservationModel observation, const Vec3& sensor_offset, const Vec2& z,
                        const Mat2& R, double gate, double sigma_position, double sigma_heading,
                        double sigma_feature);

// The association state an EkfSlam keeps across steps: the spatial hash of its feature means
// and the reusable solver buffers. The filter reports every change of its features.
class EkfAssociation {
 public:
  using Index = Eigen::Index;

  explicit EkfAssociation(const SlamConfig& config);

  // Whether associate() reads the tentative flags (SlamConfig::new_feature_beside_tentative or
  // confirmed_first_confidence); otherwise the filter need not build them.
  bool reads_tentative_flags() const {
    return config_.new_feature_beside_tentative || confirmed_first_threshold_ >= 0.0;
  }

  // Fills pairing (one entry per measurement: feature index, kNewFeature, kRejected or
  // kNewFeatureOnProbation). `tentative` marks the features still tentative, one flag per
  // feature, when reads_tentative_flags() and the filter keeps tentative features; empty,
  // the rules that read it do not apply (the filter knows its tentative-feature policy,
  // EkfSlam::associate()). Counters "jcbb_nodes", "jcbb_bound_hits", "unexplained_started" and
  // "started_beside_tentative" are added to `counters`.
  void associate(const GaussianMap& map, const MeasurementsRef& z, const ScanNoise& R,
                 const std::vector<std::uint8_t>& tentative, std::vector<Index>& pairing,
                 std::map<std::string, double>& counters);

  // Feature indices of the hash entries whose gate region may contain a feature paired with
  // z (a superset of the gate-passing ones; exposed for tests).
  void candidates(const GaussianMap& map, const Vec2& z, const Mat2& R, std::vector<int>& out);

  void feature_added(const GaussianMap& map, Index feature);
  // After GaussianMap::swap_remove_feature(feature) returned `moved_from`.
  void feature_swap_removed(Index feature, Index moved_from);
  // After an EKF update: re-hashes the features whose means moved by more than the slack
  // and refreshes the bound on feature uncertainty. O(n).
  void map_updated(const GaussianMap& map);
  void clear();
  // The last scan's pairing model (its prepared predictions).
  const EkfPairingModel& model() const { return model_; }

  // What carries over from scan to scan besides the map, for checkpoints (checkpoint.hpp): the
  // hash's cell size, where it holds each feature (a mean moved by less than the slack is not
  // re-hashed), and the bound on feature uncertainty. The hash's own bucket order does not
  // matter: candidates are sorted.
  struct SavedState {
    double cell_size = 0.0;
    std::vector<Vec2> hashed_positions;
    double sigma_feature = 0.0;
  };
  SavedState saved_state() const;
  void restore(const SavedState& state);

 private:
  // candidates() for a query radius already computed.
  void candidates_within(const GaussianMap& map, const Vec2& z, double radius, std::vector<int>& out);
  // candidate_radius() for this map's robot and feature uncertainty.
  double query_radius(const GaussianMap& map, const Vec2& z, const Mat2& R) const;
  void track_sigma(const GaussianMap& map, Index feature);
  void rebuild_hash(const GaussianMap& map, double cell_size);
  // JcbbLikelihood of the scan: the unexplained density in measurement space at each z_i and
  // ln det R_i, the floor of every pairing's conditional innovation covariance.
  void fill_likelihood(const MeasurementsRef& z, const ScanNoise& R);
  // Whether every hypothesis that pairs `measurement` (which the chosen one, of score
  // `chosen_score`, leaves unpaired) is less likely by more than new_feature_margin.
  bool clearly_unexplained(int measurement, double chosen_score,
                           std::map<std::string, double>& counters);
  double slack() const;

  SlamConfig config_;
  double gate_threshold_;
  double confirmed_first_threshold_;  // chi-square of confirmed_first_confidence; < 0: off
  SpatialHash hash_;
  std::vector<Vec2> hashed_position_;  // per feature index: where the hash holds it
  double sigma_feature_ = 0.0;         // >= sqrt(lambda_max(P_jj)) of every feature
  EkfPairingModel model_;
  Jcbb jcbb_;
  CandidateLists candidates_;
  JcbbLikelihood likelihood_;       // filled per scan when config_.unexplained_density > 0
  std::vector<int> nearby_;
  std::vector<double> radii_;  // per measurement of the scan: its query radius
  std::vector<std::pair<double, int>> ranked_;  // scratch: (individual distance, feature)
  CandidateLists spare_lists_;                  // candidate lists beyond the current scan
};

}  // namespace dcslam
