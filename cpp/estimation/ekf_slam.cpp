#include "dcslam/estimation/ekf_slam.hpp"

#include <algorithm>
#include <string>

#include <Eigen/Cholesky>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/feature_merging.hpp"
#include "dcslam/core/input_checks.hpp"
#include "dcslam/core/observation.hpp"

namespace dcslam {

namespace {

using Clock = std::chrono::steady_clock;

// Inputs pass a relative symmetry test only; the filter uses their symmetric part so that P
// stays exactly symmetric.
template <typename Matrix>
Matrix symmetric_part(const Matrix& A) {
  return 0.5 * (A + A.transpose());
}

}  // namespace

EkfSlam::EkfSlam(const SlamConfig& config) : config_(config) {
  config_.validate();
  if (config_.association != Association::Known) association_.emplace(config_);
  merge_gate_ = chi2_quantile(2, config_.gate_confidence);
}

bool EkfSlam::tentative_policy() const {
  return config_.association != Association::Known && config_.min_sightings > 1;
}

template <typename Expired>
void EkfSlam::remove_tentative(Expired expired) {
  if (!tentative_policy()) return;
  // Backwards: the feature swapped into slot k comes from the end, already kept.
  for (Index k = map_.num_features() - 1; k >= 0; --k) {
    const Track& track = tracks_[static_cast<std::size_t>(k)];
    if (track.sightings >= config_.min_sightings || !expired(track)) continue;
    removed_ids_.insert(map_.ids()[static_cast<std::size_t>(k)]);
    remove_feature(k);
    ++stats_.counters["tentative_removed"];
  }
}

EkfSlam::Index EkfSlam::remove_feature(Index k) {
  const std::int64_t id = map_.ids()[static_cast<std::size_t>(k)];
  // Deleting the rows and columns of a Gaussian's component is its exact marginal.
  const Index moved_from = map_.swap_remove_feature(k);
  index_of_id_.erase(id);
  if (moved_from >= 0) {
    tracks_[static_cast<std::size_t>(k)] = std::move(tracks_[static_cast<std::size_t>(moved_from)]);
    index_of_id_[map_.ids()[static_cast<std::size_t>(k)]] = k;
  }
  tracks_.pop_back();
  association_->feature_swap_removed(k, moved_from);
  return moved_from;
}

std::int64_t EkfSlam::shared_scans(Index a, Index b) const {
  const auto listed = [this](Index k, std::int64_t id) {
    const auto& ids = tracks_[static_cast<std::size_t>(k)].seen_with;
    return std::count(ids.begin(), ids.end(), id);
  };
  return listed(a, map_.ids()[static_cast<std::size_t>(b)]) + listed(b, map_.ids()[static_cast<std::size_t>(a)]);
}

// D&C's final merge asks whether a pair shared more than final_merge_shared_scans scans, so
// counting stops one above it.
void EkfSlam::record_seen_together(const std::vector<Index>& touched) {
  const double radius_sq = config_.merge_radius * config_.merge_radius;
  const std::int64_t enough = static_cast<std::int64_t>(config_.final_merge_shared_scans) + 1;
  for (std::size_t p = 0; p < touched.size(); ++p) {
    for (std::size_t q = p + 1; q < touched.size(); ++q) {
      const Index a = touched[p], b = touched[q];
      if (a == b || (map_.feature(a) - map_.feature(b)).squaredNorm() > radius_sq || shared_scans(a, b) >= enough) {
        continue;
      }
      tracks_[static_cast<std::size_t>(a)].seen_with.push_back(map_.ids()[static_cast<std::size_t>(b)]);
    }
  }
}

// A duplicate is found by the test a join applies to a pair of its two maps: f_a - f_b
// compatible with 0 at gate_confidence. Within one map two more conditions keep distinct
// landmarks apart: the two were never paired in one scan (distinct landmarks in view together
// almost always are), and each is the other's only compatible feature (no ambiguity to
// resolve, which is what a joint test would be for).
EkfSlam::Index EkfSlam::merge_partner(Index k) const {
  return dcslam::merge_partner(map_, k, config_.merge_radius, merge_gate_, 0.0,
                               [this](Index a, Index b) { return shared_scans(a, b) == 0; });
}

void EkfSlam::merge_duplicates(const std::vector<Index>& touched) {
  std::vector<std::int64_t> touched_ids;
  for (Index k : touched) touched_ids.push_back(map_.ids()[static_cast<std::size_t>(k)]);
  bool merged = false;
  for (std::int64_t id : touched_ids) {
    const auto found = index_of_id_.find(id);
    if (found == index_of_id_.end()) continue;
    const Index k = found->second;
    const Index partner = merge_partner(k);
    if (partner < 0 || merge_partner(partner) != k) continue;
    // The older feature stays: its id is the one already returned for most measurements.
    const auto older = [this](Index a, Index b) {
      const Track& ta = tracks_[static_cast<std::size_t>(a)];
      const Track& tb = tracks_[static_cast<std::size_t>(b)];
      return std::make_pair(ta.first_seen_step, map_.ids()[static_cast<std::size_t>(a)]) <
             std::make_pair(tb.first_seen_step, map_.ids()[static_cast<std::size_t>(b)]);
    };
    const Index keep = older(k, partner) ? k : partner;
    const Index drop = keep == k ? partner : k;
    if (!impose_equal_features(map_, keep, drop)) continue;
    Track& kept = tracks_[static_cast<std::size_t>(keep)];
    const Track& dropped = tracks_[static_cast<std::size_t>(drop)];
    kept.sightings += dropped.sightings;
    kept.first_seen_step = std::min(kept.first_seen_step, dropped.first_seen_step);
    kept.last_seen_step = std::max(kept.last_seen_step, dropped.last_seen_step);
    kept.seen_with.insert(kept.seen_with.end(), dropped.seen_with.begin(), dropped.seen_with.end());
    add_alias(merged_into_, map_.ids()[static_cast<std::size_t>(drop)], map_.ids()[static_cast<std::size_t>(keep)]);
    remove_feature(drop);
    ++stats_.counters["features_merged"];
    merged = true;
  }
  if (merged) association_->map_updated(map_);
}

void EkfSlam::prune_tentative() {
  remove_tentative([](const Track&) { return true; });
}

std::vector<EkfSlam::TentativeTrack> EkfSlam::tentative_features() const {
  std::vector<TentativeTrack> features;
  if (!tentative_policy()) return features;
  for (std::size_t k = 0; k < tracks_.size(); ++k) {
    const Track& track = tracks_[k];
    if (track.sightings < config_.min_sightings) {
      features.push_back(TentativeTrack{map_.ids()[k], track.first_seen_step, track.last_seen_step});
    }
  }
  return features;
}

StepStats& EkfSlam::current_step() {
  // An update before any predict belongs to an implicit first step.
  if (stats_.steps.empty()) stats_.steps.emplace_back();
  return stats_.steps.back();
}

void EkfSlam::finish_timing(Clock::time_point start) {
  StepStats& step = current_step();
  step.num_features = map_.num_features();
  step.seconds += std::chrono::duration<double>(Clock::now() - start).count();
}

void EkfSlam::predict(const Vec3& u, const Mat3& Q) {
  check_motion(u, Q, "predict");
  const auto start = Clock::now();
  stats_.steps.emplace_back();
  ++stats_.counters["predicts"];
  ++step_;

  Mat3 F, G;
  const Vec3 robot = compose(map_.robot(), u, &F, &G);
  auto P = map_.P();
  const Mat3 P_RR = F * P.topLeftCorner<3, 3>() * F.transpose() + G * symmetric_part(Q) * G.transpose();
  P.topLeftCorner<3, 3>() = symmetric_part(P_RR);
  // P_RM <- F P_RM and its mirror: one pass over the robot's rows and columns, O(n).
  for (Index j = GaussianMap::kRobotDim; j < map_.dim(); ++j) {
    const Vec3 column = F * P.block<3, 1>(0, j);
    P.block<3, 1>(0, j) = column;
    P.block<1, 3>(j, 0) = column.transpose();
  }
  map_.x().head<3>() = robot;
  finish_timing(start);
}

std::vector<std::int64_t> EkfSlam::update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                          const std::vector<std::int64_t>* landmark_ids) {
  check_measurements(z, R, landmark_ids, config_.observation, config_.association, "update");
  const auto start = Clock::now();
  const auto m = static_cast<std::size_t>(z.rows());
  noise_.assign(R, m);

  remove_tentative(
      [this](const Track& track) {
        return step_ - track.last_seen_step > config_.tentative_window &&
               track.first_seen_step > keep_until_step_;
      });
  const auto association_start = Clock::now();
  associate(z, noise_, landmark_ids);
  const double association_seconds =
      std::chrono::duration<double>(Clock::now() - association_start).count();
  update_paired(z, noise_);
  if (association_ && !paired_measurements_.empty()) association_->map_updated(map_);

  // New features come from the robot as updated by the paired measurements (docs/design.md §3.3).
  std::vector<std::int64_t> assigned(m, -1);
  touched_.clear();
  StepStats& step = current_step();
  step.measurements += static_cast<int>(m);
  step.association_seconds += association_seconds;
  for (std::size_t i = 0; i < m; ++i) {
    const Index decision = pairing_[i];
    if (decision >= 0) {
      assigned[i] = map_.ids()[static_cast<std::size_t>(decision)];
      Track& track = tracks_[static_cast<std::size_t>(decision)];
      ++track.sightings;
      track.last_seen_step = step_;
      touched_.push_back(decision);
      ++step.paired;
    } else if (decision == kNewFeature || decision == kNewFeatureOnProbation) {
      const std::int64_t id = landmark_ids ? (*landmark_ids)[i] : next_fresh_id_++;
      const Index index =
          add_feature(z.row(static_cast<Index>(i)).transpose(), noise_[i], id);
      index_of_id_[id] = index;
      // On probation, the first sighting does not count: it needs min_sightings more, and the
      // merges' "seen without the other" counts leave out the scan that was a close call.
      tracks_.push_back(Track{decision == kNewFeatureOnProbation ? 0 : 1, step_, step_, {}});
      if (association_) association_->feature_added(map_, index);
      touched_.push_back(index);
      assigned[i] = id;
      ++step.new_features;
    } else {
      ++step.rejected;
    }
  }
  if (association_ && config_.merge_radius > 0.0) {
    record_seen_together(touched_);
    merge_duplicates(touched_);
  }
  ++stats_.counters["updates"];
  finish_timing(start);
  return assigned;
}

