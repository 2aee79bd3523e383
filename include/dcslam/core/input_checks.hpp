#pragma once
// Validation of the inputs of SlamFilter::predict and SlamFilter::update (the input rules of
// docs/api.md), shared by EkfSlam and DCSlam. Each check throws InvalidArgument whose message
// names the function and the argument, e.g. "update: argument 'R'[3] is not positive definite".
// Filters call them before touching any state, so a rejected call leaves the filter unchanged.
// The file readers apply the same rules to what they read, through the *_fault functions, so a
// file the filter would refuse is refused at its line.
#include <cstdint>
#include <string>
#include <vector>

#include "dcslam/core/config.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/slam_filter.hpp"

namespace dcslam {

// Bounds of every input: far beyond any robot's, and small enough that the filter's products
// (F P F', S = H P H' + R, squared distances) stay far from overflow. Finite but absurd
// values (a range of 1e155) would otherwise turn the covariance into inf and NaN.
constexpr double kMaxDistance = 1e6;   // |u_x|, |u_y|, a range, a point coordinate [m]
constexpr double kMaxAngle = 1e3;      // |u_phi|, |bearing| [rad]; the filter wraps angles
constexpr double kMaxVariance = 1e12;  // |each entry| of Q and R [m^2, rad^2, m rad]

// The most negative eigenvalue a positive semi-definite Q may show [m^2 or rad^2]. Absolute,
// not relative to Q's largest eigenvalue: Q is added to the robot's covariance as it is, so a
// negative variance along one direction makes P indefinite however large the variance along
// another (a relative test passed diag(1e6, 1e-4, -1e-7)). 1e-12 is a variance of (1 um)^2
// or (1 urad)^2, below any sensor; the eigen-solver's own error, about 2e-16 times the
// largest eigenvalue, stays below it for variances up to 1e3, so a zero variance that comes
// out of arithmetic as -1e-17 is still legal.
constexpr double kSemiDefiniteTolerance = 1e-12;

// "" when the value keeps its bound, else e.g. "1e+155 exceeds 1e+06 m in magnitude" (also
// for NaN and inf), to follow the value's name and a colon.
std::string distance_fault(double value);
std::string angle_fault(double value);
std::string covariance_entry_fault(double value);
// "" when the matrix keeps its rule, else e.g. "is not positive semi-definite (smallest
// eigenvalue -1e-07)", to follow the matrix's name. Q: symmetric (relative tolerance 1e-9)
// and positive semi-definite within kSemiDefiniteTolerance (a zero variance, e.g. a known
// heading, is legal); R: symmetric and positive definite.
std::string semidefinite_fault(const Mat3& Q);
std::string definite_fault(const Mat2& R);

// u finite and within kMaxDistance / kMaxAngle; Q finite, entries within kMaxVariance,
// semidefinite_fault(Q) empty.
void check_motion(const Vec3& u, const Mat3& Q, const char* function);

// z finite and within the bounds (m may be 0; range_bearing ranges must be positive); R
// holds 1 or m matrices, finite, entries within kMaxVariance, definite_fault(R) empty;
// landmark_ids given iff the association mode is "known", with m entries, each >= -1 (-1:
// "not a landmark", rejected), no id twice in one scan.
void check_measurements(const MeasurementsRef& z, const std::vector<Mat2>& R,
                        const std::vector<std::int64_t>* landmark_ids,
                        ObservationModel observation, Association association,
                        const char* function);

}  // namespace dcslam
