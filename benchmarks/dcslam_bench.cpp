// dcslam_bench: the native benchmark (no Python needed). Runs the EKF and/or D&C SLAM on the
// paper's simulator, on Victoria Park and on iSAM/GTSAM 2D files, and reports total time,
// worst and mean step, map size, joins, association counts and peak memory, as ratios
// measured in one run (docs/design.md §9); it also times a join's data association against map
// size. Usage: dcslam_bench --help.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "association_bench.hpp"
#include "dcslam/joining/dc_slam.hpp"
#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/core/errors.hpp"
#include "dcslam/datasets/isam2d.hpp"
#include "dcslam/datasets/simulator.hpp"
#include "dcslam/datasets/victoria_park.hpp"

namespace {

using namespace dcslam;
using Clock = std::chrono::steady_clock;

const char* kUsage = R"(dcslam_bench: native benchmarks of EKF and D&C SLAM.

  dcslam_bench sim         [options]   one simulated run, EKF and/or D&C on the same data
  dcslam_bench scaling     [options]   several runs of growing size; fitted exponents of time vs n
  dcslam_bench vp          [options]   Victoria Park, configured as Python's vp.slam_config()
                                       (range-bearing from the laser offset, JCBB, RJC joins)
  dcslam_bench isam FILE   [options]   an iSAM/GTSAM 2D file, point observations, known ids
  dcslam_bench association [options]   cost of a join's association vs map size: RJC, JCBB over
                                       the whole overlap, all-pairs individual compatibility
  dcslam_bench ekf-association [options]   the EKF's association per scan vs map size

Options of sim and scaling (defaults in brackets):
  --trajectory straight|loop|lawn_mowing|snail   [snail]
  --steps N            simulated steps (sim)                       [500]
  --sizes a,b,...      steps of each run (scaling)                 [100,200,400,800]
  --association known|nn|jcbb  (local maps; joins use known|rjc)   [known]
                       with nn|jcbb, sim also scores the pairings against the true ids
  --clutter F          fraction of spurious measurements            [0]
  --odometry-noise-scale F  odometry sigmas times F                [1]
  --gate C             gate_confidence of the compatibility tests   [0.999]
  --unexplained-density D   SlamConfig.unexplained_density (jcbb)  [0.02]
  --new-feature-margin M    SlamConfig.new_feature_margin (jcbb; inf: always reject)  [5]

Options of sim, scaling, vp and isam:
  --filter ekf|dc|both                                              [both]
  --joins immediate|amortized|threaded                              [amortized]
  --local-map-features P                                           [30]
  --join-iterations K  linearisation points per join (1: one-shot)  [10]
  --join-feature-sigma S  SlamConfig.join_feature_sigma [m]   [0; vp: 0.1]
  --keep-local-map-poses 0|1  D&C keeps the robot at every local map's end  [0]
  --new-feature-beside-tentative 0|1  SlamConfig.new_feature_beside_tentative: unpaired beside
                       tentative features only starts a feature on probation  [0]
  --tree-relinearisation N  SlamConfig.tree_relinearisation: passes in estimate()  [0]
  --tree-relinearisation-tolerance T  SlamConfig.tree_relinearisation_tolerance: the passes
                       stop once another could gain at most T of the objective  [3.84]
  --weak-join-pairings N  SlamConfig.weak_join_pairings (0: off)   [30]
  --join-merge-max-leaves N  SlamConfig.join_merge_max_leaves (0: off)  [0]
  --chunked-jcbb-min-overlap N  SlamConfig.chunked_jcbb_min_overlap (0: off)  [100]
  --join-rival-margin N|none  SlamConfig.join_rival_margin (none: off)  [3]
  --online-localisation-sigma S|inf|none  SlamConfig.online_localisation_sigma [m]: D&C
                       localises each closed local map against its oldest map  [none]
  --confirmed-first-confidence C|none  SlamConfig.confirmed_first_confidence: close to a
                       confirmed feature, tentative ones are not candidates  [0.9]
  --rjc-p-fail F       SlamConfig.rjc_p_fail: RJC's chance of missing a good sample  [0.001]
  --seed S                                                          [0]
  --json FILE          write per-step times and totals as JSON

Options of vp:
  --data-dir DIR       folder of the four vp_*.csv.gz files
                       [)" DCSLAM_SOURCE_DIR R"(/python/dcslam/data/victoria_park]
                       noise and max range: VictoriaParkOptions' defaults (printed)
  --unexplained-density D   SlamConfig.unexplained_density  [0, the park's preset]

Options of association:
  --sizes a,b,...      features of both maps together              [1000,2000,5000,10000]
  --overlap K          features of the second map re-observed      [200]
  --repetitions R      timings are the median of R runs            [3]
  --seed S                                                          [1]
  --json FILE          write the table as JSON

Options of ekf-association:
  --sizes a,b,...      map sizes                                    [100,500,1000,2000,5000]
  --scans S            scans timed per size (medians)               [50]
  --seed S                                                          [1]
  --json FILE          write the table as JSON

A missing or malformed data file prints the reader's message and exits with status 2.
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

long parse_integer(const std::string& text, const std::string& key) {
  try {
    std::size_t used = 0;
    const long value = std::stol(text, &used);
    if (used == text.size()) return value;
  } catch (const std::exception&) {
  }
  throw InvalidArgument("dcslam_bench: --" + key + " expects integers, got '" + text + "'");
}

long number(const Args& args, const std::string& key, long fallback) {
  return parse_integer(get(args, key, std::to_string(fallback)), key);
}

// A 0|1 option, e.g. --keep-local-map-poses 1.
bool switch_option(const Args& args, const std::string& key, bool fallback) {
  const long value = number(args, key, fallback ? 1 : 0);
  if (value != 0 && value != 1) throw InvalidArgument("dcslam_bench: --" + key + " expects 0 or 1");
  return value == 1;
}

// An option of an optional field, e.g. --join-rival-margin N|none: "none" unsets the field, a
// value (read by `parse(key)`) sets it, and without the option the field keeps its preset.
template <typename T, typename Parse>
void optional_option(const Args& args, const std::string& key, std::optional<T>& field, const Parse& parse) {
  const std::string text = get(args, key, "");
  if (text == "none") {
    field.reset();
  } else if (!text.empty()) {
    field = parse(key);
  }
}

// A comma-separated list of integers, e.g. --sizes 100,200,400.
std::vector<long> number_list(const Args& args, const std::string& key, const std::string& fallback) {
  std::vector<long> values;
  std::stringstream list(get(args, key, fallback));
  for (std::string item; std::getline(list, item, ',');) values.push_back(parse_integer(item, key));
  return values;
}

// A field of /proc/self/status given in kB ("VmRSS", "VmHWM"), in bytes; -1 if absent.
std::int64_t status_bytes(const std::string& field) {
  std::ifstream status("/proc/self/status");
  const std::string prefix = field + ":";
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind(prefix, 0) == 0) return std::stoll(line.substr(prefix.size())) * 1024;
  }
  return -1;
}