void EkfSlam::associate(const MeasurementsRef& z, const ScanNoise& R,
                        const std::vector<std::int64_t>* landmark_ids) {
  if (association_) {
    tentative_flags_.clear();
    if (association_->reads_tentative_flags() && tentative_policy()) {
      for (const Track& track : tracks_) tentative_flags_.push_back(track.sightings < config_.min_sightings);
    }
    association_->associate(map_, z, R, tentative_flags_, pairing_, stats_.counters);
    return;
  }
  pairing_.assign(static_cast<std::size_t>(z.rows()), kRejected);
  associate_known(*landmark_ids);  // check_measurements guarantees the ids in this mode
}

void EkfSlam::associate_known(const std::vector<std::int64_t>& landmark_ids) {
  for (std::size_t i = 0; i < landmark_ids.size(); ++i) {
    const std::int64_t id = landmark_ids[i];
    if (id == -1) continue;  // the caller's "not a landmark" (e.g. simulator clutter)
    const auto found = index_of_id_.find(id);
    pairing_[i] = found == index_of_id_.end() ? kNewFeature : found->second;
  }
}

void EkfSlam::ensure_workspace(Index rows, Index measurement_rows) {
  if (PHt_.rows() < rows || PHt_.cols() < measurement_rows) {
    // Rows follow the map's capacity so that they reallocate only when the map does; columns
    // double past the largest scan seen.
    const Index cols = PHt_.cols() < measurement_rows ? std::max(measurement_rows, 2 * PHt_.cols())
                                                      : PHt_.cols();
    PHt_.resize(std::max(rows, map_.capacity()), cols);
  }
  if (S_.rows() < measurement_rows) {
    S_.resize(PHt_.cols(), PHt_.cols());
    innovation_.resize(PHt_.cols());
  }
}

