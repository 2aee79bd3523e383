#pragma once
// Observation models of docs/design.md §2: a point feature seen from a sensor mounted at a fixed
// offset x_RS on the robot, either as range–bearing (r, beta) or as a Cartesian point (x, y)
// in the sensor frame. Each has its Jacobians and an inverse (feature initialisation).
#include <cstddef>
#include <vector>

#include "dcslam/core/geometry.hpp"

namespace dcslam {

enum class ObservationModel { RangeBearing, Point };

// Parses "range_bearing" | "point"; throws InvalidArgument naming `field` otherwise.
ObservationModel parse_observation_model(const std::string& name, const char* field);
const char* to_string(ObservationModel model);

// z = h(x_R, f): the measurement predicted for feature f (base frame) from robot pose x_R.
// J_robot = dh/dx_R (2x3), J_feature = dh/df (2x2).
Vec2 observe(ObservationModel model, const Vec3& sensor_offset, const Vec3& robot,
             const Vec2& feature, Mat23* J_robot = nullptr, Mat2* J_feature = nullptr);

// f = g(x_R, z): the feature position (base frame) implied by measurement z.
// J_robot = dg/dx_R (2x3), J_z = dg/dz (2x2).
Vec2 inverse_observe(ObservationModel model, const Vec3& sensor_offset, const Vec3& robot,
                     const Vec2& z, Mat23* J_robot = nullptr, Mat2* J_z = nullptr);

// z - z_hat, with the bearing component wrapped for range–bearing.
Vec2 innovation(ObservationModel model, const Vec2& z, const Vec2& z_hat);

// One scan's measurement noise as the filters use it: one symmetric 2x2 R per measurement.
// update() takes R as one matrix for the whole scan or one per measurement, each symmetric to
// a relative tolerance (check_measurements()). A ScanNoise decodes that rule and takes the
// symmetric parts once, where EkfSlam::update() begins, so that nothing after it (association,
// the update, new features) decodes or symmetrises R again and P stays exactly symmetric.
class ScanNoise {
 public:
  ScanNoise() = default;
  // R: 1 or `measurements` matrices, as check_measurements() accepts them.
  ScanNoise(const std::vector<Mat2>& R, std::size_t measurements) { assign(R, measurements); }
  void assign(const std::vector<Mat2>& R, std::size_t measurements);
  const Mat2& operator[](std::size_t measurement) const { return noise_[measurement]; }

 private:
  std::vector<Mat2> noise_;  // kept between scans, so that it only allocates while it grows
};

}  // namespace dcslam
