#include "dcslam/simulator.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <sstream>
#include <string>

#include "dcslam/errors.hpp"

namespace dcslam {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Samplers over raw mt19937_64 output. std::uniform_real_distribution and friends are not
// specified bit for bit, so they would tie a seed's simulation to one standard library.
class Random {
 public:
  explicit Random(std::uint64_t seed) : engine_(seed) {}

  // Uniform in [0, 1), 53 random bits.
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }

  // Uniform index in [0, n); the bias of flooring is below 2^-40 for any n used here.
  std::size_t index_below(std::size_t n) {
    return std::min(n - 1, static_cast<std::size_t>(uniform() * static_cast<double>(n)));
  }

  // Standard normal, Marsaglia's polar method (keeps the second variate of each pair).
  double normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u, v, s;
    do {
      u = uniform(-1.0, 1.0);
      v = uniform(-1.0, 1.0);
      s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    const double scale = std::sqrt(-2.0 * std::log(s) / s);
    spare_ = v * scale;
    has_spare_ = true;
    return u * scale;
  }

  // Poisson by Knuth's product of uniforms, in chunks of mean <= 30 (a sum of independent
  // Poissons is Poisson) so that exp(-mean) never underflows.
  std::int64_t poisson(double mean) {
    constexpr double kChunk = 30.0;
    std::int64_t count = 0;
    while (mean > 0.0) {
      const double chunk = std::min(mean, kChunk);
      mean -= chunk;
      const double limit = std::exp(-chunk);
      double product = uniform();
      while (product > limit) {
        ++count;
        product *= uniform();
      }
    }
    return count;
  }