// Resets the peak-RSS mark to the current RSS (Linux >= 4.0), so that the second filter of a
// run is not measured against the first one's peak. On older kernels the write is ignored and
// the second filter's growth is only what it adds above the first one's peak.
void reset_peak_rss() { std::ofstream("/proc/self/clear_refs") << "5"; }

using RowMatrix4 = Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>;

// Steps from flat arrays laid out as the simulator and the loaders give them: step k predicts
// with u.row(k) and covariance_of_step(k), then updates with measurement rows
// [offsets[k], offsets[k + 1]) (z, row-major 2x2 R, and ids when given).
std::vector<SlamStep> steps_from_arrays(const RowMatrix3& u,
                                        const std::function<Mat3(Eigen::Index)>& covariance_of_step,
                                        const std::vector<std::int64_t>& offsets,
                                        const RowMatrix2& z, const RowMatrix4& R,
                                        const std::vector<std::int64_t>* landmark_ids) {
  std::vector<SlamStep> steps(static_cast<std::size_t>(u.rows()));
  for (std::size_t k = 0; k < steps.size(); ++k) {
    SlamStep& step = steps[k];
    const auto row = static_cast<Eigen::Index>(k);
    step.u = u.row(row).transpose();
    step.Q = covariance_of_step(row);
    const std::int64_t begin = offsets[k], end = offsets[k + 1];
    step.z = z.middleRows(begin, end - begin);
    for (std::int64_t i = begin; i < end; ++i) {
      step.R.push_back(Eigen::Map<const Eigen::Matrix<double, 2, 2, Eigen::RowMajor>>(R.row(i).data()));
      if (landmark_ids) step.landmark_ids.push_back((*landmark_ids)[static_cast<std::size_t>(i)]);
    }
    step.has_landmark_ids = landmark_ids != nullptr;
  }
  return steps;
}

// Row k of an (n, 9) array of row-major 3x3 covariances.
std::function<Mat3(Eigen::Index)> covariance_rows(const Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor>& Q) {
  return [&Q](Eigen::Index k) {
    return Mat3(Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(Q.row(k).data()));
  };
}

// How the pairings of a run with unknown ids compare with the simulator's truth.
struct PairingScore {
  std::int64_t paired = 0;             // measurements that went to a feature already mapped
  std::int64_t correctly_paired = 0;   // ... whose feature stands for the measured landmark
  std::int64_t revisits = 0;           // measurements of a landmark the map already held
  double precision() const { return paired ? static_cast<double>(correctly_paired) / paired : 0.0; }
  double recall() const { return revisits ? static_cast<double>(correctly_paired) / revisits : 0.0; }
};

