// One property suite run over both of the library's pairing models (EkfPairingModel, for both
// observation models, and a map join's JoinPairingModel, with and without a feature sigma;
// RJC's internal SampledModel only re-indexes one of them): the contract of
// jcbb.hpp checked against an oracle that knows nothing of the model's algebra. The oracle
// draws the random state the model linearises (the map, or both maps of a join, from their
// Gaussians, and the measurement noise) and evaluates the innovations non-linearly; their
// empirical covariance must be the model's covariance(a, b).
#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "dcslam/association/ekf_association.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/observation.hpp"
#include "dcslam/core/slam_filter.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/join_frame.hpp"

namespace dcslam {
namespace {

using Eigen::Index;
using Eigen::MatrixXd;
using Eigen::VectorXd;

constexpr int kSamples = 40000;

// A model, the pairings it is tested on, its innovation computed from the definition, and a
// draw of their innovations from the random state behind it (a sample of nu minus its mean,
// non-linearly evaluated).
class ModelCase {
 public:
  virtual ~ModelCase() = default;
  virtual const PairingModel& model() const = 0;
  virtual Vec2 expected_innovation(const Pairing& pairing) const = 0;
  virtual std::vector<Vec2> draw(const std::vector<Pairing>& pairings, std::mt19937_64& rng) const = 0;
  std::vector<Pairing> pairings;
};

// A fresh distribution per number: no cached value carries over from one test to the next.
double standard_normal(std::mt19937_64& rng) { return std::normal_distribution<double>()(rng); }

VectorXd draw_gaussian(const VectorXd& mean, const MatrixXd& lower, std::mt19937_64& rng) {
  VectorXd white(mean.size());
  for (Index i = 0; i < white.size(); ++i) white(i) = standard_normal(rng);
  return mean + lower * white;
}

// A map with features 2-4 m from the robot and a random dense covariance: small enough
// (centimetres, a hundredth of a radian) that the models' linearisation is exact to well
// within the sampling error, correlated everywhere.
GaussianMap random_map(std::mt19937_64& rng, int features, std::int64_t first_id) {
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  GaussianMap map;
  map.x().head<3>() = Vec3(uniform(rng), uniform(rng), 3.0 * uniform(rng));
  for (int k = 0; k < features; ++k) {
    const double range = 3.0 + uniform(rng), angle = 3.14159 * uniform(rng);
    map.append_feature(map.robot().head<2>() + range * Vec2(std::cos(angle), std::sin(angle)), first_id + k);
  }
  const Index dim = map.dim();
  MatrixXd A(dim, dim);
  for (Index i = 0; i < dim; ++i) {
    for (Index j = 0; j < dim; ++j) A(i, j) = uniform(rng);
  }
  VectorXd scale = VectorXd::Constant(dim, 0.03);
  scale(2) = 0.01;
  const MatrixXd core = A * A.transpose() / static_cast<double>(dim) + 0.1 * MatrixXd::Identity(dim, dim);
  map.P() = scale.asDiagonal() * core * scale.asDiagonal();
  return map;
}

MatrixXd lower_factor(const MatrixXd& P) { return Eigen::LLT<MatrixXd>(P).matrixL(); }

// EkfPairingModel: nu_a = z_i - h(x_R, f_j); the random state is the map and each
// measurement's noise.
class EkfCase : public ModelCase {
 public:
  EkfCase(ObservationModel observation, std::uint64_t seed) : observation_(observation) {
    std::mt19937_64 rng(seed);
    map_ = random_map(rng, 5, 100);
    z_.resize(3, 2);
    for (int i = 0; i < 3; ++i) {
      z_.row(i) = observe(observation_, kOffset, map_.robot(), map_.feature(i)).transpose();
      R_.push_back(observation_ == ObservationModel::RangeBearing ? Mat2(Vec2(4e-4, 1e-4).asDiagonal())
                                                                   : Mat2(Vec2(9e-4, 4e-4).asDiagonal()));
      R_.back()(0, 1) = R_.back()(1, 0) = 0.3 * std::sqrt(R_.back()(0, 0) * R_.back()(1, 1));
    }
    noise_.assign(R_, 3);
    model_.reset(map_, observation_, kOffset, z_, noise_);
    for (int j = 0; j < map_.num_features(); ++j) model_.prepare(j);
    pairings = {{0, 0}, {0, 3}, {1, 1}, {1, 0}, {2, 4}, {2, 2}};
    state_lower_ = lower_factor(map_.P());
    for (const Mat2& r : R_) noise_lower_.push_back(Eigen::LLT<Mat2>(r).matrixL());
  }
  const PairingModel& model() const override { return model_; }
  std::vector<Vec2> draw(const std::vector<Pairing>& drawn, std::mt19937_64& rng) const override {
    GaussianMap sample = map_;
    sample.x() = draw_gaussian(map_.x(), state_lower_, rng);
    std::vector<Vec2> noise;
    for (const Mat2& lower : noise_lower_) noise.push_back(lower * Vec2(standard_normal(rng), standard_normal(rng)));
    std::vector<Vec2> nu;
    for (const Pairing& p : drawn) {
      // The true measurement of the sampled state, against the estimate's prediction.
      const Vec2 truth = observe(observation_, kOffset, sample.robot(), sample.feature(p.feature));
      const Vec2 predicted = observe(observation_, kOffset, map_.robot(), map_.feature(p.feature));
      nu.push_back(innovation(observation_, truth, predicted) + noise[static_cast<std::size_t>(p.measurement)]);
    }
    return nu;
  }
  // z_i - h(x_R, f_j) at the means.
  Vec2 expected_innovation(const Pairing& p) const override {
    return innovation(observation_, z_.row(p.measurement).transpose(),
                      observe(observation_, kOffset, map_.robot(), map_.feature(p.feature)));
  }

