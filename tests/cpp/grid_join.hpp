#pragma once
// A join association problem with a known answer, for the association tests: two maps over a
// grid of features, the second with a rigid-body error and the matching correlated
// covariance. Inline: several test files include it.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Eigenvalues>

#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/spatial_hash.hpp"

namespace dcslam {

// Two maps to be joined, as one Gaussian over [first map features; second map features].
// A pairing (j, i) says second-map feature j is first-map feature i: h = f_i - f_j = 0, so
// nu = x_j - x_i and cov(nu_(j,i), nu_(l,k)) = P_jl - P_jk - P_il + P_ik.
class TwoMapModel : public PairingModel {
 public:
  Eigen::VectorXd x;
  Eigen::MatrixXd P;
  int first_size = 0;

  Vec2 innovation(const Pairing& p) const override {
    return x.segment<2>(second(p.measurement)) - x.segment<2>(2 * p.feature);
  }
  Mat2 covariance(const Pairing& a, const Pairing& b) const override {
    const Eigen::Index j = second(a.measurement), l = second(b.measurement);
    const Eigen::Index i = 2 * a.feature, k = 2 * b.feature;
    return P.block<2, 2>(j, l) - P.block<2, 2>(j, k) - P.block<2, 2>(i, l) + P.block<2, 2>(i, k);
  }

 private:
  Eigen::Index second(int j) const { return 2 * (first_size + j); }
};

struct JoinProblem {
  TwoMapModel model;
  CandidateLists candidates;   // individually compatible, found through a SpatialHash
  std::vector<int> truth;      // per second-map feature: its first-map feature or kStar
};

inline constexpr double kSpacing = 2.0;

// Features on a regular grid (columns x rows) seen by both maps; the second map carries a
// rigid-body error (translation about 1.3 spacing/2, a small rotation) with matching
// correlated covariance, so nearest neighbour pairs each feature with its +x grid neighbour
// while joint compatibility, which knows the error is common, does not. Spurious features sit
// at cell centres.
inline JoinProblem grid_join(std::uint64_t seed, int first_columns_begin, int first_columns_end,
                      int second_columns_begin, int second_columns_end, double far_shift = 0.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  const int rows = 6;
  const double sigma = 0.05;
  std::vector<Vec2> first_true, second_true;
  std::vector<int> truth;
  for (int c = first_columns_begin; c < first_columns_end; ++c) {
    for (int r = 0; r < rows; ++r) first_true.emplace_back(c * kSpacing, r * kSpacing);
  }
  for (const Vec2& spurious : {Vec2(3.5, 4.5), Vec2(5.5, 2.5)}) {
    first_true.push_back(spurious * kSpacing);
  }
  for (int c = second_columns_begin; c < second_columns_end; ++c) {
    for (int r = 0; r < rows; ++r) {
      second_true.emplace_back(c * kSpacing, r * kSpacing);
      const bool shared = c >= first_columns_begin && c < first_columns_end;
      truth.push_back(shared ? (c - first_columns_begin) * rows + r : kStar);
    }
  }
  for (const Vec2& spurious : {Vec2(3.5, 1.5), Vec2(4.5, 3.5), Vec2(5.5, 0.5)}) {
    second_true.push_back(spurious * kSpacing);
    truth.push_back(kStar);
  }

  const Eigen::Index n1 = static_cast<Eigen::Index>(first_true.size());
  const Eigen::Index n2 = static_cast<Eigen::Index>(second_true.size());
  JoinProblem problem;
  TwoMapModel& model = problem.model;
  model.first_size = static_cast<int>(n1);
  model.x.resize(2 * (n1 + n2));
  model.P = Eigen::MatrixXd::Zero(2 * (n1 + n2), 2 * (n1 + n2));
  for (Eigen::Index i = 0; i < n1; ++i) {
    model.x.segment<2>(2 * i) = first_true[i] + sigma * Vec2(normal(rng), normal(rng));
    model.P.block<2, 2>(2 * i, 2 * i) = sigma * sigma * Mat2::Identity();
  }
  const Vec2 pivot(6.0 * kSpacing, 3.0 * kSpacing);
  const Vec3 pose_error(1.3, 0.3, 0.02);
  const Vec3 pose_sigma(1.0, 1.0, 0.03);
  Eigen::MatrixXd jacobian(2 * n2, 3);
  for (Eigen::Index j = 0; j < n2; ++j) {
    const Vec2 arm = second_true[j] - pivot;
    const double c = std::cos(pose_error.z()), s = std::sin(pose_error.z());
    const Vec2 moved = pivot + Vec2(c * arm.x() - s * arm.y(), s * arm.x() + c * arm.y()) +
                       pose_error.head<2>() + Vec2(far_shift, 0.0);
    model.x.segment<2>(2 * (n1 + j)) = moved + sigma * Vec2(normal(rng), normal(rng));
    jacobian.block<2, 3>(2 * j, 0) << 1.0, 0.0, -arm.y(), 0.0, 1.0, arm.x();
  }
  model.P.bottomRightCorner(2 * n2, 2 * n2) =
      jacobian * pose_sigma.cwiseAbs2().asDiagonal() * jacobian.transpose() +
      sigma * sigma * Eigen::MatrixXd::Identity(2 * n2, 2 * n2);

  // Candidates: first-map features within the gate's Euclidean radius, then the exact test.
  const double gate = chi2_quantile(2, 0.99);
  SpatialHash hash(3.0);
  for (Eigen::Index i = 0; i < n1; ++i) hash.insert(static_cast<int>(i), model.x.segment<2>(2 * i));
  std::vector<int> nearby;
  for (Eigen::Index j = 0; j < n2; ++j) {
    const Eigen::Index row = 2 * (n1 + j);
    const Mat2 spread = model.P.block<2, 2>(row, row) + sigma * sigma * Mat2::Identity();
    const double largest = Eigen::SelfAdjointEigenSolver<Mat2>(spread).eigenvalues().maxCoeff();
    const double radius = std::sqrt(gate * largest);
    hash.query(model.x.segment<2>(2 * (n1 + j)), radius, nearby);
    std::sort(nearby.begin(), nearby.end());
    problem.candidates.push_back(nearby);
  }
  problem.candidates = individually_compatible(problem.candidates, model, 0.99);
  problem.truth = truth;
  return problem;
}

}  // namespace dcslam