// Scores on the final map: each measurement's returned id is resolved to the feature holding
// it now (D&C merges features at joins, so pairings made by joins count), and each feature
// stands for the true landmark most of its measurements came from. Measurements are then
// replayed in order: one is paired when its feature already had a measurement, and a revisit
// when an earlier measurement had mapped a feature standing for its landmark. Clutter
// (true id -1) is never correct; measurements whose feature was removed count as unpaired.
PairingScore score_pairings(const SlamFilter& slam, const std::vector<std::int64_t>& returned_ids,
                            const std::vector<std::int64_t>& true_ids) {
  const std::vector<std::int64_t> features = slam.resolve(returned_ids);
  std::unordered_map<std::int64_t, std::map<std::int64_t, std::int64_t>> votes;
  for (std::size_t i = 0; i < features.size(); ++i) {
    if (features[i] >= 0 && true_ids[i] >= 0) ++votes[features[i]][true_ids[i]];
  }
  std::unordered_map<std::int64_t, std::int64_t> landmark_of;
  for (const auto& [feature, counts] : votes) {
    // std::map order makes ties go to the smaller landmark id, so the score is deterministic.
    landmark_of[feature] = std::max_element(counts.begin(), counts.end(), [](const auto& a, const auto& b) {
                             return a.second < b.second;
                           })->first;
  }
  PairingScore score;
  std::unordered_set<std::int64_t> features_seen, landmarks_mapped;
  for (std::size_t i = 0; i < features.size(); ++i) {
    const std::int64_t feature = features[i], landmark = true_ids[i];
    if (landmark >= 0 && landmarks_mapped.count(landmark)) ++score.revisits;
    if (feature < 0) continue;
    const auto label = landmark_of.find(feature);
    if (features_seen.insert(feature).second) {
      if (label != landmark_of.end()) landmarks_mapped.insert(label->second);
      continue;
    }
    ++score.paired;
    if (landmark >= 0 && label != landmark_of.end() && label->second == landmark) ++score.correctly_paired;
  }
  return score;
}

