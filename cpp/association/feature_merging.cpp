#include "dcslam/association/feature_merging.hpp"

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

double feature_difference_distance_sq(const GaussianMap& map, Index a, Index b, double feature_sigma) {
  const Mat2 tested = difference_covariance(map, a, b) + 2.0 * feature_sigma * feature_sigma * Mat2::Identity();
  const Eigen::LLT<Mat2> cholesky(tested);
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
  map.mirror_lower_triangle();
  return true;
}

Index merge_partner(const GaussianMap& map, Index k, double radius, double gate, double feature_sigma,
                    const MayBeOneLandmark& may_be_one) {
  const double radius_sq = radius * radius;
  const Vec2 position = map.feature(k);
  Index partner = -1;
  for (Index j = 0; j < map.num_features(); ++j) {
    if (j == k || (map.feature(j) - position).squaredNorm() > radius_sq) continue;
    if (feature_difference_distance_sq(map, k, j, feature_sigma) > gate || !may_be_one(k, j)) continue;
    if (partner >= 0) return -1;
    partner = j;
  }
  return partner;
}

std::vector<std::pair<std::int64_t, std::int64_t>> merge_duplicate_features(
    GaussianMap& map, double radius, double gate, double feature_sigma, const MayBeOneLandmark& may_be_one,
    const OnMerge& on_merge) {
  std::vector<std::pair<std::int64_t, std::int64_t>> merged;
  while (true) {
    const Index n = map.num_features();
    std::vector<Index> partner(static_cast<std::size_t>(n));
    for (Index k = 0; k < n; ++k) {
      partner[static_cast<std::size_t>(k)] = merge_partner(map, k, radius, gate, feature_sigma, may_be_one);
    }
    std::vector<Index> dropped;
    for (Index k = 0; k < n; ++k) {
      const Index j = partner[static_cast<std::size_t>(k)];
      if (j <= k || partner[static_cast<std::size_t>(j)] != k) continue;
      // Earlier merges of this round moved both: the pair must still pass.
      if (feature_difference_distance_sq(map, k, j, feature_sigma) > gate) continue;
      const bool k_older = map.ids()[static_cast<std::size_t>(k)] < map.ids()[static_cast<std::size_t>(j)];
      const Index keep = k_older ? k : j, drop = k_older ? j : k;
      if (!impose_equal_features(map, keep, drop)) continue;
      merged.emplace_back(map.ids()[static_cast<std::size_t>(drop)], map.ids()[static_cast<std::size_t>(keep)]);
      if (on_merge) on_merge(merged.back().first, merged.back().second);
      dropped.push_back(drop);
    }
    if (dropped.empty()) break;
    map.remove_features(dropped);
  }
  return merged;
}

}  // namespace dcslam
