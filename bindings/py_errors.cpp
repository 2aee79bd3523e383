#include <pybind11/pybind11.h>

#include "dcslam/core/errors.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

void define_errors(py::module_& m) {
  // Both are ValueError subclasses, as docs/api.md promises for bad input and malformed files.
  py::register_exception<InvalidArgument>(m, "InvalidArgument", PyExc_ValueError);
  py::register_exception<ParseError>(m, "ParseError", PyExc_ValueError);
}

}  // namespace dcslam::bindings
