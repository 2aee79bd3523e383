#pragma once
// Validation of the inputs of SlamFilter::predict and SlamFilter::update (the input rules of
// docs/api.md), shared by EkfSlam and DCSlam. Each check throws InvalidArgument whose message
// names the function and the argument, e.g. "update: argument 'R'[3] is not positive definite".
// Filters call them before touching any state, so a rejected call leaves the filter unchanged.
#include <cstdint>
#include <vector>

#include "dcslam/config.hpp"
#include "dcslam/geometry.hpp"
#include "dcslam/slam_filter.hpp"

namespace dcslam {

// u finite; Q finite, symmetric (relative tolerance 1e-9) and positive semi-definite (a zero
// variance, e.g. a known heading, is legal).
void check_motion(const Vec3& u, const Mat3& Q, const char* function);

// z finite (m may be 0; range_bearing ranges must be positive); R holds 1 or m symmetric
// positive definite 2x2 matrices; landmark_ids given iff the association mode is "known",
// with m entries, each >= -1 (-1: "not a landmark", rejected), no id twice in one scan.
void check_measurements(const MeasurementsRef& z, const std::vector<Mat2>& R,
                        const std::vector<std::int64_t>* landmark_ids,
                        ObservationModel observation, Association association,
                        const char* function);

}  // namespace dcslam
