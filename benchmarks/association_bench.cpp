#include "association_bench.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <random>
#include <string>

#include <Eigen/Cholesky>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/association/ekf_association.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/core/observation.hpp"

namespace dcslam {

namespace {

using Index = Eigen::Index;

// A lawn-mowing pass is kLandmarksPerColumn landmarks long; the maps grow by adding passes.
constexpr Index kLandmarksPerColumn = 20;
constexpr double kSpacing = 1.5;
constexpr double kFeatureSigma = 0.05;
const Vec3 kRobotSigma(0.1, 0.1, 0.002);

Vec2 landmark(Index k, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> jitter(-0.2, 0.2);
  return Vec2(kSpacing * static_cast<double>(k / kLandmarksPerColumn) + jitter(rng),
              kSpacing * static_cast<double>(k % kLandmarksPerColumn) + jitter(rng));
}

GaussianMap map_with_features(Index features) {
  GaussianMap map = GaussianMap::uninitialized(features);
  map.P().setZero();
  for (Index k = 0; k < map.dim(); ++k) {
    map.P()(k, k) = kFeatureSigma * kFeatureSigma;
  }
  return map;
}

struct BenchMaps {
  GaussianMap first, second;
};

// Landmarks 0 .. h-1 are m1's, landmarks h - overlap .. 2h - overlap - 1 are m2's (h = n/2);
// ids are the landmark indices, so associate_by_id gives the truth.
BenchMaps make_maps(Index half, Index overlap, std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  std::vector<Vec2> landmarks;
  for (Index k = 0; k < 2 * half - overlap; ++k) landmarks.push_back(landmark(k, rng));
  const Vec3 robot_true(landmarks[static_cast<std::size_t>(half - 1)].x(),
                        0.5 * kSpacing * static_cast<double>(kLandmarksPerColumn), 0.3);

  BenchMaps maps{map_with_features(half), map_with_features(half)};
  GaussianMap& first = maps.first;
  first.x().head<3>() = robot_true + kRobotSigma.cwiseProduct(Vec3(normal(rng), normal(rng), normal(rng)));
  first.P().topLeftCorner<3, 3>() = kRobotSigma.cwiseAbs2().asDiagonal();
  for (Index i = 0; i < half; ++i) {
    first.x().segment<2>(GaussianMap::feature_offset(i)) =
        landmarks[static_cast<std::size_t>(i)] + kFeatureSigma * Vec2(normal(rng), normal(rng));
    first.ids()[static_cast<std::size_t>(i)] = i;
  }
  GaussianMap& second = maps.second;
  second.x().head<3>().setZero();
  second.P().topLeftCorner<3, 3>().setZero();
  for (Index j = 0; j < half; ++j) {
    const Index k = half - overlap + j;
    second.x().segment<2>(GaussianMap::feature_offset(j)) =
        inverse_transform_point(robot_true, landmarks[static_cast<std::size_t>(k)]) +
        kFeatureSigma * Vec2(normal(rng), normal(rng));
    second.ids()[static_cast<std::size_t>(j)] = k;
  }
  return maps;
}

double median(std::vector<double> values) {
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2), values.end());
  return values[values.size() / 2];
}

template <typename Work>
double median_seconds(int repetitions, Work work) {
  std::vector<double> seconds;
  for (int r = 0; r < repetitions; ++r) {
    const auto start = std::chrono::steady_clock::now();
    work();
    seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  return median(std::move(seconds));
}

int count_wrong(const JoinAssociationResult& result, const BenchMaps& maps) {
  int wrong = 0;
  for (const auto& [i, j] : result.pairs) {
    wrong += maps.first.ids()[static_cast<std::size_t>(i)] !=
                     maps.second.ids()[static_cast<std::size_t>(j)]
                 ? 1
                 : 0;
  }
  return wrong;
}

// Individual compatibility of every pair, as a join would do it without a spatial index.
Index all_pairs_compatible(const JoinFrame& frame, double gate) {
  Index compatible = 0;
  for (Index j = 0; j < frame.second().num_features(); ++j) {
    const Vec2 moved = frame.moved_second_feature(j);
    for (Index i = 0; i < frame.first().num_features(); ++i) {
      const Vec2 innovation = moved - frame.first_feature(i);
      const Mat2 covariance = frame.constraint_covariance(i, j, i, j);
      compatible += innovation.dot(covariance.ldlt().solve(innovation)) <= gate ? 1 : 0;
    }
  }
  return compatible;
}

}  // namespace

