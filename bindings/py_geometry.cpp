#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "py_conversions.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/observation.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

Vec3 pose_arg(const py::handle& obj, const char* fn, const char* name) {
  return as_vector(obj, 3, std::string(fn) + ": argument '" + name + "'");
}
Vec2 point_arg(const py::handle& obj, const char* fn, const char* name) {
  return as_vector(obj, 2, std::string(fn) + ": argument '" + name + "'");
}

}  // namespace

void define_geometry(py::module_& root) {
  py::module_ m = root.def_submodule("geometry", "2D geometry with analytic Jacobians.");

  m.def("wrap_angle", &wrap_angle, py::arg("angle"), "Wraps an angle to (-pi, pi].");

  m.def(
      "compose",
      [](const py::object& a, const py::object& b, bool jacobians) -> py::object {
        Mat3 J_a, J_b;
        const Vec3 c = compose(pose_arg(a, "compose", "a"), pose_arg(b, "compose", "b"), &J_a, &J_b);
        if (!jacobians) return py::cast(c);
        return py::make_tuple(c, J_a, J_b);
      },
      py::arg("a"), py::arg("b"), py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "invert",
      [](const py::object& a, bool jacobians) -> py::object {
        Mat3 J_a;
        const Vec3 inv = invert(pose_arg(a, "invert", "a"), &J_a);
        if (!jacobians) return py::cast(inv);
        return py::make_tuple(inv, J_a);
      },
      py::arg("a"), py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "transform_point",
      [](const py::object& a, const py::object& p, bool jacobians) -> py::object {
        Mat23 J_a;
        Mat2 J_p;
        const Vec2 q = transform_point(pose_arg(a, "transform_point", "a"),
                                       point_arg(p, "transform_point", "p"), &J_a, &J_p);
        if (!jacobians) return py::cast(q);
        return py::make_tuple(q, J_a, J_p);
      },
      py::arg("a"), py::arg("p"), py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "inverse_transform_point",
      [](const py::object& a, const py::object& p, bool jacobians) -> py::object {
        Mat23 J_a;
        Mat2 J_p;
        const Vec2 q =
            inverse_transform_point(pose_arg(a, "inverse_transform_point", "a"),
                                    point_arg(p, "inverse_transform_point", "p"), &J_a, &J_p);
        if (!jacobians) return py::cast(q);
        return py::make_tuple(q, J_a, J_p);
      },
      py::arg("a"), py::arg("p"), py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "observe",
      [](const std::string& model, const py::object& sensor_offset, const py::object& robot,
         const py::object& feature, bool jacobians) -> py::object {
        Mat23 J_robot;
        Mat2 J_feature;
        const Vec2 z = observe(parse_observation_model(model, "observe: argument 'model'"),
                               pose_arg(sensor_offset, "observe", "sensor_offset"),
                               pose_arg(robot, "observe", "robot"),
                               point_arg(feature, "observe", "feature"), &J_robot, &J_feature);
        if (!jacobians) return py::cast(z);
        return py::make_tuple(z, J_robot, J_feature);
      },
      py::arg("model"), py::arg("sensor_offset"), py::arg("robot"), py::arg("feature"),
      py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "inverse_observe",
      [](const std::string& model, const py::object& sensor_offset, const py::object& robot,
         const py::object& z, bool jacobians) -> py::object {
        Mat23 J_robot;
        Mat2 J_z;
        const Vec2 f = inverse_observe(
            parse_observation_model(model, "inverse_observe: argument 'model'"),
            pose_arg(sensor_offset, "inverse_observe", "sensor_offset"),
            pose_arg(robot, "inverse_observe", "robot"), point_arg(z, "inverse_observe", "z"),
            &J_robot, &J_z);
        if (!jacobians) return py::cast(f);
        return py::make_tuple(f, J_robot, J_z);
      },
      py::arg("model"), py::arg("sensor_offset"), py::arg("robot"), py::arg("z"),
      py::kw_only(), py::arg("jacobians") = false);

  m.def(
      "innovation",
      [](const std::string& model, const py::object& z, const py::object& z_hat) -> Vec2 {
        return innovation(parse_observation_model(model, "innovation: argument 'model'"),
                          point_arg(z, "innovation", "z"), point_arg(z_hat, "innovation", "z_hat"));
      },
      py::arg("model"), py::arg("z"), py::arg("z_hat"));
}

}  // namespace dcslam::bindings
