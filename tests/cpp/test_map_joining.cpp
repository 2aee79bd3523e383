#include <cstdint>
#include <memory>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <gtest/gtest.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/map_joining.hpp"
#include "numeric_jacobian.hpp"
#include "random_map.hpp"

namespace dcslam {
namespace {

using Index = Eigen::Index;

// `map` with `poses` past poses appended (ids first_id, first_id + 1, ...): random poses,
// correlated with the map as q = B x + e would be (so P stays positive definite).
GaussianMap with_past_poses(const GaussianMap& map, std::mt19937_64& rng, Index poses,
                            std::int64_t first_id) {
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> uniform(-20, 20);
  GaussianMap out = GaussianMap::uninitialized(map.num_features(), poses);
  const Index d = map.dim(), e = 3 * poses;
  Eigen::MatrixXd B(e, d), E(e, e);
  for (Index i = 0; i < e; ++i) {
    for (Index j = 0; j < d; ++j) B(i, j) = 0.1 * normal(rng);
    for (Index j = 0; j < e; ++j) E(i, j) = 0.1 * normal(rng);
  }
  out.x().head(d) = map.x();
  for (Index q = 0; q < poses; ++q) {
    out.x().segment<3>(d + 3 * q) = Vec3(uniform(rng), uniform(rng), uniform(rng) / 14.0);
  }
  out.P().topLeftCorner(d, d) = map.P();
  out.P().block(0, d, d, e) = map.P() * B.transpose();
  out.P().block(d, 0, e, d) = B * map.P();
  out.P().bottomRightCorner(e, e) =
      B * map.P() * B.transpose() + E * E.transpose() + 0.05 * Eigen::MatrixXd::Identity(e, e);
  out.ids() = map.ids();
  for (Index q = 0; q < poses; ++q) out.pose_ids()[static_cast<std::size_t>(q)] = first_id + q;
  return out;
}

// The joined map's state in the stacked vector [m1.x; m2.x]: [R2'; F1 kept; F2' unmatched;
// Q1; R1 if kept; Q2'], with the result's feature and pose ids.
struct JoinedOrder {
  std::vector<Index> rows;
  std::vector<std::int64_t> ids, pose_ids;
  Index features = 0, poses = 0;
};

JoinedOrder joined_order(const GaussianMap& m1, const GaussianMap& m2,
                         const std::vector<std::pair<Index, Index>>& pairs,
                         const std::set<Index>& dropped_first, const std::set<Index>& dropped_second,
                         bool keep_first_robot, std::int64_t first_robot_id) {
  const Index d1 = m1.dim();
  std::set<Index> matched;
  for (const auto& p : pairs) matched.insert(p.second);
  JoinedOrder order;
  order.rows = {d1, d1 + 1, d1 + 2};
  for (Index i = 0; i < m1.num_features(); ++i) {
    if (dropped_first.count(i)) continue;
    order.rows.push_back(3 + 2 * i);
    order.rows.push_back(4 + 2 * i);
    order.ids.push_back(m1.ids()[i]);
  }
  for (Index j = 0; j < m2.num_features(); ++j) {
    if (matched.count(j) || dropped_second.count(j)) continue;
    order.rows.push_back(d1 + 3 + 2 * j);
    order.rows.push_back(d1 + 4 + 2 * j);
    order.ids.push_back(m2.ids()[j]);
  }
  const auto add_pose = [&](Index row, std::int64_t id) {
    for (Index c = 0; c < 3; ++c) order.rows.push_back(row + c);
    order.pose_ids.push_back(id);
  };
  for (Index q = 0; q < m1.num_poses(); ++q) add_pose(m1.pose_offset(q), m1.pose_ids()[q]);
  if (keep_first_robot) add_pose(0, first_robot_id);
  for (Index q = 0; q < m2.num_poses(); ++q) add_pose(d1 + m2.pose_offset(q), m2.pose_ids()[q]);
  order.features = static_cast<Index>(order.ids.size());
  order.poses = static_cast<Index>(order.pose_ids.size());
  return order;
}

// The rows `order` selects of (y, P), headings wrapped.
GaussianMap select(const JoinedOrder& order, const Eigen::VectorXd& y, const Eigen::MatrixXd& P) {
  GaussianMap out = GaussianMap::uninitialized(order.features, order.poses);
  for (std::size_t a = 0; a < order.rows.size(); ++a) {
    out.x()(a) = y(order.rows[a]);
    for (std::size_t b = 0; b < order.rows.size(); ++b) out.P()(a, b) = P(order.rows[a], order.rows[b]);
  }
  out.x()(2) = wrap_angle(out.x()(2));
  for (Index q = 0; q < out.num_poses(); ++q) {
    out.x()(out.pose_offset(q) + 2) = wrap_angle(out.x()(out.pose_offset(q) + 2));
  }
  out.ids() = order.ids;
  out.pose_ids() = order.pose_ids;
  return out;
}

// The textbook join of docs/design.md §4, dense: stack, move m2 (robot, features and past poses)
// with the full Jacobian, impose the matched pairs with an EKF update (S = H P H', no R), then
// keep the rows joined_order() lists (marginalising = deleting rows and columns of the
// updated P): R1 goes unless kept, so do the matched f'_j and the dropped tentative features.
// `constraint_distance_sq`, if given, gets h' S^-1 h of the pairs (h = H z at the prior means).
GaussianMap dense_join(const GaussianMap& m1, const GaussianMap& m2,
                       const std::vector<std::pair<Index, Index>>& pairs,
                       const std::set<Index>& dropped_first = {},
                       const std::set<Index>& dropped_second = {},
                       bool keep_first_robot = false, std::int64_t first_robot_id = -1,
                       double* constraint_distance_sq = nullptr) {
  const Index d1 = m1.dim(), d2 = m2.dim(), D = d1 + d2;
  const Vec3 T = m1.robot();
  Eigen::VectorXd z(D);
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(D, D);
  z.head(d1) = m1.x();
  J.topLeftCorner(d1, d1).setIdentity();
  const auto move_pose = [&](Index row) {
    Mat3 J_T, J_e;
    z.segment<3>(row) = compose(T, m2.x().segment<3>(row - d1), &J_T, &J_e);
    J.block<3, 3>(row, 0) = J_T;
    J.block<3, 3>(row, row) = J_e;
  };
  move_pose(d1);
  for (Index j = 0; j < m2.num_features(); ++j) {
    Mat23 J_Tp;
    Mat2 J_p;
    const Index row = d1 + 3 + 2 * j;
    z.segment<2>(row) = transform_point(T, m2.feature(j), &J_Tp, &J_p);
    J.block<2, 3>(row, 0) = J_Tp;
    J.block<2, 2>(row, row) = J_p;
  }
  for (Index q = 0; q < m2.num_poses(); ++q) move_pose(d1 + m2.pose_offset(q));
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(D, D);
  P0.topLeftCorner(d1, d1) = m1.P();
  P0.bottomRightCorner(d2, d2) = m2.P();
  Eigen::MatrixXd P = J * P0 * J.transpose();
  const Index r = static_cast<Index>(pairs.size());
  if (r > 0) {
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(2 * r, D);
    for (Index k = 0; k < r; ++k) {
      H.block<2, 2>(2 * k, 3 + 2 * pairs[k].first).setIdentity();
      H.block<2, 2>(2 * k, d1 + 3 + 2 * pairs[k].second) = -Mat2::Identity();
    }
    const Eigen::MatrixXd S = H * P * H.transpose();
    if (constraint_distance_sq != nullptr) {
      const Eigen::VectorXd h = H * z;
      *constraint_distance_sq = h.dot(S.inverse() * h);
    }
    const Eigen::MatrixXd K = P * H.transpose() * S.inverse();
    z -= K * (H * z);
    P -= K * S * K.transpose();
  }
  return select(joined_order(m1, m2, pairs, dropped_first, dropped_second, keep_first_robot,
                             first_robot_id),
                z, P);
}

void expect_maps_equal(const GaussianMap& a, const GaussianMap& b, double tol) {
  ASSERT_EQ(a.dim(), b.dim());
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_EQ(a.pose_ids(), b.pose_ids());
  EXPECT_LT((a.x() - b.x()).cwiseAbs().maxCoeff(), tol);
  EXPECT_LT((a.P() - b.P()).cwiseAbs().maxCoeff(), tol * std::max(1.0, b.P().cwiseAbs().maxCoeff()));
}

struct JoinCase {
  int n1, n2, shared;
  Index block_columns;
};

// The cases print as text: without a PrintTo gtest prints their raw bytes (padding included,
// different from build to build), and CTest puts the printed value in the test name.
void PrintTo(const JoinCase& c, std::ostream* out) {
  *out << "n1_" << c.n1 << "_n2_" << c.n2 << "_shared" << c.shared << "_columns" << c.block_columns;
}

class MapJoiningTest : public ::testing::TestWithParam<JoinCase> {};

TEST_P(MapJoiningTest, FusedJoinEqualsDenseTextbookJoin) {
  const JoinCase c = GetParam();
  std::mt19937_64 rng(1000 + c.n1 * 31 + c.n2 * 7 + c.shared);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < c.n1; ++i) ids1.push_back(i);
  for (int j = 0; j < c.n2; ++j) ids2.push_back(j < c.shared ? (c.n1 - 1 - 2 * j) : 1000 + j);
  std::shuffle(ids2.begin(), ids2.end(), rng);
  const GaussianMap m1 = random_map(rng, ids1);
  const GaussianMap m2 = random_map(rng, ids2);
  JoinOptions options;
  options.block_columns = c.block_columns;
  options.max_iterations = 1;  // the textbook join linearises once, at the prior means
  JoinReport report;
  const GaussianMap joined = join_maps(m1, m2, options, &report);
  const auto pairs = associate_by_id(m1, m2);
  EXPECT_EQ(static_cast<int>(pairs.size()), c.shared);
  EXPECT_EQ(report.pairings, c.shared);
  EXPECT_EQ(report.iterations, c.shared > 0 ? 1 : 0);
  double constraint_distance_sq = 0.0;
  expect_maps_equal(joined, dense_join(m1, m2, pairs, {}, {}, false, -1, &constraint_distance_sq), 1e-9);
  // What imposing the pairs adds to the linearised least-squares objective (the
  // re-linearisation passes sum it, join_tree.hpp).
  EXPECT_NEAR(report.constraint_distance_sq, constraint_distance_sq, 1e-9 * std::max(1.0, constraint_distance_sq));
  if (c.shared > 0) {
    EXPECT_GT(constraint_distance_sq, 0.0);
  }
  EXPECT_TRUE(joined.P().isApprox(joined.P().transpose(), 1e-12));
  if (c.shared == 0) {  // no constraint, nothing to re-linearise: the same join
    options.max_iterations = 10;
    const GaussianMap iterated = join_maps(m1, m2, options, &report);
    EXPECT_EQ(report.iterations, 0);
    EXPECT_TRUE((iterated.x().array() == joined.x().array()).all());
    EXPECT_TRUE((iterated.P().array() == joined.P().array()).all());
  }
}

INSTANTIATE_TEST_SUITE_P(Cases, MapJoiningTest,
                         ::testing::Values(JoinCase{5, 4, 0, 64}, JoinCase{5, 4, 2, 64},
                                           JoinCase{12, 9, 3, 2}, JoinCase{12, 9, 3, 6},
                                           JoinCase{20, 20, 10, 4}, JoinCase{0, 6, 0, 4},
                                           JoinCase{6, 0, 0, 4}, JoinCase{1, 1, 1, 2},
                                           // blocks wider than the fill's shortest tile
                                           JoinCase{90, 60, 40, 128}));

// m1's tentative features: those matched by an m2 feature stay, the others are marginalised.
class MapJoiningTentativeTest : public ::testing::TestWithParam<Index> {};

TEST_P(MapJoiningTentativeTest, DropsUnmatchedTentativeFeaturesOfTheFirstMapExactly) {
  std::mt19937_64 rng(42);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < 14; ++i) ids1.push_back(i);
  for (int j = 0; j < 10; ++j) ids2.push_back(j < 4 ? 3 * j : 100 + j);  // 0, 3, 6, 9 shared
  std::shuffle(ids2.begin(), ids2.end(), rng);
  const auto m1 = std::make_shared<const GaussianMap>(random_map(rng, ids1));
  const auto m2 = std::make_shared<const GaussianMap>(random_map(rng, ids2));
  // Tentative: 3 and 9 (matched, so confirmed); 1, 7, 8 and the last feature 13 (unmatched,
  // dropped; given out of order).
  const std::vector<Index> tentative = {13, 3, 7, 9, 8, 1};
  const std::set<Index> dropped = {1, 7, 8, 13};
  JoinOptions options;
  options.block_columns = GetParam();
  options.max_iterations = 1;  // compared with the one-shot textbook join
  MapJoin at_once(m1, m2, options, tentative);
  at_once.finish();
  EXPECT_EQ(at_once.report().pairings, 4);
  EXPECT_EQ(at_once.report().dropped_tentative, 4);
  EXPECT_EQ(at_once.dropped_ids(), (std::vector<std::int64_t>{1, 7, 8, 13}));
  MapJoin sliced(m1, m2, options, tentative);
  while (!sliced.done()) sliced.advance(20);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  EXPECT_EQ(a.num_features(), 14 - 4 + 10 - 4);
  expect_maps_equal(a, dense_join(*m1, *m2, associate_by_id(*m1, *m2), dropped), 1e-9);
  EXPECT_TRUE(a.P().isApprox(a.P().transpose(), 1e-12));
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_TRUE((a.x().array() == b.x().array()).all());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
}

