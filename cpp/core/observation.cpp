#include "dcslam/core/observation.hpp"

#include <cmath>
#include <string>

#include "dcslam/core/errors.hpp"

namespace dcslam {

ObservationModel parse_observation_model(const std::string& name, const char* field) {
  if (name == "range_bearing") return ObservationModel::RangeBearing;
  if (name == "point") return ObservationModel::Point;
  throw InvalidArgument(std::string(field) + ": unknown observation model '" + name +
                        "' (expected 'range_bearing' or 'point')");
}

const char* to_string(ObservationModel model) {
  return model == ObservationModel::RangeBearing ? "range_bearing" : "point";
}

Vec2 observe(ObservationModel model, const Vec3& sensor_offset, const Vec3& robot,
             const Vec2& feature, Mat23* J_robot, Mat2* J_feature) {
  Mat3 J_sensor_robot;
  const Vec3 sensor = compose(robot, sensor_offset, J_robot ? &J_sensor_robot : nullptr);
  Mat23 J_q_sensor;
  Mat2 J_q_feature;
  const Vec2 q = inverse_transform_point(sensor, feature, &J_q_sensor, &J_q_feature);
  Mat2 J_z_q = Mat2::Identity();
  Vec2 z = q;
  if (model == ObservationModel::RangeBearing) {
    const double r2 = q.squaredNorm();
    const double r = std::sqrt(r2);
    z << r, std::atan2(q.y(), q.x());
    J_z_q << q.x() / r, q.y() / r, -q.y() / r2, q.x() / r2;
  }
  if (J_robot) *J_robot = J_z_q * J_q_sensor * J_sensor_robot;
  if (J_feature) *J_feature = J_z_q * J_q_feature;
  return z;
}

Vec2 inverse_observe(ObservationModel model, const Vec3& sensor_offset, const Vec3& robot,
                     const Vec2& z, Mat23* J_robot, Mat2* J_z) {
  Mat3 J_sensor_robot;
  const Vec3 sensor = compose(robot, sensor_offset, J_robot ? &J_sensor_robot : nullptr);
  Vec2 q = z;
  Mat2 J_q_z = Mat2::Identity();
  if (model == ObservationModel::RangeBearing) {
    const double c = std::cos(z.y()), s = std::sin(z.y());
    q << z.x() * c, z.x() * s;
    J_q_z << c, -z.x() * s, s, z.x() * c;
  }
  Mat23 J_f_sensor;
  Mat2 J_f_q;
  const Vec2 f = transform_point(sensor, q, &J_f_sensor, &J_f_q);
  if (J_robot) *J_robot = J_f_sensor * J_sensor_robot;
  if (J_z) *J_z = J_f_q * J_q_z;
  return f;
}

Vec2 innovation(ObservationModel model, const Vec2& z, const Vec2& z_hat) {
  Vec2 nu = z - z_hat;
  if (model == ObservationModel::RangeBearing) nu.y() = wrap_angle(nu.y());
  return nu;
}

void ScanNoise::assign(const std::vector<Mat2>& R, std::size_t measurements) {
  noise_.resize(measurements);
  for (std::size_t i = 0; i < measurements; ++i) {
    const Mat2& Ri = R.size() == 1 ? R[0] : R[i];
    noise_[i] = 0.5 * (Ri + Ri.transpose());
  }
}

}  // namespace dcslam
