#include "dcslam/joining/join_relinearisation.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#include <utility>

#include <Eigen/LU>

#include "dcslam/joining/join_cost.hpp"
#include "dcslam/joining/join_frame.hpp"

namespace dcslam {

using Index = Eigen::Index;

// The iterated EKF with noise-free constraints c(x) = f_i - (R1 ⊕ f_j) = 0, i.e. Gauss–Newton
// on the constrained MAP: x+ = x0 + P0 H' λ, λ = (H P0 H')^-1 (-c(x) - H (x0 - x)), H = dc/dx
// at x. Only s enters c, so the steps are taken in s with its prior covariance P_ss (blocks of
// P1 and P2); m2's other elements then follow as x0 + P0 H' λ with the last λ, O(n r). The
// pipeline takes the final step itself, linearised at the point found here. Each step is
// split into bounded units (amortized D&C spreads them over frames); begin, units, finish.
void JoinRelinearisation::begin(const GaussianMap& first, const GaussianMap& second,
                                const Pairs& pairs, const JoinOptions& options) {
  first_ = &first;
  second_ = &second;
  pairs_ = &pairs;
  work_unit_ = options.work_unit;
  block_columns_ = options.block_columns;
  max_iterations_ = options.max_iterations;
  first_robot_ = options.linearisation ? options.linearisation->first_robot : first.robot();
  second_x_ = options.linearisation ? options.linearisation->second_x : second.x();
  const Index r = static_cast<Index>(pairs.size());
  iterations_ = r > 0 ? 1 : 0;
  state_.steps = 0;
  state_.converged = r == 0 || options.max_iterations == 1 || options.linearisation != nullptr;
  if (state_.converged) return;

  const Index ds = 3 + 4 * r;
  std::vector<Index>& rows1 = state_.first_rows;
  std::vector<Index>& rows2 = state_.second_rows;
  rows1 = {0, 1, 2};
  rows2.clear();
  for (const auto& [i, j] : *pairs_) {
    rows1.push_back(GaussianMap::feature_offset(i));
    rows1.push_back(GaussianMap::feature_offset(i) + 1);
    rows2.push_back(GaussianMap::feature_offset(j));
    rows2.push_back(GaussianMap::feature_offset(j) + 1);
  }
  state_.prior.resize(ds);
  state_.covariance.resize(ds, ds);
  state_.gathered = 0;
  state_.next_build = 0;
  state_.factor_built = false;
}

// One unit of the re-linearisation: first s0 and P_ss gathered a block of columns at a time
// (P_ss is 2r + 3 rows of m1 and 2r of m2, zero between them); then per Gauss–Newton step H at
// the current point and P_ss H' a few pairs at a time, S = H P_ss H' and the right-hand side a
// few pairs at a time; then S's Cholesky factor a panel at a time; then λ and the next point.
// The blocks depend only on r and the work unit, so slicing never changes the result.
std::int64_t JoinRelinearisation::unit() {
  State& gn = state_;
  const Index r = static_cast<Index>(pairs_->size());
  const Index ds = 3 + 4 * r, second_begin = 3 + 2 * r;
  const Eigen::VectorXd& s0 = gn.prior;
  Eigen::MatrixXd& P_ss = gn.covariance;
  Eigen::VectorXd& s = gn.point;
  // Pair k's rows of H (-J_R on R1, I on f_i, -Rot on f_j, at this step's point) times X, any
  // matrix or vector indexed like s: the right-hand side, S = H (P_ss H') and Newton's H P U.
  const auto H_rows = [&](Index k, const auto& X) {
    Eigen::Matrix<double, 2, std::decay_t<decltype(X)>::ColsAtCompileTime> rows =
        X.template middleRows<2>(3 + 2 * k);
    rows.noalias() -= gn.robot_jacobians[static_cast<std::size_t>(k)] * X.template topRows<3>();
    rows.noalias() -= gn.rotation * X.template middleRows<2>(second_begin + 2 * k);
    return rows;
  };
  if (gn.gathered < ds) {
    const Index columns = join_cost::gather_columns_per_unit(work_unit_, ds);
    const Index begin = gn.gathered, end = std::min(ds, begin + columns);
    for (Index b = begin; b < end; ++b) {  // column by column: both are column-major
      const bool second = b >= second_begin;
      const GaussianMap& map = second ? *second_ : *first_;
      const std::vector<Index>& rows = second ? gn.second_rows : gn.first_rows;
      const Index at = second ? second_begin : 0;
      const Index row = rows[static_cast<std::size_t>(b - at)];
      gn.prior(b) = map.x()(row);
      const auto source = map.P().col(row);
      auto column = P_ss.col(b);
      column.setZero();
      for (Index a = 0; a < static_cast<Index>(rows.size()); ++a) {
        column(at + a) = source(rows[static_cast<std::size_t>(a)]);
      }
    }
    gn.gathered = end;
    if (gn.gathered == ds) {
      // Converged when no coordinate moves by more than 1e-9 of its prior standard deviation
      // (or, for one known almost exactly, a few ulps of its value).
      gn.tolerance = 1e-9 * P_ss.diagonal().array().sqrt() + 1e-14 * s0.array().abs();
      gn.point = s0;
      gn.dual.setZero(ds);
    }
    return join_cost::gather(end - begin, ds);
  }
  if (!gn.factor_built) {
    Eigen::MatrixXd& PHt = gn.gain;
    Eigen::MatrixXd& S = gn.factor;
    const Index pairs_per_unit = join_cost::relinearise_pairs_per_unit(work_unit_, ds, r);
    Mat2& rotation = gn.rotation;
    if (gn.next_build == 0) {
      PHt.resize(ds, 2 * r);
      S.resize(2 * r, 2 * r);
      gn.rhs.resize(2 * r);
      gn.robot_jacobians.resize(static_cast<std::size_t>(r));
      const double c = std::cos(s(2)), sn = std::sin(s(2));
      rotation << c, -sn, sn, c;
    }
    const Index begin = gn.next_build;
    if (begin < r) {
      const Index end = std::min(r, begin + pairs_per_unit);
      for (Index k = begin; k < end; ++k) {
        const Vec2 rotated = rotation * s.segment<2>(second_begin + 2 * k);
        auto& J = gn.robot_jacobians[static_cast<std::size_t>(k)];
        J = point_jacobian(rotated);
        const Vec2 constraint = s.segment<2>(3 + 2 * k) - s.head<2>() - rotated;
        gn.rhs.segment<2>(2 * k) = -constraint - H_rows(k, s0 - s);
        // P_ss is block diagonal (m1's rows, then m2's): only the non-zero blocks are read.
        auto columns = PHt.middleCols<2>(2 * k);
        auto first = columns.topRows(second_begin);
        first.noalias() = P_ss.block(0, 3 + 2 * k, second_begin, 2);
        first.noalias() -= P_ss.topLeftCorner(second_begin, 3) * J.transpose();
        columns.bottomRows(2 * r).noalias() =
            -P_ss.block(second_begin, second_begin + 2 * k, 2 * r, 2) * rotation.transpose();
      }
      gn.next_build = end;
      return join_cost::gain_columns(end - begin, ds);
    }
    // S's lower triangle (all the factor reads), a few of its pair columns per unit: column by
    // column, the reads of P_ss H' are contiguous (row by row they were a cache miss each).
    const Index end = std::min(2 * r, begin + pairs_per_unit);
    std::int64_t work = 0;
    for (Index k = begin - r; k < end - r; ++k) {
      const auto column = PHt.middleCols<2>(2 * k);
      for (Index l = k; l < r; ++l) S.block<2, 2>(2 * l, 2 * k) = H_rows(l, column);
      work += join_cost::factor_column(k, r);
    }
    gn.next_build = end;
    if (end == 2 * r) {
      gn.next_build = 0;
      gn.factor_built = true;
      gn.cholesky = ResumableCholesky(std::move(gn.factor), block_columns_);
    }
    return std::max<std::int64_t>(1, work);
  }
  if (!gn.cholesky.done()) return factor_constraint_panel(gn.cholesky);
  // The Gauss–Newton step, and Newton's (docs/divide_and_conquer.md): with the last step's
  // multipliers the Lagrangian's curvature Σ λ_k ∇²c_k is U B U', U = [e_θ, a] (a: -Rot_θ' λ_k
  // on each f_j, Rot_θ = dRot/dθ), B = [h 1; 1 0] (h = Σ λ_k' Rot f_j). M = P^-1 - U B U' has
  // M^-1 = P + P U K U'P with K^-1 = B^-1 - U'P U, and Newton's system H M^-1 H' = S + W K W'
  // (W = H P U) is solved by Woodbury on S's factor: both steps cost one factor.
  const auto solve_S = [&](auto& rhs) {
    gn.cholesky.matrix().triangularView<Eigen::Lower>().solveInPlace(rhs);
    gn.cholesky.matrix().triangularView<Eigen::Lower>().transpose().solveInPlace(rhs);
  };
  const Mat2& rotation = gn.rotation;
  // s+ = s0 + P (H'λ + U q) and g+ = H'λ + U q keep s+ - s0 = P g+ (q = 0: Gauss–Newton).
  const auto step_to = [&](const Eigen::VectorXd& lambda, Eigen::VectorXd& point,
                           Eigen::VectorXd& dual) {
    point = s0;
    point.noalias() += gn.gain * lambda;
    dual.resize(ds);
    dual.head<3>().setZero();
    for (Index k = 0; k < r; ++k) {
      const Vec2 lambda_k = lambda.segment<2>(2 * k);
      dual.head<3>().noalias() -= gn.robot_jacobians[static_cast<std::size_t>(k)].transpose() * lambda_k;
      dual.segment<2>(3 + 2 * k) = lambda_k;
      dual.segment<2>(second_begin + 2 * k).noalias() = -rotation.transpose() * lambda_k;
    }
  };
  const auto moved_to = [&](const Eigen::VectorXd& point) {  // in units of the tolerance
    return ((point - s).array().abs() / gn.tolerance.max(std::numeric_limits<double>::min())).maxCoeff();
  };
  Eigen::VectorXd lambda = gn.rhs;  // -c + H (s - s0)
  solve_S(lambda);
  Eigen::VectorXd next, dual;
  step_to(lambda, next, dual);
  double moved = moved_to(next);
  bool newton = false;
  if (gn.steps > 0) {
    constexpr Index kTheta = 2;
    Mat2 rotation_derivative;
    rotation_derivative << -rotation(1, 0), -rotation(0, 0), rotation(0, 0), -rotation(1, 0);
    Eigen::VectorXd a(2 * r);
    double h = 0.0;
    for (Index k = 0; k < r; ++k) {
      const Vec2 lambda_k = gn.multipliers.segment<2>(2 * k);
      a.segment<2>(2 * k).noalias() = -rotation_derivative.transpose() * lambda_k;
      h += lambda_k.dot(rotation * s.segment<2>(second_begin + 2 * k));
    }
    Eigen::Matrix<double, Eigen::Dynamic, 2> PU(ds, 2), W(2 * r, 2);
    PU.col(0) = P_ss.col(kTheta);
    PU.col(1).head(second_begin).setZero();  // a lives on the f_j, m2's block of P_ss
    PU.col(1).tail(2 * r).noalias() = P_ss.bottomRightCorner(2 * r, 2 * r) * a;
    Mat2 K_inverse;
    K_inverse << -PU(kTheta, 0), 1.0 - PU(kTheta, 1), 1.0 - PU(kTheta, 1),
        -h - a.dot(PU.col(1).tail(2 * r));
    for (Index k = 0; k < r; ++k) W.middleRows<2>(2 * k) = H_rows(k, PU);
    Eigen::Matrix<double, Eigen::Dynamic, 2> Z = W;
    solve_S(Z);
    Mat2 capacitance = K_inverse;
    capacitance.noalias() += W.transpose() * Z;
    const auto invertible = [](const Mat2& A) {
      return std::abs(A.determinant()) > 1e-12 * A.squaredNorm();
    };
    if (invertible(K_inverse) && invertible(capacitance)) {
      // λ = (S + W K W')^-1 (-c + H (s - s0) + W K U'P g), with s - s0 = P g.
      const Mat2 K = K_inverse.inverse();
      Eigen::VectorXd newton_lambda = lambda;
      newton_lambda.noalias() += Z * (K * (PU.transpose() * gn.dual));
      newton_lambda.noalias() -= Z * (capacitance.inverse() * (W.transpose() * newton_lambda));
      Eigen::VectorXd newton_next, newton_dual;
      step_to(newton_lambda, newton_next, newton_dual);
      const Vec2 q = K * (PU.transpose() * (newton_dual - gn.dual));
      newton_next.noalias() += PU * q;
      newton_dual(kTheta) += q(0);
      newton_dual.tail(2 * r) += q(1) * a;
      // Far from the solution the curvature can send Newton astray (it did on two Victoria
      // Park joins whose maps disagree by a few σ): its step is taken only while contracting.
      const double newton_moved = moved_to(newton_next);
      if (newton_moved < gn.moved) {
        newton = true;
        lambda = std::move(newton_lambda);
        next = std::move(newton_next);
        dual = std::move(newton_dual);
        moved = newton_moved;
      }
    }
  }
  // Converged when no coordinate moves by more than its tolerance (1e-9 σ), or when Newton is
  // contracting and its next step, about (this step)² in units of σ, would be below that:
  // Newton converges quadratically, with a constant between 0.003 and 0.1 on Victoria Park's
  // joins (1 here), so the confirming step need not be taken.
  gn.converged = moved <= 1.0 || (newton && moved * moved <= 1e9);
  gn.moved = moved;
  gn.multipliers = std::move(lambda);
  gn.dual = std::move(dual);
  s = std::move(next);
  ++gn.steps;
  if (gn.steps + 1 >= max_iterations_) gn.converged = true;
  gn.factor_built = false;
  gn.cholesky = ResumableCholesky();
  // Both steps' solves and products.
  return join_cost::step_solve(ds, r);
}

std::int64_t JoinRelinearisation::finish() {
  const Index r = static_cast<Index>(pairs_->size());
  if (state_.steps == 0) return 0;
  iterations_ = state_.steps + 1;
  first_robot_ = state_.point.head<3>();
  // m2's rows of P0 g: its prior covariance with each f_j times g's f_j entries (at a KKT
  // point g = H'λ, so these are m2's rows of P0 H' λ; short of one, the mean of m2 given s).
  const auto P2 = second_->P();
  const Index second_begin = 3 + 2 * r;
  for (Index k = 0; k < r; ++k) {
    second_x_.noalias() += P2.middleCols(state_.second_rows[static_cast<std::size_t>(2 * k)], 2) *
                           state_.dual.segment<2>(second_begin + 2 * k);
  }
  state_ = State();
  return join_cost::relinearise_finish(second_->dim(), r);
}

void JoinRelinearisation::release() {
  first_ = nullptr;
  second_ = nullptr;
  pairs_ = nullptr;
  second_x_ = Eigen::VectorXd();
}

}  // namespace dcslam
