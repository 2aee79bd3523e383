#include "dcslam/association/ekf_association.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/LU>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/observation.hpp"

namespace dcslam {

namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();
// Cell size before any feature uncertainty is known; replaced at the first scan with features.
constexpr double kInitialCellSize = 1.0;
// A feature is re-hashed only when its mean has moved by more than this fraction of a cell;
// queries widen their radius by the same amount, so they never miss it.
constexpr double kSlackFraction = 0.25;
// The cell size follows the scan's largest query radius within this factor.
constexpr double kCellDrift = 4.0;
// Up to this many features a scan of their positions is cheaper than the hash's cell look-ups
// (local maps of D&C stay below it).
constexpr EkfAssociation::Index kLinearScanFeatures = 64;

}  // namespace

void EkfPairingModel::reset(const GaussianMap& map, ObservationModel observation,
                            const Vec3& sensor_offset, const MeasurementsRef& z,
                            const ScanNoise& R) {
  map_ = &map;
  observation_ = observation;
  sensor_offset_ = sensor_offset;
  z_ = z;
  R_ = R;
  for (int feature : prepared_features_) slot_of_feature_[static_cast<std::size_t>(feature)] = -1;
  prepared_features_.clear();
  predictions_.clear();
  std::fill(known_.begin(), known_.end(), std::uint8_t{0});
  slot_of_feature_.resize(static_cast<std::size_t>(map.num_features()), -1);
}

void EkfPairingModel::prepare(int feature) {
  int& slot = slot_of_feature_.at(static_cast<std::size_t>(feature));
  if (slot >= 0) return;
  slot = static_cast<int>(predictions_.size());
  prepared_features_.push_back(feature);
  Prediction& p = predictions_.emplace_back();
  p.z_hat = observe(observation_, sensor_offset_, map_->robot(), map_->feature(feature),
                    &p.H_robot, &p.H_feature);
}

const EkfPairingModel::Prediction* EkfPairingModel::find_prediction(int feature) const {
  if (feature < 0 || static_cast<std::size_t>(feature) >= slot_of_feature_.size()) return nullptr;
  const int slot = slot_of_feature_[static_cast<std::size_t>(feature)];
  return slot < 0 ? nullptr : &predictions_[static_cast<std::size_t>(slot)];
}

int EkfPairingModel::slot(int feature) const {
  if (!find_prediction(feature)) {
    throw InvalidArgument("EkfPairingModel: feature " + std::to_string(feature) + " not prepared");
  }
  return slot_of_feature_[static_cast<std::size_t>(feature)];
}

const EkfPairingModel::Prediction& EkfPairingModel::prediction(int feature) const {
  return predictions_[static_cast<std::size_t>(slot(feature))];
}

const Mat2& EkfPairingModel::noise(int measurement) const {
  return R_[static_cast<std::size_t>(measurement)];
}

Vec2 EkfPairingModel::innovation(const Pairing& pairing) const {
  return dcslam::innovation(observation_, z_.row(pairing.measurement).transpose(),
                            prediction(pairing.feature).z_hat);
}

void EkfPairingModel::compute_feature_covariance(int feature_a, int feature_b, Mat2& C) const {
  const Prediction& pa = prediction(feature_a);
  const Prediction& pb = prediction(feature_b);
  const auto P = map_->P();
  const Index ja = GaussianMap::feature_offset(feature_a);
  const Index jb = GaussianMap::feature_offset(feature_b);
  C = pa.H_robot * P.topLeftCorner<3, 3>() * pb.H_robot.transpose();
  C.noalias() += pa.H_robot * P.block<3, 2>(0, jb) * pb.H_feature.transpose();
  C.noalias() += pa.H_feature * P.block<2, 3>(ja, 0) * pb.H_robot.transpose();
  C.noalias() += pa.H_feature * P.block<2, 2>(ja, jb) * pb.H_feature.transpose();
}

Mat2 EkfPairingModel::feature_covariance(int feature_a, int feature_b) const {
  const int slot_a = slot(feature_a), slot_b = slot(feature_b);
  const int slots = std::max(slot_a, slot_b) + 1;
  if (slots > kCachedSlots) {
    Mat2 C;
    compute_feature_covariance(feature_a, feature_b, C);
    return C;
  }
  if (slots > cached_slots_) {
    // Features are prepared as a scan's candidates are found, so the table grows rarely:
    // start it again, larger.
    cached_slots_ = std::min(kCachedSlots, std::max({2 * cached_slots_, slots, 16}));
    const auto cells = static_cast<std::size_t>(cached_slots_) * static_cast<std::size_t>(cached_slots_);
    covariance_cache_.assign(cells, Mat2::Zero());
    known_.assign(cells, 0);
  }
  const std::size_t cell = static_cast<std::size_t>(slot_a) * static_cast<std::size_t>(cached_slots_) +
                           static_cast<std::size_t>(slot_b);
  if (!known_[cell]) {
    compute_feature_covariance(feature_a, feature_b, covariance_cache_[cell]);
    known_[cell] = 1;
  }
  return covariance_cache_[cell];
}

