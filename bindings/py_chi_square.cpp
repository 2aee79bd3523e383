#include <pybind11/pybind11.h>

#include "dcslam/core/chi_square.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

void define_chi_square(py::module_& m) {
  // The one chi-square quantile of the library: the gates use it in C++, and
  // dcslam.chi2_threshold() (python/dcslam/consistency.py) is this function.
  m.def("chi2_upper_quantile", &chi2_upper_quantile, py::arg("dof"), py::arg("alpha"),
        "The x with P(X > x) = alpha for X ~ chi2(dof); dof > 0 real, 0 < alpha < 1.");
}

}  // namespace dcslam::bindings
