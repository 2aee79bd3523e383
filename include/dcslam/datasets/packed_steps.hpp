#pragma once
// A whole run's inputs in flat arrays, as the datasets and the simulator hold them, and the
// batch call that feeds them to a filter in one go (docs/api.md, "Batch runs"): Python crosses
// into C++ once for a whole dataset instead of three times a step.
#include <cstdint>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"
#include "dcslam/core/slam_filter.hpp"

namespace dcslam {

// Views, not copies: the caller keeps the arrays alive while the run uses them. All arrays are
// C-contiguous, row-major.
struct PackedSteps {
  Eigen::Index steps = 0;         // N
  Eigen::Index measurements = 0;  // M
  const double* u = nullptr;      // (N, 3) relative motions x_{R(k-1) R(k)}
  const double* Q = nullptr;      // (N, 3, 3), or one (3, 3) for every step (Q_per_step false)
  bool Q_per_step = true;
  const double* z = nullptr;      // (M, 2) every step's measurements, in step order
  const double* R = nullptr;      // (M, 2, 2), or one (2, 2) for every measurement
  bool R_per_measurement = true;
  // (N + 1): step k owns rows offsets[k] .. offsets[k + 1] - 1 of z, R and landmark_ids;
  // offsets[0] = 0, non-decreasing, offsets[N] = M.
  const std::int64_t* offsets = nullptr;
  const std::int64_t* landmark_ids = nullptr;  // (M), only in "known" association mode
};

// Where run_packed_steps() writes; every pointer is required.
struct PackedOutputs {
  std::int64_t* ids = nullptr;         // (M): update()'s id of each measurement
  double* trajectory = nullptr;        // (N + 1, 3): pose() before the first step, then after each
  double* step_seconds = nullptr;      // (N): wall time of each step's predict and update
};

// Checks the structure (offsets) and every step's values with the rules predict() and update()
// apply (input_checks.hpp), so that a refused batch leaves the filter as it was. Throws
// InvalidArgument naming the array and index, e.g. "run_batch: offsets[3] = 7 is below
// offsets[2] = 9" or "run_batch: step 12 (rows 40..42 of z): update: argument 'z'[1] ...".
void check_packed_steps(const PackedSteps& steps, const SlamConfig& config);

// predict(u[k], Q[k]) then update(z, R, ids of step k) for every step, after
// check_packed_steps(). A D&C join that fails during the run raises InvalidArgument as the
// step call would; the steps before it stay applied.
void run_packed_steps(SlamFilter& filter, const PackedSteps& steps, const PackedOutputs& outputs);

}  // namespace dcslam
