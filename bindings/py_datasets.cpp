#include <cstring>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/datasets/isam2d.hpp"
#include "dcslam/datasets/victoria_park.hpp"
#include "py_conversions.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

// Copies a row-major Eigen block into a fresh numpy array of the given shape: one copy per
// dataset, after which Python steps are views into it.
template <typename Matrix>
py::array_t<double> to_array(const Matrix& matrix, std::vector<py::ssize_t> shape) {
  py::array_t<double> array(shape);
  if (matrix.size() > 0)
    std::memcpy(array.mutable_data(), matrix.data(),
                static_cast<std::size_t>(matrix.size()) * sizeof(double));
  return array;
}

py::array_t<std::int64_t> to_array(const std::vector<std::int64_t>& values) {
  py::array_t<std::int64_t> array(static_cast<py::ssize_t>(values.size()));
  if (!values.empty()) std::memcpy(array.mutable_data(), values.data(), values.size() * sizeof(std::int64_t));
  return array;
}

}  // namespace

void define_datasets(py::module_& root) {
  py::module_ m = root.def_submodule("datasets", "Dataset readers (use dcslam.datasets).");

  m.def(
      "load_victoria_park",
      [](const std::string& odometry, const std::string& scans, const std::string& trees,
         const std::string& gps, const std::string& steering, double max_range,
         double sigma_range, double sigma_bearing, double sigma_speed, double sigma_steering,
         double floor_sigma_xy, double floor_sigma_phi) {
        VictoriaParkOptions options;
        options.steering = parse_steering(steering, "victoria_park: steering");
        options.max_range = max_range;
        options.sigma_range = sigma_range;
        options.sigma_bearing = sigma_bearing;
        options.odometry.sigma_speed = sigma_speed;
        options.odometry.sigma_steering = sigma_steering;
        options.odometry.floor_sigma_xy = floor_sigma_xy;
        options.odometry.floor_sigma_phi = floor_sigma_phi;
        VictoriaParkData data;
        {
          py::gil_scoped_release release;
          data = load_victoria_park({odometry, scans, trees, gps}, options);
        }
        const auto n = static_cast<py::ssize_t>(data.t.size());
        const auto count = static_cast<py::ssize_t>(data.z.rows());
        py::dict out;
        out["t"] = to_array(data.t, {n});
        out["u"] = to_array(data.u, {n, 3});
        out["Q"] = to_array(data.Q, {n, 3, 3});
        out["offsets"] = to_array(data.offsets);
        out["z"] = to_array(data.z, {count, 2});
        out["R"] = to_array(data.R, {count, 2, 2});
        out["diameters"] = to_array(data.diameters, {count});
        out["gps"] = to_array(data.gps, {static_cast<py::ssize_t>(data.gps.rows()), 3});
        out["detections_total"] = data.detections_total;
        out["detections_beyond_range"] = data.detections_beyond_range;
        out["laser_offset"] = py::make_tuple(data.laser_offset.x(), data.laser_offset.y(),
                                             data.laser_offset.z());
        return out;
      },
      py::arg("odometry"), py::arg("scans"), py::arg("trees"), py::arg("gps"), py::kw_only(),
      py::arg("steering"), py::arg("max_range"), py::arg("sigma_range"),
      py::arg("sigma_bearing"), py::arg("sigma_speed"), py::arg("sigma_steering"),
      py::arg("floor_sigma_xy"), py::arg("floor_sigma_phi"),
      "Reads the four Victoria Park CSVs into flat arrays (one step per laser scan).");

  m.def(
      "victoria_park_options",
      [] {
        const VictoriaParkOptions options;
        py::dict out;
        out["steering"] = to_string(options.steering);
        out["max_range"] = options.max_range;
        out["sigma_range"] = options.sigma_range;
        out["sigma_bearing"] = options.sigma_bearing;
        out["sigma_speed"] = options.odometry.sigma_speed;
        out["sigma_steering"] = options.odometry.sigma_steering;
        out["floor_sigma_xy"] = options.odometry.floor_sigma_xy;
        out["floor_sigma_phi"] = options.odometry.floor_sigma_phi;
        return out;
      },
      "VictoriaParkOptions' defaults, by load_victoria_park's keyword names.");

  m.def(
      "victoria_park_slam_config",
      [](const py::object& laser_offset) {
        return victoria_park_slam_config(
            as_fixed<3, 1>(laser_offset, "victoria_park_slam_config: argument 'laser_offset'"));
      },
      py::arg("laser_offset"), "The filter options for Victoria Park (victoria_park_slam_config in C++).");

  m.def("isam2d_slam_config", &isam2d_slam_config,
        "The filter options for replaying an iSAM 2D file (isam2d_slam_config in C++).");

  m.def(
      "read_isam2d",
      [](const std::string& path) {
        Isam2dData data;
        {
          py::gil_scoped_release release;
          data = read_isam2d(path);
        }
        const auto n = static_cast<py::ssize_t>(data.u.rows());
        const auto count = static_cast<py::ssize_t>(data.z.rows());
        py::dict out;
        out["pose_ids"] = to_array(data.pose_ids);
        out["u"] = to_array(data.u, {n, 3});
        out["Q"] = to_array(data.Q, {n, 3, 3});
        out["offsets"] = to_array(data.offsets);
        out["z"] = to_array(data.z, {count, 2});
        out["R"] = to_array(data.R, {count, 2, 2});
        out["landmark_ids"] = to_array(data.landmark_ids);
        out["odometry_lines"] = data.odometry_lines;
        out["landmark_lines"] = data.landmark_lines;
        return out;
      },
      py::arg("path"), "Reads an iSAM/GTSAM 2D text file (ODOMETRY/LANDMARK lines).");

  m.def(
      "integrate_odometry",
      [](const py::array_t<double, py::array::c_style | py::array::forcecast>& samples,
         double t_begin, double t_end, double sigma_speed, double sigma_steering,
         double floor_sigma_xy, double floor_sigma_phi) {
        if (samples.ndim() != 2 || samples.shape(1) != 3)
          throw InvalidArgument("integrate_odometry: argument 'samples' must have shape (k, 3)");
        std::vector<OdometrySample> list(static_cast<std::size_t>(samples.shape(0)));
        const auto view = samples.unchecked<2>();
        for (py::ssize_t i = 0; i < samples.shape(0); ++i)
          list[static_cast<std::size_t>(i)] = {view(i, 0), view(i, 1), view(i, 2)};
        OdometryNoise noise;
        noise.sigma_speed = sigma_speed;
        noise.sigma_steering = sigma_steering;
        noise.floor_sigma_xy = floor_sigma_xy;
        noise.floor_sigma_phi = floor_sigma_phi;
        Vec3 u;
        Mat3 Q;
        integrate_odometry(AckermannVehicle{}, noise, list, t_begin, t_end, u, Q);
        return py::make_tuple(to_array(u, {3}), to_array(Q, {3, 3}));
      },
      py::arg("samples"), py::arg("t_begin"), py::arg("t_end"), py::kw_only(),
      py::arg("sigma_speed"), py::arg("sigma_steering"), py::arg("floor_sigma_xy"),
      py::arg("floor_sigma_phi"),
      "Victoria Park's vehicle model: (t, encoder speed, steering) samples -> (u, Q).");
}

}  // namespace dcslam::bindings