Mat2 EkfPairingModel::covariance(const Pairing& a, const Pairing& b) const {
  Mat2 C = feature_covariance(a.feature, b.feature);
  if (a.measurement == b.measurement) C += 0.5 * (noise(a.measurement) + noise(a.measurement).transpose());
  return C;
}

double candidate_radius(ObservationModel observation, const Vec3& sensor_offset, const Vec2& z,
                        const Mat2& R, double gate, double sigma_position, double sigma_heading,
                        double sigma_feature) {
  const double c = std::sqrt(gate);
  const double lever = sensor_offset.head<2>().norm();  // sensor position moves lever * dphi
  if (observation == ObservationModel::RangeBearing) {
    // |nu_r| <= c sqrt(S_rr) and the range row of [H_R H_f] moves by at most
    // sigma_position + lever sigma_heading + sigma_feature (one standard deviation each).
    // Plain sqrt: std::hypot's overflow guard costs more than the rest of this function.
    const double position_bound = sigma_position + lever * sigma_heading + sigma_feature;
    const double range_std_bound = std::sqrt(position_bound * position_bound + std::max(0.0, R(0, 0)));
    const double max_range = z(0) + c * range_std_bound;
    // r_j |nu_beta| <= c r_j sqrt(S_bb): the bearing row scaled by r_j has position and
    // feature parts of norm 1 and a heading part of at most r_j + lever.
    const double arc_position_bound = sigma_position + (max_range + lever) * sigma_heading + sigma_feature;
    const double bearing_arc_bound = std::sqrt(arc_position_bound * arc_position_bound +
                                               max_range * max_range * std::max(0.0, R(1, 1)));
    // |g(x_R, z) - f_j| <= |nu_r| + r_j |nu_beta| (radial step, then the arc).
    return c * (range_std_bound + bearing_arc_bound);
  }
  // Cartesian: |nu| <= c sqrt(lambda_max(S)) and the heading moves the prediction by up to
  // (r_j + lever) sigma_heading with r_j <= |z| + |nu|; solve for |nu|.
  const double shrink = 1.0 - c * sigma_heading;
  if (!(shrink > 0.0)) return kInfinity;
  return c * (sigma_position + (z.norm() + lever) * sigma_heading + sigma_feature + largest_std(R)) /
         shrink;
}

EkfAssociation::EkfAssociation(const SlamConfig& config)
    : config_(config),
      gate_threshold_(chi2_quantile(2, config.gate_confidence)),
      confirmed_first_threshold_(config.confirmed_first_confidence
                                     ? chi2_quantile(2, *config.confirmed_first_confidence)
                                     : -1.0),
      hash_(kInitialCellSize),
      jcbb_([&config] {
        JcbbOptions options;
        options.confidence = config.gate_confidence;
        options.max_nodes = config.jcbb_max_nodes;
        return options;
      }()) {}

double EkfAssociation::slack() const { return kSlackFraction * hash_.cell_size(); }

void EkfAssociation::clear() {
  hash_.clear();
  hashed_position_.clear();
  sigma_feature_ = 0.0;
}

EkfAssociation::SavedState EkfAssociation::saved_state() const {
  return SavedState{hash_.cell_size(), hashed_position_, sigma_feature_};
}

void EkfAssociation::restore(const SavedState& state) {
  hash_ = SpatialHash(state.cell_size);
  hashed_position_ = state.hashed_positions;
  for (std::size_t k = 0; k < hashed_position_.size(); ++k) hash_.insert(static_cast<int>(k), hashed_position_[k]);
  sigma_feature_ = state.sigma_feature;
}

void EkfAssociation::track_sigma(const GaussianMap& map, Index feature) {
  const Index offset = GaussianMap::feature_offset(feature);
  sigma_feature_ = std::max(sigma_feature_, largest_std(map.P().block<2, 2>(offset, offset)));
}

void EkfAssociation::feature_added(const GaussianMap& map, Index feature) {
  const Vec2 mean = map.feature(feature);
  hash_.insert(static_cast<int>(feature), mean);
  hashed_position_.push_back(mean);
  track_sigma(map, feature);
}

void EkfAssociation::feature_swap_removed(Index feature, Index moved_from) {
  hash_.remove(static_cast<int>(feature));
  if (moved_from >= 0) {
    const Vec2 position = hashed_position_[static_cast<std::size_t>(moved_from)];
    hash_.remove(static_cast<int>(moved_from));
    hash_.insert(static_cast<int>(feature), position);
    hashed_position_[static_cast<std::size_t>(feature)] = position;
  }
  hashed_position_.pop_back();
  // sigma_feature_ stays an upper bound; map_updated() tightens it.
}