// Tentative features on both sides: m2's unmatched ones are marginalised the same way.
TEST_P(MapJoiningTentativeTest, DropsUnmatchedTentativeFeaturesOfBothMapsExactly) {
  std::mt19937_64 rng(43);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < 12; ++i) ids1.push_back(i);
  for (int j = 0; j < 11; ++j) ids2.push_back(j < 5 ? 2 * j : 100 + j);  // 0, 2, 4, 6, 8 shared
  const auto m1 = std::make_shared<const GaussianMap>(random_map(rng, ids1));
  const auto m2 = std::make_shared<const GaussianMap>(random_map(rng, ids2));
  // m1: 2 matched (stays), 5 and 11 unmatched (dropped). m2 (indices): 1 (id 2) and 3 (id 6)
  // matched, so merged; 5, 7 and the last one, 10, unmatched, so dropped.
  const std::vector<Index> first_tentative = {11, 2, 5};
  const std::vector<Index> second_tentative = {7, 1, 10, 3, 5};
  JoinOptions options;
  options.block_columns = GetParam();
  options.max_iterations = 1;  // compared with the one-shot textbook join
  MapJoin at_once(m1, m2, options, first_tentative, second_tentative);
  at_once.finish();
  EXPECT_EQ(at_once.report().pairings, 5);
  EXPECT_EQ(at_once.report().dropped_tentative, 5);
  EXPECT_EQ(at_once.dropped_ids(), (std::vector<std::int64_t>{5, 11, 105, 107, 110}));
  MapJoin sliced(m1, m2, options, first_tentative, second_tentative);
  while (!sliced.done()) sliced.advance(20);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  EXPECT_EQ(a.num_features(), 12 - 2 + 11 - 5 - 3);
  expect_maps_equal(a, dense_join(*m1, *m2, associate_by_id(*m1, *m2), {5, 11}, {5, 7, 10}), 1e-9);
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
  EXPECT_THROW(MapJoin(m1, m2, JoinOptions{}, {}, {11}), InvalidArgument);
}

