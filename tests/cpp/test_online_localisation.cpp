// localise_against() against the joint Gaussian of the three independent parts, conditioned
// directly: every function of the stacked state differentiated by central differences, the
// conditional mean g - J_g Σ J_h' (J_h Σ J_h')^-1 h computed as one dense solve.
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dcslam/joining/join_options.hpp"
#include "dcslam/joining/online_localisation.hpp"
#include "numeric_jacobian.hpp"
#include "random_map.hpp"

namespace dcslam {
namespace {

using Eigen::Index;

constexpr double kAlways = std::numeric_limits<double>::infinity();

struct Stacked {
  Eigen::VectorXd mean;
  Eigen::MatrixXd covariance;
};

// [oldest's state; the links; newest's state], block diagonal.
Stacked stack(const GaussianMap& oldest, const std::vector<PoseLink>& between, const GaussianMap& newest) {
  const Index d = oldest.dim() + 3 * static_cast<Index>(between.size()) + newest.dim();
  Stacked s{Eigen::VectorXd::Zero(d), Eigen::MatrixXd::Zero(d, d)};
  s.mean.head(oldest.dim()) = oldest.x();
  s.covariance.topLeftCorner(oldest.dim(), oldest.dim()) = oldest.P();
  Index at = oldest.dim();
  for (const PoseLink& link : between) {
    s.mean.segment<3>(at) = link.mean;
    s.covariance.block<3, 3>(at, at) = link.covariance;
    at += 3;
  }
  s.mean.tail(newest.dim()) = newest.x();
  s.covariance.bottomRightCorner(newest.dim(), newest.dim()) = newest.P();
  return s;
}

// The newest map's base in oldest's base frame, as a function of the stacked state.
Vec3 newest_base(const Eigen::VectorXd& z, const GaussianMap& oldest, Index links) {
  Vec3 base = z.head<3>();
  for (Index k = 0; k < links; ++k) base = compose(base, z.segment<3>(oldest.dim() + 3 * k));
  return base;
}

TEST(OnlineLocalisation, EqualsTheJointGaussianConditionedOnThePairsByCentralDifferences) {
  std::mt19937_64 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    const GaussianMap oldest = random_map(rng, {1, 2, 3, 4, 5, 6, 7, 8});
    GaussianMap newest = random_map(rng, {4, 9, 2, 6, 11, 1, 8, 5, 3});
    newest.P() *= 0.3;
    std::vector<PoseLink> between(static_cast<std::size_t>(trial % 3));
    std::normal_distribution<double> normal;
    for (PoseLink& link : between) {
      link.mean = Vec3(3 * normal(rng), 3 * normal(rng), normal(rng));
      Mat3 A = Mat3::Random() * 0.2;
      link.covariance = A * A.transpose() + 0.01 * Mat3::Identity();
    }
    const std::vector<Index> left_out{3, 7};  // ids 6 and 5: their pairs must not count
    JoinOptions options;
    options.association = JoinAssociation::Known;
    const auto localised = localise_against(oldest, between, newest, left_out, kAlways, options);
    ASSERT_TRUE(localised.has_value());
    EXPECT_EQ(localised->pairs, 5);  // ids 4, 2, 1, 8 and 3

    const Stacked s = stack(oldest, between, newest);
    const auto links = static_cast<Index>(between.size());
    const Index newest_at = oldest.dim() + 3 * links;
    const auto g = [&](const Eigen::VectorXd& z) -> Eigen::VectorXd {
      return compose(newest_base(z, oldest, links), z.segment<3>(newest_at));
    };
    // Pairs by id (oldest's feature, newest's): ids 4, 2, 1, 8 and 3.
    const std::vector<std::pair<Index, Index>> pairs{{3, 0}, {1, 2}, {0, 5}, {7, 6}, {2, 8}};
    const auto h = [&](const Eigen::VectorXd& z) -> Eigen::VectorXd {
      Eigen::VectorXd out(2 * static_cast<Index>(pairs.size()));
      const Vec3 base = newest_base(z, oldest, links);
      for (std::size_t a = 0; a < pairs.size(); ++a) {
        const auto [i, j] = pairs[a];
        out.segment<2>(2 * static_cast<Index>(a)) =
            z.segment<2>(GaussianMap::feature_offset(i)) -
            transform_point(base, z.segment<2>(newest_at + GaussianMap::feature_offset(j)));
      }
      return out;
    };
    const Eigen::MatrixXd J_g = testing::numeric_jacobian(g, s.mean, {2});
    const Eigen::MatrixXd J_h = testing::numeric_jacobian(h, s.mean);
    const Eigen::MatrixXd S = J_h * s.covariance * J_h.transpose();
    const Eigen::MatrixXd C = J_g * s.covariance * J_h.transpose();
    Vec3 expected = g(s.mean) - C * S.ldlt().solve(h(s.mean));
    expected.z() = wrap_angle(expected.z());
    EXPECT_LT((localised->pose.head<2>() - expected.head<2>()).norm(), 1e-6) << "trial " << trial;
    EXPECT_NEAR(wrap_angle(localised->pose.z() - expected.z()), 0.0, 1e-6) << "trial " << trial;
  }
}

// An amortized D&C spreads a localisation over steps: any slicing gives the one-go result.
TEST(OnlineLocalisation, InAnySlicesItIsTheLocalisationRunAtOnce) {
  std::mt19937_64 rng(19);
  std::normal_distribution<double> normal;
  int localised = 0;
  for (int trial = 0; trial < 6; ++trial) {
    std::vector<std::int64_t> old_ids;
    for (std::int64_t id = 0; id < 40; ++id) old_ids.push_back(id);
    GaussianMap oldest = random_map(rng, old_ids);
    oldest.P() *= 0.01;
    PoseLink link{Vec3(2 * normal(rng), 2 * normal(rng), 0.3 * normal(rng)), 1e-4 * Mat3::Identity()};
    // The newest map sees 20 of oldest's features from its base, oldest's robot ⊕ link (new ids:
    // association without ids has to find them).
    const Vec3 base = compose(oldest.robot(), link.mean);
    GaussianMap newest;
    for (Index k = 0; k < 20; ++k) {
      const Vec2 seen = transform_point(invert(base), oldest.feature(2 * k)) + 0.01 * Vec2(normal(rng), normal(rng));
      newest.append_feature(seen, 100 + k);
    }
    newest.x().head<3>() = Vec3(normal(rng), normal(rng), 0.1 * normal(rng));
    newest.P() = 1e-4 * Eigen::MatrixXd::Identity(newest.dim(), newest.dim());
    JoinOptions options;
    options.association = JoinAssociation::Rjc;
    options.rjc.seed = static_cast<std::uint64_t>(trial);
    const auto shared = [](const GaussianMap& map) { return std::make_shared<const GaussianMap>(map); };
    const LocalisationInputs inputs{shared(oldest), {link}, shared(newest), {2}, kAlways, options};
    MapLocalisation at_once(inputs);
    at_once.finish();
    MapLocalisation sliced(inputs);
    std::uniform_int_distribution<std::int64_t> budget(1, 50);
    int steps = 0;
    while (!sliced.done()) {
      ASSERT_GT(sliced.remaining_work(), 0);
      sliced.advance(budget(rng));
      ++steps;
    }
    EXPECT_GT(steps, 3) << "trial " << trial;
    EXPECT_EQ(sliced.remaining_work(), 0);
    ASSERT_EQ(sliced.result().has_value(), at_once.result().has_value()) << "trial " << trial;
    if (!at_once.result()) continue;
    ++localised;
    EXPECT_EQ(sliced.result()->pairs, at_once.result()->pairs);
    EXPECT_TRUE(sliced.result()->pose == at_once.result()->pose) << "trial " << trial;
    EXPECT_GE(at_once.result()->pairs, 17) << "trial " << trial;  // 19 kept features, all in oldest
  }
  EXPECT_GE(localised, 5);
}

TEST(OnlineLocalisation, NoPairNoLocalisation) {
  std::mt19937_64 rng(3);
  const GaussianMap oldest = random_map(rng, {1, 2, 3, 4, 5, 6});
  JoinOptions options;
  options.association = JoinAssociation::Known;
  EXPECT_FALSE(localise_against(oldest, {}, random_map(rng, {7, 8, 9, 10, 11}), {}, kAlways, options).has_value());
  EXPECT_FALSE(localise_against(oldest, {}, GaussianMap(), {}, kAlways, options).has_value());
  EXPECT_FALSE(localise_against(GaussianMap(), {}, oldest, {}, kAlways, options).has_value());
  EXPECT_TRUE(localise_against(oldest, {}, random_map(rng, {1, 2, 3, 4, 5, 9}), {}, kAlways, options).has_value());
}

// The cap is on the position std of newest's robot moved through the chain, relative to
// oldest's robot: here the chain's own, newest's robot being certain.
TEST(OnlineLocalisation, AboveItsPositionSigmaTheChainDecides) {
  std::mt19937_64 rng(5);
  const GaussianMap oldest = random_map(rng, {1, 2, 3, 4, 5, 6});
  GaussianMap newest = random_map(rng, {1, 2, 3, 4, 5, 6});
  newest.P().setZero();
  newest.P().bottomRightCorner(12, 12) = 0.01 * Eigen::MatrixXd::Identity(12, 12);
  PoseLink link;
  link.mean = Vec3(1.0, 2.0, 0.3);
  link.covariance = Vec3(4.0, 1.0, 0.0).asDiagonal();  // position std 2 m along x at most
  JoinOptions options;
  options.association = JoinAssociation::Known;
  EXPECT_FALSE(localise_against(oldest, {link}, newest, {}, 1.99, options).has_value());
  const auto localised = localise_against(oldest, {link}, newest, {}, 2.01, options);
  ASSERT_TRUE(localised.has_value());
  EXPECT_EQ(localised->pairs, 6);
  // Fewer than five pairs: the chain decides too.
  EXPECT_FALSE(localise_against(oldest, {link}, newest, {0, 1}, kAlways, options).has_value());
}

}  // namespace
}  // namespace dcslam