void EkfSlam::update_paired(const MeasurementsRef& z, const ScanNoise& R) {
  paired_measurements_.clear();
  for (std::size_t i = 0; i < pairing_.size(); ++i) {
    if (pairing_[i] >= 0) paired_measurements_.push_back(static_cast<Index>(i));
  }
  const auto k = static_cast<Index>(paired_measurements_.size());
  if (k == 0) return;
  const Index n = map_.dim();
  const Index rows = 2 * k;
  // The workspace's size sets the rounding of what is computed in it (checkpoint.cpp): a
  // refused update puts it back, so that the run goes on as if it had never been called.
  const Index workspace_rows = PHt_.rows(), workspace_cols = PHt_.cols(), innovation_rows = S_.rows();
  ensure_workspace(n, rows);
  H_robot_.resize(static_cast<std::size_t>(k));
  H_feature_.resize(static_cast<std::size_t>(k));

  auto P = map_.P();
  auto PHt = PHt_.topLeftCorner(n, rows);
  auto S = S_.topLeftCorner(rows, rows);
  auto nu = innovation_.head(rows);
  const Vec3 robot = map_.robot();

  // P H' = P[:,R] H_R' + sum P[:,f] H_f': O(n k), H is never formed.
  for (Index a = 0; a < k; ++a) {
    const auto i = static_cast<std::size_t>(paired_measurements_[static_cast<std::size_t>(a)]);
    const Index feature = pairing_[i];
    const Index offset = GaussianMap::feature_offset(feature);
    Mat23& H_R = H_robot_[static_cast<std::size_t>(a)];
    Mat2& H_f = H_feature_[static_cast<std::size_t>(a)];
    const EkfPairingModel::Prediction* predicted =
        association_ ? association_->model().find_prediction(static_cast<int>(feature)) : nullptr;
    Vec2 z_hat;
    if (predicted) {
      z_hat = predicted->z_hat;
      H_R = predicted->H_robot;
      H_f = predicted->H_feature;
    } else {
      z_hat = observe(config_.observation, config_.sensor_offset, robot, map_.feature(feature), &H_R, &H_f);
    }
    nu.segment<2>(2 * a) =
        innovation(config_.observation, z.row(static_cast<Index>(i)).transpose(), z_hat);
    PHt.middleCols<2>(2 * a).noalias() = P.leftCols<3>() * H_R.transpose();
    PHt.middleCols<2>(2 * a).noalias() += P.middleCols<2>(offset) * H_f.transpose();
  }
  // S = H (P H') + R, row block by row block.
  for (Index a = 0; a < k; ++a) {
    const auto i = static_cast<std::size_t>(paired_measurements_[static_cast<std::size_t>(a)]);
    const Index offset = GaussianMap::feature_offset(pairing_[i]);
    S.middleRows<2>(2 * a).noalias() = H_robot_[static_cast<std::size_t>(a)] * PHt.topRows<3>();
    S.middleRows<2>(2 * a).noalias() += H_feature_[static_cast<std::size_t>(a)] * PHt.middleRows<2>(offset);
    S.block<2, 2>(2 * a, 2 * a) += R[i];
  }

  // In-place Cholesky S = L L' (reads the lower triangle only). A measurement at a range that
  // squares to zero (1e-300) gives infinite Jacobians and a NaN S, which the factorisation
  // would pass on without failing: refused before it.
  const bool finite = S.allFinite() && nu.allFinite();
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> cholesky(S);
  if (!finite || cholesky.info() != Eigen::Success) {
    PHt_.resize(workspace_rows, workspace_cols);
    S_.resize(innovation_rows, innovation_rows);
    innovation_.resize(innovation_rows);
    throw InvalidArgument(std::string("update: the innovation covariance is ") +
                          (finite ? "not positive definite" : "not finite (a measurement at a range too small?)") +
                          " (state left unchanged)");
  }
  // W = P H' L^-T and L^-1 nu, both in place: then K nu = W (L^-1 nu) and K S K' = W W'.
  cholesky.matrixU().solveInPlace<Eigen::OnTheRight>(PHt);
  cholesky.matrixL().solveInPlace(nu);

  map_.x().noalias() += PHt * nu;
  map_.x()(2) = wrap_angle(map_.x()(2));
  // The one O(n^2) line: P -= W W' on the lower triangle (a symmetric rank-2k update), then
  // one blocked copy onto the upper triangle. Measured (n = 2003, 2k = 32): rankUpdate 8.4 ms
  // + mirror 4.2 ms against 16.5 ms for a full-matrix product; a hand-tiled fused
  // update-and-mirror was no faster than this pair.
  P.selfadjointView<Eigen::Lower>().rankUpdate(PHt, -1.0);
  map_.mirror_lower_triangle();
}

