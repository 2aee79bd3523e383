#include "dcslam/core/errors.hpp"

#include <cstdio>

namespace dcslam {

std::string number_text(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%.10g", value);
  return text;
}

}  // namespace dcslam
