#pragma once
// Randomized Joint Compatibility (Paz et al. 2007, Algorithm 3; DESIGN.md §6): data
// association between the two maps of a join in time linear in the overlap, generic over the
// same PairingModel as JCBB (measurement = feature of the second map, feature = feature of
// the first).
#include <cstdint>
#include <vector>

#include "dcslam/jcbb.hpp"

namespace dcslam {

struct RjcOptions {
  int b = 4;             // measurements drawn per try and paired by JCBB*
  double p_good = 0.8;   // prior probability that an overlap measurement has a true pairing
  double p_fail = 0.01;  // accepted probability of never drawing an all-good sample
  double confidence = 0.99;
  std::uint64_t seed = 0;
  int max_tries = 100;                       // cap on t
  std::int64_t max_nodes_per_try = 100000;   // JCBB node bound of each try
  bool verify = true;  // enforce joint compatibility of the final hypothesis (see rjc())
};

struct RjcResult {
  std::vector<int> feature_of;  // per measurement: its feature, or kStar
  int pairings = 0;
  int overlap_size = 0;  // measurements with at least one candidate
  int tries = 0;
  int dropped = 0;  // pairings removed by the final verification
  // D^2 of the final hypothesis; NaN when verify is off and the hypothesis came from the
  // randomized tries (computing it is the O(k^3) work that verify = false skips).
  double joint_distance_sq = 0.0;
};

// candidates[i]: the individually compatible features of measurement i (the overlap O is the
// set of measurements with a non-empty list). If |O| <= b, plain JCBB (with star) on O.
// Otherwise each try draws b distinct measurements of O (std::mt19937_64 seeded with
// options.seed; the draw does not depend on the standard library's distributions, so it is
// reproducible across platforms), pairs all of them by JCBB*, and gives every other
// measurement of O its nearest candidate among those compatible conditioned on that seed
// hypothesis H: nu_c = nu_a - C_aH S_H^-1 nu_H, C_c = C_aa - C_aH S_H^-1 C_Ha, 2-dof gate,
// resolved greedily by distance so that each feature is used once. A try whose JCBB* finds
// no complete hypothesis contributes nothing. The best try has most pairings, ties broken by
// D^2(H) + sum of the conditional distances (an O(k) stand-in for the joint distance).
// After each try p_good = max(p_good, pairings(best) / |O|) and the number of tries becomes
// t = log(p_fail) / log(1 - p_good^b); tries continue while tries < min(t, max_tries)
// (9 tries at the defaults).
//
// The conditional gate tests each pairing against H only, not against the other added
// pairings, so with verify on the best hypothesis is re-tested by accept_sequentially() (each
// pairing against all those kept before it, in the order the try accepted them) and then made
// jointly compatible by enforce_joint_compatibility(). That costs O(k^3) for k pairings, no
// more than the O(n^2 k) join update that consumes them.
RjcResult rjc(const CandidateLists& candidates, const PairingModel& model,
              const RjcOptions& options = RjcOptions());

// Re-tests a hypothesis given as pairings in order: the first seed_size are kept, every later
// one must pass the individual gate (D^2 <= gate) conditioned on all the pairings kept before
// it; the others are set to kStar in feature_of. Returns the number removed. O(k^3).
int accept_sequentially(const std::vector<Pairing>& order, int seed_size,
                        std::vector<int>& feature_of, const PairingModel& model, double gate);

// Removes pairings from feature_of until D^2 <= chi2_quantile(2k, confidence): each time the
// pairing whose removal lowers D^2 most (its distance conditioned on all the others). One
// O(k^3) inverse of S, then O(k^2) per removal. Returns the number removed and writes the
// final D^2 (0 if nothing is left). InvalidArgument if S is not positive definite.
int enforce_joint_compatibility(std::vector<int>& feature_of, const PairingModel& model,
                                double confidence, double* joint_distance_sq = nullptr);

}  // namespace dcslam
