#pragma once
// The features of D&C's closed local maps that were seen only once (docs/data_association.md,
// "Spurious measurements"): kept until the joins with the neighbouring local maps, confirmed
// by a match there, else dropped. The rules shared by the real joins, the anytime estimate
// and the re-linearised tree (join_tree.hpp).
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"

namespace dcslam {

class MapJoin;

// A feature of a closed map seen only once. Its landmark may also have been seen once by the
// local map before (`needs_previous`: first seen in the local map's first tentative_window
// steps) or after (`needs_next`: still unexpired when the map closed). Made from the local
// filter's EkfSlam::TentativeTrack when the map closes; a separate type because a closed map
// is judged by the joins it waits for, not by the steps of a filter that has moved on.
struct TentativeFeature {
  std::int64_t id = 0;
  std::int64_t leaf = 0;  // the local map that saw it (0: the first)
  bool needs_previous = false;
  bool needs_next = false;
};

// Indices in `map` of the tentative features that need nothing more after the join of local
// maps [first_leaf, last_leaf]: matched there they are confirmed, unmatched they are dropped.
std::vector<Eigen::Index> last_chance(const GaussianMap& map,
                                      const std::vector<TentativeFeature>& tentative,
                                      std::int64_t first_leaf, std::int64_t last_leaf);

// The tentative features of a join's result: those of both inputs that still need a later
// join and were not matched in this one (a match confirms a feature: seen in both maps).
std::vector<TentativeFeature> joined_tentative(const std::vector<TentativeFeature>& first,
                                               const std::vector<TentativeFeature>& second,
                                               const MapJoin& join, std::int64_t first_leaf,
                                               std::int64_t last_leaf);

// The tentative features of a join of D&C's final fold, where every one stays: those of both
// inputs that the join did not match.
std::vector<TentativeFeature> unmatched_tentative(const std::vector<TentativeFeature>& first,
                                                  const std::vector<TentativeFeature>& second,
                                                  const MapJoin& join);

}  // namespace dcslam
