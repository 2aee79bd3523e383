#include "dcslam/datasets/simulator.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <sstream>
#include <string>

#include "dcslam/core/errors.hpp"

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
    case Trajectory::LoopBothWays: {
      // A lap turning left, a U-turn at the start, a lap back turning right, a U-turn: every
      // place is seen again from the other direction.
      const int side = config.side_steps.value_or(std::max(1, steps / 8));
      return {{side, kPi / 2},  {side, kPi / 2},  {side, kPi / 2},  {side, kPi},
              {side, -kPi / 2}, {side, -kPi / 2}, {side, -kPi / 2}, {side, kPi}};
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

// Square cells over a rectangle; coordinates outside it clamp to the border cells.
struct GridShape {
  GridShape(const Vec2& lower, const Vec2& upper, double cell_size)
      : origin(lower),
        cell_size(cell_size),
        columns(count(upper.x() - lower.x())),
        rows(count(upper.y() - lower.y())) {}

  Eigen::Index count(double length) const {
    return std::max<Eigen::Index>(1, static_cast<Eigen::Index>(std::ceil(length / cell_size)));
  }
  Eigen::Index clamp(double offset, Eigen::Index cells) const {
    const double cell = std::floor(offset / cell_size);
    if (!(cell > 0.0)) return 0;
    return std::min(cells - 1, static_cast<Eigen::Index>(cell));
  }
  Eigen::Index column_of(double x) const { return clamp(x - origin.x(), columns); }
  Eigen::Index row_of(double y) const { return clamp(y - origin.y(), rows); }
  Eigen::Index size() const { return columns * rows; }

  // Calls visit(cell) for every cell meeting the square of half side `radius` at `centre`.
  template <class Visit>
  void for_each_cell_near(const Vec2& centre, double radius, Visit&& visit) const {
    const Eigen::Index c0 = column_of(centre.x() - radius), c1 = column_of(centre.x() + radius);
    const Eigen::Index r0 = row_of(centre.y() - radius), r1 = row_of(centre.y() + radius);
    for (Eigen::Index r = r0; r <= r1; ++r) {
      for (Eigen::Index c = c0; c <= c1; ++c) visit(r * columns + c);
    }
  }

  Vec2 origin;
  double cell_size;
  Eigen::Index columns, rows;
};

// Buckets points in the cells of a GridShape, so that finding the points around a position
// touches a bounded number of cells whatever the map size.
class PointGrid {
 public:
  PointGrid(const Simulation::Rows<2>& points, const GridShape& shape) : shape_(shape) {
    std::vector<Eigen::Index> cell_of(static_cast<std::size_t>(points.rows()));
    cell_start_.assign(static_cast<std::size_t>(shape.size() + 1), 0);
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const Eigen::Index cell =
          shape.row_of(points(i, 1)) * shape.columns + shape.column_of(points(i, 0));
      cell_of[static_cast<std::size_t>(i)] = cell;
      ++cell_start_[static_cast<std::size_t>(cell + 1)];
    }
    std::partial_sum(cell_start_.begin(), cell_start_.end(), cell_start_.begin());
    members_.resize(static_cast<std::size_t>(points.rows()));
    std::vector<Eigen::Index> fill(cell_start_.begin(), cell_start_.end() - 1);
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const auto cell = static_cast<std::size_t>(cell_of[static_cast<std::size_t>(i)]);
      members_[static_cast<std::size_t>(fill[cell]++)] = i;
    }
  }

  // Calls visit(point index) for every point within `radius` of `centre` (and some more).
  template <class Visit>
  void for_each_near(const Vec2& centre, double radius, Visit&& visit) const {
    shape_.for_each_cell_near(centre, radius, [&](Eigen::Index cell) {
      const auto c = static_cast<std::size_t>(cell);
      for (Eigen::Index k = cell_start_[c]; k < cell_start_[c + 1]; ++k) {
        visit(members_[static_cast<std::size_t>(k)]);
      }
    });
  }

 private:
  GridShape shape_;
  std::vector<Eigen::Index> cell_start_;
  std::vector<Eigen::Index> members_;
};

