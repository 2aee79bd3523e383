#pragma once
// How gtest prints the library's enums used as test parameters. Without a PrintTo gtest
// prints a parameter as its raw bytes, and CTest (gtest_discover_tests) puts the printed
// value in the test's name: "Models/ObservationTest.X/point", not ".../4-byte object <01-00 00-00>".
// Inline: several test files include it, and ADL finds it in the enums' namespace.
#include <ostream>

#include "dcslam/core/config.hpp"
#include "dcslam/core/observation.hpp"

namespace dcslam {

inline void PrintTo(ObservationModel model, std::ostream* out) { *out << to_string(model); }
inline void PrintTo(JoinAssociation association, std::ostream* out) { *out << to_string(association); }

}  // namespace dcslam