void EkfAssociation::map_updated(const GaussianMap& map) {
  // An update only shrinks feature covariances, but the bound is refreshed from scratch in
  // the same pass that re-hashes, so removed or well-observed features stop widening queries.
  const double limit_sq = slack() * slack();
  sigma_feature_ = 0.0;
  for (Index k = 0; k < map.num_features(); ++k) {
    Vec2& hashed = hashed_position_[static_cast<std::size_t>(k)];
    const Vec2 mean = map.feature(k);
    if ((mean - hashed).squaredNorm() > limit_sq) {
      hash_.move(static_cast<int>(k), mean);
      hashed = mean;
    }
    track_sigma(map, k);
  }
}

void EkfAssociation::rebuild_hash(const GaussianMap& map, double cell_size) {
  hash_ = SpatialHash(cell_size);
  for (Index k = 0; k < map.num_features(); ++k) {
    hashed_position_[static_cast<std::size_t>(k)] = map.feature(k);
    hash_.insert(static_cast<int>(k), map.feature(k));
  }
}

double EkfAssociation::query_radius(const GaussianMap& map, const Vec2& z, const Mat2& R) const {
  const Mat3 P_RR = map.P().topLeftCorner<3, 3>();
  return candidate_radius(config_.observation, config_.sensor_offset, z, R, gate_threshold_,
                          largest_std(P_RR.topLeftCorner<2, 2>()),
                          std::sqrt(std::max(0.0, P_RR(2, 2))), sigma_feature_);
}

void EkfAssociation::candidates(const GaussianMap& map, const Vec2& z, const Mat2& R,
                                std::vector<int>& out) {
  candidates_within(map, z, query_radius(map, z, R), out);
}

void EkfAssociation::candidates_within(const GaussianMap& map, const Vec2& z, double radius,
                                       std::vector<int>& out) {
  if (!std::isfinite(radius)) {
    // No finite bound (Cartesian model, heading std near 1/sqrt(gate)): every feature.
    out.resize(static_cast<std::size_t>(map.num_features()));
    for (std::size_t k = 0; k < out.size(); ++k) out[k] = static_cast<int>(k);
    return;
  }
  const Vec2 center =
      inverse_observe(config_.observation, config_.sensor_offset, map.robot(), z);
  const double reach = radius + slack();
  if (map.num_features() <= kLinearScanFeatures) {
    // The hash's own test on the positions it holds, so the answer is the same set.
    out.clear();
    const double reach_sq = reach * reach;
    for (std::size_t k = 0; k < hashed_position_.size(); ++k) {
      if ((hashed_position_[k] - center).squaredNorm() <= reach_sq) out.push_back(static_cast<int>(k));
    }
    return;
  }
  hash_.query(center, reach, out);
  std::sort(out.begin(), out.end());  // hash order is arbitrary; keep runs reproducible
}

void EkfAssociation::fill_likelihood(const MeasurementsRef& z, const ScanNoise& R) {
  const auto m = static_cast<std::size_t>(z.rows());
  likelihood_.log_unexplained_density.resize(m);
  likelihood_.log_noise_det.resize(m);
  const double log_density = std::log(config_.unexplained_density);
  for (std::size_t i = 0; i < m; ++i) {
    // A density uniform in the plane, seen in measurement space: times |det dg/dz|, the
    // range for (r, beta) and 1 for Cartesian points.
    const double jacobian = config_.observation == ObservationModel::RangeBearing
                                ? std::abs(z(static_cast<Index>(i), 0))
                                : 1.0;
    likelihood_.log_unexplained_density[i] = log_density + std::log(jacobian);
    likelihood_.log_noise_det[i] = std::log(R[i].determinant());
  }
}

