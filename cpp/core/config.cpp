#include "dcslam/core/config.hpp"

#include <cmath>
#include <string>

#include "dcslam/core/errors.hpp"

namespace dcslam {

Association parse_association(const std::string& name, const char* field) {
  if (name == "known") return Association::Known;
  if (name == "nn") return Association::NearestNeighbour;
  if (name == "jcbb") return Association::Jcbb;
  throw InvalidArgument(std::string(field) + ": unknown association '" + name +
                        "' (expected 'known', 'nn' or 'jcbb')");
}

JoinAssociation parse_join_association(const std::string& name, const char* field) {
  if (name == "known") return JoinAssociation::Known;
  if (name == "jcbb") return JoinAssociation::Jcbb;
  if (name == "rjc") return JoinAssociation::Rjc;
  throw InvalidArgument(std::string(field) + ": unknown join association '" + name +
                        "' (expected 'known', 'jcbb' or 'rjc')");
}

const char* to_string(Association association) {
  switch (association) {
    case Association::Known: return "known";
    case Association::NearestNeighbour: return "nn";
    case Association::Jcbb: return "jcbb";
  }
  return "?";
}

const char* to_string(JoinAssociation association) {
  switch (association) {
    case JoinAssociation::Known: return "known";
    case JoinAssociation::Jcbb: return "jcbb";
    case JoinAssociation::Rjc: return "rjc";
  }
  return "?";
}

namespace {
void require(bool ok, const std::string& message) {
  if (!ok) throw InvalidArgument("SlamConfig." + message);
}
}  // namespace

void SlamConfig::validate() const {
  require(sensor_offset.allFinite(), "sensor_offset: must be finite");
  require(gate_confidence > 0.0 && gate_confidence < 1.0,
          "gate_confidence: must lie in (0, 1), got " + number_text(gate_confidence));
  require(std::isfinite(unexplained_density) && unexplained_density >= 0.0,
          "unexplained_density: must be finite and >= 0, got " + number_text(unexplained_density));
  require(new_feature_margin >= 0.0,
          "new_feature_margin: must be >= 0 (infinity: never), got " + number_text(new_feature_margin));
  require(jcbb_max_nodes >= 1,
          "jcbb_max_nodes: must be >= 1, got " + std::to_string(jcbb_max_nodes));
  require(min_sightings >= 1, "min_sightings: must be >= 1, got " + std::to_string(min_sightings));
  require(std::isfinite(merge_radius) && merge_radius >= 0.0,
          "merge_radius: must be finite and >= 0, got " + number_text(merge_radius));
  require(final_merge_shared_scans >= 0,
          "final_merge_shared_scans: must be >= 0, got " + std::to_string(final_merge_shared_scans));
  require(join_merge_max_leaves >= 0,
          "join_merge_max_leaves: must be >= 0, got " + std::to_string(join_merge_max_leaves));
  require(!final_merge_confidence || (*final_merge_confidence > 0.0 && *final_merge_confidence < 1.0),
          "final_merge_confidence: must lie in (0, 1) or be None, got " +
              (final_merge_confidence ? number_text(*final_merge_confidence) : std::string()));
  require(!confirmed_first_confidence ||
              (*confirmed_first_confidence > 0.0 && *confirmed_first_confidence < 1.0),
          "confirmed_first_confidence: must lie in (0, 1) or be None, got " +
              (confirmed_first_confidence ? number_text(*confirmed_first_confidence) : std::string()));
  require(estimate_threads >= 0,
          "estimate_threads: must be >= 0 (0: every hardware thread), got " + std::to_string(estimate_threads));
  require(tentative_window >= 1,
          "tentative_window: must be >= 1, got " + std::to_string(tentative_window));
  require(weak_join_pairings >= 0,
          "weak_join_pairings: must be >= 0, got " + std::to_string(weak_join_pairings));
  require(local_map_features >= 1,
          "local_map_features: must be >= 1, got " + std::to_string(local_map_features));
  require(rjc_b >= 1, "rjc_b: must be >= 1, got " + std::to_string(rjc_b));
  require(rjc_p_good > 0.0 && rjc_p_good < 1.0,
          "rjc_p_good: must lie in (0, 1), got " + number_text(rjc_p_good));
  require(rjc_p_fail > 0.0 && rjc_p_fail < 1.0,
          "rjc_p_fail: must lie in (0, 1), got " + number_text(rjc_p_fail));
  require(join_iterations >= 1,
          "join_iterations: must be >= 1, got " + std::to_string(join_iterations));
  require(tree_relinearisation >= 0 && tree_relinearisation <= 100,
          "tree_relinearisation: must lie in [0, 100], got " + std::to_string(tree_relinearisation));
  require(std::isfinite(tree_relinearisation_tolerance) && tree_relinearisation_tolerance >= 0.0,
          "tree_relinearisation_tolerance: must be finite and >= 0, got " + number_text(tree_relinearisation_tolerance));
  require(large_overlap_confidence > 0.0 && large_overlap_confidence < 1.0,
          "large_overlap_confidence: must lie in (0, 1), got " + number_text(large_overlap_confidence));
  require(!join_rival_margin || *join_rival_margin >= 0,
          "join_rival_margin: must be >= 0 or None, got " + std::to_string(join_rival_margin.value_or(0)));
  require(!online_localisation_sigma || *online_localisation_sigma > 0.0,
          "online_localisation_sigma: must be > 0 (inf: always) or None, got " +
              (online_localisation_sigma ? number_text(*online_localisation_sigma) : std::string()));
  require(chunked_jcbb_min_overlap >= 0,
          "chunked_jcbb_min_overlap: must be >= 0 (0: RJC alone), got " + std::to_string(chunked_jcbb_min_overlap));
  require(std::isfinite(join_feature_sigma) && join_feature_sigma >= 0.0,
          "join_feature_sigma: must be finite and >= 0, got " + number_text(join_feature_sigma));
  // Joins by id pair the features of two local maps that carry the same caller's id; the
  // features "nn" and "jcbb" start carry fresh ids of their own map, so no pair would ever match.
  require(join_association != JoinAssociation::Known || association == Association::Known,
          std::string("join_association: 'known' needs association 'known' inside local maps (got '") +
              to_string(association) + "'): use 'rjc' or 'jcbb' at joins");
}

}  // namespace dcslam
