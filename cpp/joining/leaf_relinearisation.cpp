#include "dcslam/joining/leaf_relinearisation.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/LU>

namespace dcslam {

namespace {

using Index = Eigen::Index;

// Gauss–Newton steps of fit_leaf_poses(); they usually stop earlier, when no pose is estimated
// to be further than kPoseTolerance from the fit.
constexpr int kPoseSteps = 10;
constexpr double kPoseTolerance = 1e-9;
// Step halvings when a Gauss–Newton step of the poses raises the objective.
constexpr int kPoseHalvings = 10;

// ⊖a ⊕ b - u, the heading wrapped (the batch problem's odometry residual), with d/da, d/db.
Vec3 odometry_error(const Vec3& a, const Vec3& b, const Vec3& u, Mat3* J_a = nullptr, Mat3* J_b = nullptr) {
  Mat3 J_inverse, J_first;
  const Vec3 inverse = invert(a, &J_inverse);
  Vec3 error = compose(inverse, b, &J_first, J_b) - u;
  error.z() = wrap_angle(error.z());
  if (J_a != nullptr) *J_a = J_first * J_inverse;
  return error;
}

// The inverse of a covariance, a zero variance (a known heading, an exactly known motion)
// weighted as a constraint: a floor of 1e-12 of the largest variance (at least 1e-12).
template <int N>
Eigen::Matrix<double, N, N> information(const Eigen::Matrix<double, N, N>& covariance) {
  const double floor = 1e-12 * std::max(1.0, covariance.diagonal().cwiseAbs().maxCoeff());
  const Eigen::Matrix<double, N, N> floored =
      covariance + floor * Eigen::Matrix<double, N, N>::Identity();
  return floored.ldlt().solve(Eigen::Matrix<double, N, N>::Identity());
}

Vec3 pose_difference(const Vec3& a, const Vec3& b) {
  Vec3 d = a - b;
  d.z() = wrap_angle(d.z());
  return d;
}

// The leaf's pose t (base frame): the base at the origin, the intermediate poses, the end.
class LeafPoses {
 public:
  LeafPoses(const std::vector<Vec3>& intermediate, const Vec3& end) : intermediate_(intermediate), end_(end) {}
  std::size_t steps() const { return intermediate_.size() + 1; }
  Vec3 operator()(std::int64_t t) const {
    if (t == 0) return Vec3::Zero();
    const auto k = static_cast<std::size_t>(t);
    return k == steps() ? end_ : intermediate_[k - 1];
  }

