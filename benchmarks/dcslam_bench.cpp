// dcslam_bench: the native benchmark (no Python needed). Runs the EKF and/or D&C SLAM on the
// paper's simulator and reports total time, worst step, map size, joins and peak memory, as
// ratios measured in one run (DESIGN.md §9). Usage: dcslam_bench --help.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "dcslam/dc_slam.hpp"
#include "dcslam/ekf_slam.hpp"
#include "dcslam/errors.hpp"
#include "dcslam/simulator.hpp"

namespace {

using namespace dcslam;
using Clock = std::chrono::steady_clock;

const char* kUsage = R"(dcslam_bench: native benchmarks of EKF and D&C SLAM.

  dcslam_bench sim     [options]   one simulated run, EKF and/or D&C on the same data
  dcslam_bench scaling [options]   several runs of growing size; fitted exponents of time vs n

Options (defaults in brackets):
  --trajectory straight|loop|lawn_mowing|snail   [snail]
  --steps N            simulated steps (sim)                       [500]
  --sizes a,b,...      steps of each run (scaling)                 [100,200,400,800]
  --filter ekf|dc|both                                              [both]
  --joins immediate|amortized|threaded                              [amortized]
  --local-map-features P                                           [30]
  --association known|nn|jcbb  (local maps; joins use known|rjc)   [known]
  --clutter F          fraction of spurious measurements            [0]
  --seed S                                                          [0]
  --json FILE          write per-step times and totals as JSON
)";

using Args = std::map<std::string, std::string>;

Args parse_args(int argc, char** argv, int first) {
  Args args;
  for (int i = first; i < argc; ++i) {
    std::string key = argv[i];
    if (key.rfind("--", 0) != 0 || i + 1 >= argc) {
      throw InvalidArgument("dcslam_bench: expected '--option value', got '" + key + "'");
    }
    args[key.substr(2)] = argv[++i];
  }
  return args;
}

std::string get(const Args& args, const std::string& key, const std::string& fallback) {
  const auto it = args.find(key);
  return it == args.end() ? fallback : it->second;
}

long number(const Args& args, const std::string& key, long fallback) {
  const std::string text = get(args, key, std::to_string(fallback));
  try {
    std::size_t used = 0;
    const long value = std::stol(text, &used);
    if (used == text.size()) return value;
  } catch (const std::exception&) {
  }
  throw InvalidArgument("dcslam_bench: --" + key + " expects an integer, got '" + text + "'");
}

// Peak resident memory of this process so far (VmHWM), in bytes.
std::int64_t peak_rss_bytes() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stoll(line.substr(6)) * 1024;
  }
  return -1;
}

std::vector<SlamStep> to_steps(const Simulation& sim, bool with_ids) {
  std::vector<SlamStep> steps(static_cast<std::size_t>(sim.config.steps));
  for (std::size_t k = 0; k < steps.size(); ++k) {
    SlamStep& step = steps[k];
    step.u = sim.odometry.row(static_cast<Eigen::Index>(k)).transpose();
    step.Q = sim.odometry_covariance;
    const std::int64_t begin = sim.step_offsets[k], end = sim.step_offsets[k + 1];
    step.z = sim.measurements.middleRows(begin, end - begin);
    for (std::int64_t i = begin; i < end; ++i) {
      Mat2 R;
      R << sim.measurement_covariances(i, 0), sim.measurement_covariances(i, 1),
          sim.measurement_covariances(i, 2), sim.measurement_covariances(i, 3);
      step.R.push_back(R);
      if (with_ids) step.landmark_ids.push_back(sim.true_ids[static_cast<std::size_t>(i)]);
    }
    step.has_landmark_ids = with_ids;
  }
  return steps;
}

struct RunResult {
  std::string filter;
  double total_seconds = 0.0;
  double worst_step_seconds = 0.0;
  std::int64_t features = 0;
  std::int64_t peak_rss_growth_bytes = 0;
  std::vector<double> step_seconds;
  std::vector<std::int64_t> step_features;
  std::vector<JoinEvent> joins;
  double stream_seconds = 0.0;  // one copy of a matrix the size of the final covariance
};

// Time to stream a matrix the size of the final covariance through memory once (a copy:
// one read and one write of every element), the floor for any O(n^2) pass over P.
double stream_seconds(Eigen::Index dim) {
  Eigen::MatrixXd source = Eigen::MatrixXd::Constant(dim, dim, 1.0);
  Eigen::MatrixXd target(dim, dim);
  double best = 1e30;
  for (int repeat = 0; repeat < 3; ++repeat) {
    const auto start = Clock::now();
    target = source;
    best = std::min(best, std::chrono::duration<double>(Clock::now() - start).count());
  }
  if (target(dim - 1, dim - 1) != 1.0) std::abort();  // keeps the copy from being elided
  return best;
}

