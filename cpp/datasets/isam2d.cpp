#include "dcslam/datasets/isam2d.hpp"

#include <unordered_set>

#include "dcslam/core/errors.hpp"
#include "dcslam/core/input_checks.hpp"
#include "dcslam/datasets/text_reader.hpp"

namespace dcslam {

namespace {

const char* const kOdometryFields[] = {"tag", "i", "j", "dx", "dy", "dtheta",
                                       "c11", "c12", "c13", "c22", "c23", "c33"};
const char* const kLandmarkFields[] = {"tag", "i", "l", "x", "y", "c11", "c12", "c22"};

std::int64_t parse_id(const std::string& token, const std::string& where, const char* field,
                      const char* what) {
  const std::int64_t id = parse_integer(token, where, field);
  if (id < 0)
    throw field_error(where, field, std::to_string(id) + " is negative (" +
                      what + " ids are >= 0)");
  return id;
}

}  // namespace

Isam2dData read_isam2d(const std::string& path) {
  TextReader reader(path);
  std::vector<std::int64_t> pose_ids;
  std::vector<Eigen::Matrix<double, 1, 3>> u;
  std::vector<Eigen::Matrix<double, 1, 9>> Q;
  std::vector<std::int64_t> offsets{0};
  std::vector<Eigen::Matrix<double, 1, 2>> z;
  std::vector<Eigen::Matrix<double, 1, 4>> R;
  std::vector<std::int64_t> landmark_ids;
  Isam2dData data;

  bool have_pose = false;
  std::int64_t current_pose = 0;
  std::unordered_set<std::int64_t> landmarks_at_pose;
  std::string line;
  while (reader.next_line(line)) {
    const std::vector<std::string> tokens = split_whitespace(line);
    if (tokens.empty() || tokens.front().front() == '#') continue;
    const std::string where = reader.where();
    const auto at_line = [&] { return where; };
    const std::string& tag = tokens.front();
    if (tag == "ODOMETRY") {
      if (tokens.size() != 12)
        throw ParseError(where + ": ODOMETRY needs 12 tokens (ODOMETRY i j dx dy dtheta c11 c12 "
                         "c13 c22 c23 c33), found " + std::to_string(tokens.size()));
      const std::int64_t from = parse_id(tokens[1], where, "i", "pose");
      const std::int64_t to = parse_id(tokens[2], where, "j", "pose");
      double values[9];
      for (int f = 0; f < 9; ++f) values[f] = parse_number(tokens[3 + f], where, kOdometryFields[3 + f]);
      require_no_fault(distance_fault(values[0]), at_line, "dx");
      require_no_fault(distance_fault(values[1]), at_line, "dy");
      require_no_fault(angle_fault(values[2]), at_line, "dtheta");
      for (int f = 3; f < 9; ++f)
        require_no_fault(covariance_entry_fault(values[f]), at_line, kOdometryFields[3 + f]);
      if (have_pose && from != current_pose)
        throw field_error(where, "i", std::to_string(from) +
                          " breaks the pose chain (the current pose is " +
                          std::to_string(current_pose) + ")");
      if (to <= from)
        throw field_error(where, "j", std::to_string(to) +
                          " does not follow pose " + std::to_string(from));
      Eigen::Matrix3d covariance;
      covariance << values[3], values[4], values[5], values[4], values[6], values[7], values[5],
          values[7], values[8];
      const std::string fault = semidefinite_fault(covariance);
      if (!fault.empty()) throw ParseError(where + ": fields 'c11'..'c33': covariance " + fault);
      pose_ids.push_back(to);
      u.emplace_back(values[0], values[1], values[2]);
      Q.emplace_back(Eigen::Map<const Eigen::Matrix<double, 1, 9>>(covariance.data()));
      offsets.push_back(static_cast<std::int64_t>(z.size()));
      have_pose = true;
      current_pose = to;
      landmarks_at_pose.clear();
      ++data.odometry_lines;
    } else if (tag == "LANDMARK") {
      if (tokens.size() != 8)
        throw ParseError(where + ": LANDMARK needs 8 tokens (LANDMARK i l x y c11 c12 c22), "
                         "found " + std::to_string(tokens.size()));
      const std::int64_t from = parse_id(tokens[1], where, "i", "pose");
      const std::int64_t landmark = parse_id(tokens[2], where, "l", "landmark");
      double values[5];
      for (int f = 0; f < 5; ++f) values[f] = parse_number(tokens[3 + f], where, kLandmarkFields[3 + f]);
      require_no_fault(distance_fault(values[0]), at_line, "x");
      require_no_fault(distance_fault(values[1]), at_line, "y");
      for (int f = 2; f < 5; ++f)
        require_no_fault(covariance_entry_fault(values[f]), at_line, kLandmarkFields[3 + f]);
      if (!have_pose) {
        // Seen from the first pose, before any motion: the initial step with u = 0, Q = 0.
        have_pose = true;
        current_pose = from;
        pose_ids.push_back(from);
        u.emplace_back(Eigen::Matrix<double, 1, 3>::Zero());
        Q.emplace_back(Eigen::Matrix<double, 1, 9>::Zero());
        offsets.push_back(0);
      }
      if (from != current_pose)
        throw field_error(where, "i", "landmark seen from pose " + std::to_string(from) +
                          " but the current pose is " + std::to_string(current_pose));
      Eigen::Matrix2d covariance;
      covariance << values[2], values[3], values[3], values[4];
      const std::string fault = definite_fault(covariance);
      if (!fault.empty()) throw ParseError(where + ": fields 'c11'..'c22': covariance " + fault);
      // One scan holds each landmark once (the filter refuses an id twice in one update).
      if (!landmarks_at_pose.insert(landmark).second)
        throw field_error(where, "l", "landmark " + std::to_string(landmark) +
                          " is seen twice from pose " + std::to_string(from));
      z.emplace_back(values[0], values[1]);
      R.emplace_back(values[2], values[3], values[3], values[4]);
      landmark_ids.push_back(landmark);
      offsets.back() = static_cast<std::int64_t>(z.size());
      ++data.landmark_lines;
    } else {
      throw field_error(where, "tag", "unknown tag '" + excerpt(tag) +
                        "' (expected ODOMETRY or LANDMARK)");
    }
  }
  if (u.empty()) throw ParseError(path + ": no ODOMETRY or LANDMARK line (nothing to replay)");
  const auto n = static_cast<Eigen::Index>(u.size());
  const auto m = static_cast<Eigen::Index>(z.size());
  data.pose_ids = std::move(pose_ids);
  data.offsets = std::move(offsets);
  data.landmark_ids = std::move(landmark_ids);
  data.u.resize(n, 3);
  data.Q.resize(n, 9);
  for (Eigen::Index k = 0; k < n; ++k) {
    data.u.row(k) = u[static_cast<std::size_t>(k)];
    data.Q.row(k) = Q[static_cast<std::size_t>(k)];
  }
  data.z.resize(m, 2);
  data.R.resize(m, 4);
  for (Eigen::Index i = 0; i < m; ++i) {
    data.z.row(i) = z[static_cast<std::size_t>(i)];
    data.R.row(i) = R[static_cast<std::size_t>(i)];
  }
  return data;
}

SlamConfig isam2d_slam_config() {
  SlamConfig config;
  config.observation = ObservationModel::Point;
  config.sensor_offset = Vec3::Zero();
  config.association = Association::Known;
  config.join_association = JoinAssociation::Known;
  return config;
}

}  // namespace dcslam
