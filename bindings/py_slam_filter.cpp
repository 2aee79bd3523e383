// Bindings of the SlamFilter interface (bound once, on the base class, so that every filter
// bound as a subclass inherits predict/update/estimate/...) and of EkfSlam. The Python
// wrappers in dcslam/slam.py give them their documented, numpy-facing surface.
#include <optional>

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "py_conversions.hpp"
#include "dcslam/joining/checkpoint.hpp"
#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/datasets/packed_steps.hpp"
#include "dcslam/core/slam_filter.hpp"

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
  const bool shaped = array.ndim() == 2 && array.shape(1) == 2;  // (m, 2), m = 0 included: as it is
  if (!shaped && array.size() == 0 && array.ndim() <= 2) return DoubleArray(std::vector<py::ssize_t>{0, 2});
  if (!shaped) {
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

// Whether a Python thread other than the caller exists in this interpreter (one that could
// take the GIL while C++ works).
bool other_python_threads() {
  PyThreadState* const self = PyThreadState_Get();
  for (PyThreadState* thread = PyInterpreterState_ThreadHead(PyThreadState_GetInterpreter(self)); thread;
       thread = PyThreadState_Next(thread)) {
    if (thread != self) return true;
  }
  return false;
}

// The per-step calls release the GIL only when another Python thread could use it: alone, the
// release and re-acquire (0.35-0.5 us a scan measured on the development machine, BENCHMARKS.md)
// would be paid for nothing. A thread started meanwhile waits for the call, as it would for any
// Python code.
class ReleaseGilIfShared {
 public:
  ReleaseGilIfShared() {
    if (other_python_threads()) release_.emplace();
  }

 private:
  std::optional<py::gil_scoped_release> release_;
};

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

// The packed arrays of run_batch, checked for shape and dtype (values: check_packed_steps()).
struct PackedArrays {
  DoubleArray u, Q, z, R;
  Int64Array offsets;
  std::optional<Int64Array> landmark_ids;

  PackedSteps view() const {
    PackedSteps steps;
    steps.steps = u.shape(0);
    steps.measurements = z.shape(0);
    steps.u = u.data();
    steps.Q = Q.data();
    steps.Q_per_step = Q.ndim() == 3;
    steps.z = z.data();
    steps.R = R.data();
    steps.R_per_measurement = R.ndim() == 3;
    steps.offsets = offsets.data();
    steps.landmark_ids = landmark_ids ? landmark_ids->data() : nullptr;
    return steps;
  }
};

PackedArrays packed_arrays(const py::handle& u, const py::handle& Q, const py::handle& z,
                           const py::handle& R, const py::handle& offsets,
                           const py::handle& landmark_ids) {
  const auto where = [](const char* name) { return argument("run_batch", name); };
  PackedArrays arrays{as_double_array(u, where("u")), as_double_array(Q, where("Q")),
                      measurements_array(z, where("z")), as_double_array(R, where("R")),
                      as_int64_array(offsets, where("offsets")), std::nullopt};
  const py::ssize_t n = arrays.u.ndim() == 2 ? arrays.u.shape(0) : 0;
  const py::ssize_t m = arrays.z.shape(0);
  if (arrays.u.ndim() != 2 || arrays.u.shape(1) != 3) {
    throw py::value_error(where("u") + ": expected shape (N, 3), got " + shape_string(arrays.u));
  }
  const bool Q_shared = arrays.Q.ndim() == 2 && arrays.Q.shape(0) == 3 && arrays.Q.shape(1) == 3;
  const bool Q_per_step = arrays.Q.ndim() == 3 && arrays.Q.shape(0) == n && arrays.Q.shape(1) == 3 &&
                          arrays.Q.shape(2) == 3;
  if (!Q_shared && !Q_per_step) {
    throw py::value_error(where("Q") + ": expected shape (3, 3) or (" + std::to_string(n) +
                          ", 3, 3), got " + shape_string(arrays.Q));
  }
  const bool R_shared = arrays.R.ndim() == 2 && arrays.R.shape(0) == 2 && arrays.R.shape(1) == 2;
  const bool R_per_measurement = arrays.R.ndim() == 3 && arrays.R.shape(0) == m &&
                                 arrays.R.shape(1) == 2 && arrays.R.shape(2) == 2;
  if (!R_shared && !R_per_measurement) {
    throw py::value_error(where("R") + ": expected shape (2, 2) or (" + std::to_string(m) +
                          ", 2, 2), got " + shape_string(arrays.R));
  }
  if (arrays.offsets.shape(0) != n + 1) {
    throw py::value_error(where("offsets") + ": expected shape (" + std::to_string(n + 1) +
                          ",) (one more than the steps in u), got " + shape_string(arrays.offsets));
  }
  if (!landmark_ids.is_none()) {
    arrays.landmark_ids = as_int64_array(landmark_ids, where("landmark_ids"));
    if (arrays.landmark_ids->shape(0) != m) {
      throw py::value_error(where("landmark_ids") + ": expected shape (" + std::to_string(m) +
                            ",) (one per row of z), got " + shape_string(*arrays.landmark_ids));
    }
  }
  return arrays;
}

// Packs step objects' (u, Q, z, R, landmark_ids or None) tuples into run_batch's arrays,
// converting each value as predict() and update() convert theirs.
py::tuple pack_steps(const py::iterable& steps, bool with_ids) {
  std::vector<double> u, Q, z, R;
  std::vector<std::int64_t> offsets{0}, ids;
  std::size_t index = 0;
  for (const py::handle item : steps) {
    const std::string prefix = "run: step " + std::to_string(index++);
    if (!py::isinstance<py::tuple>(item) || py::len(item) != 5) {
      throw py::value_error(prefix + ": expected a tuple (u, Q, z, R, landmark_ids or None)");
    }
    const auto fields = py::reinterpret_borrow<py::tuple>(item);
    const Eigen::VectorXd motion = as_vector(fields[0], 3, prefix + ": argument 'u'");
    u.insert(u.end(), motion.data(), motion.data() + 3);
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> covariance =
        as_matrix(fields[1], 3, 3, prefix + ": argument 'Q'");
    Q.insert(Q.end(), covariance.data(), covariance.data() + 9);
    const DoubleArray measurements = measurements_array(fields[2], prefix + ": argument 'z'");
    const py::ssize_t m = measurements.shape(0);
    z.insert(z.end(), measurements.data(), measurements.data() + 2 * m);
    const std::vector<Mat2> noise = covariances(fields[3], m, prefix + ": argument 'R'");
    for (py::ssize_t i = 0; i < m; ++i) {
      const Eigen::Matrix<double, 2, 2, Eigen::RowMajor> Ri = noise[noise.size() == 1 ? 0 : static_cast<std::size_t>(i)];
      R.insert(R.end(), Ri.data(), Ri.data() + 4);
    }
    offsets.push_back(offsets.back() + m);
    if (with_ids) {
      const std::string where = prefix + ": argument 'landmark_ids'";
      if (fields[4].is_none()) throw py::value_error(where + " is required in association mode 'known'");
      const std::vector<std::int64_t> step_ids = as_int64_vector(fields[4], where);
      if (static_cast<py::ssize_t>(step_ids.size()) != m) {
        throw py::value_error(where + ": expected " + std::to_string(m) + " ids (one per row of z), got " +
                              std::to_string(step_ids.size()));
      }
      ids.insert(ids.end(), step_ids.begin(), step_ids.end());
    }
  }
  const auto n = static_cast<py::ssize_t>(offsets.size() - 1);
  const auto total = static_cast<py::ssize_t>(offsets.back());
  const auto array = [](const auto& values, std::vector<py::ssize_t> shape) {
    using Value = typename std::decay_t<decltype(values)>::value_type;
    py::array_t<Value> out(shape);
    std::copy(values.begin(), values.end(), out.mutable_data());
    return out;
  };
  return py::make_tuple(array(u, {n, 3}), array(Q, {n, 3, 3}), array(z, {total, 2}), array(R, {total, 2, 2}),
                        array(offsets, {n + 1}), with_ids ? py::object(array(ids, {total})) : py::none());
}

}  // namespace

