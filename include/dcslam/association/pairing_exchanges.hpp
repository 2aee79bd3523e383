#pragma once
// Exchanges inside a greedy assignment: an RJC try pairs its conditional candidates nearest
// first, each feature once, so where two landmarks lie close together (two features of each
// map within the noise of each other) the nearest single pair can take the feature that the
// other measurement needed, and the two pairings then cross. Exchanging their features when
// that lowers the sum of the two distances undoes the crossing (docs/data_association.md,
// "Crossed pairings exchanged").
#include <cstdint>
#include <tuple>
#include <vector>

namespace dcslam {

// `scored`: (distance^2, measurement, feature) of every candidate pairing, sorted by distance
// (as a try's conditional list is). `movable`: the measurements whose pairings may exchange
// features; each is paired (`feature_of[m] != kStar`) and its pairing is in `scored`.
// Exchanges the features of two movable pairings (m1, f1), (m2, f2) whenever (m1, f2) and
// (m2, f1) are both candidates and d(m1, f2) + d(m2, f1) < d(m1, f1) + d(m2, f2), until no
// such exchange is left or `max_rounds` rounds over `movable` have passed. The paired
// measurements and the used features stay the same; the sum of the distances only falls.
// Returns the work done (candidate entries visited), O(|scored|) a round.
std::int64_t exchange_crossed_pairings(const std::vector<std::tuple<double, int, int>>& scored,
                                       const std::vector<int>& movable, std::vector<int>& feature_of,
                                       int max_rounds = 10);

}  // namespace dcslam
