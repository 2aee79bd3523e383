#pragma once
// Cost of a join's data association against the size of the maps joined (docs/design.md §6, §9):
// RJC, JCBB over the whole overlap, and the all-pairs individual compatibility that the
// spatial hash avoids. Meant to be called from dcslam_bench; no time is asserted anywhere.
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace dcslam {

struct AssociationBenchRow {
  Eigen::Index features = 0;  // n: features of both maps together (n/2 each)
  int overlap = 0;            // features of m2 with a candidate in m1
  int true_pairs = 0;
  int pairs_rjc = 0, wrong_rjc = 0;
  int pairs_jcbb = 0, wrong_jcbb = 0;
  int tries_rjc = 0;
  double seconds_rjc = 0.0;        // associate_maps, RJC
  double seconds_jcbb = 0.0;       // associate_maps, JCBB over the whole overlap
  double seconds_all_pairs = 0.0;  // individual distance of every (i, j), n^2 / 4 of them
  Eigen::Index compatible_all_pairs = 0;  // pairs inside the 2-dof gate among all of them
};

struct AssociationBenchResult {
  std::vector<AssociationBenchRow> rows;
  // Slopes of log(seconds) against log(n), least squares over the rows.
  double exponent_rjc = 0.0;
  double exponent_jcbb = 0.0;
  double exponent_all_pairs = 0.0;
};

// For each n in `total_features` (each >= 2 * overlap_features), two synthetic maps of n/2
// features each on a jittered 1.5 m grid: m1 a corridor ending at its robot R1, m2 (based at
// R1) re-observing `overlap_features` landmarks of m1 near R1 and going on through new ones,
// as at the turn of a lawn-mowing path or the closure of a loop: the overlap does not grow
// with n. Feature and relative-pose errors are drawn from the maps' own covariances (R1:
// 0.1 m, 0.01 rad; features: 0.05 m). Each timing is the median of `repetitions` runs.
// Memory: two dense covariances, 2 (n + 3)^2 doubles (1.6 GB at n = 10,000).
AssociationBenchResult benchmark_join_association(const std::vector<Eigen::Index>& total_features,
                                                  int overlap_features = 200,
                                                  int repetitions = 3,
                                                  std::uint64_t seed = 1);

// The EKF's data association per scan against map size: for each n, a map of n features on
// the same jittered grid (fixed uncertainty: robot 0.1 m / 0.002 rad, features 0.05 m), and
// `scans` range-bearing scans of every landmark within 3.5 m of a robot placed at random along
// the map (the reach fits in the smallest map, n >= 100, so every size sees the same scans). Timed: EkfAssociation::associate ("jcbb"), i.e. candidate search through the
// spatial hash, gates and JCBB; and, apart, map_updated(), the O(n) refresh of the hash after
// an update. Medians over the scans. Memory: one dense covariance, (2n + 3)^2 doubles.
struct EkfAssociationBenchRow {
  Eigen::Index features = 0;
  double measurements = 0.0;      // per scan, mean
  double candidates = 0.0;        // features returned by the hash per scan, mean
  double seconds_associate = 0.0;
  double seconds_map_updated = 0.0;
};
std::vector<EkfAssociationBenchRow> benchmark_ekf_association(const std::vector<Eigen::Index>& features,
                                                              int scans = 50, std::uint64_t seed = 1);

// Least-squares slope of log(y) against log(x); InvalidArgument unless there are two or
// more points, all positive, with distinct x.
double fitted_exponent(const std::vector<double>& x, const std::vector<double>& y);

}  // namespace dcslam
