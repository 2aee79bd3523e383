#pragma once
// Victoria Park (ACFR): the Ackermann vehicle model that turns the 40 Hz wheel odometry into
// one relative motion (u, Q) per laser scan, and the tree detections into range–bearing
// measurements of the trunk centres in the laser frame. The data and the choices made here
// are described in docs/victoria_park.md.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"
#include "dcslam/core/geometry.hpp"

namespace dcslam {

// ACFR's car (info.txt). The robot frame is the rear-axle centre, x forward, y left.
struct AckermannVehicle {
  double wheelbase = 2.83;       // L: front to rear axle [m]
  double encoder_lateral = 0.76;  // H: centreline to the rear-left wheel carrying the encoder [m]

  // Speed of the rear-axle centre from the rear-left wheel's speed: v / (1 - (H/L) tan alpha).
  double centre_speed(double encoder_speed, double steering) const;
  // Motion of the rear-axle frame over dt at constant encoder speed and steering, as a
  // relative pose (midpoint rule: the chord of the arc, at half the turn). J_inputs is
  // d(delta)/d(encoder_speed, steering).
  Vec3 motion(double encoder_speed, double steering, double dt,
              Eigen::Matrix<double, 3, 2>* J_inputs = nullptr) const;
};

enum class Steering { Raw, Recalibrated };
Steering parse_steering(const std::string& name, const char* field);
const char* to_string(Steering steering);

// ACFR's ASCII release recalibrated the steering: DRS ≈ 1.059·raw + 0.0026 rad
// (docs/victoria_park.md, "The data").
double recalibrated_steering(double raw_steering);

struct OdometryNoise {
  // White noise on the encoder speed [m/s] and steering [rad], as the standard deviation of
  // one 40 Hz sample; a segment of length dt gets variance sigma^2 * sample_period / dt.
  // The real errors are mostly systematic (slip, steering bias) and do not average out over
  // a scan as white noise would, hence values well above the sensors' resolution; chosen
  // with studies/vp_noise_study.py (docs/victoria_park.md).
  double sigma_speed = 0.6;
  double sigma_steering = 0.1;
  double sample_period = 0.025;
  // Additive floor per second of motion, in the robot frame: keeps Q positive definite when
  // the car stands still and covers what the two-input model leaves out (slip, wheel radius,
  // bumps). The xy value is set by the long-span join test of studies/vp_noise_study.py: errors
  // that persist over minutes, which white input noise underrates.
  double floor_sigma_xy = 0.14;   // m / sqrt(s)
  double floor_sigma_phi = 0.002;  // rad / sqrt(s)
};

// Bounds of the odometry file's fields: far beyond the car, and they keep the vehicle model
// finite (at the steering bound, 1 - (H/L) tan(alpha) is still above 0.5).
constexpr double kMaxSpeed = 100.0;   // |speed_mps| [m/s]
constexpr double kMaxSteering = 1.0;  // |steering_rad|, as logged [rad]

struct OdometrySample {
  double t;
  double encoder_speed;
  double steering;
};

// Integrates the zero-order-held odometry over [t_begin, t_end] into the relative motion of
// the rear-axle frame and its covariance. Samples are sorted by time; before the first sample
// the car is taken as standing still, after the last one the last sample is held.
void integrate_odometry(const AckermannVehicle& vehicle, const OdometryNoise& noise,
                        const std::vector<OdometrySample>& samples, double t_begin, double t_end,
                        Vec3& u, Mat3& Q);

struct VictoriaParkOptions {
  Steering steering = Steering::Recalibrated;
  OdometryNoise odometry;
  double max_range = 30.0;       // trees whose trunk centre is farther are dropped [m]
  // Per detection, set so that local maps averaging many correlated detections of one trunk
  // stay consistent with each other (docs/victoria_park.md).
  double sigma_range = 0.2;      // [m]
  double sigma_bearing = 0.016;  // [rad]
};

// File names inside a Victoria Park data folder.
struct VictoriaParkFiles {
  std::string odometry;  // vp_odometry.csv.gz: t_s, speed_mps, steering_rad
  std::string scans;     // vp_scans.csv.gz:    scan, t_s, n_trees
  std::string trees;     // vp_trees.csv.gz:    scan, t_s, range_m, bearing_rad, diameter_m
  std::string gps;       // vp_gps.csv.gz:      t_s, x_m, y_m
  static VictoriaParkFiles in_folder(const std::string& folder);
};

using RowMatrix3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using RowMatrix2 = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

// The whole run, one step per laser scan, in flat arrays (the Python layer views them).
struct VictoriaParkData {
  Eigen::VectorXd t;                      // (n,) scan times [s]
  RowMatrix3 u;                           // (n, 3) motion since the previous scan
  Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor> Q;  // (n, 9) row-major 3x3
  std::vector<std::int64_t> offsets;      // (n + 1): step k owns measurements [o_k, o_k+1)
  RowMatrix2 z;                           // (M, 2) range of the trunk centre, bearing
  Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> R;  // (M, 4) row-major 2x2
  Eigen::VectorXd diameters;              // (M,) trunk diameters [m]
  RowMatrix3 gps;                         // (k, 3) t, x, y as recorded
  std::int64_t detections_total = 0;      // in the tree file
  std::int64_t detections_beyond_range = 0;  // dropped by max_range
  Vec3 laser_offset{3.78, 0.5, 0.0};      // laser pose on the rear-axle frame
};

VictoriaParkData load_victoria_park(const VictoriaParkFiles& files,
                                    const VictoriaParkOptions& options);

// The filter options for the park, the one preset that the Python package
// (VictoriaPark.slam_config()) and dcslam_bench both start from: range–bearing from the laser at
// laser_offset, JCBB inside local maps, RJC at joins with the trunks' spread in
// join_feature_sigma, and gate_confidence at every join (docs/victoria_park.md); SlamConfig's
// defaults elsewhere.
SlamConfig victoria_park_slam_config(const Vec3& laser_offset);

}  // namespace dcslam
