#pragma once
// The stacked map of a join (docs/design.md §4.1, §4.2) seen without building it: m1 as it is
// and m2 moved into m1's base B1 by x_{B1 R1} ⊕ ·, linearised at a chosen point.
#include <cstdint>

#include <Eigen/Core>

#include "dcslam/core/blocked_cholesky.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"

namespace dcslam {

// Row of x_{B1 R1} ⊕ p's Jacobian w.r.t. x_{B1 R1}, for a point p of m2 (rotated: Rp).
inline Eigen::Matrix<double, 2, 3> point_jacobian(const Vec2& rotated) {
  Eigen::Matrix<double, 2, 3> J;
  J << 1, 0, -rotated.y(), 0, 1, rotated.x();
  return J;
}

// The next panel of the factorisation of S, the covariance of matched-pair constraints (its
// blocks are constraint_covariance()'s); throws std::runtime_error when S is not positive
// definite.
std::int64_t factor_constraint_panel(ResumableCholesky& cholesky);

// Covariance blocks of the stacked map [R1; F1; Q1; R2'; F2'; Q2'] (m2 moved into B1 by
// x_{B1 R1} ⊕ ·), computed on demand in O(1) each, without building the stacked matrix.
// Feature indices are local: i indexes m1's features, j indexes m2's.
//
// ⊕ is linearised at a point x* = (R1*, m2*), by default the prior means. The moved means
// are then the linearised values g(x*) + G*(x0 - x*), which with x* = x0 are g(x0).
class JoinFrame {
 public:
  JoinFrame(const GaussianMap& first, const GaussianMap& second);
  // Linearised at R1 = first_robot and m2's state vector = second_x (sized as second.x()).
  JoinFrame(const GaussianMap& first, const GaussianMap& second, const Vec3& first_robot,
            const Eigen::VectorXd& second_x);

  const GaussianMap& first() const { return first_; }
  const GaussianMap& second() const { return second_; }

  Vec2 first_feature(Eigen::Index i) const { return first_.feature(i); }
  // m2's feature j, robot, and the pose at state offset `offset` (0: the robot; or a past
  // pose's pose_offset) moved into B1 (the linearised values above).
  Vec2 moved_second_feature(Eigen::Index j) const;
  Vec3 moved_second_robot() const { return moved_second_pose(0); }
  Vec3 moved_second_pose(Eigen::Index offset) const;

  // cov(f_i, f_k), cov(f_i, f'_j), cov(f'_j, f'_l) of the stacked map.
  Mat2 first_first(Eigen::Index i, Eigen::Index k) const;
  Mat2 first_second(Eigen::Index i, Eigen::Index j) const;
  Mat2 second_second(Eigen::Index j, Eigen::Index l) const;

  // cov(h_a, h_b) for the constraints h_a = f_i - f'_j and h_b = f_k - f'_l.
  Mat2 constraint_covariance(Eigen::Index i, Eigen::Index j, Eigen::Index k,
                             Eigen::Index l) const;
  // The same blocks along one column (i, j) of S, cov(h_(k,l), h_(i,j)) for many (k, l): what
  // depends on (i, j) alone is computed once, and P's blocks are read in the columns of i and j
  // (P is symmetric), which a run over (k, l) reads in order, not one scattered pair of
  // columns a block. 40 multiply-adds a block instead of 70.
  struct ConstraintColumn {
    Eigen::Index i = 0, j = 0;
    Eigen::Matrix<double, 3, 2> jacobian_j;  // J_j'
    Eigen::Matrix<double, 3, 2> robot_terms;  // P_RR J_j' - P1[R, i]
  };
  ConstraintColumn constraint_column(Eigen::Index i, Eigen::Index j) const;
  Mat2 constraint_covariance(const ConstraintColumn& column, Eigen::Index k, Eigen::Index l) const;

  // J_R: d(x_{B1 R1} ⊕ e)/d x_{B1 R1} for every element e of m2, stacked (d2 x 3).
  const Eigen::Matrix<double, Eigen::Dynamic, 3>& jacobian_first_robot() const { return J_R_; }
  // The rotation of R1: d(x_{B1 R1} ⊕ p)/dp for a point p.
  const Mat2& rotation() const { return rotation_; }

 private:
  Vec2 linearisation_offset(const Vec2& p0, const Vec2& p_lin) const;

  const GaussianMap& first_;
  const GaussianMap& second_;
  Vec3 T_;  // x_{B1 R1} at the linearisation point
  Eigen::VectorXd second_x_;  // m2's state at the linearisation point
  Mat2 rotation_;
  Eigen::Matrix<double, Eigen::Dynamic, 3> J_R_;
};

}  // namespace dcslam
