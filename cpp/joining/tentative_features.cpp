#include "dcslam/joining/tentative_features.hpp"

#include <unordered_set>

#include "dcslam/joining/map_joining.hpp"

namespace dcslam {

namespace {

// A tentative feature once the join of local maps [first_leaf, last_leaf] has met it: the
// previous local map is met when it is inside, the next one likewise.
TentativeFeature met(TentativeFeature feature, std::int64_t first_leaf, std::int64_t last_leaf) {
  feature.needs_previous = feature.needs_previous && feature.leaf <= first_leaf;
  feature.needs_next = feature.needs_next && feature.leaf >= last_leaf;
  return feature;
}

}  // namespace

std::vector<Eigen::Index> last_chance(const GaussianMap& map,
                                      const std::vector<TentativeFeature>& tentative,
                                      std::int64_t first_leaf, std::int64_t last_leaf) {
  std::unordered_set<std::int64_t> wanted;
  for (const TentativeFeature& feature : tentative) {
    const TentativeFeature after = met(feature, first_leaf, last_leaf);
    if (!after.needs_previous && !after.needs_next) wanted.insert(feature.id);
  }
  std::vector<Eigen::Index> indices;
  for (std::size_t k = 0; k < map.ids().size(); ++k) {
    if (wanted.count(map.ids()[k]) != 0) indices.push_back(static_cast<Eigen::Index>(k));
  }
  return indices;
}

std::vector<TentativeFeature> joined_tentative(const std::vector<TentativeFeature>& first,
                                               const std::vector<TentativeFeature>& second,
                                               const MapJoin& join, std::int64_t first_leaf,
                                               std::int64_t last_leaf) {
  std::vector<TentativeFeature> kept;
  for (const TentativeFeature& feature : unmatched_tentative(first, second, join)) {
    const TentativeFeature after = met(feature, first_leaf, last_leaf);
    if (after.needs_previous || after.needs_next) kept.push_back(after);
  }
  return kept;
}

std::vector<TentativeFeature> unmatched_tentative(const std::vector<TentativeFeature>& first,
                                                  const std::vector<TentativeFeature>& second,
                                                  const MapJoin& join) {
  std::unordered_set<std::int64_t> matched;
  for (const auto& [from, to] : join.merged_ids()) {
    matched.insert(from);
    matched.insert(to);
  }
  std::vector<TentativeFeature> kept;
  for (const auto* side : {&first, &second}) {
    for (const TentativeFeature& feature : *side) {
      if (matched.count(feature.id) == 0) kept.push_back(feature);
    }
  }
  return kept;
}

}  // namespace dcslam