struct RunResult {
  std::string filter;
  double total_seconds = 0.0;
  double worst_step_seconds = 0.0;
  double mean_step_seconds = 0.0;
  // Part of the total spent in estimate(): for D&C the final joins of the stack, which run on
  // copies and so are not among `joins`.
  double estimate_seconds = 0.0;
  std::int64_t features = 0;
  std::int64_t peak_rss_growth_bytes = 0;
  std::int64_t paired = 0, new_features = 0, rejected = 0;  // summed over the steps' stats
  std::optional<PairingScore> score;                        // sim with unknown ids only
  std::vector<double> step_seconds;
  std::vector<double> step_association_seconds;
  std::vector<std::int64_t> step_features;
  std::vector<JoinEvent> joins;
  // D&C with tree_relinearisation: the passes' counters (relinearisation_*), else empty.
  std::map<std::string, double> relinearisation;
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

// Runs one filter over `steps`; with `true_ids` (one per measurement, in step order) it also
// scores the pairings (outside the timed part).
RunResult run_filter(const std::string& filter, const SlamConfig& config,
                     const std::vector<SlamStep>& steps, const std::vector<std::int64_t>* true_ids) {
  RunResult result;
  result.filter = filter;
  reset_peak_rss();
  const std::int64_t rss_before = status_bytes("VmRSS");
  std::unique_ptr<SlamFilter> slam;
  if (filter == "ekf") {
    slam = std::make_unique<EkfSlam>(config);
  } else {
    slam = std::make_unique<DCSlam>(config);
  }
  const auto start = Clock::now();
  const std::vector<std::vector<std::int64_t>> returned_ids = run_steps(*slam, steps);
  // The final map: for D&C the stack joined as at the end of Algorithm 2 (counted in the total).
  auto* dc = dynamic_cast<DCSlam*>(slam.get());
  if (dc) dc->finish_joins();
  const auto estimate_start = Clock::now();
  const Estimate estimate = slam->estimate();
  result.estimate_seconds = std::chrono::duration<double>(Clock::now() - estimate_start).count();
  if (dc) result.joins = dc->joins();
  result.total_seconds = std::chrono::duration<double>(Clock::now() - start).count();
  result.peak_rss_growth_bytes = status_bytes("VmHWM") - rss_before;
  for (const auto& [name, value] : slam->stats().counters) {
    if (name.rfind("relinearisation_", 0) == 0) result.relinearisation[name] = value;
  }
  for (const StepStats& step : slam->stats().steps) {
    result.step_seconds.push_back(step.seconds);
    result.step_association_seconds.push_back(step.association_seconds);
    result.step_features.push_back(step.num_features);
    result.worst_step_seconds = std::max(result.worst_step_seconds, step.seconds);
    result.mean_step_seconds += step.seconds;
    result.paired += step.paired;
    result.new_features += step.new_features;
    result.rejected += step.rejected;
  }
  if (!result.step_seconds.empty()) result.mean_step_seconds /= static_cast<double>(result.step_seconds.size());
  result.features = static_cast<std::int64_t>(estimate.landmark_ids.size());
  if (true_ids) {
    std::vector<std::int64_t> flat_ids;
    for (const auto& ids : returned_ids) flat_ids.insert(flat_ids.end(), ids.begin(), ids.end());
    result.score = score_pairings(*slam, flat_ids, *true_ids);
  }
  return result;
}

double real_number(const Args& args, const std::string& key, double fallback) {
  const std::string text = get(args, key, "");
  if (text.empty()) return fallback;
  try {
    std::size_t used = 0;
    const double value = std::stod(text, &used);
    if (used == text.size()) return value;
  } catch (const std::exception&) {
  }
  throw InvalidArgument("dcslam_bench: --" + key + " expects a number, got '" + text + "'");
}

// The options every filter run takes from the command line, whatever the data.
void apply_run_options(const Args& args, SlamConfig& config) {
  config.local_map_features =
      static_cast<int>(number(args, "local-map-features", config.local_map_features));
  config.join_iterations = static_cast<int>(number(args, "join-iterations", config.join_iterations));
  config.join_feature_sigma = real_number(args, "join-feature-sigma", config.join_feature_sigma);
  config.rjc_p_fail = real_number(args, "rjc-p-fail", config.rjc_p_fail);
  config.tree_relinearisation = static_cast<int>(number(args, "tree-relinearisation", config.tree_relinearisation));
  config.tree_relinearisation_tolerance =
      real_number(args, "tree-relinearisation-tolerance", config.tree_relinearisation_tolerance);
  config.weak_join_pairings = static_cast<int>(number(args, "weak-join-pairings", config.weak_join_pairings));
  config.join_merge_max_leaves =
      static_cast<int>(number(args, "join-merge-max-leaves", config.join_merge_max_leaves));
  config.chunked_jcbb_min_overlap =
      static_cast<int>(number(args, "chunked-jcbb-min-overlap", config.chunked_jcbb_min_overlap));
  optional_option(args, "join-rival-margin", config.join_rival_margin,
                  [&](const std::string& key) { return static_cast<int>(number(args, key, 0)); });
  optional_option(args, "online-localisation-sigma", config.online_localisation_sigma,
                  [&](const std::string& key) { return real_number(args, key, 0.0); });
  optional_option(args, "confirmed-first-confidence", config.confirmed_first_confidence,
                  [&](const std::string& key) { return real_number(args, key, 0.0); });
  config.keep_local_map_poses = switch_option(args, "keep-local-map-poses", false);
  config.new_feature_beside_tentative = switch_option(args, "new-feature-beside-tentative", false);
  const std::string joins = get(args, "joins", "amortized");
  if (joins != "immediate" && joins != "amortized" && joins != "threaded") {
    throw InvalidArgument("dcslam_bench: --joins must be immediate, amortized or threaded");
  }
  config.amortize = joins == "amortized";
  config.threaded_joins = joins == "threaded";
  config.seed = static_cast<std::uint64_t>(number(args, "seed", 0));
  config.validate();
}

SlamConfig simulation_config(const Args& args) {
  SlamConfig config;
  config.association = parse_association(get(args, "association", "known"), "--association");
  config.gate_confidence = real_number(args, "gate", config.gate_confidence);
  config.unexplained_density = real_number(args, "unexplained-density", config.unexplained_density);
  config.new_feature_margin = real_number(args, "new-feature-margin", config.new_feature_margin);
  config.join_association =
      config.association == Association::Known ? JoinAssociation::Known : JoinAssociation::Rjc;
  apply_run_options(args, config);
  return config;
}

// The preset Python's VictoriaPark.slam_config() gives too.
SlamConfig victoria_park_config(const Args& args, const VictoriaParkData& data) {
  SlamConfig config = victoria_park_slam_config(data.laser_offset);
  config.unexplained_density = real_number(args, "unexplained-density", config.unexplained_density);
  apply_run_options(args, config);
  return config;
}

// The preset Python's Isam2d.slam_config() gives too.
SlamConfig isam_config(const Args& args) {
  SlamConfig config = isam2d_slam_config();
  apply_run_options(args, config);
  return config;
}

std::vector<std::string> filters_from(const Args& args) {
  const std::string filter = get(args, "filter", "both");
  if (filter == "both") return {"ekf", "dc"};
  if (filter == "ekf" || filter == "dc") return {filter};
  throw InvalidArgument("dcslam_bench: --filter must be ekf, dc or both, got '" + filter + "'");
}

std::vector<RunResult> run_filters(const Args& args, const SlamConfig& config,
                                   const std::vector<SlamStep>& steps,
                                   const std::vector<std::int64_t>* true_ids) {
  std::vector<RunResult> results;
  for (const std::string& filter : filters_from(args)) {
    results.push_back(run_filter(filter, config, steps, true_ids));
    const Eigen::Index dim = 3 + 2 * results.back().features;
    results.back().stream_seconds = stream_seconds(dim);
  }
  return results;
}

void print_result(const RunResult& r) {
  std::printf("  %-4s features %6lld  total %9.3f s  mean step %9.6f s  worst step %8.4f s  "
              "peak RSS growth %8.1f MB  (final estimate() %.3f s)\n",
              r.filter.c_str(), static_cast<long long>(r.features), r.total_seconds,
              r.mean_step_seconds, r.worst_step_seconds,
              static_cast<double>(r.peak_rss_growth_bytes) / 1e6, r.estimate_seconds);
  std::printf("       measurements paired %lld, new features %lld, rejected %lld",
              static_cast<long long>(r.paired), static_cast<long long>(r.new_features),
              static_cast<long long>(r.rejected));
  if (r.score) {
    std::printf("; vs truth: precision %.4f (%lld/%lld), recall %.4f (%lld/%lld)",
                r.score->precision(), static_cast<long long>(r.score->correctly_paired),
                static_cast<long long>(r.score->paired), r.score->recall(),
                static_cast<long long>(r.score->correctly_paired),
                static_cast<long long>(r.score->revisits));
  }
  std::printf("\n");
  if (!r.joins.empty()) {
    const auto biggest = std::max_element(r.joins.begin(), r.joins.end(), [](const auto& a, const auto& b) {
      return a.report.features_joined < b.report.features_joined;
    });
    int most_iterations = 0;
    for (const JoinEvent& e : r.joins) most_iterations = std::max(most_iterations, e.report.iterations);
    std::printf("       joins %zu, biggest %lld features in %.3f s (%.1fx one stream of the final P); "
                "at most %d linearisation points\n",
                r.joins.size(), static_cast<long long>(biggest->report.features_joined),
                biggest->report.seconds_total, biggest->report.seconds_total / r.stream_seconds,
                most_iterations);
  }
  if (!r.relinearisation.empty()) {
    const auto value = [&](const char* name) { return r.relinearisation.at(std::string("relinearisation_") + name); };
    std::printf("       re-linearised: %d passes, batch objective %.3f -> %.3f (last pass predicted %.3f)\n",
                static_cast<int>(value("passes")), value("first_objective"), value("objective"),
                value("predicted_objective"));
  }
}

// Medians of `values` in bins of map size `bin_width` wide, over the steps `use` accepts:
// bin centres in `n`, medians in `t`.
template <typename Use>
void binned_medians(const RunResult& r, const std::vector<double>& values, std::int64_t bin_width,
                    Use use, std::vector<double>& n, std::vector<double>& t) {
  std::map<std::int64_t, std::vector<double>> bins;
  for (std::size_t k = 0; k < values.size(); ++k) {
    if (use(k)) bins[r.step_features[k] / bin_width].push_back(values[k]);
  }
  for (auto& [bin, times] : bins) {
    std::nth_element(times.begin(), times.begin() + static_cast<std::ptrdiff_t>(times.size() / 2), times.end());
    n.push_back(static_cast<double>((bin + 0.5) * bin_width));
    t.push_back(times[times.size() / 2]);
  }
}

// The EKF's per-step cost against map size: the fitted exponent of median step time in
// bins of n (over the second half of the map's growth, where the O(n^2) update dominates),
// and the last steps' time against one stream of P of the final size.
void print_ekf_step_scaling(const RunResult& r) {
  if (r.filter != "ekf" || r.step_seconds.size() < 40 || r.features < 100) return;
  std::vector<double> n, t;
  binned_medians(r, r.step_seconds, std::max<std::int64_t>(1, r.features / 20),
                 [&r](std::size_t k) { return 2 * r.step_features[k] >= r.features; }, n, t);
  if (n.size() < 3) return;
  const std::size_t tail = std::max<std::size_t>(1, r.step_seconds.size() / 20);
  std::vector<double> last(r.step_seconds.end() - static_cast<std::ptrdiff_t>(tail), r.step_seconds.end());
  std::nth_element(last.begin(), last.begin() + static_cast<std::ptrdiff_t>(last.size() / 2), last.end());
  std::printf("       EKF time per step ~ n^%.2f (median per bin, n from %lld to %lld); last steps' median %.4f s = %.1fx one stream of P\n",
              fitted_exponent(n, t), static_cast<long long>(r.features / 2), static_cast<long long>(r.features),
              last[last.size() / 2], last[last.size() / 2] / r.stream_seconds);
}

// The EKF's association cost per step against map size (unknown ids only): median per bin of
// n over the whole run; flat (exponent near 0) when the candidate search is local.
void print_association_scaling(const RunResult& r) {
  if (r.filter != "ekf" || !r.score || r.step_seconds.size() < 40 || r.features < 100) return;
  std::vector<double> n, t;
  binned_medians(r, r.step_association_seconds, std::max<std::int64_t>(1, r.features / 10),
                 [&r](std::size_t k) { return r.step_association_seconds[k] > 0.0; }, n, t);
  if (n.size() < 3) return;
  std::printf("       EKF association per step ~ n^%.2f (median per bin, n from %lld to %lld): %.1f us at the "
              "first bin, %.1f us at the last\n",
              fitted_exponent(n, t), static_cast<long long>(n.front()), static_cast<long long>(n.back()),
              t.front() * 1e6, t.back() * 1e6);
}

void print_ratios(const std::vector<RunResult>& results) {
  for (const RunResult& r : results) {
    print_ekf_step_scaling(r);
    print_association_scaling(r);
  }
  if (results.size() != 2) return;
  std::printf("  EKF/D&C total time ratio %.1f, worst-step ratio %.1f\n",
              results[0].total_seconds / results[1].total_seconds,
              results[0].worst_step_seconds / results[1].worst_step_seconds);
}

void write_args(std::ostream& out, const std::string& command, const Args& args) {
  out << "{\n  \"command\": \"" << command << "\",\n  \"args\": {";
  bool first = true;
  for (const auto& [key, value] : args) {
    out << (first ? "" : ", ") << "\"" << key << "\": \"" << value << "\"";
    first = false;
  }
  out << "},\n";
}

void write_json(const std::string& path, const std::string& command, const Args& args,
                const std::vector<std::pair<int, std::vector<RunResult>>>& runs) {
  std::ofstream out(path);
  if (!out) throw InvalidArgument("dcslam_bench: cannot write --json file '" + path + "'");
  write_args(out, command, args);
  out << "  \"runs\": [\n";
  for (std::size_t r = 0; r < runs.size(); ++r) {
    for (std::size_t f = 0; f < runs[r].second.size(); ++f) {
      const RunResult& result = runs[r].second[f];
      out << "    {\"steps\": " << runs[r].first << ", \"filter\": \"" << result.filter
          << "\", \"features\": " << result.features << ", \"total_seconds\": " << result.total_seconds
          << ", \"worst_step_seconds\": " << result.worst_step_seconds
          << ", \"mean_step_seconds\": " << result.mean_step_seconds
          << ", \"estimate_seconds\": " << result.estimate_seconds
          << ", \"peak_rss_growth_bytes\": " << result.peak_rss_growth_bytes
          << ", \"stream_seconds\": " << result.stream_seconds << ",\n     \"paired\": " << result.paired
          << ", \"new_features\": " << result.new_features << ", \"rejected\": " << result.rejected;
      if (result.score) {
        out << ", \"pairing_precision\": " << result.score->precision()
            << ", \"pairing_recall\": " << result.score->recall()
            << ", \"correctly_paired\": " << result.score->correctly_paired
            << ", \"paired_in_final_map\": " << result.score->paired
            << ", \"revisits\": " << result.score->revisits;
      }
      out << ",\n     \"step_seconds\": [";
      for (std::size_t k = 0; k < result.step_seconds.size(); ++k) {
        out << (k ? "," : "") << result.step_seconds[k];
      }
      out << "],\n     \"step_association_seconds\": [";
      for (std::size_t k = 0; k < result.step_association_seconds.size(); ++k) {
        out << (k ? "," : "") << result.step_association_seconds[k];
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
            << ", \"tries\": " << e.report.tries << ", \"iterations\": " << e.report.iterations
            << ", \"seconds\": " << e.report.seconds_total
            << ", \"seconds_association\": " << e.report.seconds_association << "}";
      }
      const bool last = r + 1 == runs.size() && f + 1 == runs[r].second.size();
      out << "]}" << (last ? "\n" : ",\n");
    }
  }
  out << "  ]\n}\n";
}

// Prints the results of one run on fixed data and writes them as JSON when asked.
int report(const std::string& command, const Args& args, int steps, const std::vector<RunResult>& results) {
  for (const RunResult& r : results) print_result(r);
  print_ratios(results);
  if (args.count("json")) write_json(args.at("json"), command, args, {{steps, results}});
  return 0;
}

Simulation simulate_from(const Args& args, int steps) {
  SimulationConfig sim;
  sim.trajectory = parse_trajectory(get(args, "trajectory", "snail"), "--trajectory");
  sim.steps = steps;
  sim.seed = static_cast<std::uint64_t>(number(args, "seed", 0));
  sim.clutter = real_number(args, "clutter", 0.0);
  sim.odometry_sigma *= real_number(args, "odometry-noise-scale", 1.0);
  return simulate(sim);
}

std::vector<RunResult> run_simulation(const Args& args, int steps) {
  const SlamConfig config = simulation_config(args);
  const Simulation sim = simulate_from(args, steps);
  const bool known = config.association == Association::Known;
  const auto data = steps_from_arrays(
      sim.odometry, [&sim](Eigen::Index) { return sim.odometry_covariance; }, sim.step_offsets,
      sim.measurements, sim.measurement_covariances, known ? &sim.true_ids : nullptr);
  return run_filters(args, config, data, known ? nullptr : &sim.true_ids);
}

int command_sim(const Args& args) {
  const int steps = static_cast<int>(number(args, "steps", 500));
  const SlamConfig config = simulation_config(args);
  std::printf("sim: %s, %d steps, association %s, clutter %s, odometry noise x%s, gate %g, "
              "unexplained density %g, new feature margin %g\n",
              get(args, "trajectory", "snail").c_str(), steps, get(args, "association", "known").c_str(),
              get(args, "clutter", "0").c_str(), get(args, "odometry-noise-scale", "1").c_str(),
              config.gate_confidence, config.unexplained_density, config.new_feature_margin);
  return report("sim", args, steps, run_simulation(args, steps));
}

int command_scaling(const Args& args) {
  std::vector<std::pair<int, std::vector<RunResult>>> runs;
  std::map<std::string, std::vector<double>> features, totals;
  for (long steps : number_list(args, "sizes", "100,200,400,800")) {
    std::printf("scaling: %s, %ld steps\n", get(args, "trajectory", "snail").c_str(), steps);
    auto results = run_simulation(args, static_cast<int>(steps));
    for (const RunResult& r : results) {
      print_result(r);
      features[r.filter].push_back(static_cast<double>(r.features));
      totals[r.filter].push_back(r.total_seconds);
    }
    runs.emplace_back(static_cast<int>(steps), std::move(results));
  }
  for (const auto& [filter, n] : features) {
    std::printf("  %s: fitted exponent of total time vs features: %.2f\n", filter.c_str(),
                fitted_exponent(n, totals[filter]));
  }
  if (args.count("json")) write_json(args.at("json"), "scaling", args, runs);
  return 0;
}

int command_vp(const Args& args) {
  const std::string folder = get(args, "data-dir", DCSLAM_SOURCE_DIR "/python/dcslam/data/victoria_park");
  // Noise and range come from the struct so that the bench follows the tuned defaults.
  const VictoriaParkOptions options;
  const VictoriaParkData data = load_victoria_park(VictoriaParkFiles::in_folder(folder), options);
  const SlamConfig config = victoria_park_config(args, data);
  const auto covariance = covariance_rows(data.Q);
  const auto steps = steps_from_arrays(data.u, covariance, data.offsets, data.z, data.R, nullptr);
  std::printf("vp: %s\n  %zu steps, %lld measurements (%lld detections, %lld beyond max_range %g m)\n",
              folder.c_str(), steps.size(), static_cast<long long>(data.z.rows()),
              static_cast<long long>(data.detections_total),
              static_cast<long long>(data.detections_beyond_range), options.max_range);
  std::printf("  options: steering %s, sigma_range %g m, sigma_bearing %g rad, sigma_speed %g m/s, "
              "sigma_steering %g rad, floor_sigma_xy %g, floor_sigma_phi %g\n",
              to_string(options.steering), options.sigma_range,
              options.sigma_bearing, options.odometry.sigma_speed, options.odometry.sigma_steering,
              options.odometry.floor_sigma_xy, options.odometry.floor_sigma_phi);
  std::printf("  config: range_bearing, sensor offset (%g, %g, %g), association %s, join %s, gate %g, "
              "local maps of %d features, min_sightings %d, tentative_window %d, join_iterations %d, "
              "join_feature_sigma %g m, weak_join_pairings %d, unexplained_density %g\n",
              config.sensor_offset.x(), config.sensor_offset.y(), config.sensor_offset.z(),
              to_string(config.association), to_string(config.join_association), config.gate_confidence,
              config.local_map_features, config.min_sightings, config.tentative_window,
              config.join_iterations, config.join_feature_sigma, config.weak_join_pairings,
              config.unexplained_density);
  return report("vp", args, static_cast<int>(steps.size()), run_filters(args, config, steps, nullptr));
}

int command_isam(const std::string& path, Args args) {
  const Isam2dData data = read_isam2d(path);
  const SlamConfig config = isam_config(args);
  const auto covariance = covariance_rows(data.Q);
  const auto steps =
      steps_from_arrays(data.u, covariance, data.offsets, data.z, data.R, &data.landmark_ids);
  std::printf("isam: %s\n  %zu steps (%lld ODOMETRY lines), %lld measurements (LANDMARK lines)\n",
              path.c_str(), steps.size(), static_cast<long long>(data.odometry_lines),
              static_cast<long long>(data.landmark_lines));
  args["file"] = path;  // recorded in the JSON with the options
  return report("isam", args, static_cast<int>(steps.size()), run_filters(args, config, steps, nullptr));
}

void write_association_json(const std::string& path, const Args& args, const AssociationBenchResult& result) {
  std::ofstream out(path);
  if (!out) throw InvalidArgument("dcslam_bench: cannot write --json file '" + path + "'");
  write_args(out, "association", args);
  out << "  \"exponent_rjc\": " << result.exponent_rjc << ", \"exponent_jcbb\": " << result.exponent_jcbb
      << ", \"exponent_all_pairs\": " << result.exponent_all_pairs << ",\n  \"rows\": [\n";
  for (std::size_t k = 0; k < result.rows.size(); ++k) {
    const AssociationBenchRow& row = result.rows[k];
    out << "    {\"features\": " << row.features << ", \"overlap\": " << row.overlap
        << ", \"true_pairs\": " << row.true_pairs << ", \"pairs_rjc\": " << row.pairs_rjc
        << ", \"wrong_rjc\": " << row.wrong_rjc << ", \"tries_rjc\": " << row.tries_rjc
        << ", \"pairs_jcbb\": " << row.pairs_jcbb << ", \"wrong_jcbb\": " << row.wrong_jcbb
        << ", \"seconds_rjc\": " << row.seconds_rjc << ", \"seconds_jcbb\": " << row.seconds_jcbb
        << ", \"seconds_all_pairs\": " << row.seconds_all_pairs
        << ", \"compatible_all_pairs\": " << row.compatible_all_pairs << "}"
        << (k + 1 == result.rows.size() ? "\n" : ",\n");
  }
  out << "  ]\n}\n";
}

int command_association(const Args& args) {
  std::vector<Eigen::Index> sizes;
  for (long size : number_list(args, "sizes", "1000,2000,5000,10000")) sizes.push_back(size);
  const int overlap = static_cast<int>(number(args, "overlap", 200));
  const int repetitions = static_cast<int>(number(args, "repetitions", 3));
  const auto seed = static_cast<std::uint64_t>(number(args, "seed", 1));
  std::printf("association: two maps of n/2 features, %d of the second re-observed; median of %d runs\n",
              overlap, repetitions);
  const AssociationBenchResult result = benchmark_join_association(sizes, overlap, repetitions, seed);
  std::printf("  %6s %7s %6s | %9s %5s %5s %5s | %9s %5s %5s | %11s %10s\n", "n", "overlap", "true",
              "RJC s", "pairs", "wrong", "tries", "JCBB s", "pairs", "wrong", "all-pairs s", "compatible");
  for (const AssociationBenchRow& row : result.rows) {
    std::printf("  %6lld %7d %6d | %9.5f %5d %5d %5d | %9.5f %5d %5d | %11.5f %10lld\n",
                static_cast<long long>(row.features), row.overlap, row.true_pairs, row.seconds_rjc,
                row.pairs_rjc, row.wrong_rjc, row.tries_rjc, row.seconds_jcbb, row.pairs_jcbb,
                row.wrong_jcbb, row.seconds_all_pairs, static_cast<long long>(row.compatible_all_pairs));
  }
  if (result.rows.size() >= 2) {
    std::printf("  fitted exponents of time vs n: RJC %.2f, JCBB %.2f, all-pairs %.2f\n",
                result.exponent_rjc, result.exponent_jcbb, result.exponent_all_pairs);
  }
  if (args.count("json")) write_association_json(args.at("json"), args, result);
  return 0;
}

int command_ekf_association(const Args& args) {
  std::vector<Eigen::Index> sizes;
  for (long size : number_list(args, "sizes", "100,500,1000,2000,5000")) sizes.push_back(size);
  const int scans = static_cast<int>(number(args, "scans", 50));
  const auto seed = static_cast<std::uint64_t>(number(args, "seed", 1));
  std::printf("ekf-association: EKF data association (jcbb) per scan against map size, fixed uncertainty; "
              "median of %d scans\n", scans);
  std::printf("  %6s %12s %12s | %13s %17s | %15s\n", "n", "measurements", "candidates", "associate s",
              "per measurement", "map_updated s");
  const auto rows = benchmark_ekf_association(sizes, scans, seed);
  std::vector<double> n, associate, refresh;
  for (const auto& row : rows) {
    std::printf("  %6lld %12.1f %12.1f | %13.6f %15.2f us | %15.6f\n", static_cast<long long>(row.features),
                row.measurements, row.candidates, row.seconds_associate,
                1e6 * row.seconds_associate / row.measurements, row.seconds_map_updated);
    n.push_back(static_cast<double>(row.features));
    associate.push_back(row.seconds_associate);
    refresh.push_back(row.seconds_map_updated);
  }
  if (rows.size() >= 2) {
    std::printf("  fitted exponents of time vs n: associate %.2f, map_updated %.2f\n",
                fitted_exponent(n, associate), fitted_exponent(n, refresh));
  }
  if (args.count("json")) {
    std::ofstream out(args.at("json"));
    if (!out) throw InvalidArgument("dcslam_bench: cannot write --json file '" + args.at("json") + "'");
    write_args(out, "ekf-association", args);
    out << "  \"rows\": [\n";
    for (std::size_t k = 0; k < rows.size(); ++k) {
      out << "    {\"features\": " << rows[k].features << ", \"measurements\": " << rows[k].measurements
          << ", \"candidates\": " << rows[k].candidates << ", \"seconds_associate\": "
          << rows[k].seconds_associate << ", \"seconds_map_updated\": " << rows[k].seconds_map_updated << "}"
          << (k + 1 == rows.size() ? "\n" : ",\n");
    }
    out << "  ]\n}\n";
  }
  return 0;
}

// Options each command reads (the usage above): any other is refused before the run, rather
// than silently ignored (e.g. --gate given to vp, whose preset sets it).
void refuse_unknown_options(const std::string& command, const Args& args) {
  const std::vector<std::string> run = {"filter", "joins", "local-map-features", "join-iterations",
                                        "join-feature-sigma", "keep-local-map-poses", "new-feature-beside-tentative",
                                        "tree-relinearisation", "tree-relinearisation-tolerance", "weak-join-pairings", "join-merge-max-leaves",
                                        "chunked-jcbb-min-overlap", "join-rival-margin", "online-localisation-sigma",
                                        "confirmed-first-confidence", "rjc-p-fail", "seed", "json"};
  const std::vector<std::string> simulated = {"trajectory", "association", "clutter", "odometry-noise-scale",
                                              "gate", "unexplained-density", "new-feature-margin"};
  std::vector<std::string> known;
  const auto add = [&known](const std::vector<std::string>& names) { known.insert(known.end(), names.begin(), names.end()); };
  if (command == "sim" || command == "scaling") {
    add(run);
    add(simulated);
    known.push_back(command == "sim" ? "steps" : "sizes");
  } else if (command == "vp") {
    add(run);
    add({"data-dir", "unexplained-density"});
  } else if (command == "isam") {
    add(run);
  } else if (command == "association") {
    add({"sizes", "overlap", "repetitions", "seed", "json"});
  } else if (command == "ekf-association") {
    add({"sizes", "scans", "seed", "json"});
  } else {
    return;  // an unknown command is refused by main()
  }
  for (const auto& [key, value] : args) {
    if (std::find(known.begin(), known.end(), key) == known.end()) {
      throw InvalidArgument("dcslam_bench " + command + ": unknown option '--" + key + "' (see --help)");
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::string command = argc > 1 ? argv[1] : "--help";
    if (command == "--help" || command == "-h") {
      std::cout << kUsage;
      return 0;
    }
    if (command == "isam") {
      if (argc < 3 || std::strncmp(argv[2], "--", 2) == 0) {
        std::cerr << "dcslam_bench: isam needs a FILE\n" << kUsage;
        return 2;
      }
      const Args args = parse_args(argc, argv, 3);
      refuse_unknown_options(command, args);
      return command_isam(argv[2], args);
    }
    const Args args = parse_args(argc, argv, 2);
    refuse_unknown_options(command, args);
    if (command == "sim") return command_sim(args);
    if (command == "scaling") return command_scaling(args);
    if (command == "vp") return command_vp(args);
    if (command == "association") return command_association(args);
    if (command == "ekf-association") return command_ekf_association(args);
    std::cerr << "dcslam_bench: unknown command '" << command << "'\n" << kUsage;
    return 2;
  } catch (const std::exception& error) {
    std::cerr << error.what() << "\n";
    return 2;
  }
}