INSTANTIATE_TEST_SUITE_P(BlockColumns, MapJoiningTentativeTest, ::testing::Values(2, 4, 6, 64));

TEST(MapJoining, EveryFeatureOfTheFirstMapTentativeAndUnmatched) {
  std::mt19937_64 rng(9);
  const auto m1 = std::make_shared<const GaussianMap>(random_map(rng, {0, 1, 2}));
  const auto m2 = std::make_shared<const GaussianMap>(random_map(rng, {10, 11}));
  MapJoin join(m1, m2, JoinOptions{}, {0, 1, 2});
  join.finish();
  expect_maps_equal(join.take_result(), dense_join(*m1, *m2, {}, {0, 1, 2}), 1e-9);
  EXPECT_THROW(MapJoin(m1, m2, JoinOptions{}, {3}), InvalidArgument);
}

TEST(JoinFrame, CovarianceBlocksEqualTheDenseStackedCovariance) {
  std::mt19937_64 rng(77);
  const GaussianMap m1 = random_map(rng, {0, 1, 2, 3, 4});
  const GaussianMap m2 = random_map(rng, {10, 11, 12, 13});
  const Index d1 = m1.dim(), d2 = m2.dim(), D = d1 + d2;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(D, D);
  J.topLeftCorner(d1, d1).setIdentity();
  Mat3 J_T, J_e;
  compose(m1.robot(), m2.robot(), &J_T, &J_e);
  J.block<3, 3>(d1, 0) = J_T;
  J.block<3, 3>(d1, d1) = J_e;
  for (Index j = 0; j < m2.num_features(); ++j) {
    Mat23 J_Tp;
    Mat2 J_p;
    transform_point(m1.robot(), m2.feature(j), &J_Tp, &J_p);
    J.block<2, 3>(d1 + 3 + 2 * j, 0) = J_Tp;
    J.block<2, 2>(d1 + 3 + 2 * j, d1 + 3 + 2 * j) = J_p;
  }
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(D, D);
  P0.topLeftCorner(d1, d1) = m1.P();
  P0.bottomRightCorner(d2, d2) = m2.P();
  const Eigen::MatrixXd P = J * P0 * J.transpose();
  const JoinFrame frame(m1, m2);
  const auto row1 = [](Index i) { return 3 + 2 * i; };
  const auto row2 = [&](Index j) { return d1 + 3 + 2 * j; };
  for (Index i = 0; i < 5; ++i) {
    for (Index j = 0; j < 4; ++j) {
      EXPECT_LT((frame.first_second(i, j) - P.block<2, 2>(row1(i), row2(j))).norm(), 1e-12);
      EXPECT_LT((frame.second_second(j, (j + 1) % 4) - P.block<2, 2>(row2(j), row2((j + 1) % 4))).norm(), 1e-12);
      const Index k = (i + 2) % 5, l = (j + 3) % 4;
      Eigen::MatrixXd H_a = Eigen::MatrixXd::Zero(2, D), H_b = Eigen::MatrixXd::Zero(2, D);
      H_a.block<2, 2>(0, row1(i)).setIdentity();
      H_a.block<2, 2>(0, row2(j)) = -Mat2::Identity();
      H_b.block<2, 2>(0, row1(k)).setIdentity();
      H_b.block<2, 2>(0, row2(l)) = -Mat2::Identity();
      EXPECT_LT((frame.constraint_covariance(i, j, k, l) - H_a * P * H_b.transpose()).norm(), 1e-12);
      EXPECT_LT((frame.constraint_covariance(frame.constraint_column(k, l), i, j) - H_a * P * H_b.transpose()).norm(),
                1e-12);
      EXPECT_LT((frame.moved_second_feature(j) - transform_point(m1.robot(), m2.feature(j))).norm(), 1e-12);
    }
  }
  // The join's pairing model gives a pairing's blocks with many at once as one at a time, the
  // feature error included where two pairings share a feature (and a pairing with itself).
  const JoinPairingModel model(frame, 0.3);
  const std::vector<Pairing> pairings{{0, 0}, {1, 2}, {2, 2}, {1, 4}, {3, 1}, {0, 3}};
  for (const Pairing& b : pairings) {
    Eigen::Matrix<double, Eigen::Dynamic, 2> cross(2 * static_cast<Index>(pairings.size()), 2);
    model.covariances_with(pairings.data(), pairings.size(), b, cross);
    for (std::size_t c = 0; c < pairings.size(); ++c) {
      EXPECT_LT((cross.middleRows<2>(2 * static_cast<Index>(c)) - model.covariance(pairings[c], b)).norm(), 1e-12);
    }
  }
}

