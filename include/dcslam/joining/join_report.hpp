#pragma once
// What a join did and decided (docs/design.md §4): sizes, pairings, work and time, and for
// diagnosis the pairing by feature id, audited against a JoinOracle's truth when one is set.
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

namespace dcslam {

// A JoinOracle's pairing seen through the join's own pairing model, to tell why a true pair
// was not made: it failed the individual gate that builds the candidate lists (the pair is
// never tested), or it is not compatible given the other true pairs (the two maps disagree
// about it beyond their covariances, so no association search can accept it), or it is
// consistent and the search chose something else.
struct JoinTruthAudit {
  Eigen::Index first = 0, second = 0;  // i in m1, j in m2
  double distance_sq = 0.0;            // marginal D^2 of the pair
  bool candidate = false;              // D^2 within the pruning gate
  // Accepted when the candidate true pairs are taken in increasing marginal D^2, each at the
  // decision gate conditioned on the true pairs kept before it (accept_sequentially()).
  bool consistent = false;
};

// What a join's association saw and decided, by feature id: for diagnosis against a truth
// (studies/duplicate_diagnosis.py). O(n) ids a join.
struct JoinPairingRecord {
  std::vector<std::int64_t> first_ids, second_ids;              // features of m1 and m2
  std::vector<std::pair<std::int64_t, std::int64_t>> pairs;     // (id in m1, id in m2)
  // With a JoinOracle: its pairing, audited against the join's own model (JoinTruthAudit).
  std::vector<std::pair<std::int64_t, std::int64_t>> truth_pairs;  // (id in m1, id in m2)
  std::vector<double> truth_distance_sq;  // marginal D^2 of each
  std::vector<char> truth_candidate;      // passed the individual (pruning) gate
  std::vector<char> truth_consistent;     // passed the gate given the more certain true pairs
  std::vector<std::pair<std::int64_t, std::int64_t>> own_pairs;  // the association's, uncorrected
  // Duplicates merged in the result after the join (SlamConfig::join_merge_max_leaves): (id
  // merged, id it was merged into).
  std::vector<std::pair<std::int64_t, std::int64_t>> merged;
  // RJC's pairs (id in m1, id in m2) left out because a rival hypothesis disagrees
  // (SlamConfig::join_rival_margin; the last join of estimate()'s fold only).
  std::vector<std::pair<std::int64_t, std::int64_t>> disputed;
};

struct JoinReport {
  Eigen::Index features_first = 0;
  Eigen::Index features_second = 0;
  Eigen::Index features_joined = 0;
  int overlap = 0;   // features of m2 with at least one individually compatible candidate
  int pairings = 0;  // matched pairs imposed as constraints
  int tries = 0;     // RJC hypotheses tried (0 for other modes)
  bool chunked = false;  // the pairs are chunked JCBB's, which paired more than RJC
  bool widened = false;  // the pairs are the second search's, at a wider pruning gate
  int dropped_tentative = 0;  // tentative features left unmatched (marginalised)
  // A weak join's pairs with a feature seen once, left to the next join's decision
  // (join_alternatives.hpp); 0 when its result is final.
  int deferred_pairings = 0;
  int alternatives_taken = 0;  // inputs whose alternative this join took (0-2)
  int iterations = 0;  // linearisation points of the constraint update (0 when r = 0)
  // h' S^-1 h of the imposed pairs at the last linearisation point (0 when r = 0).
  double constraint_distance_sq = 0.0;
  double seconds_association = 0.0;
  double seconds_total = 0.0;  // summed over all the slices the join was run in
  std::int64_t work_units = 0;  // covariance elements written plus association/preparation
};

}  // namespace dcslam
