#pragma once
// Reader of the iSAM/GTSAM 2D text graph format restricted to what a filter can replay:
//   ODOMETRY i j dx dy dtheta  c11 c12 c13 c22 c23 c33
//   LANDMARK i l x y  c11 c12 c22
// The noise columns are read as covariances (upper triangle, row by row), as GTSAM's load2D
// does; iSAM itself reads them as square-root information. GTSAM turns a LANDMARK's noise
// into bearing/range noise; we keep the file's Cartesian point (x, y) in pose i's frame with
// its 2x2 covariance, which is what the file states.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"

namespace dcslam {

// One step per ODOMETRY line (pose i -> pose j), holding the LANDMARK lines seen from pose j.
// LANDMARK lines seen from the first pose, before any ODOMETRY line, make an initial step
// with u = 0, Q = 0 (there is none when the first pose sees nothing).
struct Isam2dData {
  std::vector<std::int64_t> pose_ids;  // (n,) the pose each step ends at
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> u;  // (n, 3)
  Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor> Q;  // (n, 9) row-major 3x3
  std::vector<std::int64_t> offsets;  // (n + 1): step k owns measurements [o_k, o_k+1)
  Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> z;  // (M, 2) point in pose frame
  Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> R;  // (M, 4) row-major 2x2
  std::vector<std::int64_t> landmark_ids;  // (M,)
  std::int64_t odometry_lines = 0;
  std::int64_t landmark_lines = 0;
};

// Throws ParseError naming file, line and field for an unknown tag, a wrong token count, a
// non-number, a negative id, a broken pose chain (i must be the previous j, j > i), a LANDMARK
// not seen from the current pose or seen twice from it, a file with no ODOMETRY or LANDMARK
// line, and whatever the filter would refuse (input_checks.hpp): a value beyond its bound, an
// ODOMETRY covariance that is not positive semi-definite, a LANDMARK covariance that is not
// positive definite.
Isam2dData read_isam2d(const std::string& path);

// The filter options for replaying such a file, the one preset that the Python package
// (Isam2d.slam_config()) and dcslam_bench both start from: Cartesian point observations from
// the robot frame, the file's landmark ids as known association, inside local maps and at
// joins; SlamConfig's defaults elsewhere.
SlamConfig isam2d_slam_config();

}  // namespace dcslam