TEST(MapJoining, ResumedInSlicesGivesBitwiseTheSameResult) {
  std::mt19937_64 rng(5);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < 40; ++i) ids1.push_back(i);
  for (int j = 0; j < 35; ++j) ids2.push_back(j < 6 ? j * 5 : 500 + j);
  const auto m1 = std::make_shared<const GaussianMap>(random_map(rng, ids1));
  const auto m2 = std::make_shared<const GaussianMap>(random_map(rng, ids2));
  JoinOptions options;
  options.block_columns = 8;
  MapJoin at_once(m1, m2, options);
  at_once.finish();
  MapJoin sliced(m1, m2, options);
  // The first slice associates: from then on the pairs are known and the work left only
  // goes down.
  EXPECT_GT(sliced.advance(1), 0);
  int slices = 1;
  while (!sliced.done()) {
    const std::int64_t before = sliced.remaining_work();
    const std::int64_t spent = sliced.advance(50);
    EXPECT_GT(spent, 0);
    EXPECT_LE(sliced.remaining_work(), before);
    ++slices;
  }
  EXPECT_GT(slices, 10);
  EXPECT_EQ(sliced.report().work_units, at_once.report().work_units);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_TRUE((a.x().array() == b.x().array()).all());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
  const auto merged = sliced.merged_ids();
  EXPECT_EQ(merged.size(), 6u);
  for (const auto& [from, to] : merged) EXPECT_EQ(from, to);  // known ids merge equal ids
}

// Two random maps of 45 and 40 features, 22 of them with ids in both.
std::pair<std::shared_ptr<const GaussianMap>, std::shared_ptr<const GaussianMap>> maps_sharing_22_features(
    std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < 45; ++i) ids1.push_back(i);
  for (int j = 0; j < 40; ++j) ids2.push_back(j < 22 ? 2 * j : 500 + j);
  auto m1 = std::make_shared<const GaussianMap>(random_map(rng, ids1));
  auto m2 = std::make_shared<const GaussianMap>(random_map(rng, ids2));
  return {std::move(m1), std::move(m2)};
}

// The fill's column blocks side by side (MapJoin::finish(threads), as estimate()'s joins are
// made): the result and the work counted are bitwise those of the tile-by-tile fill, from the
// start and from the middle of a column block.
TEST(MapJoining, FilledOnSeveralThreadsGivesBitwiseTheSameResult) {
  const auto [m1, m2] = maps_sharing_22_features(7);
  JoinOptions options;
  options.block_columns = 8;
  options.work_unit = 256;
  MapJoin one_thread(m1, m2, options);
  int steps = 0;
  while (!one_thread.done()) {
    one_thread.advance(1);
    ++steps;
  }
  const GaussianMap expected = one_thread.take_result();
  // The last steps are fill tiles: stopping five short leaves a column block half written.
  for (const int taken : {0, steps - 5}) {
    MapJoin threaded(m1, m2, options);
    for (int step = 0; step < taken; ++step) threaded.advance(1);
    threaded.finish(3);
    EXPECT_EQ(threaded.report().work_units, one_thread.report().work_units) << taken;
    const GaussianMap result = threaded.take_result();
    EXPECT_EQ(result.ids(), expected.ids());
    EXPECT_TRUE((result.x().array() == expected.x().array()).all()) << taken;
    EXPECT_TRUE((result.P().array() == expected.P().array()).all()) << taken;
  }
}

