#pragma once
// Central-difference Jacobians: the independent oracle for every analytic Jacobian.
#include <functional>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/geometry.hpp"

namespace dcslam::testing {

// d f / d x by central differences. Rows listed in `angle_rows` are angles: their
// differences are wrapped so that a value near ±pi does not jump by 2 pi.
inline Eigen::MatrixXd numeric_jacobian(
    const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& x,
    const std::vector<int>& angle_rows = {}, double eps = 1e-6) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    Eigen::VectorXd plus = x, minus = x;
    plus(i) += eps;
    minus(i) -= eps;
    Eigen::VectorXd diff = f(plus) - f(minus);
    for (int r : angle_rows) diff(r) = wrap_angle(diff(r));
    J.col(i) = diff / (2 * eps);
  }
  return J;
}

}  // namespace dcslam::testing
