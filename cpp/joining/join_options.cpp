#include "dcslam/joining/join_options.hpp"

namespace dcslam {

JoinOptions join_options_of(const SlamConfig& config) {
  JoinOptions options;
  options.association = config.join_association;
  options.rjc.confidence = config.gate_confidence;
  options.large_overlap_confidence = config.large_overlap_confidence;
  options.chunked_jcbb_min_overlap = config.chunked_jcbb_min_overlap;
  options.rjc.b = config.rjc_b;
  options.rjc.p_good = config.rjc_p_good;
  options.rjc.p_fail = config.rjc_p_fail;
  options.rjc.exchange_crossed = config.rjc_exchange_crossed;
  options.max_iterations = config.join_iterations;
  options.feature_sigma = config.join_feature_sigma;
  // Every local-map boundary is the R1 of exactly one join of the tree (or of the anytime
  // fold): keeping R1 at every join keeps each boundary pose once.
  options.keep_first_robot = config.keep_local_map_poses;
  return options;
}

}  // namespace dcslam
