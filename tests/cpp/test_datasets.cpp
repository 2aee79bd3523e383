// Dataset layer: line reader (plain, gzip, truncated gzip), CSV errors, the Victoria Park
// vehicle model (Jacobians, Monte Carlo covariance, the data's totals) and the iSAM 2D reader.
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "dcslam/core/errors.hpp"
#include "dcslam/datasets/isam2d.hpp"
#include "dcslam/datasets/text_reader.hpp"
#include "dcslam/datasets/victoria_park.hpp"

namespace fs = std::filesystem;
using namespace dcslam;

namespace {

const std::string kBundled = std::string(DCSLAM_SOURCE_DIR) + "/python/dcslam/data/victoria_park";
const std::string kIsamFile = std::string(DCSLAM_SOURCE_DIR) + "/tests/data/isam_victoria_park.txt.gz";

fs::path temp_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("dcslam_test_datasets_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void write_text(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

void write_gzip(const fs::path& path, const std::string& text) {
  gzFile file = gzopen(path.c_str(), "wb");
  gzwrite(file, text.data(), static_cast<unsigned>(text.size()));
  gzclose(file);
}

// Runs `action`, expecting a ParseError whose message holds every one of `parts`.
template <typename Action>
void expect_parse_error(Action action, const std::vector<std::string>& parts) {
  try {
    action();
    FAIL() << "no ParseError";
  } catch (const ParseError& error) {
    for (const auto& part : parts)
      EXPECT_NE(std::string(error.what()).find(part), std::string::npos)
          << "'" << part << "' not in: " << error.what();
  }
}

}  // namespace

TEST(TextReader, ReadsPlainAndGzipLinesWithNumbers) {
  const fs::path dir = temp_dir("lines");
  const std::string text = "a,b\r\n1,2\n\n" + std::string(10000, 'x') + "\nlast";
  write_text(dir / "plain.txt", text);
  write_gzip(dir / "packed.txt.gz", text);
  for (const char* name : {"plain.txt", "packed.txt.gz"}) {
    TextReader reader((dir / name).string());
    std::string line;
    ASSERT_TRUE(reader.next_line(line));
    EXPECT_EQ(line, "a,b");
    ASSERT_TRUE(reader.next_line(line));
    EXPECT_EQ(line, "1,2");
    ASSERT_TRUE(reader.next_line(line));
    EXPECT_EQ(line, "");
    ASSERT_TRUE(reader.next_line(line));
    EXPECT_EQ(line.size(), 10000u);
    ASSERT_TRUE(reader.next_line(line));
    EXPECT_EQ(line, "last");
    EXPECT_EQ(reader.line_number(), 5);
    EXPECT_FALSE(reader.next_line(line));
  }
}

TEST(TextReader, TruncatedGzipIsAParseError) {
  const fs::path dir = temp_dir("truncated");
  std::string text;
  for (int i = 0; i < 5000; ++i) text += std::to_string(i) + ",1.5,2.5\n";
  write_gzip(dir / "full.gz", text);
  std::ifstream in(dir / "full.gz", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::ofstream(dir / "cut.gz", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  expect_parse_error(
      [&] {
        TextReader reader((dir / "cut.gz").string());
        std::string line;
        while (reader.next_line(line)) {
        }
      },
      {"cut.gz", "truncated gzip stream"});
}

TEST(CsvTable, ErrorsNameFileLineAndField) {
  const fs::path dir = temp_dir("csv");
  write_text(dir / "missing.csv", "t_s,x_m\n1,2\n");
  expect_parse_error([&] { CsvTable((dir / "missing.csv").string(), {"t_s", "y_m"}); },
                     {"missing.csv:1", "'y_m'", "missing column"});
  write_text(dir / "text.csv", "t_s,x_m\n1,2\n2,abc\n");
  expect_parse_error([&] { CsvTable((dir / "text.csv").string(), {"t_s", "x_m"}); },
                     {"text.csv:3", "field 'x_m'", "'abc' is not a number"});
  write_text(dir / "count.csv", "t_s,x_m\n1,2,3\n");
  expect_parse_error([&] { CsvTable((dir / "count.csv").string(), {"t_s"}); },
                     {"count.csv:2", "expected 2 fields", "found 3"});
  write_text(dir / "back.csv", "t_s,x_m\n1,2\n3,2\n2.5,1\n");
  const CsvTable table((dir / "back.csv").string(), {"x_m", "t_s"});
  EXPECT_EQ(table.rows(), 3u);
  EXPECT_EQ(table.column(0)[1], 2.0);
  expect_parse_error([&] { table.require_non_decreasing(1); }, {"back.csv:4", "field 't_s'", "backwards"});
}

TEST(VictoriaPark, MotionJacobianMatchesCentralDifferences) {
  const AckermannVehicle vehicle;
  for (const double steering : {-0.4, -0.05, 0.0, 0.3}) {
    const double speed = 3.7, dt = 0.025;
    Eigen::Matrix<double, 3, 2> J;
    vehicle.motion(speed, steering, dt, &J);
    const double h = 1e-6;
    const Vec3 d_speed = (vehicle.motion(speed + h, steering, dt) - vehicle.motion(speed - h, steering, dt)) / (2 * h);
    const Vec3 d_steer = (vehicle.motion(speed, steering + h, dt) - vehicle.motion(speed, steering - h, dt)) / (2 * h);
    EXPECT_LT((J.col(0) - d_speed).norm(), 1e-7);
    EXPECT_LT((J.col(1) - d_steer).norm(), 1e-7);
  }
  // The encoder sits on the rear-left wheel: in a left turn it runs slower than the centre.
  EXPECT_GT(vehicle.centre_speed(2.0, 0.3), 2.0);
  EXPECT_DOUBLE_EQ(vehicle.centre_speed(2.0, 0.0), 2.0);
}

TEST(VictoriaPark, CovarianceMatchesMonteCarlo) {
  // Ten 40 Hz samples of a car turning left and speeding up, integrated between two scan
  // times that cut the first and last sample intervals.
  std::vector<OdometrySample> samples;
  for (int i = 0; i < 12; ++i) samples.push_back({0.025 * i, 3.0 + 0.1 * i, 0.2 + 0.01 * i});
  OdometryNoise noise;
  noise.floor_sigma_xy = 0.0;
  noise.floor_sigma_phi = 0.0;
  const AckermannVehicle vehicle;
  const double t_begin = 0.01, t_end = 0.26;
  Vec3 u;
  Mat3 Q;
  integrate_odometry(vehicle, noise, samples, t_begin, t_end, u, Q);

  // Oracle: sample the per-segment input noise the model states, integrate, take the
  // empirical covariance.
  std::mt19937_64 rng(42);
  std::normal_distribution<double> normal;
  const int runs = 20000;
  std::vector<Vec3> ends(runs);
  Vec3 mean = Vec3::Zero();
  for (int run = 0; run < runs; ++run) {
    Vec3 pose = Vec3::Zero();
    double start = t_begin;
    for (std::size_t i = 0; i + 1 < samples.size() && start < t_end; ++i) {
      const double stop = std::min(samples[i + 1].t, t_end);
      if (stop <= start) continue;
      const double dt = stop - start, scale = std::sqrt(noise.sample_period / dt);
      const double v = samples[i].encoder_speed + noise.sigma_speed * scale * normal(rng);
      const double a = samples[i].steering + noise.sigma_steering * scale * normal(rng);
      pose = compose(pose, vehicle.motion(v, a, dt));
      start = stop;
    }
    ends[static_cast<std::size_t>(run)] = pose;
    mean += pose / runs;
  }
  Mat3 empirical = Mat3::Zero();
  for (const Vec3& pose : ends) empirical += (pose - mean) * (pose - mean).transpose() / (runs - 1);
  // The sample mean carries the small bias of the non-linear model.
  EXPECT_LT((mean - u).norm(), 5e-3);
  for (int r = 0; r < 3; ++r)
    EXPECT_NEAR(empirical(r, r), Q(r, r), 0.1 * Q(r, r)) << "diagonal " << r;
  // Off-diagonal terms as correlations (relative error is meaningless near zero).
  for (int r = 0; r < 3; ++r)
    for (int c = r + 1; c < 3; ++c)
      EXPECT_NEAR(empirical(r, c) / std::sqrt(empirical(r, r) * empirical(c, c)),
                  Q(r, c) / std::sqrt(Q(r, r) * Q(c, c)), 0.05);
}

TEST(VictoriaPark, BundledRunMatchesReadmeTotals) {
  VictoriaParkOptions options;
  options.steering = Steering::Raw;
  options.max_range = 1e9;
  const VictoriaParkData data = load_victoria_park(VictoriaParkFiles::in_folder(kBundled), options);
  ASSERT_EQ(data.t.size(), 7249);
  EXPECT_EQ(data.detections_total, 52974);
  EXPECT_EQ(data.detections_beyond_range, 0);
  EXPECT_EQ(data.z.rows(), 52974);
  EXPECT_EQ(data.gps.rows(), 4466);
  double length = 0.0, turn = 0.0;
  int empty = 0;
  for (Eigen::Index k = 0; k < data.u.rows(); ++k) {
    length += data.u.row(k).head<2>().norm();
    turn += data.u(k, 2);
    if (data.offsets[static_cast<std::size_t>(k) + 1] == data.offsets[static_cast<std::size_t>(k)]) ++empty;
  }
  EXPECT_NEAR(length, 4026.6, 0.1);
  EXPECT_NEAR(turn, -4.4678, 1e-3);
  EXPECT_EQ(empty, 19);
  // The first scan comes before any odometry.
  EXPECT_EQ(data.u.row(0).norm(), 0.0);
  EXPECT_EQ(data.Q.row(0).norm(), 0.0);
}

TEST(Isam2d, ReadsTheVictoriaParkGraph) {
  const Isam2dData data = read_isam2d(kIsamFile);
  EXPECT_EQ(data.odometry_lines, 6968);
  EXPECT_EQ(data.landmark_lines, 3640);
  EXPECT_EQ(data.u.rows(), 6968);
  EXPECT_EQ(data.z.rows(), 3640);
  EXPECT_EQ(data.offsets.back(), 3640);
  double length = 0.0;
  for (Eigen::Index k = 0; k < data.u.rows(); ++k) length += data.u.row(k).head<2>().norm();
  EXPECT_NEAR(length, 4026.6, 0.1);
  EXPECT_DOUBLE_EQ(data.Q(0, 0), 1e-4);
  EXPECT_DOUBLE_EQ(data.Q(0, 8), 4e-6);
  EXPECT_DOUBLE_EQ(data.R(0, 0), 0.4);
}

TEST(Isam2d, MalformedLinesNameFileLineAndField) {
  const fs::path dir = temp_dir("isam");
  const std::string good = "ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\n";
  const std::pair<std::string, std::vector<std::string>> cases[] = {
      {good + "VERTEX2 1 0 0 0\n", {":2", "'tag'", "VERTEX2"}},
      {good + "ODOMETRY 1 2 1 0 0 1e-4 0 0 4e-6 0\n", {":2", "12 tokens", "found 11"}},
      {good + "LANDMARK 1 7 x 2 0.4 0 0.4\n", {":2", "field 'x'", "'x' is not a number"}},
      {good + "ODOMETRY 3 4 1 0 0 1e-4 0 0 4e-6 0 4e-6\n", {":2", "field 'i'", "pose chain"}},
      {good + "LANDMARK 0 7 1 2 0.4 0 0.4\n", {":2", "field 'i'", "current pose is 1"}},
      {"ODOMETRY 0 1 1 0 0 -1 0 0 4e-6 0 4e-6\n", {":1", "positive semi-definite"}},
  };
  int index = 0;
  for (const auto& [text, parts] : cases) {
    const fs::path path = dir / ("case" + std::to_string(index++) + ".txt");
    write_text(path, text);
    expect_parse_error([&] { read_isam2d(path.string()); }, parts);
    expect_parse_error([&] { read_isam2d(path.string()); }, {path.filename().string()});
  }
}

TEST(Isam2d, LandmarksOfTheFirstPoseMakeAnInitialStep) {
  const fs::path dir = temp_dir("isam_first");
  write_text(dir / "g.txt",
             "LANDMARK 0 9 1 2 0.4 0 0.4\nODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\n"
             "LANDMARK 1 9 0 2 0.4 0 0.4\nLANDMARK 1 10 3 2 0.4 0 0.4\n");
  const Isam2dData data = read_isam2d((dir / "g.txt").string());
  ASSERT_EQ(data.u.rows(), 2);
  EXPECT_EQ(data.u.row(0).norm(), 0.0);
  EXPECT_EQ(data.offsets, (std::vector<std::int64_t>{0, 1, 3}));
  EXPECT_EQ(data.landmark_ids, (std::vector<std::int64_t>{9, 9, 10}));
  EXPECT_EQ(data.pose_ids, (std::vector<std::int64_t>{0, 1}));
}
