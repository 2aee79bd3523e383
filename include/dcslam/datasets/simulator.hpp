#pragma once
// The simulated experiments of Paz et al. 2007 (§III.B, Fig. 3; docs/design.md §7): a uniform
// random field of point features, a robot that moves 1 m a step along one of four
// trajectories (straight, square loop, lawn mowing, snail), noisy odometry and a noisy
// range–bearing (or Cartesian point) sensor, with ground truth for poses, features and the
// feature behind every measurement.
//
// Noise model. The true trajectory follows the commanded motions exactly; the reported
// odometry is u = u_true + n, n ~ N(0, Q), Q = diag(odometry_sigma^2) (independent along,
// across and heading). A measurement is z = observe(true pose, true feature) + v,
// v ~ N(0, R); for range–bearing R = diag((range_sigma_fraction * r)^2, bearing_sigma^2)
// where r is the TRUE range (so R does not leak the noise), for points R = point_sigma^2 I.
//
// Reproducibility: every draw comes from one std::mt19937_64 seeded with `seed`, through
// samplers written here (not the std:: distributions, whose output differs between standard
// libraries), so a seed gives the same simulation on every platform up to libm rounding.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/geometry.hpp"
#include "dcslam/core/observation.hpp"

namespace dcslam {

enum class Trajectory { Straight, Loop, LoopBothWays, LawnMowing, Snail };

// Parses "straight" | "loop" | "lawn_mowing" | "snail"; throws InvalidArgument naming
// `field` otherwise.
Trajectory parse_trajectory(const std::string& name, const char* field);
const char* to_string(Trajectory trajectory);

struct SimulationConfig {
  Trajectory trajectory = Trajectory::Straight;
  int steps = 500;
  std::uint64_t seed = 0;

  // Motion. Every step moves step_length forward; turns of ±90° happen at the end of a step.
  double step_length = 1.0;
  // Shapes, in steps. side_steps: the loop's side, the lawn's lane length, the snail's outer
  // side; unset = chosen from `steps` so the shape fits them (see simulate()).
  std::optional<int> side_steps;
  // Distance between parallel passes (lawn lanes, snail rings), in steps. The default, 3 m,
  // equals the sensor range, so neighbouring passes share features.
  int lane_spacing_steps = 3;

  // Odometry noise (along, across, heading), standard deviations in m, m, rad.
  Vec3 odometry_sigma{0.10, 0.05, 0.5 * 3.14159265358979323846 / 180.0};
  // Forces the heading sigma to zero: known headings make the problem linear with "point"
  // observations, where D&C must equal the EKF exactly (docs/design.md §4.7).
  bool zero_heading_noise = false;

  // Sensor.
  ObservationModel observation = ObservationModel::RangeBearing;
  Vec3 sensor_offset = Vec3::Zero();
  double max_range = 3.0;
  // Blind zone: features closer than this are not detected. Without it a feature at r ~ 0
  // would get a singular R (range sigma proportional to r) and an undefined bearing.
  double min_range = 0.1;
  double fov = 2.0 * 3.14159265358979323846;  // full angle, centred on the sensor's x axis
  double range_sigma_fraction = 0.05;         // sigma_r = fraction * true range
  double bearing_sigma = 3.14159265358979323846 / 180.0;
  double point_sigma = 0.05;  // isotropic sigma (m) of the "point" model

  // World. The density makes features_per_step features fall in the sensor's footprint on
  // average; num_features, when set, fixes the count instead (the density follows).
  double features_per_step = 16.0;
  std::optional<std::int64_t> num_features;
  // Features cover the points within this distance of the trajectory's positions (a
  // corridor, not the bounding box: a loop's unseen interior stays empty); unset =
  // max_range + |sensor offset|, so every footprint lies inside the field.
  std::optional<double> world_margin;

  // Expected fraction of all measurements that are spurious, in [0, 1). Spurious
  // measurements are uniform over the sensor's footprint (range and field of view).
  double clutter = 0.0;

  // Throws InvalidArgument naming the first parameter that is out of range.
  void validate() const;
  // Area (m^2) of the sensor's footprint: the annular sector of angle fov between min_range
  // and max_range.
  double footprint_area() const;
};

// A whole simulated run, in bulk arrays (row-major so that numpy views them without a copy).
// Step k goes from poses[k] to poses[k + 1]: predict with odometry[k], then update with the
// measurements taken at poses[k + 1], rows [step_offsets[k], step_offsets[k + 1]).
struct Simulation {
  template <int Cols>
  using Rows = Eigen::Matrix<double, Eigen::Dynamic, Cols, Eigen::RowMajor>;

  SimulationConfig config;
  Rows<2> landmarks;                        // (N, 2) ground truth
  Rows<3> poses;                            // (steps + 1, 3) ground truth, poses[0] = 0
  Rows<3> odometry;                         // (steps, 3) noisy u
  Mat3 odometry_covariance;                 // Q, the same at every step
  Rows<2> measurements;                     // (M, 2) all steps, concatenated
  Rows<4> measurement_covariances;          // (M, 4): each row a row-major 2x2 R
  std::vector<std::int64_t> true_ids;       // (M) landmark row, -1 for clutter
  std::vector<std::int64_t> step_offsets;   // (steps + 1)
};

// Runs the simulation described by `config` (validated first). Trajectories, with s the side:
//  - straight: forward along x;
//  - loop: a square of side s = steps / 4 turning left, back at the start after 4 s steps
//    (more steps run further laps);
//  - loop_both_ways: the square (side s = steps / 8 unless set) once turning left, a U-turn
//    at the start, once back turning right, a U-turn, and again;
//  - lawn_mowing: lanes of s steps along ±x joined by lane_spacing_steps along +y, with s
//    ~ sqrt(steps * spacing) so the swept region is roughly square;
//  - snail: an inward square spiral turning left with sides s, s, s, s - d, s - d, s - 2d,
//    s - 2d, ... (d the spacing), s the smallest side whose spiral has at least `steps`.
Simulation simulate(const SimulationConfig& config);

}  // namespace dcslam
