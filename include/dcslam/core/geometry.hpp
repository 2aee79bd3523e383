#pragma once
// 2D geometry of docs/design.md §2: pose compounding (⊕), inversion (⊖), pose ⊕ point and
// angle wrapping, each with analytic Jacobians (optional outputs: pass nullptr to skip them).
// Poses are (x, y, phi), angles in radians wrapped to (-pi, pi].
#include <Eigen/Core>

namespace dcslam {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Mat2 = Eigen::Matrix2d;
using Mat3 = Eigen::Matrix3d;
using Mat23 = Eigen::Matrix<double, 2, 3>;

// Wraps an angle to (-pi, pi].
double wrap_angle(double angle);

// a ⊕ b. J_a = d(a⊕b)/da, J_b = d(a⊕b)/db.
Vec3 compose(const Vec3& a, const Vec3& b, Mat3* J_a = nullptr, Mat3* J_b = nullptr);

// ⊖a, so that a ⊕ (⊖a) = 0. J_a = d(⊖a)/da.
Vec3 invert(const Vec3& a, Mat3* J_a = nullptr);

// a ⊕ p for a point p: p expressed in the frame of a, returned in a's parent frame.
Vec2 transform_point(const Vec3& a, const Vec2& p, Mat23* J_a = nullptr, Mat2* J_p = nullptr);

// (⊖a) ⊕ p: a point p of a's parent frame expressed in the frame of a.
Vec2 inverse_transform_point(const Vec3& a, const Vec2& p, Mat23* J_a = nullptr,
                             Mat2* J_p = nullptr);

// Square root of the largest eigenvalue of a 2x2 covariance: the largest standard deviation
// along any direction (bounds |x| <= c * sigma for the gate c of a Mahalanobis test).
double largest_std(const Mat2& covariance);

}  // namespace dcslam