 private:
  const std::vector<Vec3>& intermediate_;
  const Vec3& end_;
};

// The measurements whose feature has a place in `point`: those fit_leaf_poses() uses.
bool fitted(const LeafMeasurement& m, const LeafPoint& point) {
  const auto slot = static_cast<std::size_t>(m.feature);
  return slot < point.features.size() && point.features[slot].has_value();
}

}  // namespace

LeafLog seal_leaf_log(const LeafLog& log, const GaussianMap& map, const IdAliases& merged) {
  std::unordered_map<std::int64_t, std::int64_t> slot_of;
  for (Index k = 0; k < map.num_features(); ++k) slot_of[map.ids()[static_cast<std::size_t>(k)]] = k;
  LeafLog sealed;
  sealed.u = log.u;
  sealed.Q = log.Q;
  sealed.measurements.reserve(log.measurements.size());
  std::vector<bool> measured(static_cast<std::size_t>(map.num_features()), false);
  for (LeafMeasurement m : log.measurements) {
    const auto found = slot_of.find(follow_aliases(merged, m.feature));
    if (found == slot_of.end()) continue;  // a feature the local map removed
    m.feature = found->second;
    measured[static_cast<std::size_t>(m.feature)] = true;
    sealed.measurements.push_back(m);
  }
  for (std::size_t k = 0; k < measured.size(); ++k) {
    if (!measured[k]) {
      throw std::logic_error("seal_leaf_log: feature " + std::to_string(map.ids()[k]) + " of the local map has no measurement");
    }
  }
  return sealed;
}

LeafWeights leaf_weights(const LeafLog& log) {
  LeafWeights weights;
  weights.odometry.reserve(log.Q.size());
  for (const Mat3& Q : log.Q) weights.odometry.push_back(information<3>(Q));
  weights.measurements.reserve(log.measurements.size());
  for (const LeafMeasurement& m : log.measurements) weights.measurements.push_back(information<2>(m.R));
  return weights;
}

namespace {

// The normal equations of the intermediate poses at `pose` (block-tridiagonal: `diagonal`,
// `upper` between pose j and j+1, `gradient` = -J' W r), and the objective there.
double pose_normal_equations(const LeafLog& log, const LeafWeights& weights, const LeafPoint& point,
                             const LeafModel& model, const LeafPoses& pose, std::vector<Mat3>& diagonal,
                             std::vector<Mat3>& upper, std::vector<Vec3>& gradient) {
  const std::size_t s = log.u.size();
  const std::size_t L = diagonal.size();
  std::fill(diagonal.begin(), diagonal.end(), Mat3::Zero());
  std::fill(upper.begin(), upper.end(), Mat3::Zero());
  std::fill(gradient.begin(), gradient.end(), Vec3::Zero());
  double total = 0.0;
  // Odometry t joins poses t-1 and t; unknown pose t is slot t-1 (1 <= t <= s-1).
  for (std::size_t t = 1; t <= s; ++t) {
    Mat3 J_a, J_b;
    const Vec3 e = odometry_error(pose(static_cast<std::int64_t>(t) - 1), pose(static_cast<std::int64_t>(t)),
                                  log.u[t - 1], &J_a, &J_b);
    const Mat3& W = weights.odometry[t - 1];
    const Vec3 We = W * e;
    total += e.dot(We);
    const bool a_unknown = t >= 2, b_unknown = t <= L;
    if (a_unknown) {
      diagonal[t - 2] += J_a.transpose() * W * J_a;
      gradient[t - 2] -= J_a.transpose() * We;
    }
    if (b_unknown) {
      diagonal[t - 1] += J_b.transpose() * W * J_b;
      gradient[t - 1] -= J_b.transpose() * We;
    }
    if (a_unknown && b_unknown) upper[t - 2] += J_a.transpose() * W * J_b;
  }
  for (std::size_t i = 0; i < log.measurements.size(); ++i) {
    const LeafMeasurement& m = log.measurements[i];
    if (!fitted(m, point)) continue;
    const bool unknown = m.pose >= 1 && static_cast<std::size_t>(m.pose) <= L;
    Mat23 H;
    const Vec2 z_hat = observe(model.observation, model.sensor_offset, pose(m.pose),
                               *point.features[static_cast<std::size_t>(m.feature)], unknown ? &H : nullptr);
    const Vec2 nu = innovation(model.observation, m.z, z_hat);
    const Vec2 W_nu = weights.measurements[i] * nu;
    total += nu.dot(W_nu);
    if (!unknown) continue;
    const auto k = static_cast<std::size_t>(m.pose) - 1;
    diagonal[k] += H.transpose() * weights.measurements[i] * H;
    gradient[k] += H.transpose() * W_nu;
  }
  return total;
}

}  // namespace

double fit_leaf_poses(const LeafLog& log, const LeafWeights& weights, const LeafPoint& point, const LeafModel& model,
                      std::vector<Vec3>& poses) {
  const std::size_t s = log.u.size();
  const std::size_t L = s > 0 ? s - 1 : 0;  // unknown poses x_1..x_{s-1}
  if (poses.size() != L) {
    // Dead reckoning from the base, with its gap to the end spread in proportion to the steps.
    std::vector<Vec3> reckoned(s + 1, Vec3::Zero());
    for (std::size_t t = 0; t < s; ++t) reckoned[t + 1] = compose(reckoned[t], log.u[t]);
    const Vec3 gap = pose_difference(point.end, reckoned[s]);
    poses.resize(L);
    for (std::size_t t = 1; t <= L; ++t) {
      poses[t - 1] = reckoned[t] + (static_cast<double>(t) / static_cast<double>(s)) * gap;
    }
  }
  const LeafPoses pose(poses, point.end);
  std::vector<Mat3> diagonal(L), upper(L);
  std::vector<Vec3> gradient(L), delta(L);
  // Each evaluation builds the next step's equations with the objective: one sweep a step.
  double current = pose_normal_equations(log, weights, point, model, pose, diagonal, upper, gradient);
  double previous_step = 0.0;  // the largest move of the step before (0: none, or a halved one)
  for (int step = 0; step < kPoseSteps && L > 0; ++step) {
    // Block Thomas: eliminate forwards, substitute backwards.
    for (std::size_t j = 1; j < L; ++j) {
      const Mat3 factor = diagonal[j - 1].ldlt().solve(upper[j - 1]).transpose();
      diagonal[j] -= factor * upper[j - 1];
      gradient[j] -= factor * gradient[j - 1];
    }
    double largest = 0.0;
    for (std::size_t j = L; j-- > 0;) {
      const Vec3 rhs = j + 1 < L ? Vec3(gradient[j] - upper[j] * delta[j + 1]) : gradient[j];
      delta[j] = diagonal[j].ldlt().solve(rhs);
      largest = std::max(largest, delta[j].cwiseAbs().maxCoeff());
    }
    // Halved while it raises the objective (far from the fit only). A step below the
    // tolerance is taken as it is: there the objective changes by less than its rounding.
    const std::vector<Vec3> before = poses;
    const bool last = !(largest > kPoseTolerance);
    double scale = 1.0;
    bool lowered = false;
    for (int halving = 0; halving <= kPoseHalvings && !lowered; ++halving) {
      for (std::size_t j = 0; j < L; ++j) poses[j] = before[j] + scale * delta[j];
      const double value = pose_normal_equations(log, weights, point, model, pose, diagonal, upper, gradient);
      if (last || value <= current * (1.0 + 1e-12)) {
        current = value;
        lowered = true;
      } else {
        scale *= 0.5;
      }
    }
    if (!lowered) {
      poses = before;
      current = pose_normal_equations(log, weights, point, model, pose, diagonal, upper, gradient);
      break;
    }
    // The residuals are not zero, so Gauss–Newton converges linearly: each full step is about
    // ρ = step / previous step times the one before (ρ ~ 1e-2 on Victoria Park), and the fit
    // lies about step ρ / (1 - ρ) further on. Stopping there rather than after a step below
    // the tolerance saves the last sweep, ~1/7 of a fit.
    const double taken = scale * largest;
    const double ratio = previous_step > 0.0 && scale == 1.0 ? taken / previous_step : 1.0;
    if (last || !(taken > kPoseTolerance) || (ratio < 0.5 && taken * ratio / (1.0 - ratio) <= kPoseTolerance)) break;
    previous_step = scale == 1.0 ? taken : 0.0;
  }
  // A motion whose heading is known exactly (zero variance, uncorrelated) fixes the heading:
  // set from the pose before rather than fitted to the floor's precision (with a weight of
  // 1e12 the block elimination leaves ~1e-9 rad, and the rebuilt map depends on the heading to
  // first order).
  bool snapped = false;
  for (std::size_t t = 1; t <= L; ++t) {
    const Mat3& Q = log.Q[t - 1];
    if (Q(2, 2) != 0.0 || Q(0, 2) != 0.0 || Q(1, 2) != 0.0) continue;
    poses[t - 1].z() = pose(static_cast<std::int64_t>(t) - 1).z() + log.u[t - 1].z();
    snapped = true;
  }
  if (snapped) current = pose_normal_equations(log, weights, point, model, pose, diagonal, upper, gradient);
  return current;
}

GaussianMap rebuild_leaf(const GaussianMap& map, const LeafLog& log, const LeafPoint& point,
                         const std::vector<Vec3>& poses, const LeafModel& model,
                         double* innovation_distance_sq) {
  double distance_sq = 0.0;
  const Index p = map.num_features();
  const Index slots = p;
  if (static_cast<Index>(point.features.size()) != p || poses.size() + 1 != std::max<std::size_t>(log.u.size(), 1)) {
    throw std::logic_error("rebuild_leaf: the point does not fit the local map");
  }
  // Features enter the state in the order of their first sighting, as in the EKF, so that the
  // work is done on the part of the state that exists so far.
  std::vector<Index> position(static_cast<std::size_t>(slots), -1);
  std::vector<Vec2> linearised(static_cast<std::size_t>(slots));
  const Index n = GaussianMap::kRobotDim + GaussianMap::kFeatureDim * slots;
  Eigen::VectorXd y = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(n, n);
  Index active = GaussianMap::kRobotDim;
  const LeafPoses pose(poses, point.end);

  std::vector<std::size_t> paired;
  std::vector<Mat23> H_robot;
  std::vector<Mat2> H_feature;
  Eigen::MatrixXd PHt;
  Eigen::VectorXd nu;
  std::size_t next = 0;
  for (std::int64_t t = 0; t <= static_cast<std::int64_t>(log.u.size()); ++t) {
    const Vec3 x0 = pose(t);
    if (t > 0) {
      // u + ε = c0 + A δ_{t-1} + B δ_t (ε ~ N(0, Q)), so x_t = x0_t + B^-1 (u - c0 - A δ_{t-1} + ε).
      const Vec3 a = pose(t - 1);
      Mat3 A, B;
      const Vec3 e = odometry_error(a, x0, log.u[static_cast<std::size_t>(t) - 1], &A, &B);
      const Mat3 B_inverse = B.inverse();  // a rotation (and 1 on the heading)
      const Mat3 F = -B_inverse * A;
      const Vec3 previous = pose_difference(y.head<3>(), a);
      y.head<3>() = x0 - B_inverse * (e + A * previous);
      const Mat3 P_RR = F * P.topLeftCorner<3, 3>() * F.transpose() +
                        B_inverse * log.Q[static_cast<std::size_t>(t) - 1] * B_inverse.transpose();
      P.topLeftCorner<3, 3>() = 0.5 * (P_RR + P_RR.transpose());
      for (Index j = GaussianMap::kRobotDim; j < active; ++j) {
        const Vec3 column = F * P.block<3, 1>(0, j);
        P.block<3, 1>(0, j) = column;
        P.block<1, 3>(j, 0) = column.transpose();
      }
    }
    // This pose's measurements: those of features in the state in one joint update, then the
    // first sightings (any order gives the same linear-Gaussian posterior).
    const std::size_t first = next;
    while (next < log.measurements.size() && log.measurements[next].pose == t) ++next;
    if (next < log.measurements.size() && log.measurements[next].pose < t) {
      throw std::logic_error("rebuild_leaf: the log's measurements are not in step order");
    }
    // A feature the global map does not hold keeps its first sighting only: its later ones
    // are left out, as the batch problem leaves them out (seen once, as every such feature is
    // with min_sightings = 2, this is all the run had).
    paired.clear();
    for (std::size_t i = first; i < next; ++i) {
      const auto slot = static_cast<std::size_t>(log.measurements[i].feature);
      if (position[slot] >= 0 && point.features[slot].has_value()) paired.push_back(i);
    }
    const Vec3 robot_offset = pose_difference(y.head<3>(), x0);
    if (!paired.empty()) {
      const auto k = static_cast<Index>(paired.size());
      H_robot.resize(paired.size());
      H_feature.resize(paired.size());
      PHt.resize(active, 2 * k);
      nu.resize(2 * k);
      Eigen::MatrixXd S(2 * k, 2 * k);
      for (Index c = 0; c < k; ++c) {
        const LeafMeasurement& m = log.measurements[paired[static_cast<std::size_t>(c)]];
        const auto slot = static_cast<std::size_t>(m.feature);
        const Index offset = position[slot];
        Mat23& H_R = H_robot[static_cast<std::size_t>(c)];
        Mat2& H_f = H_feature[static_cast<std::size_t>(c)];
        const Vec2 z_hat = observe(model.observation, model.sensor_offset, x0, linearised[slot], &H_R, &H_f);
        nu.segment<2>(2 * c) = innovation(model.observation, m.z, z_hat) - H_R * robot_offset -
                               H_f * (y.segment<2>(offset) - linearised[slot]);
        PHt.middleCols<2>(2 * c).noalias() = P.topLeftCorner(active, 3) * H_R.transpose();
        PHt.middleCols<2>(2 * c).noalias() += P.block(0, offset, active, 2) * H_f.transpose();
      }
      for (Index c = 0; c < k; ++c) {
        const LeafMeasurement& m = log.measurements[paired[static_cast<std::size_t>(c)]];
        const Index offset = position[static_cast<std::size_t>(m.feature)];
        S.middleRows<2>(2 * c).noalias() = H_robot[static_cast<std::size_t>(c)] * PHt.topRows<3>();
        S.middleRows<2>(2 * c).noalias() += H_feature[static_cast<std::size_t>(c)] * PHt.middleRows<2>(offset);
        S.block<2, 2>(2 * c, 2 * c) += m.R;
      }
      Eigen::LLT<Eigen::MatrixXd> cholesky(S.selfadjointView<Eigen::Lower>());
      if (cholesky.info() != Eigen::Success) {
        throw std::runtime_error("rebuild_leaf: an innovation covariance that is not positive definite");
      }
      cholesky.matrixU().solveInPlace<Eigen::OnTheRight>(PHt);  // W = P H' L^-T
      cholesky.matrixL().solveInPlace(nu);
      distance_sq += nu.squaredNorm();
      y.head(active).noalias() += PHt * nu;
      auto P_active = P.topLeftCorner(active, active);
      P_active.selfadjointView<Eigen::Lower>().rankUpdate(PHt, -1.0);
      P_active.triangularView<Eigen::StrictlyUpper>() = P_active.transpose();
    }
    const Vec3 updated_offset = pose_difference(y.head<3>(), x0);
    for (std::size_t i = first; i < next; ++i) {
      const LeafMeasurement& m = log.measurements[i];
      const auto slot = static_cast<std::size_t>(m.feature);
      if (position[slot] >= 0) continue;
      // First sighting: f = f0 + H_f^-1 (z - h(x0, f0) - H_R δx - v), exact for the model
      // linearised at (x0, f0). A feature the global map does not hold is linearised where
      // this measurement puts it.
      linearised[slot] = point.features[slot].has_value()
                             ? *point.features[slot]
                             : inverse_observe(model.observation, model.sensor_offset, x0, m.z);
      Mat23 H_R;
      Mat2 H_f;
      const Vec2 z_hat = observe(model.observation, model.sensor_offset, x0, linearised[slot], &H_R, &H_f);
      const Mat2 H_f_inverse = H_f.inverse();
      const Mat23 G = -H_f_inverse * H_R;
      const Index offset = active;
      position[slot] = offset;
      active += GaussianMap::kFeatureDim;
      y.segment<2>(offset) = linearised[slot] + H_f_inverse * innovation(model.observation, m.z, z_hat) + G * updated_offset;
      const Eigen::MatrixXd cross = G * P.topLeftCorner(3, offset);
      P.block(offset, 0, 2, offset) = cross;
      P.block(0, offset, offset, 2) = cross.transpose();
      const Mat2 P_ff = G * P.topLeftCorner<3, 3>() * G.transpose() + H_f_inverse * m.R * H_f_inverse.transpose();
      P.block<2, 2>(offset, offset) = 0.5 * (P_ff + P_ff.transpose());
    }
  }
  // [end pose; the map's features in its order].
  GaussianMap rebuilt = GaussianMap::uninitialized(p);
  std::vector<Index> rows = {0, 1, 2};
  for (Index j = 0; j < p; ++j) {
    const Index offset = position[static_cast<std::size_t>(j)];
    if (offset < 0) throw std::logic_error("rebuild_leaf: a feature of the local map without a measurement");
    rows.push_back(offset);
    rows.push_back(offset + 1);
  }
  const auto dim = static_cast<Index>(rows.size());
  for (Index a = 0; a < dim; ++a) {
    rebuilt.x()(a) = y(rows[static_cast<std::size_t>(a)]);
    for (Index b = 0; b < dim; ++b) rebuilt.P()(a, b) = P(rows[static_cast<std::size_t>(a)], rows[static_cast<std::size_t>(b)]);
  }
  rebuilt.x()(2) = wrap_angle(rebuilt.x()(2));
  rebuilt.ids() = map.ids();
  if (innovation_distance_sq != nullptr) *innovation_distance_sq = distance_sq;
  return rebuilt;
}

}  // namespace dcslam