// Tiny work units and panels: the fill in row tiles, the Cholesky factor in panels of 4, P H'
// 16 pairs at a time, the assembly and the solve a few rows at a time. Still the textbook
// join, and bitwise the same however the units are spread over calls.
TEST(MapJoining, SmallWorkUnitsGiveTheTextbookJoin) {
  const auto [m1, m2] = maps_sharing_22_features(11);
  JoinOptions options;
  options.block_columns = 4;
  options.work_unit = 64;
  options.max_iterations = 1;
  MapJoin at_once(m1, m2, options);
  at_once.finish();
  EXPECT_EQ(at_once.report().pairings, 22);
  MapJoin sliced(m1, m2, options);
  int slices = 0;
  while (!sliced.done()) {
    sliced.advance(1);
    ++slices;
  }
  EXPECT_GT(slices, 50);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  expect_maps_equal(a, dense_join(*m1, *m2, associate_by_id(*m1, *m2)), 1e-9);
  EXPECT_TRUE((a.x().array() == b.x().array()).all());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
}

// ---------------------------------------------------------------------------------------
// The iterated join against an independent dense oracle: the constrained MAP of the stacked
// prior x = [m1.x; m2.x] ~ N(x0, blkdiag(P1, P2)) under f_i = R1 ⊕ f'_j, by the iterated EKF
// on the whole stacked vector with central-difference Jacobians, mapped into B1.

// g: identity on m1, R1 ⊕ · on m2's robot, features and past poses (these from
// second_poses_begin on, in m2's rows) (written out, not the library's ⊕).
Eigen::VectorXd oracle_to_base_one(const Eigen::VectorXd& x, Index d1, Index second_poses_begin) {
  const double c = std::cos(x(2)), s = std::sin(x(2));
  Eigen::VectorXd y = x;
  const auto move_point = [&](Index a) {
    y(a) = x(0) + c * x(a) - s * x(a + 1);
    y(a + 1) = x(1) + s * x(a) + c * x(a + 1);
  };
  const auto move_pose = [&](Index a) {
    move_point(a);
    y(a + 2) = x(2) + x(a + 2);
  };
  move_pose(d1);
  for (Index a = d1 + 3; a < d1 + second_poses_begin; a += 2) move_point(a);
  for (Index a = d1 + second_poses_begin; a < x.size(); a += 3) move_pose(a);
  return y;
}

Eigen::VectorXd oracle_constraints(const Eigen::VectorXd& x, Index d1, Index second_poses_begin,
                                   const std::vector<std::pair<Index, Index>>& pairs) {
  const Eigen::VectorXd y = oracle_to_base_one(x, d1, second_poses_begin);
  Eigen::VectorXd c(2 * static_cast<Index>(pairs.size()));
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    c.segment<2>(2 * static_cast<Index>(k)) =
        y.segment<2>(3 + 2 * pairs[k].first) - y.segment<2>(d1 + 3 + 2 * pairs[k].second);
  }
  return c;
}

struct OracleJoin {
  GaussianMap map;
  double max_constraint = 0.0;  // |c(x*)| at the oracle's solution
};

OracleJoin oracle_iterated_join(const GaussianMap& m1, const GaussianMap& m2,
                                const std::vector<std::pair<Index, Index>>& pairs,
                                bool keep_first_robot = false, std::int64_t first_robot_id = -1) {
  using testing::numeric_jacobian;
  const Index d1 = m1.dim(), d2 = m2.dim(), D = d1 + d2;
  Eigen::VectorXd x0(D);
  x0 << m1.x(), m2.x();
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(D, D);
  P0.topLeftCorner(d1, d1) = m1.P();
  P0.bottomRightCorner(d2, d2) = m2.P();
  const Index second_poses_begin = GaussianMap::feature_offset(m2.num_features());
  const auto c = [&](const Eigen::VectorXd& x) {
    return oracle_constraints(x, d1, second_poses_begin, pairs);
  };
  const auto g = [&](const Eigen::VectorXd& x) { return oracle_to_base_one(x, d1, second_poses_begin); };
  Eigen::VectorXd x = x0;
  for (int it = 0; it < 100; ++it) {
    const Eigen::MatrixXd H = numeric_jacobian(c, x);
    const Eigen::MatrixXd S = H * P0 * H.transpose();
    const Eigen::VectorXd next =
        x0 + P0 * H.transpose() * S.ldlt().solve(-c(x) - H * (x0 - x));
    const double step = (next - x).cwiseAbs().maxCoeff();
    x = next;
    if (step < 1e-13) break;
  }
  const Eigen::MatrixXd H = numeric_jacobian(c, x);
  const Eigen::MatrixXd PHt = P0 * H.transpose();
  const Eigen::MatrixXd P = P0 - PHt * (H * PHt).ldlt().solve(PHt.transpose());
  const Eigen::MatrixXd G = numeric_jacobian(g, x);
  const Eigen::VectorXd y = g(x);
  const Eigen::MatrixXd Py = G * P * G.transpose();

  OracleJoin out;
  out.map = select(joined_order(m1, m2, pairs, {}, {}, keep_first_robot, first_robot_id), y, Py);
  out.max_constraint = c(x).cwiseAbs().maxCoeff();
  return out;
}

