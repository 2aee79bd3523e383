#pragma once
// The interface shared by EkfSlam and DCSlam (docs/api.md: "dcslam.EkfSlam(cfg) has the same
// interface"). The Python wrappers are written once against it.
#include <cstdint>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"

namespace dcslam {

// Merged feature id -> the id it was merged into (or -1: removed).
using IdAliases = std::unordered_map<std::int64_t, std::int64_t>;

// Records that `from` now resolves to `to` (-1: removed). `to` names a live feature, so any
// older alias of it is dropped: with user-given ids (known association) an id can be merged
// away and come back, and a stale entry would otherwise close a cycle that
// follow_aliases() never leaves.
inline void add_alias(IdAliases& aliases, std::int64_t from, std::int64_t to) {
  if (from == to) return;
  aliases.erase(to);
  aliases[from] = to;
}

// Follows `aliases` from `id` to an id that names no merged feature.
inline std::int64_t follow_aliases(const IdAliases& aliases, std::int64_t id) {
  for (auto it = aliases.find(id); it != aliases.end(); it = aliases.find(id)) id = it->second;
  return id;
}

// Measurements of one scan: z is (m, 2), row-major so numpy arrays map without a copy.
using MeasurementMatrix = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
using MeasurementsRef = Eigen::Ref<const MeasurementMatrix>;

// The whole map in the frame of the first pose, ordered [robot, lm 0, lm 1, ..., past pose 0,
// past pose 1, ...].
struct Estimate {
  Vec3 robot = Vec3::Zero();
  Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> landmarks;  // (n, 2)
  std::vector<std::int64_t> landmark_ids;                                // (n,)
  // Past robot poses (D&C with keep_local_map_poses; none otherwise), oldest first, and the
  // step of each: the number of predict() calls made before it (a simulator's poses[id]).
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> past_poses;  // (m, 3)
  std::vector<std::int64_t> past_pose_ids;                                // (m,)
  // (3+2n+3m, 3+2n+3m); its leading (3+2n) block is the covariance of [robot, landmarks].
  Eigen::MatrixXd covariance;
};

// The Estimate of `map`, with `covariance` its P (passed apart so that a caller done with the
// map can move it in rather than copy it).
Estimate to_estimate(const GaussianMap& map, Eigen::MatrixXd covariance);

// What one step (a predict and the updates after it) did and cost.
struct StepStats {
  double seconds = 0.0;       // wall time of the step, including any join work it did
  std::int64_t num_features = 0;  // map size after the step (all local maps for D&C)
  int measurements = 0;
  int paired = 0;             // measurements paired with an existing feature
  int new_features = 0;       // measurements that started a feature
  int rejected = 0;           // measurements rejected as spurious (id -1)
  double association_seconds = 0.0;  // part of `seconds` spent in data association
};

struct RunStats {
  std::vector<StepStats> steps;
  // Named totals, e.g. "jcbb_bound_hits", "joins". Free-form, documented where set.
  std::map<std::string, double> counters;
};

class SlamFilter {
 public:
  virtual ~SlamFilter() = default;

  // u: relative motion x_{R(k-1) R(k)}; Q: its covariance, symmetric PSD. Opens a new step.
  virtual void predict(const Vec3& u, const Mat3& Q) = 0;

  // z (m, 2); R holds either one 2x2 covariance for all measurements or m of them
  // (symmetric positive definite); landmark_ids (m) only in "known" association mode.
  // Returns, per measurement, the feature id it went to (fresh id for a new feature, -1 for
  // a rejected one). Invalid input throws InvalidArgument and leaves the filter unchanged.
  virtual std::vector<std::int64_t> update(const MeasurementsRef& z, const std::vector<Mat2>& R,
                                           const std::vector<std::int64_t>* landmark_ids) = 0;

  // The whole map; never disturbs the run (D&C joins its stack on a copy).
  virtual Estimate estimate() const = 0;

  // Current robot pose in the first pose's frame, cheap (no covariance, no joins).
  virtual Vec3 pose() const = 0;

  // Maps ids ever returned by update() to the id of the feature holding them now. -1 stays -1.
  // DCSlam: right after estimate() (until the next predict or update), to that estimate's.
  virtual std::vector<std::int64_t> resolve(const std::vector<std::int64_t>& ids) const = 0;

  virtual const RunStats& stats() const = 0;

  // The options the filter was built with.
  virtual const SlamConfig& config() const = 0;
};

}  // namespace dcslam