 private:
  inline static const Vec3 kOffset{0.4, -0.2, 0.1};
  ObservationModel observation_;
  GaussianMap map_;
  MeasurementMatrix z_;
  std::vector<Mat2> R_;
  ScanNoise noise_;
  EkfPairingModel model_;
  MatrixXd state_lower_;
  std::vector<Mat2> noise_lower_;
};

// JoinPairingModel: nu = x_{B1 R1} ⊕ f2_j - f1_i; the random state is both maps, drawn
// independently (a join's inputs share no information), and with a feature sigma s one
// independent N(0, s^2 I) error per feature.
class JoinCase : public ModelCase {
 public:
  JoinCase(double feature_sigma, std::uint64_t seed) : feature_sigma_(feature_sigma) {
    std::mt19937_64 rng(seed);
    first_ = random_map(rng, 5, 100);
    second_ = random_map(rng, 4, 200);
    frame_ = std::make_unique<JoinFrame>(first_, second_);
    model_ = std::make_unique<JoinPairingModel>(*frame_, feature_sigma_);
    pairings = {{0, 0}, {0, 2}, {1, 1}, {1, 0}, {2, 4}, {3, 3}, {3, 2}};
    first_lower_ = lower_factor(first_.P());
    second_lower_ = lower_factor(second_.P());
  }
  const PairingModel& model() const override { return *model_; }
  std::vector<Vec2> draw(const std::vector<Pairing>& drawn, std::mt19937_64& rng) const override {
    GaussianMap first = first_, second = second_;
    first.x() = draw_gaussian(first_.x(), first_lower_, rng);
    second.x() = draw_gaussian(second_.x(), second_lower_, rng);
    const auto feature_error = [&]() { return Vec2(feature_sigma_ * standard_normal(rng), feature_sigma_ * standard_normal(rng)); };
    std::vector<Vec2> first_error, second_error;
    for (Index i = 0; i < first_.num_features(); ++i) first_error.push_back(feature_error());
    for (Index j = 0; j < second_.num_features(); ++j) second_error.push_back(feature_error());
    std::vector<Vec2> nu;
    for (const Pairing& p : drawn) {
      const Vec2 moved = transform_point(first.robot(), second.feature(p.measurement)) +
                         second_error[static_cast<std::size_t>(p.measurement)];
      const Vec2 at_mean = transform_point(first_.robot(), second_.feature(p.measurement));
      nu.push_back(moved - at_mean - (first.feature(p.feature) + first_error[static_cast<std::size_t>(p.feature)] -
                                      first_.feature(p.feature)));
    }
    return nu;
  }
  Vec2 expected_innovation(const Pairing& p) const override {
    return transform_point(first_.robot(), second_.feature(p.measurement)) - first_.feature(p.feature);
  }

