#include <memory>

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "py_conversions.hpp"
#include "dcslam/datasets/simulator.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

// A read-only numpy view of memory owned by the Simulation behind `owner` (zero copy: the
// whole run crosses into Python once, docs/design.md §9).
template <class T>
py::array view(const T* data, std::vector<py::ssize_t> shape, const py::capsule& owner) {
  py::array array(py::dtype::of<T>(), std::move(shape), {}, data, owner);
  py::detail::array_proxy(array.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return array;
}

}  // namespace

void define_simulator(py::module_& m) {
  // The compiled twin of the Python dataclass dcslam.SimulationConfig (built by its
  // _to_core), so that parameter checks live in one place: SimulationConfig::validate.
  py::class_<SimulationConfig>(m, "SimulationConfig")
      .def(py::init<>())
      .def_property(
          "trajectory",
          [](const SimulationConfig& c) { return std::string(to_string(c.trajectory)); },
          [](SimulationConfig& c, const std::string& v) {
            c.trajectory = parse_trajectory(v, "SimulationConfig.trajectory");
          })
      .def_readwrite("steps", &SimulationConfig::steps)
      .def_readwrite("seed", &SimulationConfig::seed)
      .def_readwrite("step_length", &SimulationConfig::step_length)
      .def_readwrite("side_steps", &SimulationConfig::side_steps)
      .def_readwrite("lane_spacing_steps", &SimulationConfig::lane_spacing_steps)
      .def_property(
          "odometry_sigma", [](const SimulationConfig& c) { return c.odometry_sigma; },
          [](SimulationConfig& c, const py::object& v) {
            c.odometry_sigma = as_vector(v, 3, "SimulationConfig.odometry_sigma");
          })
      .def_readwrite("zero_heading_noise", &SimulationConfig::zero_heading_noise)
      .def_property(
          "observation",
          [](const SimulationConfig& c) { return std::string(to_string(c.observation)); },
          [](SimulationConfig& c, const std::string& v) {
            c.observation = parse_observation_model(v, "SimulationConfig.observation");
          })
      .def_property(
          "sensor_offset", [](const SimulationConfig& c) { return c.sensor_offset; },
          [](SimulationConfig& c, const py::object& v) {
            c.sensor_offset = as_vector(v, 3, "SimulationConfig.sensor_offset");
          })
      .def_readwrite("max_range", &SimulationConfig::max_range)
      .def_readwrite("min_range", &SimulationConfig::min_range)
      .def_readwrite("fov", &SimulationConfig::fov)
      .def_readwrite("range_sigma_fraction", &SimulationConfig::range_sigma_fraction)
      .def_readwrite("bearing_sigma", &SimulationConfig::bearing_sigma)
      .def_readwrite("point_sigma", &SimulationConfig::point_sigma)
      .def_readwrite("features_per_step", &SimulationConfig::features_per_step)
      .def_readwrite("num_features", &SimulationConfig::num_features)
      .def_readwrite("world_margin", &SimulationConfig::world_margin)
      .def_readwrite("clutter", &SimulationConfig::clutter)
      .def("validate", &SimulationConfig::validate)
      .def("footprint_area", &SimulationConfig::footprint_area);

  m.def(
      "simulate",
      [](const SimulationConfig& config) {
        std::unique_ptr<Simulation> sim;
        {
          py::gil_scoped_release release;
          sim = std::make_unique<Simulation>(simulate(config));
        }
        const Simulation& s = *sim;
        py::capsule owner(sim.release(),
                          [](void* p) { delete static_cast<Simulation*>(p); });
        const py::ssize_t steps = s.odometry.rows();
        const py::ssize_t total = s.measurements.rows();
        py::dict out;
        out["landmarks"] = view(s.landmarks.data(), {s.landmarks.rows(), 2}, owner);
        out["poses"] = view(s.poses.data(), {steps + 1, 3}, owner);
        out["odometry"] = view(s.odometry.data(), {steps, 3}, owner);
        out["odometry_covariance"] = py::array(py::cast(Mat3(s.odometry_covariance)));
        out["measurements"] = view(s.measurements.data(), {total, 2}, owner);
        out["measurement_covariances"] =
            view(s.measurement_covariances.data(), {total, 2, 2}, owner);
        out["true_ids"] = view(s.true_ids.data(), {total}, owner);
        out["step_offsets"] = view(s.step_offsets.data(), {steps + 1}, owner);
        return out;
      },
      py::arg("config"),
      "Runs the simulator of Paz et al. 2007 (§III.B); returns a dict of read-only arrays.");
}

}  // namespace dcslam::bindings
