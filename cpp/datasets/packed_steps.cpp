#include "dcslam/datasets/packed_steps.hpp"

#include <chrono>
#include <string>
#include <vector>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/input_checks.hpp"

namespace dcslam {

namespace {

using RowMajor3 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
using RowMajor2 = Eigen::Matrix<double, 2, 2, Eigen::RowMajor>;

// One step's inputs as the step calls take them. The buffers are reused from step to step, so
// that a run allocates only while they grow.
class StepView {
 public:
  explicit StepView(const PackedSteps& steps) : steps_(steps) {}

  void load(Eigen::Index k) {
    u_ = Eigen::Map<const Vec3>(steps_.u + 3 * k);
    Q_ = Eigen::Map<const RowMajor3>(steps_.Q + (steps_.Q_per_step ? 9 * k : 0));
    begin_ = steps_.offsets[k];
    rows_ = steps_.offsets[k + 1] - begin_;
    R_.clear();
    if (steps_.R_per_measurement) {
      for (Eigen::Index i = 0; i < rows_; ++i) R_.emplace_back(Eigen::Map<const RowMajor2>(steps_.R + 4 * (begin_ + i)));
      // No measurements: one R keeps update()'s rule (1 or m matrices) and is never used.
      if (R_.empty()) R_.emplace_back(Mat2::Identity());
    } else {
      R_.emplace_back(Eigen::Map<const RowMajor2>(steps_.R));
    }
    if (steps_.landmark_ids) ids_.assign(steps_.landmark_ids + begin_, steps_.landmark_ids + begin_ + rows_);
  }

  const Vec3& u() const { return u_; }
  const Mat3& Q() const { return Q_; }
  Eigen::Map<const MeasurementMatrix> z() const { return {steps_.z + 2 * begin_, rows_, 2}; }
  const std::vector<Mat2>& R() const { return R_; }
  const std::vector<std::int64_t>* ids() const { return steps_.landmark_ids ? &ids_ : nullptr; }
  Eigen::Index begin() const { return begin_; }
  Eigen::Index rows() const { return rows_; }

 private:
  const PackedSteps& steps_;
  Vec3 u_;
  Mat3 Q_;
  Eigen::Index begin_ = 0, rows_ = 0;
  std::vector<Mat2> R_;
  std::vector<std::int64_t> ids_;
};

// "step 12 (u[12], Q[12])" or "step 12 (rows 40..42 of z, R, landmark_ids)": where in the
// packed arrays a step's refused input sits.
std::string motion_place(const PackedSteps& steps, Eigen::Index k) {
  const std::string index = "[" + std::to_string(k) + "]";
  return "step " + std::to_string(k) + " (u" + index + ", Q" + (steps.Q_per_step ? index : "") + ")";
}

std::string measurement_place(const PackedSteps& steps, const StepView& view, Eigen::Index k) {
  std::string arrays = "z";
  if (steps.R_per_measurement) arrays += ", R";
  if (steps.landmark_ids) arrays += ", landmark_ids";
  const std::string rows = view.rows() == 0 ? "no rows"
                                            : "rows " + std::to_string(view.begin()) + ".." +
                                                  std::to_string(view.begin() + view.rows() - 1);
  return "step " + std::to_string(k) + " (" + rows + " of " + arrays + ")";
}

[[noreturn]] void refuse(const std::string& message) { throw InvalidArgument("run_batch: " + message); }

void check_offsets(const PackedSteps& steps) {
  if (steps.steps < 0 || steps.measurements < 0) refuse("negative step or measurement count");
  if (steps.steps > 0 && (!steps.u || !steps.Q || !steps.offsets)) refuse("u, Q and offsets are required");
  if (steps.measurements > 0 && (!steps.z || !steps.R)) refuse("z and R are required");
  if (steps.steps == 0) return;
  const std::int64_t* offsets = steps.offsets;
  if (offsets[0] != 0) refuse("offsets[0] is " + std::to_string(offsets[0]) + ", expected 0");
  for (Eigen::Index k = 1; k <= steps.steps; ++k) {
    if (offsets[k] < offsets[k - 1]) {
      refuse("offsets[" + std::to_string(k) + "] = " + std::to_string(offsets[k]) + " is below offsets[" +
             std::to_string(k - 1) + "] = " + std::to_string(offsets[k - 1]) + " (offsets never decrease)");
    }
  }
  if (offsets[steps.steps] != steps.measurements) {
    refuse("offsets[" + std::to_string(steps.steps) + "] is " + std::to_string(offsets[steps.steps]) +
           ", expected the number of measurements, " + std::to_string(steps.measurements));
  }
}

}  // namespace

void check_packed_steps(const PackedSteps& steps, const SlamConfig& config) {
  check_offsets(steps);
  StepView view(steps);
  for (Eigen::Index k = 0; k < steps.steps; ++k) {
    view.load(k);
    try {
      // A shared Q is checked once.
      if (steps.Q_per_step || k == 0) check_motion(view.u(), view.Q(), "predict");
    } catch (const InvalidArgument& error) {
      refuse(motion_place(steps, k) + ": " + error.what());
    }
    try {
      check_measurements(view.z(), view.R(), view.ids(), config.observation, config.association, "update");
    } catch (const InvalidArgument& error) {
      refuse(measurement_place(steps, view, k) + ": " + error.what());
    }
  }
}

void run_packed_steps(SlamFilter& filter, const PackedSteps& steps, const PackedOutputs& outputs) {
  using Clock = std::chrono::steady_clock;
  check_packed_steps(steps, filter.config());
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>> trajectory(outputs.trajectory,
                                                                                   steps.steps + 1, 3);
  trajectory.row(0) = filter.pose().transpose();
  StepView view(steps);
  for (Eigen::Index k = 0; k < steps.steps; ++k) {
    view.load(k);
    const auto start = Clock::now();
    filter.predict(view.u(), view.Q());
    const std::vector<std::int64_t> ids = filter.update(view.z(), view.R(), view.ids());
    outputs.step_seconds[k] = std::chrono::duration<double>(Clock::now() - start).count();
    std::copy(ids.begin(), ids.end(), outputs.ids + view.begin());
    trajectory.row(k + 1) = filter.pose().transpose();
  }
}

}  // namespace dcslam