std::vector<EkfAssociationBenchRow> benchmark_ekf_association(const std::vector<Index>& features,
                                                              int scans, std::uint64_t seed) {
  if (scans < 1) throw InvalidArgument("benchmark_ekf_association: scans must be >= 1");
  std::vector<EkfAssociationBenchRow> rows;
  const Mat2 R = Vec2(0.05 * 0.05, 0.005 * 0.005).asDiagonal();
  SlamConfig config;
  config.association = Association::Jcbb;
  for (const Index n : features) {
    if (n < 5 * kLandmarksPerColumn) {
      throw InvalidArgument("benchmark_ekf_association: sizes must be >= " +
                            std::to_string(5 * kLandmarksPerColumn));
    }
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> normal;
    std::vector<Vec2> landmarks;
    for (Index k = 0; k < n; ++k) landmarks.push_back(landmark(k, rng));
    GaussianMap map = map_with_features(n);
    map.P().topLeftCorner<3, 3>() = kRobotSigma.cwiseAbs2().asDiagonal();
    for (Index k = 0; k < n; ++k) {
      map.x().segment<2>(GaussianMap::feature_offset(k)) =
          landmarks[static_cast<std::size_t>(k)] + kFeatureSigma * Vec2(normal(rng), normal(rng));
    }
    EkfAssociation association(config);
    for (Index k = 0; k < n; ++k) association.feature_added(map, k);
    const double length = kSpacing * static_cast<double>(n / kLandmarksPerColumn);
    // The sensor's reach fits inside the smallest map, so every size sees the same scans.
    const double reach = 3.5;
    std::uniform_real_distribution<double> along(reach, length - reach), heading(-M_PI, M_PI);
    std::vector<double> associate_seconds, refresh_seconds;
    EkfAssociationBenchRow row;
    row.features = n;
    std::vector<Index> pairing;
    std::vector<int> nearby;
    std::map<std::string, double> counters;
    for (int s = 0; s < scans; ++s) {
      const Vec3 robot_true(along(rng), 0.5 * kSpacing * kLandmarksPerColumn, heading(rng));
      map.x().head<3>() = robot_true + kRobotSigma.cwiseProduct(Vec3(normal(rng), normal(rng), normal(rng)));
      std::vector<Vec2> measured;
      for (const Vec2& l : landmarks) {
        if ((l - robot_true.head<2>()).norm() > reach) continue;
        measured.push_back(observe(ObservationModel::RangeBearing, Vec3::Zero(), robot_true, l) +
                           Vec2(0.05 * normal(rng), 0.005 * normal(rng)));
      }
      MeasurementMatrix z(static_cast<Index>(measured.size()), 2);
      for (std::size_t i = 0; i < measured.size(); ++i) z.row(static_cast<Index>(i)) = measured[i].transpose();
      const ScanNoise noise({R}, static_cast<std::size_t>(z.rows()));
      for (Index i = 0; i < z.rows(); ++i) {
        association.candidates(map, z.row(i).transpose(), R, nearby);
        row.candidates += static_cast<double>(nearby.size());
      }
      row.measurements += static_cast<double>(z.rows());
      auto start = std::chrono::steady_clock::now();
      association.associate(map, z, noise, {}, pairing, counters);
      associate_seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      start = std::chrono::steady_clock::now();
      association.map_updated(map);
      refresh_seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
    row.measurements /= scans;
    row.candidates /= scans;
    row.seconds_associate = median(associate_seconds);
    row.seconds_map_updated = median(refresh_seconds);
    rows.push_back(row);
  }
  return rows;
}

double fitted_exponent(const std::vector<double>& x, const std::vector<double>& y) {
  if (x.size() != y.size() || x.size() < 2) {
    throw InvalidArgument("fitted_exponent: needs two or more (x, y) points");
  }
  const auto n = static_cast<double>(x.size());
  double mean_x = 0.0, mean_y = 0.0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    if (!(x[k] > 0.0) || !(y[k] > 0.0)) throw InvalidArgument("fitted_exponent: values must be > 0");
    mean_x += std::log(x[k]) / n;
    mean_y += std::log(y[k]) / n;
  }
  double sxx = 0.0, sxy = 0.0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    const double dx = std::log(x[k]) - mean_x;
    sxx += dx * dx;
    sxy += dx * (std::log(y[k]) - mean_y);
  }
  if (!(sxx > 0.0)) throw InvalidArgument("fitted_exponent: x values must not all be equal");
  return sxy / sxx;
}

