// Bindings of the SlamFilter interface (bound once, on the base class, so that every filter
// bound as a subclass inherits predict/update/estimate/...) and of EkfSlam. The Python
// wrappers in dcslam/slam.py give them their documented, numpy-facing surface.
#include <optional>

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "conversions.hpp"
#include "dcslam/ekf_slam.hpp"
#include "dcslam/slam_filter.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

std::string argument(const char* function, const char* name) {
  return std::string(function) + ": argument '" + name + "'";
}

// z as (m, 2) float64; also an empty list or any empty array (m = 0). Finiteness and ranges
// are checked by check_measurements, which names the offending row.
DoubleArray measurements_array(const py::handle& obj, const std::string& where) {
  DoubleArray array = as_double_array(obj, where);
  if (array.size() == 0 && array.ndim() <= 2) return DoubleArray(std::vector<py::ssize_t>{0, 2});
  if (array.ndim() != 2 || array.shape(1) != 2) {
    throw py::value_error(where + ": expected shape (m, 2), got " + shape_string(array));
  }
  return array;
}

// R as (2, 2) for all measurements or (m, 2, 2).
std::vector<Mat2> covariances(const py::handle& obj, py::ssize_t m, const std::string& where) {
  const DoubleArray array = as_double_array(obj, where);
  using RowMajor2 = Eigen::Matrix<double, 2, 2, Eigen::RowMajor>;
  if (array.ndim() == 2 && array.shape(0) == 2 && array.shape(1) == 2) {
    return {Eigen::Map<const RowMajor2>(array.data())};
  }
  if (array.ndim() == 3 && array.shape(0) == m && array.shape(1) == 2 && array.shape(2) == 2) {
    std::vector<Mat2> R;
    R.reserve(static_cast<std::size_t>(m));
    for (py::ssize_t i = 0; i < m; ++i) R.emplace_back(Eigen::Map<const RowMajor2>(array.data() + 4 * i));
    // Zero measurements with an (0, 2, 2) R: nothing to check, and one R keeps the rule.
    if (R.empty()) R.emplace_back(Mat2::Identity());
    return R;
  }
  throw py::value_error(where + ": expected shape (2, 2) or (" + std::to_string(m) +
                        ", 2, 2), got " + shape_string(array));
}

std::optional<std::vector<std::int64_t>> optional_ids(const py::handle& obj, const char* function) {
  if (obj.is_none()) return std::nullopt;
  return as_int64_vector(obj, argument(function, "landmark_ids"));
}

py::array_t<std::int64_t> int64_array(std::vector<std::int64_t> values) {
  py::array_t<std::int64_t> array(static_cast<py::ssize_t>(values.size()));
  std::copy(values.begin(), values.end(), array.mutable_data());
  return array;
}

template <typename Field>
py::array step_column(const RunStats& stats, Field field) {
  using Value = std::decay_t<decltype(StepStats{}.*field)>;
  using Stored = std::conditional_t<std::is_floating_point_v<Value>, double, std::int64_t>;
  py::array_t<Stored> column(static_cast<py::ssize_t>(stats.steps.size()));
  auto out = column.mutable_data();
  for (const StepStats& step : stats.steps) *out++ = static_cast<Stored>(step.*field);
  return std::move(column);
}

SlamStep step_from_python(const py::handle& item, std::size_t index) {
  const std::string prefix = "run: step " + std::to_string(index);
  if (!py::isinstance<py::tuple>(item) || py::len(item) != 5) {
    throw py::value_error(prefix + ": expected a tuple (u, Q, z, R, landmark_ids or None)");
  }
  const auto fields = py::reinterpret_borrow<py::tuple>(item);
  SlamStep step;
  step.u = as_vector(fields[0], 3, prefix + ": argument 'u'");
  step.Q = as_matrix(fields[1], 3, 3, prefix + ": argument 'Q'");
  const DoubleArray z = measurements_array(fields[2], prefix + ": argument 'z'");
  step.z = Eigen::Map<const MeasurementMatrix>(z.data(), z.shape(0), 2);
  step.R = covariances(fields[3], z.shape(0), prefix + ": argument 'R'");
  if (!fields[4].is_none()) {
    step.landmark_ids = as_int64_vector(fields[4], prefix + ": argument 'landmark_ids'");
    step.has_landmark_ids = true;
  }
  return step;
}

}  // namespace