void define_slam_filter(py::module_& m) {
  m.def("pack_steps", &pack_steps, py::arg("steps"), py::arg("with_ids"));
  py::class_<SlamFilter>(m, "SlamFilter",
                         "The interface shared by EkfSlam and DCSlam (use dcslam.EkfSlam).")
      // A copy: the filter's settings are fixed at construction (the Python wrapper keeps the
      // dataclass it was given; this is what the filter runs with, e.g. after a checkpoint).
      .def_property_readonly("config", [](const SlamFilter& filter) { return filter.config(); })
      .def(
          "predict",
          [](SlamFilter& filter, const py::object& u, const py::object& Q) {
            // Built once: the per-step path should not allocate its error messages' prefixes.
            static const std::string where_u = argument("predict", "u"), where_Q = argument("predict", "Q");
            const Vec3 motion = as_fixed<3, 1>(u, where_u);
            const Mat3 covariance = as_fixed<3, 3>(Q, where_Q);
            const ReleaseGilIfShared release;
            filter.predict(motion, covariance);
          },
          py::arg("u"), py::arg("Q"))
      .def(
          "update",
          [](SlamFilter& filter, const py::object& z, const py::object& R,
             const py::object& landmark_ids) {
            static const std::string where_z = argument("update", "z"), where_R = argument("update", "R");
            const DoubleArray z_array = measurements_array(z, where_z);
            const std::vector<Mat2> covariance = covariances(R, z_array.shape(0), where_R);
            const auto ids = optional_ids(landmark_ids, "update");
            // Zero-copy view of the numpy rows.
            const Eigen::Map<const MeasurementMatrix> measurements(z_array.data(), z_array.shape(0), 2);
            std::vector<std::int64_t> assigned;
            {
              const ReleaseGilIfShared release;
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
      .def("pose",
           [](const SlamFilter& filter) {
             // A plain (3,) array: cheaper than the Eigen caster's capsule-owned copy.
             const Vec3 pose = filter.pose();
             py::array_t<double> out(3);
             std::copy(pose.data(), pose.data() + 3, out.mutable_data());
             return out;
           })
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
          "run_batch",
          [](SlamFilter& filter, const py::object& u, const py::object& Q, const py::object& z,
             const py::object& R, const py::object& offsets, const py::object& landmark_ids) {
            const PackedArrays arrays = packed_arrays(u, Q, z, R, offsets, landmark_ids);
            const PackedSteps steps = arrays.view();
            py::array_t<std::int64_t> ids(steps.measurements);
            py::array_t<double> trajectory(std::vector<py::ssize_t>{steps.steps + 1, 3});
            py::array_t<double> step_seconds(steps.steps);
            const PackedOutputs outputs{ids.mutable_data(), trajectory.mutable_data(),
                                        step_seconds.mutable_data()};
            {
              py::gil_scoped_release release;
              run_packed_steps(filter, steps, outputs);
            }
            return py::make_tuple(ids, trajectory, step_seconds);
          },
          py::arg("u"), py::arg("Q"), py::arg("z"), py::arg("R"), py::arg("offsets"),
          py::arg("landmark_ids") = py::none());

  py::class_<EkfSlam, SlamFilter>(m, "EkfSlam")
      .def(py::init<const SlamConfig&>(), py::arg("config"))
      .def(py::pickle(
          [](const EkfSlam& filter) {
            std::string bytes;
            {
              py::gil_scoped_release release;
              bytes = save_checkpoint(filter);
            }
            return py::bytes(bytes);
          },
          [](const py::bytes& state) { return load_ekf_checkpoint(std::string_view(state)); }))
      .def_property("next_fresh_id", &EkfSlam::next_fresh_id, &EkfSlam::set_next_fresh_id);
}

}  // namespace dcslam::bindings