void EkfAssociation::associate(const GaussianMap& map, const MeasurementsRef& z,
                               const ScanNoise& R, const std::vector<std::uint8_t>& tentative,
                               std::vector<Index>& pairing, std::map<std::string, double>& counters) {
  const auto m = static_cast<std::size_t>(z.rows());
  pairing.assign(m, kNewFeature);
  if (m == 0 || map.num_features() == 0) return;

  // Keep the cell about one query radius wide, so a query touches about 3x3 cells.
  radii_.resize(m);
  double largest_radius = 0.0;
  for (std::size_t i = 0; i < m; ++i) {
    radii_[i] = query_radius(map, z.row(static_cast<Index>(i)).transpose(), R[i]);
    largest_radius = std::max(largest_radius, radii_[i]);
  }
  if (std::isfinite(largest_radius) && largest_radius > 0.0 &&
      (largest_radius > kCellDrift * hash_.cell_size() ||
       largest_radius < hash_.cell_size() / kCellDrift)) {
    rebuild_hash(map, largest_radius);
  }

  model_.reset(map, config_.observation, config_.sensor_offset, z, R);
  // Lists are parked rather than destroyed when a scan is shorter, so they keep their capacity.
  while (candidates_.size() > m) {
    spare_lists_.push_back(std::move(candidates_.back()));
    candidates_.pop_back();
  }
  while (candidates_.size() < m) {
    if (spare_lists_.empty()) {
      candidates_.emplace_back();
    } else {
      candidates_.push_back(std::move(spare_lists_.back()));
      spare_lists_.pop_back();
    }
  }
  for (std::size_t i = 0; i < m; ++i) {
    ranked_.clear();
    candidates_within(map, z.row(static_cast<Index>(i)).transpose(), radii_[i], nearby_);
    for (int feature : nearby_) {
      model_.prepare(feature);
      const double distance_sq = individual_distance_sq(model_, Pairing{static_cast<int>(i), feature});
      if (distance_sq <= gate_threshold_) ranked_.emplace_back(distance_sq, feature);
    }
    // Closest first, ties in feature order: the order JCBB tries them in.
    std::stable_sort(ranked_.begin(), ranked_.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<int>& compatible = candidates_[i];
    compatible.clear();
    for (const auto& [distance_sq, feature] : ranked_) compatible.push_back(feature);
    // SlamConfig::confirmed_first_confidence: close to a confirmed feature, the tentative ones
    // are not candidates.
    if (confirmed_first_threshold_ >= 0.0 && !tentative.empty()) {
      const bool close_to_confirmed = std::any_of(ranked_.begin(), ranked_.end(), [&](const auto& ranked) {
        return ranked.first <= confirmed_first_threshold_ && tentative[static_cast<std::size_t>(ranked.second)] == 0;
      });
      if (close_to_confirmed) {
        compatible.erase(std::remove_if(compatible.begin(), compatible.end(),
                                        [&](int f) { return tentative[static_cast<std::size_t>(f)] != 0; }),
                         compatible.end());
      }
    }
  }

  std::vector<int> feature_of;
  const bool likelihood = config_.association == Association::Jcbb && config_.unexplained_density > 0.0;
  double chosen_score = 0.0;
  if (config_.association == Association::Jcbb) {
    if (likelihood) fill_likelihood(z, R);
    JcbbResult result = jcbb_.solve_ranked(candidates_, model_, likelihood ? &likelihood_ : nullptr);
    counters["jcbb_nodes"] += static_cast<double>(result.nodes_expanded);
    counters["jcbb_bound_hits"] += result.bound_hit ? 1.0 : 0.0;
    chosen_score = result.score;
    feature_of = std::move(result.feature_of);
  } else {
    feature_of = nearest_neighbour(candidates_, model_, config_.gate_confidence);
  }
  for (std::size_t i = 0; i < m; ++i) {
    if (feature_of[i] != kStar) {
      pairing[i] = feature_of[i];
    } else if (!candidates_[i].empty()) {
      // Compatible with a feature that the hypothesis gave to another measurement (or left
      // out): a new feature here would duplicate that landmark if the decision was a close
      // one, so it is started only when the decision was clear.
      // A tentative feature is not a landmark yet (most are clutter): beside tentative ones
      // only, a close decision starts a feature, on probation.
      if (likelihood && clearly_unexplained(static_cast<int>(i), chosen_score, counters)) {
        pairing[i] = kNewFeature;
      } else if (config_.new_feature_beside_tentative && !tentative.empty() &&
                 std::all_of(candidates_[i].begin(), candidates_[i].end(),
                             [&](int feature) { return tentative[static_cast<std::size_t>(feature)] != 0; })) {
        pairing[i] = kNewFeatureOnProbation;
        counters["started_beside_tentative"] += 1.0;
      } else {
        pairing[i] = kRejected;
      }
    }
  }
}

bool EkfAssociation::clearly_unexplained(int measurement, double chosen_score,
                                         std::map<std::string, double>& counters) {
  if (!std::isfinite(config_.new_feature_margin)) return false;
  const JcbbResult rival = jcbb_.first_pairing_above(candidates_, model_, likelihood_, measurement,
                                                     chosen_score - config_.new_feature_margin);
  counters["jcbb_nodes"] += static_cast<double>(rival.nodes_expanded);
  // A search stopped at the node bound has not shown that no rival is close.
  const bool clear = rival.pairings == 0 && !rival.bound_hit;
  if (clear) counters["unexplained_started"] += 1.0;
  return clear;
}

}  // namespace dcslam
