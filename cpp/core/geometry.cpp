#include "dcslam/core/geometry.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/LU>

namespace dcslam {

double wrap_angle(double angle) {
  constexpr double kPi = 3.14159265358979323846;
  // Most angles are already wrapped; std::remainder costs a rounding-mode switch.
  if (angle > -kPi && angle <= kPi) return angle;
  double wrapped = std::remainder(angle, 2.0 * kPi);  // in [-pi, pi]
  if (wrapped <= -kPi) wrapped += 2.0 * kPi;
  return wrapped;
}

Vec3 compose(const Vec3& a, const Vec3& b, Mat3* J_a, Mat3* J_b) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  const double dx = c * b.x() - s * b.y();
  const double dy = s * b.x() + c * b.y();
  if (J_a) *J_a << 1, 0, -dy, 0, 1, dx, 0, 0, 1;
  if (J_b) *J_b << c, -s, 0, s, c, 0, 0, 0, 1;
  return {a.x() + dx, a.y() + dy, wrap_angle(a.z() + b.z())};
}

Vec3 invert(const Vec3& a, Mat3* J_a) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  const double x = -c * a.x() - s * a.y();
  const double y = s * a.x() - c * a.y();
  if (J_a) *J_a << -c, -s, y, s, -c, -x, 0, 0, -1;
  return {x, y, wrap_angle(-a.z())};
}

Vec2 transform_point(const Vec3& a, const Vec2& p, Mat23* J_a, Mat2* J_p) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  const double dx = c * p.x() - s * p.y();
  const double dy = s * p.x() + c * p.y();
  if (J_a) *J_a << 1, 0, -dy, 0, 1, dx;
  if (J_p) *J_p << c, -s, s, c;
  return {a.x() + dx, a.y() + dy};
}

Vec2 inverse_transform_point(const Vec3& a, const Vec2& p, Mat23* J_a, Mat2* J_p) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  const double ex = p.x() - a.x(), ey = p.y() - a.y();
  const double qx = c * ex + s * ey;
  const double qy = -s * ex + c * ey;
  if (J_a) *J_a << -c, -s, qy, s, -c, -qx;
  if (J_p) *J_p << c, s, -s, c;
  return {qx, qy};
}

double largest_std(const Mat2& covariance) {
  const double half_trace = 0.5 * covariance.trace();
  const double det = covariance.determinant();
  return std::sqrt(std::max(0.0, half_trace + std::sqrt(std::max(0.0, half_trace * half_trace - det))));
}

}  // namespace dcslam