// Two maps of the same landmarks where the linearisation matters: R1's heading is uncertain
// (σθ 0.3 rad) and wrong by about that much (plus `heading_offset`), and the shared landmarks
// lie 30-60 m away.
std::pair<GaussianMap, GaussianMap> nonlinear_maps(std::uint64_t seed, int shared,
                                                   double heading_offset = 0.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> uniform(-1, 1);
  const double kPi = 3.14159265358979323846;
  const Vec3 true_first_robot(5 * uniform(rng), 5 * uniform(rng), kPi * uniform(rng));
  std::vector<Vec2> landmarks;
  for (int k = 0; k < shared + 2; ++k) {
    const double range = 45 + 15 * uniform(rng), bearing = kPi * uniform(rng);
    landmarks.push_back(true_first_robot.head<2>() +
                        range * Vec2(std::cos(bearing), std::sin(bearing)));
  }
  const auto random_spd = [&](Index d, const Eigen::VectorXd& variances) {
    Eigen::MatrixXd A(d, d);
    for (Index i = 0; i < d; ++i)
      for (Index j = 0; j < d; ++j) A(i, j) = 0.05 * normal(rng);
    Eigen::MatrixXd P = A * A.transpose();
    P.diagonal() += variances;
    return P;
  };
  // m1: the robot R1 (heading off by ~σθ) and every landmark but the last; ids 0, 1, ...
  GaussianMap m1;
  for (int k = 0; k < shared + 1; ++k) {
    m1.append_feature(landmarks[k] + 0.3 * Vec2(normal(rng), normal(rng)), k);
  }
  m1.x().head<3>() = true_first_robot + Vec3(normal(rng), normal(rng), 0.3 * normal(rng));
  m1.x()(2) += heading_offset;
  Eigen::VectorXd variances = Eigen::VectorXd::Constant(m1.dim(), 0.1);
  variances.head<3>() << 1.0, 1.0, 0.09;
  m1.P() = random_spd(m1.dim(), variances);
  // m2 (base R1): the shared landmarks (ids of m1's) and the last one, seen from R1.
  GaussianMap m2;
  const double c = std::cos(true_first_robot.z()), s = std::sin(true_first_robot.z());
  const auto local = [&](const Vec2& p) {
    const Vec2 d = p - true_first_robot.head<2>();
    return Vec2(c * d.x() + s * d.y(), -s * d.x() + c * d.y());
  };
  for (int k = 0; k < shared; ++k) {
    m2.append_feature(local(landmarks[k]) + 0.1 * Vec2(normal(rng), normal(rng)), k);
  }
  m2.append_feature(local(landmarks[shared + 1]), 1000);
  m2.x().head<3>() = Vec3(20 * uniform(rng), 20 * uniform(rng), uniform(rng));
  m2.P() = random_spd(m2.dim(), Eigen::VectorXd::Constant(m2.dim(), 0.02));
  return {m1, m2};
}

struct IteratedCase {
  std::uint64_t seed;
  int shared;
  Index block_columns;
};

void PrintTo(const IteratedCase& c, std::ostream* out) {
  *out << "seed" << c.seed << "_shared" << c.shared << "_columns" << c.block_columns;
}

class IteratedJoinTest : public ::testing::TestWithParam<IteratedCase> {};

TEST_P(IteratedJoinTest, EqualsTheDenseConstrainedMapAndSatisfiesTheConstraints) {
  const IteratedCase c = GetParam();
  const auto [m1, m2] = nonlinear_maps(c.seed, c.shared);
  const auto pairs = associate_by_id(m1, m2);
  ASSERT_EQ(static_cast<int>(pairs.size()), c.shared);
  const OracleJoin oracle = oracle_iterated_join(m1, m2, pairs);
  ASSERT_LT(oracle.max_constraint, 1e-9);

  JoinOptions options;
  options.block_columns = c.block_columns;
  options.max_iterations = 50;
  JoinReport report;
  const GaussianMap joined = join_maps(m1, m2, options, &report);
  EXPECT_GT(report.iterations, 2);
  EXPECT_LT(report.iterations, 20);
  expect_maps_equal(joined, oracle.map, 1e-8);
  EXPECT_LT(std::abs(wrap_angle(joined.x()(2) - oracle.map.x()(2))), 1e-8);

  // The matched features of m1 sit exactly where R1* ⊕ f'_j* puts them (the oracle's
  // constraint holds at 1e-9); the one-shot join leaves them millimetres to metres away in these cases.
  options.max_iterations = 1;
  const GaussianMap one_shot = join_maps(m1, m2, options, &report);
  EXPECT_EQ(report.iterations, 1);
  expect_maps_equal(one_shot, dense_join(m1, m2, pairs), 1e-9);
  double one_shot_error = 0.0;
  for (const auto& [i, j] : pairs) {
    const Index row = 3 + 2 * i;
    EXPECT_LT((joined.x().segment<2>(row) - oracle.map.x().segment<2>(row)).norm(), 1e-8);
    one_shot_error = std::max(
        one_shot_error, (one_shot.x().segment<2>(row) - oracle.map.x().segment<2>(row)).norm());
  }
  EXPECT_GT(one_shot_error, 1e-3);
}

INSTANTIATE_TEST_SUITE_P(Cases, IteratedJoinTest,
                         ::testing::Values(IteratedCase{1, 2, 64}, IteratedCase{2, 3, 4},
                                           IteratedCase{3, 4, 2}, IteratedCase{4, 4, 64},
                                           IteratedCase{5, 3, 6}, IteratedCase{6, 2, 2}));

// Gauss–Newton converges linearly (about a digit a step); from the second point on the join
// takes Newton steps, which converge quadratically, so a few points reach the oracle's
// constrained MAP. With R1's heading 2-3 σ further off, the maps disagree by several σ and
// Newton's first steps may not contract: Gauss–Newton steps are taken then, and the join still
// ends at the oracle's answer.
TEST(IteratedJoin, NewtonStepsReachTheConstrainedMapInAFewPoints) {
  for (const double heading_offset : {0.0, 0.6, 0.9}) {
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
      SCOPED_TRACE("seed " + std::to_string(seed) + ", heading offset " + std::to_string(heading_offset));
      const auto [m1, m2] = nonlinear_maps(seed, 2 + static_cast<int>(seed % 4), heading_offset);
      const auto pairs = associate_by_id(m1, m2);
      const OracleJoin oracle = oracle_iterated_join(m1, m2, pairs);
      ASSERT_LT(oracle.max_constraint, 1e-9);
      JoinOptions options;
      options.max_iterations = 50;
      JoinReport report;
      const GaussianMap joined = join_maps(m1, m2, options, &report);
      if (heading_offset == 0.0) {
        EXPECT_LE(report.iterations, 6);
      }
      EXPECT_LT(report.iterations, 50);
      expect_maps_equal(joined, oracle.map, 1e-8);
    }
  }
}

TEST(IteratedJoin, ResumedInSlicesGivesBitwiseTheSameResult) {
  const auto [m1, m2] = nonlinear_maps(11, 4);
  const auto first = std::make_shared<const GaussianMap>(m1);
  const auto second = std::make_shared<const GaussianMap>(m2);
  JoinOptions options;
  options.block_columns = 2;
  MapJoin at_once(first, second, options, {m1.num_features() - 1});
  at_once.finish();
  EXPECT_GT(at_once.report().iterations, 2);
  MapJoin sliced(first, second, options, {m1.num_features() - 1});
  while (!sliced.done()) sliced.advance(3);
  EXPECT_EQ(sliced.report().work_units, at_once.report().work_units);
  EXPECT_EQ(sliced.report().iterations, at_once.report().iterations);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_TRUE((a.x().array() == b.x().array()).all());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
}