AssociationBenchResult benchmark_join_association(const std::vector<Index>& total_features,
                                                  int overlap_features, int repetitions,
                                                  std::uint64_t seed) {
  if (overlap_features < 1) throw InvalidArgument("benchmark_join_association: overlap must be >= 1");
  if (repetitions < 1) throw InvalidArgument("benchmark_join_association: repetitions must be >= 1");
  std::mt19937_64 rng(seed);
  // The joins of a DCSlam with the default configuration, gates and all.
  const JoinOptions defaults = join_options_of(SlamConfig());
  const double gate = chi2_quantile(2, defaults.rjc.confidence);
  AssociationBenchResult result;
  std::vector<double> n, rjc_seconds, jcbb_seconds, all_pairs_seconds;
  for (Index total : total_features) {
    const Index half = total / 2;
    if (half < 2 * overlap_features) {
      throw InvalidArgument("benchmark_join_association: each size must be >= 4 * overlap");
    }
    const BenchMaps maps = make_maps(half, overlap_features, rng);
    const JoinFrame frame(maps.first, maps.second);
    AssociationBenchRow row;
    row.features = 2 * half;
    row.true_pairs = static_cast<int>(associate_by_id(maps.first, maps.second).size());

    JoinOptions options = defaults;
    options.rjc.seed = seed;
    JoinAssociationResult association;
    options.association = JoinAssociation::Rjc;
    row.seconds_rjc = median_seconds(repetitions, [&] { association = associate_maps(frame, options); });
    row.overlap = association.overlap;
    row.pairs_rjc = static_cast<int>(association.pairs.size());
    row.wrong_rjc = count_wrong(association, maps);
    row.tries_rjc = association.tries;
    options.association = JoinAssociation::Jcbb;
    row.seconds_jcbb = median_seconds(repetitions, [&] { association = associate_maps(frame, options); });
    row.pairs_jcbb = static_cast<int>(association.pairs.size());
    row.wrong_jcbb = count_wrong(association, maps);
    row.seconds_all_pairs = median_seconds(
        repetitions, [&] { row.compatible_all_pairs = all_pairs_compatible(frame, gate); });

    n.push_back(static_cast<double>(row.features));
    rjc_seconds.push_back(row.seconds_rjc);
    jcbb_seconds.push_back(row.seconds_jcbb);
    all_pairs_seconds.push_back(row.seconds_all_pairs);
    result.rows.push_back(row);
  }
  if (n.size() >= 2) {
    result.exponent_rjc = fitted_exponent(n, rjc_seconds);
    result.exponent_jcbb = fitted_exponent(n, jcbb_seconds);
    result.exponent_all_pairs = fitted_exponent(n, all_pairs_seconds);
  }
  return result;
}

}  // namespace dcslam