void define_slam_filter(py::module_& m) {
  py::class_<SlamFilter>(m, "SlamFilter",
                         "The interface shared by EkfSlam and DCSlam (use dcslam.EkfSlam).")
      .def(
          "predict",
          [](SlamFilter& filter, const py::object& u, const py::object& Q) {
            const Vec3 motion = as_vector(u, 3, argument("predict", "u"));
            const Mat3 covariance = as_matrix(Q, 3, 3, argument("predict", "Q"));
            py::gil_scoped_release release;
            filter.predict(motion, covariance);
          },
          py::arg("u"), py::arg("Q"))
      .def(
          "update",
          [](SlamFilter& filter, const py::object& z, const py::object& R,
             const py::object& landmark_ids) {
            const DoubleArray z_array = measurements_array(z, argument("update", "z"));
            const std::vector<Mat2> covariance =
                covariances(R, z_array.shape(0), argument("update", "R"));
            const auto ids = optional_ids(landmark_ids, "update");
            // Zero-copy view of the numpy rows.
            const Eigen::Map<const MeasurementMatrix> measurements(z_array.data(), z_array.shape(0), 2);
            std::vector<std::int64_t> assigned;
            {
              py::gil_scoped_release release;
              assigned = filter.update(measurements, covariance, ids ? &*ids : nullptr);
            }
            return int64_array(std::move(assigned));
          },
          py::arg("z"), py::arg("R"), py::arg("landmark_ids") = py::none())
      .def("estimate",
           [](const SlamFilter& filter) {
             Estimate estimate;
             {
               py::gil_scoped_release release;
               estimate = filter.estimate();
             }
             py::dict out;
             out["robot"] = py::cast(estimate.robot);
             out["landmarks"] = py::cast(std::move(estimate.landmarks));
             out["landmark_ids"] = int64_array(std::move(estimate.landmark_ids));
             out["past_poses"] = py::cast(std::move(estimate.past_poses));
             out["past_pose_ids"] = int64_array(std::move(estimate.past_pose_ids));
             // Moved into numpy without a copy; the Python wrapper views its leading block
             // as the [robot, landmarks] covariance.
             out["joint_covariance"] = py::cast(std::move(estimate.covariance));
             return out;
           })
      .def("pose", &SlamFilter::pose)
      .def(
          "resolve",
          [](const SlamFilter& filter, const py::object& ids) {
            return int64_array(filter.resolve(as_int64_vector(ids, argument("resolve", "ids"))));
          },
          py::arg("ids"))
      .def_property_readonly("stats",
                             [](const SlamFilter& filter) {
                               const RunStats& stats = filter.stats();
                               py::dict out;
                               out["step_seconds"] = step_column(stats, &StepStats::seconds);
                               out["num_features"] = step_column(stats, &StepStats::num_features);
                               out["measurements"] = step_column(stats, &StepStats::measurements);
                               out["paired"] = step_column(stats, &StepStats::paired);
                               out["new_features"] = step_column(stats, &StepStats::new_features);
                               out["rejected"] = step_column(stats, &StepStats::rejected);
                               out["association_seconds"] =
                                   step_column(stats, &StepStats::association_seconds);
                               out["counters"] = py::cast(stats.counters);
                               return out;
                             })
      .def(
          "run",
          [](SlamFilter& filter, const py::iterable& steps) {
            std::vector<SlamStep> converted;
            std::size_t index = 0;
            for (const py::handle item : steps) converted.push_back(step_from_python(item, index++));
            std::vector<std::vector<std::int64_t>> assigned;
            {
              py::gil_scoped_release release;
              assigned = run_steps(filter, converted);
            }
            py::list out;
            for (auto& ids : assigned) out.append(int64_array(std::move(ids)));
            return out;
          },
          py::arg("steps"));

  py::class_<EkfSlam, SlamFilter>(m, "EkfSlam")
      .def(py::init<const SlamConfig&>(), py::arg("config"))
      .def_property("next_fresh_id", &EkfSlam::next_fresh_id, &EkfSlam::set_next_fresh_id);
}

}  // namespace dcslam::bindings
