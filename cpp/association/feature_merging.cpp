#include "dcslam/association/feature_merging.hpp"

#include <limits>

#include <Eigen/Cholesky>

namespace dcslam {

namespace {

using Index = Eigen::Index;

// Which of P's triangles hold its current values: both, or (after a merge's rank update, until
// mirror_lower_triangle()) the lower one only, read where a mirrored P would hold them.
enum class Current { Both, Lower };

template <typename Matrix>
Mat2 block2(const Matrix& P, Index r, Index c, Current current) {
  if (current == Current::Both || r > c) return P.template block<2, 2>(r, c);
  if (r < c) return P.template block<2, 2>(c, r).transpose();
  Mat2 block = P.template block<2, 2>(r, r);
  block(0, 1) = block(1, 0);
  return block;
}

// Columns c, c + 1 of P.
template <typename Matrix>
Eigen::MatrixXd columns2(const Matrix& P, Index c, Current current) {
  if (current == Current::Both) return P.template middleCols<2>(c);
  Eigen::MatrixXd columns(P.rows(), 2);
  columns.topRows(c) = P.block(c, 0, 2, c).transpose();
  columns.bottomRows(P.rows() - c) = P.bottomRows(P.rows() - c).template middleCols<2>(c);
  columns(c, 1) = P(c + 1, c);
  return columns;
}

Mat2 difference_covariance(const GaussianMap& map, Index a, Index b, Current current) {
  const auto P = map.P();
  const Index oa = GaussianMap::feature_offset(a), ob = GaussianMap::feature_offset(b);
  const Mat2 cross = block2(P, oa, ob, current);
  const Mat2 S = block2(P, oa, oa, current) + block2(P, ob, ob, current) - cross - cross.transpose();
  return 0.5 * (S + S.transpose());
}

double difference_distance_sq(const GaussianMap& map, Index a, Index b, double feature_sigma, Current current) {
  const Mat2 tested =
      difference_covariance(map, a, b, current) + 2.0 * feature_sigma * feature_sigma * Mat2::Identity();
  const Eigen::LLT<Mat2> cholesky(tested);
  if (cholesky.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  const Vec2 whitened = cholesky.matrixL().solve(map.feature(a) - map.feature(b));
  return whitened.squaredNorm();
}

// impose_equal_features() up to its mirror: P's lower triangle only is updated.
bool impose_on_lower(GaussianMap& map, Index a, Index b, Current current) {
  const Eigen::LLT<Mat2> cholesky(difference_covariance(map, a, b, current));
  if (cholesky.info() != Eigen::Success) return false;
  auto P = map.P();
  const Index oa = GaussianMap::feature_offset(a), ob = GaussianMap::feature_offset(b);
  // W = P H' L^-T, so that K (f_a - f_b) = W L^-1 (f_a - f_b) and K S K' = W W'.
  Eigen::MatrixXd W = columns2(P, oa, current) - columns2(P, ob, current);
  cholesky.matrixU().solveInPlace<Eigen::OnTheRight>(W);
  const Vec2 whitened = cholesky.matrixL().solve(map.feature(a) - map.feature(b));
  map.x().noalias() -= W * whitened;
  map.x()(2) = wrap_angle(map.x()(2));
  P.selfadjointView<Eigen::Lower>().rankUpdate(W, -1.0);
  return true;
}

}  // namespace

double feature_difference_distance_sq(const GaussianMap& map, Index a, Index b, double feature_sigma) {
  return difference_distance_sq(map, a, b, feature_sigma, Current::Both);
}

bool impose_equal_features(GaussianMap& map, Index a, Index b) {
  if (!impose_on_lower(map, a, b, Current::Both)) return false;
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
    // P is mirrored once a round, not after each merge (O(n^2) each): until then the merges
    // read and update its lower triangle, the values a mirror after each would give.
    Current current = Current::Both;
    for (Index k = 0; k < n; ++k) {
      const Index j = partner[static_cast<std::size_t>(k)];
      if (j <= k || partner[static_cast<std::size_t>(j)] != k) continue;
      // Earlier merges of this round moved both: the pair must still pass.
      if (difference_distance_sq(map, k, j, feature_sigma, current) > gate) continue;
      const bool k_older = map.ids()[static_cast<std::size_t>(k)] < map.ids()[static_cast<std::size_t>(j)];
      const Index keep = k_older ? k : j, drop = k_older ? j : k;
      if (!impose_on_lower(map, keep, drop, current)) continue;
      current = Current::Lower;
      merged.emplace_back(map.ids()[static_cast<std::size_t>(drop)], map.ids()[static_cast<std::size_t>(keep)]);
      if (on_merge) on_merge(merged.back().first, merged.back().second);
      dropped.push_back(drop);
    }
    if (dropped.empty()) break;
    map.mirror_lower_triangle();
    map.remove_features(dropped);
  }
  return merged;
}

}  // namespace dcslam