RunResult run_filter(const std::string& filter, const SlamConfig& config,
                     const std::vector<SlamStep>& steps) {
  RunResult result;
  result.filter = filter;
  const std::int64_t rss_before = peak_rss_bytes();
  std::unique_ptr<SlamFilter> slam;
  if (filter == "ekf") {
    slam = std::make_unique<EkfSlam>(config);
  } else {
    slam = std::make_unique<DCSlam>(config);
  }
  const auto start = Clock::now();
  run_steps(*slam, steps);
  Estimate estimate;
  if (auto* dc = dynamic_cast<DCSlam*>(slam.get())) {
    // The final map: the stack joined as at the end of Algorithm 2 (counted in the total).
    dc->finish_joins();
    estimate = dc->estimate();
    result.joins = dc->joins();
  } else {
    estimate = slam->estimate();
  }
  result.total_seconds = std::chrono::duration<double>(Clock::now() - start).count();
  result.peak_rss_growth_bytes = peak_rss_bytes() - rss_before;
  for (const StepStats& step : slam->stats().steps) {
    result.step_seconds.push_back(step.seconds);
    result.step_features.push_back(step.num_features);
    result.worst_step_seconds = std::max(result.worst_step_seconds, step.seconds);
  }
  result.features = static_cast<std::int64_t>(estimate.landmark_ids.size());
  return result;
}

SlamConfig config_from(const Args& args) {
  SlamConfig config;
  config.association = parse_association(get(args, "association", "known"), "--association");
  config.join_association =
      config.association == Association::Known ? JoinAssociation::Known : JoinAssociation::Rjc;
  config.local_map_features = static_cast<int>(number(args, "local-map-features", 30));
  const std::string joins = get(args, "joins", "amortized");
  if (joins != "immediate" && joins != "amortized" && joins != "threaded") {
    throw InvalidArgument("dcslam_bench: --joins must be immediate, amortized or threaded");
  }
  config.amortize = joins == "amortized";
  config.threaded_joins = joins == "threaded";
  config.seed = static_cast<std::uint64_t>(number(args, "seed", 0));
  config.validate();
  return config;
}

std::vector<std::string> filters_from(const Args& args) {
  const std::string filter = get(args, "filter", "both");
  if (filter == "both") return {"ekf", "dc"};
  if (filter == "ekf" || filter == "dc") return {filter};
  throw InvalidArgument("dcslam_bench: --filter must be ekf, dc or both, got '" + filter + "'");
}

Simulation simulate_from(const Args& args, int steps) {
  SimulationConfig sim;
  sim.trajectory = parse_trajectory(get(args, "trajectory", "snail"), "--trajectory");
  sim.steps = steps;
  sim.seed = static_cast<std::uint64_t>(number(args, "seed", 0));
  sim.clutter = std::stod(get(args, "clutter", "0"));
  return simulate(sim);
}

void print_result(const RunResult& r) {
  std::printf("  %-4s features %6lld  total %9.3f s  worst step %8.4f s  peak RSS growth %8.1f MB",
              r.filter.c_str(), static_cast<long long>(r.features), r.total_seconds,
              r.worst_step_seconds, static_cast<double>(r.peak_rss_growth_bytes) / 1e6);
  if (!r.joins.empty()) {
    const auto biggest = std::max_element(r.joins.begin(), r.joins.end(), [](const auto& a, const auto& b) {
      return a.report.features_joined < b.report.features_joined;
    });
    std::printf("  joins %zu, biggest %lld features in %.3f s (%.1fx one stream of the final P)",
                r.joins.size(), static_cast<long long>(biggest->report.features_joined),
                biggest->report.seconds_total, biggest->report.seconds_total / r.stream_seconds);
  }
  std::printf("\n");
}