 private:
  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

void require(bool ok, const std::string& message) {
  if (!ok) throw InvalidArgument("SimulationConfig." + message);
}

// Shortest faithful text of a number for messages (std::to_string prints 1e-9 as 0.000000).
std::string str(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

// One straight run of `length` steps, then a turn (rad, left positive) at the end of its
// last step.
struct Segment {
  int length;
  double turn;
};

// Steps of the inward square spiral with outer side `side` and ring spacing `spacing`:
// sides side, side, side, side - d, side - d, side - 2d, side - 2d, ... while positive.
std::vector<Segment> snail_segments(int side, int spacing) {
  std::vector<Segment> segments{{side, kPi / 2}, {side, kPi / 2}};
  for (int length = side; length > 0; length -= spacing) {
    segments.push_back({length, kPi / 2});
    if (length != side) segments.push_back({length, kPi / 2});
  }
  return segments;
}

std::int64_t total_steps(const std::vector<Segment>& segments) {
  std::int64_t total = 0;
  for (const Segment& segment : segments) total += segment.length;
  return total;
}

// One period of the trajectory's turn pattern; the trajectory repeats it until `steps`
// (the snail's spiral is sized to hold them all).
std::vector<Segment> trajectory_pattern(const SimulationConfig& config) {
  const int steps = config.steps;
  const int spacing = config.lane_spacing_steps;
  switch (config.trajectory) {
    case Trajectory::Straight:
      return {{steps, 0.0}};
    case Trajectory::Loop: {
      const int side = config.side_steps.value_or(std::max(1, steps / 4));
      return {{side, kPi / 2}};
    }
    case Trajectory::LawnMowing: {
      // Lanes of length s and spacing d: about steps / (s + d) lanes spanning steps d / (s + d)
      // across, which equals s (a square region) for s ~ sqrt(steps d).
      const int lane = config.side_steps.value_or(std::max(
          1, static_cast<int>(std::lround(std::sqrt(static_cast<double>(steps) * spacing)))));
      return {{lane, kPi / 2}, {spacing, kPi / 2}, {lane, -kPi / 2}, {spacing, -kPi / 2}};
    }
    case Trajectory::Snail: {
      if (config.side_steps) {
        std::vector<Segment> segments = snail_segments(*config.side_steps, spacing);
        require(total_steps(segments) >= steps,
                "steps: a snail of side_steps=" + std::to_string(*config.side_steps) +
                    " has only " + std::to_string(total_steps(segments)) + " steps, asked for " +
                    std::to_string(steps));
        return segments;
      }
      int side = 1;
      while (total_steps(snail_segments(side, spacing)) < steps) ++side;
      return snail_segments(side, spacing);
    }
  }
  return {};
}

std::vector<double> commanded_turns(const SimulationConfig& config) {
  const std::vector<Segment> pattern = trajectory_pattern(config);
  std::vector<double> turns;
  turns.reserve(static_cast<std::size_t>(config.steps));
  while (static_cast<int>(turns.size()) < config.steps) {
    for (const Segment& segment : pattern) {
      for (int i = 0; i < segment.length && static_cast<int>(turns.size()) < config.steps; ++i) {
        turns.push_back(i + 1 == segment.length ? segment.turn : 0.0);
      }
    }
  }
  return turns;
}

// Buckets features in square cells of the sensor's range, so that finding the features
// around a sensor touches a bounded number of cells whatever the map size.
class FeatureGrid {
 public:
  FeatureGrid(const Simulation::Rows<2>& features, const Vec2& origin, double cell_size,
              Eigen::Index columns, Eigen::Index rows)
      : origin_(origin), cell_size_(cell_size), columns_(columns), rows_(rows) {
    std::vector<Eigen::Index> cell_of(static_cast<std::size_t>(features.rows()));
    cell_start_.assign(static_cast<std::size_t>(columns * rows + 1), 0);
    for (Eigen::Index i = 0; i < features.rows(); ++i) {
      const Eigen::Index cell =
          row_of(features(i, 1)) * columns_ + column_of(features(i, 0));
      cell_of[static_cast<std::size_t>(i)] = cell;
      ++cell_start_[static_cast<std::size_t>(cell + 1)];
    }
    std::partial_sum(cell_start_.begin(), cell_start_.end(), cell_start_.begin());
    members_.resize(static_cast<std::size_t>(features.rows()));
    std::vector<Eigen::Index> fill(cell_start_.begin(), cell_start_.end() - 1);
    for (Eigen::Index i = 0; i < features.rows(); ++i) {
      members_[static_cast<std::size_t>(fill[static_cast<std::size_t>(cell_of[i])]++)] = i;
    }
  }

  // Calls visit(feature index) for every feature within `radius` of `centre` (and some more).
  template <class Visit>
  void for_each_near(const Vec2& centre, double radius, Visit&& visit) const {
    const Eigen::Index c0 = column_of(centre.x() - radius), c1 = column_of(centre.x() + radius);
    const Eigen::Index r0 = row_of(centre.y() - radius), r1 = row_of(centre.y() + radius);
    for (Eigen::Index r = r0; r <= r1; ++r) {
      for (Eigen::Index c = c0; c <= c1; ++c) {
        const auto cell = static_cast<std::size_t>(r * columns_ + c);
        for (Eigen::Index k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k) {
          visit(members_[static_cast<std::size_t>(k)]);
        }
      }
    }
  }

 private:
  Eigen::Index clamp_cell(double coordinate, Eigen::Index count) const {
    const double cell = std::floor(coordinate / cell_size_);
    if (!(cell > 0.0)) return 0;
    return std::min(count - 1, static_cast<Eigen::Index>(cell));
  }
  Eigen::Index column_of(double x) const { return clamp_cell(x - origin_.x(), columns_); }
  Eigen::Index row_of(double y) const { return clamp_cell(y - origin_.y(), rows_); }

  Vec2 origin_;
  double cell_size_;
  Eigen::Index columns_, rows_;
  std::vector<Eigen::Index> cell_start_;
  std::vector<Eigen::Index> members_;
};

Mat2 measurement_covariance(const SimulationConfig& config, double true_range) {
  if (config.observation == ObservationModel::Point) {
    return Mat2::Identity() * (config.point_sigma * config.point_sigma);
  }
  const double range_sigma = config.range_sigma_fraction * true_range;
  return Eigen::Vector2d(range_sigma * range_sigma, config.bearing_sigma * config.bearing_sigma)
      .asDiagonal();
}

struct Measurement {
  Vec2 z;
  Mat2 R;
  std::int64_t true_id;
};

}  // namespace

Trajectory parse_trajectory(const std::string& name, const char* field) {
  if (name == "straight") return Trajectory::Straight;
  if (name == "loop") return Trajectory::Loop;
  if (name == "lawn_mowing") return Trajectory::LawnMowing;
  if (name == "snail") return Trajectory::Snail;
  throw InvalidArgument(std::string(field) + ": unknown trajectory '" + name +
                        "' (expected 'straight', 'loop', 'lawn_mowing' or 'snail')");
}

const char* to_string(Trajectory trajectory) {
  switch (trajectory) {
    case Trajectory::Straight: return "straight";
    case Trajectory::Loop: return "loop";
    case Trajectory::LawnMowing: return "lawn_mowing";
    case Trajectory::Snail: return "snail";
  }
  return "?";
}

double SimulationConfig::footprint_area() const {
  return 0.5 * fov * (max_range * max_range - min_range * min_range);
}

void SimulationConfig::validate() const {
  const auto non_negative = [](double v) { return std::isfinite(v) && v >= 0.0; };
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  require(steps >= 1, "steps: must be >= 1, got " + std::to_string(steps));
  require(positive(step_length), "step_length: must be finite and > 0, got " + str(step_length));
  require(!side_steps || *side_steps >= 1,
          "side_steps: must be >= 1, got " + std::to_string(side_steps.value_or(0)));
  require(lane_spacing_steps >= 1,
          "lane_spacing_steps: must be >= 1, got " + std::to_string(lane_spacing_steps));
  require(odometry_sigma.allFinite() && (odometry_sigma.array() >= 0.0).all(),
          "odometry_sigma: every sigma must be finite and >= 0");
  require(sensor_offset.allFinite(), "sensor_offset: must be finite");
  require(positive(max_range), "max_range: must be finite and > 0, got " + str(max_range));
  require(non_negative(min_range) && min_range < max_range,
          "min_range: must lie in [0, max_range), got " + str(min_range));
  require(fov > 0.0 && fov <= 2.0 * kPi, "fov: must lie in (0, 2 pi], got " + str(fov));
  require(non_negative(range_sigma_fraction),
          "range_sigma_fraction: must be finite and >= 0, got " + str(range_sigma_fraction));
  require(non_negative(bearing_sigma),
          "bearing_sigma: must be finite and >= 0, got " + str(bearing_sigma));
  require(non_negative(point_sigma),
          "point_sigma: must be finite and >= 0, got " + str(point_sigma));
  require(positive(features_per_step),
          "features_per_step: must be finite and > 0, got " + str(features_per_step));
  require(!num_features || *num_features >= 0,
          "num_features: must be >= 0, got " + std::to_string(num_features.value_or(0)));
  require(!world_margin || non_negative(*world_margin),
          "world_margin: must be finite and >= 0, got " + str(world_margin.value_or(0.0)));
  require(clutter >= 0.0 && clutter < 1.0, "clutter: must lie in [0, 1), got " + str(clutter));
}

Simulation simulate(const SimulationConfig& config) {
  config.validate();
  Simulation sim;
  sim.config = config;
  Random random(config.seed);

  // Ground-truth trajectory: the commanded motions, exactly.
  const std::vector<double> turns = commanded_turns(config);
  sim.poses.resize(config.steps + 1, 3);
  sim.poses.row(0).setZero();
  for (int k = 0; k < config.steps; ++k) {
    const Vec3 command(config.step_length, 0.0, turns[static_cast<std::size_t>(k)]);
    sim.poses.row(k + 1) = compose(sim.poses.row(k).transpose(), command).transpose();
  }

  // The field: uniform over the trajectory's bounding box plus a margin.
  const double margin =
      config.world_margin.value_or(config.max_range + config.sensor_offset.head<2>().norm());
  const Vec2 lower = sim.poses.leftCols<2>().colwise().minCoeff().transpose().array() - margin;
  const Vec2 upper = sim.poses.leftCols<2>().colwise().maxCoeff().transpose().array() + margin;
  const Vec2 extent = upper - lower;
  const double world_area = extent.prod();
  const double density = config.features_per_step / config.footprint_area();
  const std::int64_t num_features =
      config.num_features.value_or(std::llround(density * world_area));
  sim.landmarks.resize(num_features, 2);
  for (std::int64_t i = 0; i < num_features; ++i) {
    sim.landmarks(i, 0) = random.uniform(lower.x(), upper.x());
    sim.landmarks(i, 1) = random.uniform(lower.y(), upper.y());
  }
  const double cell_size = config.max_range;
  const auto cells = [&](double length) {
    return std::max<Eigen::Index>(1, static_cast<Eigen::Index>(std::ceil(length / cell_size)));
  };
  const FeatureGrid grid(sim.landmarks, lower, cell_size, cells(extent.x()), cells(extent.y()));

  // Clutter: a Poisson number per step whose mean makes spurious measurements the fraction
  // `clutter` of all of them, given the features expected in the footprint.
  const double expected_visible =
      world_area > 0.0 ? static_cast<double>(num_features) / world_area * config.footprint_area()
                       : 0.0;
  const double clutter_mean = config.clutter / (1.0 - config.clutter) * expected_visible;

  Vec3 odometry_sigma = config.odometry_sigma;
  if (config.zero_heading_noise) odometry_sigma.z() = 0.0;
  sim.odometry_covariance = odometry_sigma.array().square().matrix().asDiagonal();
  sim.odometry.resize(config.steps, 3);
  sim.step_offsets.assign(1, 0);

  const double half_fov = 0.5 * config.fov;
  std::vector<Measurement> scan;
  std::vector<Measurement> all;
  for (int k = 0; k < config.steps; ++k) {
    const Vec3 true_motion(config.step_length, 0.0, turns[static_cast<std::size_t>(k)]);
    Vec3 u = true_motion;
    for (int i = 0; i < 3; ++i) u(i) += odometry_sigma(i) * random.normal();
    u.z() = wrap_angle(u.z());
    sim.odometry.row(k) = u.transpose();

    const Vec3 robot = sim.poses.row(k + 1).transpose();
    const Vec3 sensor = compose(robot, config.sensor_offset);
    scan.clear();
    grid.for_each_near(sensor.head<2>(), config.max_range, [&](Eigen::Index i) {
      const Vec2 feature = sim.landmarks.row(i).transpose();
      const Vec2 local = inverse_transform_point(sensor, feature);
      const double range = local.norm();
      if (range < config.min_range || range > config.max_range) return;
      if (std::abs(std::atan2(local.y(), local.x())) > half_fov) return;
      Measurement m{observe(config.observation, config.sensor_offset, robot, feature),
                    measurement_covariance(config, range), i};
      if (config.observation == ObservationModel::RangeBearing) {
        m.z.x() += std::sqrt(m.R(0, 0)) * random.normal();
        m.z.y() = wrap_angle(m.z.y() + config.bearing_sigma * random.normal());
      } else {
        m.z.x() += config.point_sigma * random.normal();
        m.z.y() += config.point_sigma * random.normal();
      }
      scan.push_back(m);
    });

    const std::int64_t spurious = random.poisson(clutter_mean);
    const double r0 = config.min_range * config.min_range, r1 = config.max_range * config.max_range;
    for (std::int64_t j = 0; j < spurious; ++j) {
      // Uniform over the annular sector: r^2 uniform makes the area element uniform.
      const double range = std::sqrt(random.uniform(r0, r1));
      const double bearing = wrap_angle(random.uniform(-half_fov, half_fov));
      const Vec2 z = config.observation == ObservationModel::RangeBearing
                         ? Vec2(range, bearing)
                         : Vec2(range * std::cos(bearing), range * std::sin(bearing));
      scan.push_back({z, measurement_covariance(config, range), -1});
    }

    // Fisher–Yates, so that the order of a scan tells nothing about feature ids.
    for (std::size_t i = scan.size(); i > 1; --i) {
      std::swap(scan[i - 1], scan[random.index_below(i)]);
    }
    all.insert(all.end(), scan.begin(), scan.end());
    sim.step_offsets.push_back(static_cast<std::int64_t>(all.size()));
  }

  const auto total = static_cast<Eigen::Index>(all.size());
  sim.measurements.resize(total, 2);
  sim.measurement_covariances.resize(total, 4);
  sim.true_ids.resize(all.size());
  for (Eigen::Index i = 0; i < total; ++i) {
    const Measurement& m = all[static_cast<std::size_t>(i)];
    sim.measurements.row(i) = m.z.transpose();
    sim.measurement_covariances.row(i) << m.R(0, 0), m.R(0, 1), m.R(1, 0), m.R(1, 1);
    sim.true_ids[static_cast<std::size_t>(i)] = m.true_id;
  }
  return sim;
}

}  // namespace dcslam
