#include "dcslam/joining/join_frame.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include "dcslam/core/blocked_cholesky.hpp"
#include "dcslam/core/errors.hpp"

namespace dcslam {

using Index = Eigen::Index;

std::int64_t factor_constraint_panel(ResumableCholesky& cholesky) {
  const std::int64_t work = cholesky.step(1);
  if (cholesky.failed()) {
    throw std::runtime_error(
        "map join: the covariance of the matched-pair constraints is not positive definite "
        "(two matched features are perfectly correlated)");
  }
  return work;
}

JoinFrame::JoinFrame(const GaussianMap& first, const GaussianMap& second)
    : JoinFrame(first, second, first.robot(), second.x()) {}

JoinFrame::JoinFrame(const GaussianMap& first, const GaussianMap& second,
                     const Vec3& first_robot, const Eigen::VectorXd& second_x)
    : first_(first), second_(second), T_(first_robot), second_x_(second_x) {
  if (second_x_.size() != second.dim()) {
    throw InvalidArgument("JoinFrame: the linearisation point of m2 has " +
                          std::to_string(second_x_.size()) + " entries, m2 has " +
                          std::to_string(second.dim()));
  }
  const double c = std::cos(T_.z()), s = std::sin(T_.z());
  rotation_ << c, -s, s, c;
  J_R_.resize(second.dim(), 3);
  const auto pose_rows = [&](Index offset) {
    J_R_.middleRows<3>(offset) << point_jacobian(rotation_ * second_x_.segment<2>(offset)), 0, 0, 1;
  };
  pose_rows(0);
  for (Index j = 0; j < second.num_features(); ++j) {
    J_R_.middleRows<2>(GaussianMap::feature_offset(j)) =
        point_jacobian(rotation_ * second_x_.segment<2>(GaussianMap::feature_offset(j)));
  }
  for (Index q = 0; q < second.num_poses(); ++q) pose_rows(second.pose_offset(q));
}

// G*(x0 - x*) for an element p of m2 (prior mean p0, linearised at p_lin):
// J_R (R1_0 - R1*) + Rot* (p0 - p_lin). Exactly zero at x* = x0, so the one-shot join's moved
// means come out unchanged.
Vec2 JoinFrame::linearisation_offset(const Vec2& p0, const Vec2& p_lin) const {
  const Vec2 rotated = rotation_ * p_lin;
  const Vec3 robot_offset = first_.robot() - T_;
  return robot_offset.head<2>() + Vec2(-rotated.y(), rotated.x()) * robot_offset.z() +
         rotation_ * (p0 - p_lin);
}

Vec2 JoinFrame::moved_second_feature(Index j) const {
  const Vec2 p_lin = second_x_.segment<2>(GaussianMap::feature_offset(j));
  return T_.head<2>() + rotation_ * p_lin + linearisation_offset(second_.feature(j), p_lin);
}

// The heading is linear in the headings: the result is their prior sum, wrapped only at the
// linearisation point (the caller wraps the final value).
Vec3 JoinFrame::moved_second_pose(Index offset) const {
  const Vec3 pose_lin = second_x_.segment<3>(offset);
  const Vec3 pose0 = second_.x().segment<3>(offset);
  Vec3 moved = compose(T_, pose_lin);
  moved.head<2>() += linearisation_offset(pose0.head<2>(), pose_lin.head<2>());
  moved.z() += (first_.robot().z() - T_.z()) + (pose0.z() - pose_lin.z());
  return moved;
}

Mat2 JoinFrame::first_first(Index i, Index k) const {
  return first_.P().block<2, 2>(GaussianMap::feature_offset(i), GaussianMap::feature_offset(k));
}

Mat2 JoinFrame::first_second(Index i, Index j) const {
  return first_.P().block<2, 3>(GaussianMap::feature_offset(i), 0) *
         J_R_.middleRows<2>(GaussianMap::feature_offset(j)).transpose();
}

Mat2 JoinFrame::second_second(Index j, Index l) const {
  const Index oj = GaussianMap::feature_offset(j), ol = GaussianMap::feature_offset(l);
  return J_R_.middleRows<2>(oj) * first_.P().topLeftCorner<3, 3>() *
             J_R_.middleRows<2>(ol).transpose() +
         rotation_ * second_.P().block<2, 2>(oj, ol) * rotation_.transpose();
}

Mat2 JoinFrame::constraint_covariance(Index i, Index j, Index k, Index l) const {
  return first_first(i, k) - first_second(i, l) - first_second(k, j).transpose() +
         second_second(j, l);
}

// cov(h_(k,l), h_(i,j)) = P1[k,i] - P1[k,R] J_j' - J_l P1[R,i] + J_l P_RR J_j' + Rot P2[l,j] Rot'.
JoinFrame::ConstraintColumn JoinFrame::constraint_column(Index i, Index j) const {
  ConstraintColumn column;
  column.i = i;
  column.j = j;
  column.jacobian_j = J_R_.middleRows<2>(GaussianMap::feature_offset(j)).transpose();
  column.robot_terms = first_.P().topLeftCorner<3, 3>() * column.jacobian_j -
                       first_.P().block<3, 2>(0, GaussianMap::feature_offset(i));
  return column;
}

Mat2 JoinFrame::constraint_covariance(const ConstraintColumn& column, Index k, Index l) const {
  const Index ok = GaussianMap::feature_offset(k), ol = GaussianMap::feature_offset(l);
  const Mat2 second = second_.P().block<2, 2>(ol, GaussianMap::feature_offset(column.j));
  return first_.P().block<2, 2>(ok, GaussianMap::feature_offset(column.i)) -
         first_.P().block<2, 3>(ok, 0) * column.jacobian_j + J_R_.middleRows<2>(ol) * column.robot_terms +
         rotation_ * second * rotation_.transpose();
}

}  // namespace dcslam