EkfSlam::Index EkfSlam::add_feature(const Vec2& z, const Mat2& R, std::int64_t id) {
  Mat23 G_R;
  Mat2 G_z;
  const Vec2 feature =
      inverse_observe(config_.observation, config_.sensor_offset, map_.robot(), z, &G_R, &G_z);
  const Index offset = map_.dim();
  const Index index = map_.append_feature(feature, id);
  auto P = map_.P();
  // P_f* = G_R P_R*: O(n).
  for (Index j = 0; j < offset; ++j) {
    const Vec2 column = G_R * P.block<3, 1>(0, j);
    P.block<2, 1>(offset, j) = column;
    P.block<1, 2>(j, offset) = column.transpose();
  }
  const Mat2 P_ff = G_R * P.topLeftCorner<3, 3>() * G_R.transpose() +
                    G_z * R * G_z.transpose();
  P.block<2, 2>(offset, offset) = symmetric_part(P_ff);
  return index;
}

Estimate EkfSlam::estimate() const { return to_estimate(map_, map_.P()); }

std::vector<std::int64_t> EkfSlam::resolve(const std::vector<std::int64_t>& ids) const {
  std::vector<std::int64_t> resolved = ids;
  for (std::int64_t& id : resolved) {
    id = follow_aliases(merged_into_, id);
    if (removed_ids_.count(id) != 0) id = -1;
  }
  return resolved;
}

GaussianMap EkfSlam::take_map() {
  GaussianMap taken = std::move(map_);
  map_ = GaussianMap();
  index_of_id_.clear();
  tracks_.clear();
  if (association_) association_->clear();
  return taken;
}

std::vector<std::vector<std::int64_t>> run_steps(SlamFilter& filter,
                                                 const std::vector<SlamStep>& steps) {
  std::vector<std::vector<std::int64_t>> assigned;
  assigned.reserve(steps.size());
  for (std::size_t s = 0; s < steps.size(); ++s) {
    const SlamStep& step = steps[s];
    try {
      filter.predict(step.u, step.Q);
      assigned.push_back(
          filter.update(step.z, step.R, step.has_landmark_ids ? &step.landmark_ids : nullptr));
    } catch (const InvalidArgument& error) {
      throw InvalidArgument("run_steps: step " + std::to_string(s) + ": " + error.what());
    }
  }
  return assigned;
}

}  // namespace dcslam
