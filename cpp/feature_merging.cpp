#include "dcslam/feature_merging.hpp"

#include <limits>

#include <Eigen/Cholesky>

namespace dcslam {

namespace {

using Index = Eigen::Index;

Mat2 difference_covariance(const GaussianMap& map, Index a, Index b) {
  const auto P = map.P();
  const Index oa = GaussianMap::feature_offset(a), ob = GaussianMap::feature_offset(b);
  const Mat2 cross = P.block<2, 2>(oa, ob);
  const Mat2 S = P.block<2, 2>(oa, oa) + P.block<2, 2>(ob, ob) - cross - cross.transpose();
  return 0.5 * (S + S.transpose());
}

}  // namespace

double feature_difference_distance_sq(const GaussianMap& map, Index a, Index b) {
  const Eigen::LLT<Mat2> cholesky(difference_covariance(map, a, b));
  if (cholesky.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  const Vec2 whitened = cholesky.matrixL().solve(map.feature(a) - map.feature(b));
  return whitened.squaredNorm();
}

bool impose_equal_features(GaussianMap& map, Index a, Index b) {
  const Eigen::LLT<Mat2> cholesky(difference_covariance(map, a, b));
  if (cholesky.info() != Eigen::Success) return false;
  auto P = map.P();
  const Index oa = GaussianMap::feature_offset(a), ob = GaussianMap::feature_offset(b);
  // W = P H' L^-T, so that K (f_a - f_b) = W L^-1 (f_a - f_b) and K S K' = W W'.
  Eigen::MatrixXd W = P.middleCols<2>(oa) - P.middleCols<2>(ob);
  cholesky.matrixU().solveInPlace<Eigen::OnTheRight>(W);
  const Vec2 whitened = cholesky.matrixL().solve(map.feature(a) - map.feature(b));
  map.x().noalias() -= W * whitened;
  map.x()(2) = wrap_angle(map.x()(2));
  P.selfadjointView<Eigen::Lower>().rankUpdate(W, -1.0);
  P.triangularView<Eigen::StrictlyUpper>() = P.transpose();
  return true;
}

}  // namespace dcslam
