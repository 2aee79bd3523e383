#pragma once
// The configuration of a SLAM run (API.md's SlamConfig), as a plain struct. The Python
// dataclass dcslam.SlamConfig mirrors it field for field.
#include <cstdint>
#include <string>

#include "dcslam/geometry.hpp"
#include "dcslam/observation.hpp"

namespace dcslam {

// Data association inside a local map (or the whole EKF map).
enum class Association { Known, NearestNeighbour, Jcbb };
// Data association between the two maps of a D&C join.
enum class JoinAssociation { Known, Jcbb, Rjc };

Association parse_association(const std::string& name, const char* field);
JoinAssociation parse_join_association(const std::string& name, const char* field);
const char* to_string(Association association);
const char* to_string(JoinAssociation association);

struct SlamConfig {
  ObservationModel observation = ObservationModel::RangeBearing;
  Vec3 sensor_offset = Vec3::Zero();
  Association association = Association::Jcbb;
  double gate_confidence = 0.99;
  int local_map_features = 30;
  JoinAssociation join_association = JoinAssociation::Rjc;
  int rjc_b = 4;
  double rjc_p_good = 0.8;
  double rjc_p_fail = 0.01;
  std::uint64_t seed = 0;
  bool amortize = true;
  // D&C: run joins on a background worker thread instead (the multi-core form of the
  // amortized schedule); results are bitwise identical to immediate and amortized joins.
  bool threaded_joins = false;

  // Throws InvalidArgument naming the first field that is out of range.
  void validate() const;
};

}  // namespace dcslam
