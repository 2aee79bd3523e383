// The private compiled module dcslam._core. Each area of the library binds itself in its own
// file through one define_<area>() function.
#include <pybind11/pybind11.h>

namespace py = pybind11;

namespace dcslam::bindings {
void define_errors(py::module_& m);
void define_chi_square(py::module_& m);
void define_geometry(py::module_& m);
void define_config(py::module_& m);
void define_slam_filter(py::module_& m);
void define_dc_slam(py::module_& m);
void define_datasets(py::module_& m);
void define_simulator(py::module_& m);
}  // namespace dcslam::bindings

PYBIND11_MODULE(_core, m) {
  m.doc() = "dcslam's compiled core (private: use the dcslam package).";
  m.attr("__version__") = DCSLAM_VERSION;
  dcslam::bindings::define_errors(m);
  dcslam::bindings::define_chi_square(m);
  dcslam::bindings::define_geometry(m);
  dcslam::bindings::define_config(m);
  dcslam::bindings::define_slam_filter(m);
  dcslam::bindings::define_dc_slam(m);
  dcslam::bindings::define_datasets(m);
  dcslam::bindings::define_simulator(m);
}
