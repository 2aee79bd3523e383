#pragma once
// Checked conversions from Python objects to Eigen values. Every failure raises ValueError
// with a message that names the function and the argument, so users learn which input was
// wrong and why (shape, dtype, non-finite values).
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

namespace dcslam::bindings {

namespace py = pybind11;

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;
using Int64Array = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>;

// "(3,)" or "(4, 2)" for messages.
std::string shape_string(const py::array& array);

// Converts `obj` (integers or floats; not strings, complex numbers or booleans) to a
// C-contiguous float64 array, or raises ValueError naming `where`.
DoubleArray as_double_array(const py::handle& obj, const std::string& where);

// Requires every element to be finite.
void require_finite(const DoubleArray& array, const std::string& where);

// A finite vector of exactly `size` elements (shape (size,)).
Eigen::VectorXd as_vector(const py::handle& obj, Eigen::Index size, const std::string& where);

// A finite matrix of exactly rows x cols (rows or cols may be -1 for "any").
Eigen::MatrixXd as_matrix(const py::handle& obj, Eigen::Index rows, Eigen::Index cols,
                          const std::string& where);

// as_vector (Cols == 1) or as_matrix for a fixed size, with their checks and messages, without
// a heap allocation (the per-step path). Defined for 3 x 1 and 3 x 3.
template <int Rows, int Cols>
Eigen::Matrix<double, Rows, Cols> as_fixed(const py::handle& obj, const std::string& where);

// A 1-D array of integers (any integer dtype; an empty list is accepted) as int64 values.
// Floats, strings and booleans are refused rather than converted, unsigned values beyond
// int64 rather than wrapped.
std::vector<std::int64_t> as_int64_vector(const py::handle& obj, const std::string& where);
// The same, as a C-contiguous int64 array: the caller's own when it is one (no copy).
Int64Array as_int64_array(const py::handle& obj, const std::string& where);

}  // namespace dcslam::bindings