 private:
  double feature_sigma_;
  GaussianMap first_, second_;
  std::unique_ptr<JoinFrame> frame_;
  std::unique_ptr<JoinPairingModel> model_;
  MatrixXd first_lower_, second_lower_;
};

struct Case {
  std::string name;
  std::function<std::unique_ptr<ModelCase>()> make;
};

std::vector<Case> every_model() {
  std::vector<Case> cases;
  for (const auto& [name, observation] : {std::pair{"EkfRangeBearing", ObservationModel::RangeBearing},
                                          std::pair{"EkfPoint", ObservationModel::Point}}) {
    cases.push_back({name, [observation = observation] { return std::make_unique<EkfCase>(observation, 11); }});
  }
  for (const auto& [name, sigma] : {std::pair{"Join", 0.0}, std::pair{"JoinFeatureSigma", 0.02}}) {
    cases.push_back({name, [sigma = sigma] { return std::make_unique<JoinCase>(sigma, 12); }});
  }
  return cases;
}

void PrintTo(const Case& tested, std::ostream* out) { *out << tested.name; }

class PairingModelProperties : public ::testing::TestWithParam<Case> {};

TEST_P(PairingModelProperties, InnovationIsTheDefinitionAtTheMeans) {
  const auto tested = GetParam().make();
  for (const Pairing& p : tested->pairings) {
    EXPECT_LT((tested->model().innovation(p) - tested->expected_innovation(p)).norm(), 1e-12);
  }
}

TEST_P(PairingModelProperties, CovarianceIsSymmetricAcrossPairings) {
  const auto tested = GetParam().make();
  for (const Pairing& a : tested->pairings) {
    for (const Pairing& b : tested->pairings) {
      const Mat2 ab = tested->model().covariance(a, b), ba = tested->model().covariance(b, a);
      EXPECT_LT((ab - ba.transpose()).norm(), 1e-14 * (1.0 + ab.norm()));
    }
  }
}

TEST_P(PairingModelProperties, StackedCovarianceOfDistinctMeasurementsIsPositiveDefinite) {
  const auto tested = GetParam().make();
  // One pairing per measurement, every choice of the second pairing for each.
  const std::vector<Pairing>& all = tested->pairings;
  for (std::size_t skip = 0; skip < all.size(); ++skip) {
    std::vector<Pairing> chosen;
    for (std::size_t k = 0; k < all.size(); ++k) {
      const bool taken = std::any_of(chosen.begin(), chosen.end(),
                                     [&](const Pairing& p) { return p.measurement == all[k].measurement; });
      if (k != skip && !taken) chosen.push_back(all[k]);
    }
    const auto n = static_cast<Index>(chosen.size());
    MatrixXd S(2 * n, 2 * n);
    for (Index a = 0; a < n; ++a) {
      for (Index b = 0; b < n; ++b) {
        S.block<2, 2>(2 * a, 2 * b) = tested->model().covariance(chosen[static_cast<std::size_t>(a)],
                                                                 chosen[static_cast<std::size_t>(b)]);
      }
    }
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<MatrixXd>(S).eigenvalues().minCoeff(), 0.0);
  }
}

// covariance(a, b) = E[nu_a nu_b'] of the sampled innovations, block by block, within five
// standard errors of the sample covariance (var of an entry's estimate: (C_aa C_bb + C_ab^2)/N).
TEST_P(PairingModelProperties, CovarianceIsTheInnovationsSampledCovariance) {
  const auto tested = GetParam().make();
  const std::vector<Pairing>& pairings = tested->pairings;
  const auto k = static_cast<Index>(pairings.size());
  std::mt19937_64 rng(2026);
  MatrixXd samples(kSamples, 2 * k);
  for (int s = 0; s < kSamples; ++s) {
    const std::vector<Vec2> nu = tested->draw(pairings, rng);
    for (Index a = 0; a < k; ++a) samples.block<1, 2>(s, 2 * a) = nu[static_cast<std::size_t>(a)].transpose();
  }
  const MatrixXd centred = samples.rowwise() - samples.colwise().mean();
  const MatrixXd empirical = centred.transpose() * centred / static_cast<double>(kSamples - 1);
  MatrixXd model(2 * k, 2 * k);
  for (Index a = 0; a < k; ++a) {
    for (Index b = 0; b < k; ++b) {
      model.block<2, 2>(2 * a, 2 * b) = tested->model().covariance(pairings[static_cast<std::size_t>(a)],
                                                                   pairings[static_cast<std::size_t>(b)]);
    }
  }
  for (Index r = 0; r < 2 * k; ++r) {
    for (Index c = 0; c < 2 * k; ++c) {
      const double standard_error = std::sqrt((model(r, r) * model(c, c) + model(r, c) * model(r, c)) / kSamples);
      EXPECT_LT(std::abs(empirical(r, c) - model(r, c)), 5.0 * standard_error) << "entry " << r << ", " << c;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(EveryModel, PairingModelProperties, ::testing::ValuesIn(every_model()),
                         [](const ::testing::TestParamInfo<Case>& info) { return info.param.name; });

// The EKF model keeps each scan's H_a P H_b' blocks (up to EkfPairingModel's table of 256
// prepared features, computed directly beyond): on a map of 300 features, every block against
// H P H' with the Jacobians by central differences of observe(), before and after a reset()
// onto another map (a kept block must not outlive the scan), with the measurement noise on a
// shared measurement only.
TEST(EkfPairingModelBlocks, AreHPHtBeyondTheTableAndAfterAReset) {
  std::mt19937_64 rng(11);
  const Vec3 offset(0.4, -0.2, 0.1);
  MeasurementMatrix z = MeasurementMatrix::Zero(2, 2);
  const std::vector<Mat2> R{Mat2(Vec2(4e-4, 1e-4).asDiagonal()), Mat2(Vec2(9e-4, 4e-4).asDiagonal())};
  ScanNoise noise;
  noise.assign(R, 2);
  const auto jacobian = [&](const GaussianMap& map, int feature) {
    Eigen::Matrix<double, 2, Eigen::Dynamic> H = Eigen::Matrix<double, 2, Eigen::Dynamic>::Zero(2, map.dim());
    const Index columns[5] = {0, 1, 2, GaussianMap::feature_offset(feature), GaussianMap::feature_offset(feature) + 1};
    for (const Index c : columns) {
      GaussianMap up = map, down = map;
      up.x()(c) += 1e-6;
      down.x()(c) -= 1e-6;
      H.col(c) = (observe(ObservationModel::RangeBearing, offset, up.robot(), up.feature(feature)) -
                  observe(ObservationModel::RangeBearing, offset, down.robot(), down.feature(feature))) / 2e-6;
    }
    return H;
  };
  EkfPairingModel model;
  for (const std::uint64_t draw : {0, 1}) {
    const GaussianMap map = random_map(rng, 300, 1000 * static_cast<std::int64_t>(draw));
    model.reset(map, ObservationModel::RangeBearing, offset, z, noise);
    // Prepared out of order, so that table slots and feature indices differ.
    for (int j = map.num_features() - 1; j >= 0; --j) model.prepare(j);
    for (const auto& [a, b] : std::vector<std::pair<int, int>>{{299, 299}, {299, 0}, {0, 299}, {5, 17}, {44, 44},
                                                              {100, 250}, {250, 100}, {43, 2}}) {
      const Eigen::MatrixXd expected = jacobian(map, a) * map.P() * jacobian(map, b).transpose();
      for (int repeat = 0; repeat < 2; ++repeat) {
        const Mat2 other = model.covariance(Pairing{0, a}, Pairing{1, b});
        const Mat2 shared = model.covariance(Pairing{1, a}, Pairing{1, b});
        EXPECT_LT((other - expected).cwiseAbs().maxCoeff(), 1e-8) << a << ", " << b << " draw " << draw;
        EXPECT_LT((shared - expected - R[1]).cwiseAbs().maxCoeff(), 1e-8) << a << ", " << b << " draw " << draw;
      }
    }
  }
}

}  // namespace
}  // namespace dcslam
