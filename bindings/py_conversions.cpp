#include "py_conversions.hpp"

#include <cmath>
#include <limits>
#include <sstream>

namespace dcslam::bindings {

std::string shape_string(const py::array& array) {
  std::ostringstream out;
  out << "(";
  for (py::ssize_t i = 0; i < array.ndim(); ++i) {
    if (i) out << ", ";
    out << array.shape(i);
  }
  if (array.ndim() == 1) out << ",";
  out << ")";
  return out.str();
}

DoubleArray as_double_array(const py::handle& obj, const std::string& where) {
  // The per-step path: an array that is already C-contiguous float64 in native byte order
  // (check_ tests all three) is taken as it is. numpy's conversion below would return it
  // unchanged too, but costs two PyArray_FromAny calls and a dtype lookup, more than a
  // step on a small map.
  if (DoubleArray::check_(obj)) return py::reinterpret_borrow<DoubleArray>(obj);
  // ensure() returns a null handle (and clears the Python error) when it cannot convert.
  const py::array source = obj.is_none() ? py::array() : py::array::ensure(obj);
  if (!source) {
    throw py::value_error(where + ": expected an array of real numbers, got " +
                          std::string(py::str(py::type::of(obj).attr("__name__"))));
  }
  // Only integers and floats convert exactly enough to mean what the caller meant: numpy
  // would parse strings, drop imaginary parts and read booleans as 0 and 1.
  const char kind = source.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u') {
    throw py::value_error(where + ": expected an array of real numbers, got dtype " +
                          std::string(py::str(source.dtype())));
  }
  return DoubleArray::ensure(source);
}

void require_finite(const DoubleArray& array, const std::string& where) {
  const double* data = array.data();
  for (py::ssize_t i = 0; i < array.size(); ++i) {
    if (!std::isfinite(data[i])) {
      throw py::value_error(where + ": contains a non-finite value (NaN or inf)");
    }
  }
}

Eigen::VectorXd as_vector(const py::handle& obj, Eigen::Index size, const std::string& where) {
  DoubleArray array = as_double_array(obj, where);
  if (array.ndim() != 1 || array.shape(0) != size) {
    throw py::value_error(where + ": expected shape (" + std::to_string(size) + ",), got " +
                          shape_string(array));
  }
  require_finite(array, where);
  return Eigen::Map<const Eigen::VectorXd>(array.data(), size);
}

Eigen::MatrixXd as_matrix(const py::handle& obj, Eigen::Index rows, Eigen::Index cols,
                          const std::string& where) {
  DoubleArray array = as_double_array(obj, where);
  const bool ok = array.ndim() == 2 && (rows < 0 || array.shape(0) == rows) &&
                  (cols < 0 || array.shape(1) == cols);
  if (!ok) {
    const std::string r = rows < 0 ? "m" : std::to_string(rows);
    const std::string c = cols < 0 ? "k" : std::to_string(cols);
    throw py::value_error(where + ": expected shape (" + r + ", " + c + "), got " +
                          shape_string(array));
  }
  require_finite(array, where);
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  return Eigen::Map<const RowMajor>(array.data(), array.shape(0), array.shape(1));
}

template <int Rows, int Cols>
Eigen::Matrix<double, Rows, Cols> as_fixed(const py::handle& obj, const std::string& where) {
  const DoubleArray array = as_double_array(obj, where);
  const bool ok = Cols == 1 ? array.ndim() == 1 && array.shape(0) == Rows
                            : array.ndim() == 2 && array.shape(0) == Rows && array.shape(1) == Cols;
  if (!ok) {
    const std::string expected = Cols == 1 ? "(" + std::to_string(Rows) + ",)"
                                           : "(" + std::to_string(Rows) + ", " + std::to_string(Cols) + ")";
    throw py::value_error(where + ": expected shape " + expected + ", got " + shape_string(array));
  }
  require_finite(array, where);
  using Layout = Eigen::Matrix<double, Rows, Cols, Cols == 1 ? Eigen::ColMajor : Eigen::RowMajor>;
  return Eigen::Map<const Layout>(array.data());
}

template Eigen::Matrix<double, 3, 1> as_fixed<3, 1>(const py::handle&, const std::string&);
template Eigen::Matrix<double, 3, 3> as_fixed<3, 3>(const py::handle&, const std::string&);

Int64Array as_int64_array(const py::handle& obj, const std::string& where) {
  py::array array = obj.is_none() ? py::array() : py::array::ensure(obj);
  if (!array) {
    throw py::value_error(where + ": expected an array of integers, got " +
                          std::string(py::str(py::type::of(obj).attr("__name__"))));
  }
  if (array.ndim() != 1) {
    throw py::value_error(where + ": expected shape (m,), got " + shape_string(array));
  }
  if (array.size() == 0) return Int64Array(0);
  const char kind = array.dtype().kind();
  if (kind != 'i' && kind != 'u') {
    throw py::value_error(where + ": expected integers, got dtype " +
                          std::string(py::str(array.dtype())));
  }
  if (kind == 'u') {
    // Unsigned values above int64's range would wrap to negative ids.
    const auto values = py::array_t<std::uint64_t, py::array::c_style | py::array::forcecast>::ensure(array);
    for (py::ssize_t i = 0; i < values.size(); ++i) {
      if (values.data()[i] > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
        throw py::value_error(where + "[" + std::to_string(i) + "] is " + std::to_string(values.data()[i]) +
                              ", beyond int64");
      }
    }
  }
  return Int64Array::ensure(array);
}

std::vector<std::int64_t> as_int64_vector(const py::handle& obj, const std::string& where) {
  const Int64Array values = as_int64_array(obj, where);
  return std::vector<std::int64_t>(values.data(), values.data() + values.size());
}

}  // namespace dcslam::bindings