// The field: features uniform over the corridor of points within `margin` of the trajectory's
// positions (the region the trajectory covers, plus the sensor's reach), not its bounding
// box, which for a long loop would be mostly interior that is never seen. Drawn by rejection
// from the grid cells that meet the corridor. Returns the corridor's area (estimated from the
// acceptance rate when the count is fixed).
double place_features(const SimulationConfig& config, const Simulation::Rows<2>& positions,
                      double margin, Random& random, Simulation::Rows<2>& landmarks) {
  const Vec2 lower = positions.colwise().minCoeff().transpose().array() - margin;
  const Vec2 upper = positions.colwise().maxCoeff().transpose().array() + margin;
  // Cells no smaller than a step keep the grid small whatever the margin.
  const GridShape shape(lower, upper, std::max(margin, config.step_length));
  const PointGrid trajectory(positions, shape);
  std::vector<char> meets_corridor(static_cast<std::size_t>(shape.size()), 0);
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    shape.for_each_cell_near(positions.row(i).transpose(), margin, [&](Eigen::Index cell) {
      meets_corridor[static_cast<std::size_t>(cell)] = 1;
    });
  }
  std::vector<Eigen::Index> cells;
  for (Eigen::Index cell = 0; cell < shape.size(); ++cell) {
    if (meets_corridor[static_cast<std::size_t>(cell)]) cells.push_back(cell);
  }
  const double cell = shape.cell_size;
  const double candidate_area = static_cast<double>(cells.size()) * cell * cell;

  const auto draw = [&]() -> std::optional<Vec2> {
    const Eigen::Index index = cells[random.index_below(cells.size())];
    const double column = static_cast<double>(index % shape.columns) + random.uniform();
    const double row = static_cast<double>(index / shape.columns) + random.uniform();
    const Vec2 point = shape.origin + cell * Vec2(column, row);
    bool inside = false;
    trajectory.for_each_near(point, margin, [&](Eigen::Index i) {
      inside = inside || (positions.row(i).transpose() - point).squaredNorm() <= margin * margin;
    });
    if (!inside) return std::nullopt;
    return point;
  };

  std::vector<Vec2> accepted;
  std::int64_t drawn = 0;
  if (config.num_features) {
    while (static_cast<std::int64_t>(accepted.size()) < *config.num_features) {
      ++drawn;
      if (const auto point = draw()) accepted.push_back(*point);
    }
  } else {
    const double density = config.features_per_step / config.footprint_area();
    drawn = std::llround(density * candidate_area);
    for (std::int64_t k = 0; k < drawn; ++k) {
      if (const auto point = draw()) accepted.push_back(*point);
    }
  }
  landmarks.resize(static_cast<Eigen::Index>(accepted.size()), 2);
  for (std::size_t i = 0; i < accepted.size(); ++i) {
    landmarks.row(static_cast<Eigen::Index>(i)) = accepted[i].transpose();
  }
  return drawn > 0 ? candidate_area * static_cast<double>(accepted.size()) /
                         static_cast<double>(drawn)
                   : candidate_area;
}

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
  if (name == "loop_both_ways") return Trajectory::LoopBothWays;
  if (name == "lawn_mowing") return Trajectory::LawnMowing;
  if (name == "snail") return Trajectory::Snail;
  throw InvalidArgument(std::string(field) + ": unknown trajectory '" + name +
                        "' (expected 'straight', 'loop', 'loop_both_ways', 'lawn_mowing' or 'snail')");
}

const char* to_string(Trajectory trajectory) {
  switch (trajectory) {
    case Trajectory::Straight: return "straight";
    case Trajectory::Loop: return "loop";
    case Trajectory::LoopBothWays: return "loop_both_ways";
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
  // The filters need a positive definite R, so the noise of the model in use must be > 0.
  if (observation == ObservationModel::RangeBearing) {
    require(positive(range_sigma_fraction),
            "range_sigma_fraction: must be finite and > 0, got " + str(range_sigma_fraction));
    require(positive(bearing_sigma), "bearing_sigma: must be finite and > 0, got " + str(bearing_sigma));
  } else {
    require(positive(point_sigma), "point_sigma: must be finite and > 0, got " + str(point_sigma));
  }
  require(positive(features_per_step),
          "features_per_step: must be finite and > 0, got " + str(features_per_step));
  require(!num_features || *num_features >= 0,
          "num_features: must be >= 0, got " + std::to_string(num_features.value_or(0)));
  require(!world_margin || positive(*world_margin),
          "world_margin: must be finite and > 0, got " + str(world_margin.value_or(0.0)));
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

  const double margin =
      config.world_margin.value_or(config.max_range + config.sensor_offset.head<2>().norm());
  const Simulation::Rows<2> positions = sim.poses.leftCols<2>();
  const double corridor_area = place_features(config, positions, margin, random, sim.landmarks);
  const Vec2 lower = positions.colwise().minCoeff().transpose().array() - margin;
  const Vec2 upper = positions.colwise().maxCoeff().transpose().array() + margin;
  const PointGrid grid(sim.landmarks, GridShape(lower, upper, config.max_range));

  // Clutter: a Poisson number per step whose mean makes spurious measurements the fraction
  // `clutter` of all of them, given the features expected in the footprint.
  const double expected_visible = static_cast<double>(sim.landmarks.rows()) / corridor_area *
                                  config.footprint_area();
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