void write_json(const std::string& path, const std::string& command, const Args& args,
                const std::vector<std::pair<int, std::vector<RunResult>>>& runs) {
  std::ofstream out(path);
  if (!out) throw InvalidArgument("dcslam_bench: cannot write --json file '" + path + "'");
  out << "{\n  \"command\": \"" << command << "\",\n  \"args\": {";
  bool first = true;
  for (const auto& [key, value] : args) {
    out << (first ? "" : ", ") << "\"" << key << "\": \"" << value << "\"";
    first = false;
  }
  out << "},\n  \"runs\": [\n";
  for (std::size_t r = 0; r < runs.size(); ++r) {
    for (std::size_t f = 0; f < runs[r].second.size(); ++f) {
      const RunResult& result = runs[r].second[f];
      out << "    {\"steps\": " << runs[r].first << ", \"filter\": \"" << result.filter
          << "\", \"features\": " << result.features << ", \"total_seconds\": " << result.total_seconds
          << ", \"worst_step_seconds\": " << result.worst_step_seconds
          << ", \"peak_rss_growth_bytes\": " << result.peak_rss_growth_bytes
          << ", \"stream_seconds\": " << result.stream_seconds << ",\n     \"step_seconds\": [";
      for (std::size_t k = 0; k < result.step_seconds.size(); ++k) {
        out << (k ? "," : "") << result.step_seconds[k];
      }
      out << "],\n     \"step_features\": [";
      for (std::size_t k = 0; k < result.step_features.size(); ++k) {
        out << (k ? "," : "") << result.step_features[k];
      }
      out << "],\n     \"joins\": [";
      for (std::size_t j = 0; j < result.joins.size(); ++j) {
        const JoinEvent& e = result.joins[j];
        out << (j ? "," : "") << "{\"leaves\": " << e.leaves << ", \"step_created\": " << e.step_created
            << ", \"step_finished\": " << e.step_finished
            << ", \"features_joined\": " << e.report.features_joined
            << ", \"pairings\": " << e.report.pairings << ", \"overlap\": " << e.report.overlap
            << ", \"tries\": " << e.report.tries << ", \"seconds\": " << e.report.seconds_total
            << ", \"seconds_association\": " << e.report.seconds_association << "}";
      }
      const bool last = r + 1 == runs.size() && f + 1 == runs[r].second.size();
      out << "]}" << (last ? "\n" : ",\n");
    }
  }
  out << "  ]\n}\n";
}

// Least-squares slope of log(y) against log(x).
double fitted_exponent(const std::vector<double>& x, const std::vector<double>& y) {
  const std::size_t n = x.size();
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double lx = std::log(x[i]), ly = std::log(y[i]);
    sx += lx, sy += ly, sxx += lx * lx, sxy += lx * ly;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

std::vector<RunResult> run_all(const Args& args, int steps) {
  const SlamConfig config = config_from(args);
  const Simulation sim = simulate_from(args, steps);
  const auto data = to_steps(sim, config.association == Association::Known);
  std::vector<RunResult> results;
  for (const std::string& filter : filters_from(args)) {
    results.push_back(run_filter(filter, config, data));
    const Eigen::Index dim = 3 + 2 * results.back().features;
    results.back().stream_seconds = stream_seconds(dim);
  }
  return results;
}

int command_sim(const Args& args) {
  const int steps = static_cast<int>(number(args, "steps", 500));
  std::printf("sim: %s, %d steps\n", get(args, "trajectory", "snail").c_str(), steps);
  const auto results = run_all(args, steps);
  for (const RunResult& r : results) print_result(r);
  if (results.size() == 2) {
    std::printf("  EKF/D&C total time ratio %.1f, worst-step ratio %.1f\n",
                results[0].total_seconds / results[1].total_seconds,
                results[0].worst_step_seconds / results[1].worst_step_seconds);
  }
  if (args.count("json")) write_json(args.at("json"), "sim", args, {{steps, results}});
  return 0;
}

int command_scaling(const Args& args) {
  std::vector<int> sizes;
  std::stringstream list(get(args, "sizes", "100,200,400,800"));
  for (std::string item; std::getline(list, item, ',');) sizes.push_back(std::stoi(item));
  std::vector<std::pair<int, std::vector<RunResult>>> runs;
  std::map<std::string, std::vector<double>> features, totals;
  for (int steps : sizes) {
    std::printf("scaling: %s, %d steps\n", get(args, "trajectory", "snail").c_str(), steps);
    auto results = run_all(args, steps);
    for (const RunResult& r : results) {
      print_result(r);
      features[r.filter].push_back(static_cast<double>(r.features));
      totals[r.filter].push_back(r.total_seconds);
    }
    runs.emplace_back(steps, std::move(results));
  }
  for (const auto& [filter, n] : features) {
    std::printf("  %s: fitted exponent of total time vs features: %.2f\n", filter.c_str(),
                fitted_exponent(n, totals[filter]));
  }
  if (args.count("json")) write_json(args.at("json"), "scaling", args, runs);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::string command = argc > 1 ? argv[1] : "--help";
    if (command == "--help" || command == "-h") {
      std::cout << kUsage;
      return 0;
    }
    const Args args = parse_args(argc, argv, 2);
    if (command == "sim") return command_sim(args);
    if (command == "scaling") return command_scaling(args);
    std::cerr << "dcslam_bench: unknown command '" << command << "'\n" << kUsage;
    return 2;
  } catch (const std::exception& error) {
    std::cerr << error.what() << "\n";
    return 2;
  }
}