TEST(IteratedJoin, FewerIterationsThanNeededStopEarly) {
  const auto [m1, m2] = nonlinear_maps(3, 4);
  JoinOptions options;
  options.max_iterations = 2;
  JoinReport report;
  const GaussianMap two = join_maps(m1, m2, options, &report);
  EXPECT_EQ(report.iterations, 2);
  options.max_iterations = 1;
  const GaussianMap one = join_maps(m1, m2, options);
  const OracleJoin oracle = oracle_iterated_join(m1, m2, associate_by_id(m1, m2));
  // Each Gauss–Newton step brings the mean closer to the constrained MAP.
  const double error_one = (one.x() - oracle.map.x()).tail(one.dim() - 3).cwiseAbs().maxCoeff();
  const double error_two = (two.x() - oracle.map.x()).tail(two.dim() - 3).cwiseAbs().maxCoeff();
  EXPECT_LT(error_two, error_one);
}

// A linearisation point given from outside (JoinTree's passes) replaces the join's own
// Gauss–Newton steps: given the prior means, the join is the one-shot join bit for bit,
// whatever max_iterations says; given another point, it differs.
TEST(IteratedJoin, AGivenLinearisationPointReplacesTheJoinsOwnSteps) {
  const auto [m1, m2] = nonlinear_maps(5, 4, 0.6);
  JoinOptions one_shot;
  one_shot.max_iterations = 1;
  const GaussianMap expected = join_maps(m1, m2, one_shot);
  JoinOptions given;
  given.max_iterations = 10;
  auto point = std::make_shared<JoinLinearisation>();
  point->first_robot = m1.robot();
  point->second_x = m2.x();
  given.linearisation = point;
  JoinReport report;
  const GaussianMap joined = join_maps(m1, m2, given, &report);
  EXPECT_EQ(report.iterations, 1);
  EXPECT_TRUE((joined.x().array() == expected.x().array()).all());
  EXPECT_TRUE((joined.P().array() == expected.P().array()).all());

  auto elsewhere = std::make_shared<JoinLinearisation>(*point);
  elsewhere->first_robot.z() += 0.05;
  given.linearisation = elsewhere;
  const GaussianMap moved = join_maps(m1, m2, given);
  EXPECT_GT((moved.x() - expected.x()).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(IteratedJoin, RejectsANonPositiveIterationCount) {
  const auto [m1, m2] = nonlinear_maps(1, 2);
  JoinOptions options;
  options.max_iterations = 0;
  EXPECT_THROW(join_maps(m1, m2, options), InvalidArgument);
}

// At a linearisation point x* other than the prior means, the frame's blocks are those of
// G* P0 G*' and its moved means are g(x*) + G* (x0 - x*), G* by central differences.
TEST(JoinFrame, LinearisedElsewhereGivesTheLinearisedMeansAndCovariance) {
  std::mt19937_64 rng(78);
  const GaussianMap m1 = random_map(rng, {0, 1, 2});
  const GaussianMap m2 = random_map(rng, {10, 11, 12});
  const Index d1 = m1.dim(), d2 = m2.dim(), D = d1 + d2;
  const Vec3 robot_at = m1.robot() + Vec3(0.7, -0.4, 0.3);
  Eigen::VectorXd second_at = m2.x();
  for (Index a = 0; a < d2; ++a) second_at(a) += 0.5 * std::sin(1.0 + a);
  const JoinFrame frame(m1, m2, robot_at, second_at);

  Eigen::VectorXd x0(D), x_at(D);
  x0 << m1.x(), m2.x();
  x_at << m1.x(), second_at;
  x_at.head<3>() = robot_at;
  const auto g = [&](const Eigen::VectorXd& x) { return oracle_to_base_one(x, d1, d2); };
  const Eigen::MatrixXd G = testing::numeric_jacobian(g, x_at);
  const Eigen::VectorXd y = g(x_at) + G * (x0 - x_at);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(D, D);
  P0.topLeftCorner(d1, d1) = m1.P();
  P0.bottomRightCorner(d2, d2) = m2.P();
  const Eigen::MatrixXd P = G * P0 * G.transpose();
  const Vec3 robot = frame.moved_second_robot();
  EXPECT_LT((robot.head<2>() - y.segment<2>(d1)).norm(), 1e-8);
  EXPECT_LT(std::abs(wrap_angle(robot.z() - y(d1 + 2))), 1e-8);
  for (Index j = 0; j < 3; ++j) {
    const Index row2 = d1 + 3 + 2 * j;
    EXPECT_LT((frame.moved_second_feature(j) - y.segment<2>(row2)).norm(), 1e-8);
    for (Index i = 0; i < 3; ++i) {
      EXPECT_LT((frame.first_second(i, j) - P.block<2, 2>(3 + 2 * i, row2)).norm(), 1e-7);
      EXPECT_LT((frame.second_second(i, j) - P.block<2, 2>(d1 + 3 + 2 * i, row2)).norm(), 1e-7);
    }
  }
  EXPECT_THROW(JoinFrame(m1, m2, robot_at, second_at.head(d2 - 1)), InvalidArgument);
}

// ---------------------------------------------------------------------------------------
// Past poses (docs/design.md §4.5): both maps already hold some, R1 is kept or not. The textbook
// oracle moves m2's poses into B1 like its robot, never constrains them, and keeps
// [R2' | F1 | F2' | Q1 | R1 | Q2'].
struct PosesCase {
  int n1, n2, shared, q1, q2;
  bool keep_first_robot;
  Index block_columns, work_unit;
};

void PrintTo(const PosesCase& c, std::ostream* out) {
  *out << "n1_" << c.n1 << "_n2_" << c.n2 << "_shared" << c.shared << "_q1_" << c.q1 << "_q2_"
       << c.q2 << (c.keep_first_robot ? "_keep" : "_drop") << "_columns" << c.block_columns
       << "_unit" << c.work_unit;
}

class MapJoiningPosesTest : public ::testing::TestWithParam<PosesCase> {};

TEST_P(MapJoiningPosesTest, EqualsTheDenseTextbookJoinAndSlicingChangesNoBit) {
  const PosesCase c = GetParam();
  std::mt19937_64 rng(2000 + c.n1 * 31 + c.n2 * 7 + c.q1 * 3 + c.q2);
  std::vector<std::int64_t> ids1, ids2;
  for (int i = 0; i < c.n1; ++i) ids1.push_back(i);
  for (int j = 0; j < c.n2; ++j) ids2.push_back(j < c.shared ? (c.n1 - 1 - 2 * j) : 1000 + j);
  std::shuffle(ids2.begin(), ids2.end(), rng);
  const auto m1 = std::make_shared<const GaussianMap>(with_past_poses(random_map(rng, ids1), rng, c.q1, 10));
  const auto m2 = std::make_shared<const GaussianMap>(with_past_poses(random_map(rng, ids2), rng, c.q2, 30));
  JoinOptions options;
  options.block_columns = c.block_columns;
  options.work_unit = c.work_unit;
  options.max_iterations = 1;  // the textbook join linearises once, at the prior means
  options.keep_first_robot = c.keep_first_robot;
  options.first_robot_id = 20;
  MapJoin at_once(m1, m2, options);
  at_once.finish();
  EXPECT_EQ(at_once.report().pairings, c.shared);
  MapJoin sliced(m1, m2, options);
  EXPECT_GT(sliced.advance(1), 0);
  while (!sliced.done()) {
    const std::int64_t before = sliced.remaining_work();
    EXPECT_GT(sliced.advance(1), 0);
    EXPECT_LE(sliced.remaining_work(), before);
  }
  EXPECT_EQ(sliced.report().work_units, at_once.report().work_units);
  const GaussianMap a = at_once.take_result(), b = sliced.take_result();
  const int kept = c.keep_first_robot ? 1 : 0;
  ASSERT_EQ(a.num_poses(), c.q1 + kept + c.q2);
  EXPECT_EQ(a.num_features(), c.n1 + c.n2 - c.shared);
  expect_maps_equal(a, dense_join(*m1, *m2, associate_by_id(*m1, *m2), {}, {}, c.keep_first_robot, 20),
                    1e-9);
  EXPECT_TRUE(a.P().isApprox(a.P().transpose(), 1e-12));
  std::vector<std::int64_t> expected_ids;
  for (int q = 0; q < c.q1; ++q) expected_ids.push_back(10 + q);
  if (c.keep_first_robot) expected_ids.push_back(20);
  for (int q = 0; q < c.q2; ++q) expected_ids.push_back(30 + q);
  EXPECT_EQ(a.pose_ids(), expected_ids);
  EXPECT_EQ(a.pose_ids(), b.pose_ids());
  EXPECT_EQ(a.ids(), b.ids());
  EXPECT_TRUE((a.x().array() == b.x().array()).all());
  EXPECT_TRUE((a.P().array() == b.P().array()).all());
}

INSTANTIATE_TEST_SUITE_P(
    Cases, MapJoiningPosesTest,
    ::testing::Values(PosesCase{5, 4, 2, 2, 3, true, 64, Index{1} << 20},
                      PosesCase{5, 4, 2, 0, 0, true, 4, Index{1} << 20},
                      PosesCase{12, 9, 3, 1, 2, true, 2, Index{1} << 20},
                      PosesCase{12, 9, 3, 3, 1, false, 6, Index{1} << 20},
                      PosesCase{0, 6, 0, 2, 1, true, 4, Index{1} << 20},
                      PosesCase{6, 0, 0, 1, 2, true, 4, Index{1} << 20},
                      // Row tiles of 64 that start on every parity and split poses.
                      PosesCase{40, 35, 12, 3, 4, true, 4, 64},
                      PosesCase{40, 35, 12, 5, 0, true, 6, 64},
                      PosesCase{30, 30, 0, 4, 5, false, 2, 64}));

// The iterated join moves m2's poses by the final linearisation, like its other elements: it
// is the constrained MAP of the stacked prior with every pose kept.
TEST(IteratedJoin, WithPastPosesEqualsTheDenseConstrainedMap) {
  for (std::uint64_t seed : {2, 5}) {
    auto [plain1, plain2] = nonlinear_maps(seed, 3);
    std::mt19937_64 rng(seed);
    const GaussianMap m1 = with_past_poses(plain1, rng, 2, 0);
    const GaussianMap m2 = with_past_poses(plain2, rng, 3, 3);
    const auto pairs = associate_by_id(m1, m2);
    const OracleJoin oracle = oracle_iterated_join(m1, m2, pairs, true, 2);
    ASSERT_LT(oracle.max_constraint, 1e-9);
    JoinOptions options;
    options.block_columns = 4;
    options.max_iterations = 50;
    options.keep_first_robot = true;
    options.first_robot_id = 2;
    JoinReport report;
    const GaussianMap joined = join_maps(m1, m2, options, &report);
    EXPECT_GT(report.iterations, 2);
    ASSERT_EQ(joined.num_poses(), 6);
    EXPECT_EQ(joined.pose_ids(), (std::vector<std::int64_t>{0, 1, 2, 3, 4, 5}));
    expect_maps_equal(joined, oracle.map, 1e-8);

    const auto first = std::make_shared<const GaussianMap>(m1);
    const auto second = std::make_shared<const GaussianMap>(m2);
    MapJoin sliced(first, second, options);
    while (!sliced.done()) sliced.advance(3);
    EXPECT_EQ(sliced.report().iterations, report.iterations);
    const GaussianMap b = sliced.take_result();
    EXPECT_TRUE((joined.x().array() == b.x().array()).all());
    EXPECT_TRUE((joined.P().array() == b.P().array()).all());
  }
}

}  // namespace
}  // namespace dcslam
