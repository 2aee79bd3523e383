#pragma once
// Error types of the library. Everything derives from std::invalid_argument so that the
// Python bindings map it to ValueError (pybind11's default translation), as docs/api.md requires.
#include <stdexcept>
#include <string>

namespace dcslam {

// A bad argument: wrong shape, non-finite value, a covariance that breaks its rule, an
// unknown option. The message names the argument.
class InvalidArgument : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// A malformed input file. The message names the file, the line and the field.
class ParseError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// A number as message text, with the digits that tell it apart ("-1e-07", "1e+155"), where
// std::to_string prints "-0.000000" and 300 digits.
std::string number_text(double value);

}  // namespace dcslam
