#pragma once
// Map joining 2.0 (docs/design.md §4; Paz et al. 2007 §III): join a map m1 (base B1, robot R1)
// with the next map m2 (base B2 = R1, robot R2) into one map with base B1, robot R2,
// features (m1 \ unmatched tentative) ∪ (m2 \ matched) and past poses m1's, then R1 (if
// kept, docs/design.md §4.5), then m2's moved into B1: [R2' | F1 | F2' | Q1 | R1 | Q2'].
//
// The join is computed as one fused pass: the stacked covariance of [m1; m2 moved into B1]
// is never built. Its blocks are produced on demand from P1, P2 and the Jacobians of ⊕, the
// matched pairs are imposed as ideal constraints f_i - f_j = 0 through W = P H' L^-T
// (S = H P H' = L L'), and each column block of the result, P_out = P_stacked - W W', is
// written straight into its final place, already compacted. The pass is split into column
// blocks of fixed width so that a join can be spread over many steps (amortized D&C) or run
// on a worker thread, with bitwise the same result whichever way it is run.
//
// MapJoin composes the pass's jobs, each in its own file: the association (by id or
// JoinAssociator, join_association.hpp) over the JoinFrame (join_frame.hpp), the result's
// layout (join_layout.hpp), the linearisation point (JoinRelinearisation), the constrained
// update (ConstrainedUpdate) and the fill (JoinFill); the cost of each unit is join_cost.hpp's.
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/resumable_work.hpp"
#include "dcslam/joining/join_frame.hpp"
#include "dcslam/joining/join_layout.hpp"
#include "dcslam/joining/join_options.hpp"
#include "dcslam/joining/join_relinearisation.hpp"
#include "dcslam/joining/join_report.hpp"

namespace dcslam {

class ConstrainedUpdate;  // constrained_update.hpp
class JoinAssociator;     // join_association.hpp
class JoinFill;           // join_fill.hpp

class MapJoin : public ResumableWork<MapJoin> {
 public:
  using Pairs = std::vector<std::pair<Eigen::Index, Eigen::Index>>;

  // The inputs are shared and never modified (an anytime estimate may join copies of the same
  // inputs while the real join is pending). `first_tentative` and `second_tentative` list
  // features of m1 and m2 (indices, no duplicates) seen only once whose last chance of a
  // partner is this join: those left unmatched are marginalised out of the result (their rows
  // and columns are not written), the others are confirmed by the match.
  MapJoin(std::shared_ptr<const GaussianMap> first, std::shared_ptr<const GaussianMap> second,
          JoinOptions options, std::vector<Eigen::Index> first_tentative = {},
          std::vector<Eigen::Index> second_tentative = {});
  ~MapJoin();
  MapJoin(const MapJoin&) = delete;
  MapJoin& operator=(const MapJoin&) = delete;

  // ResumableWork: a step is one unit of the current phase, or the association advanced by
  // `budget`.
  std::int64_t step(std::int64_t budget);
  bool done() const { return phase_ == Phase::Done; }
  using ResumableWork<MapJoin>::finish;
  // finish(), with the result's column blocks filled side by side on up to `threads` threads:
  // the same result and work (for a join made whole, as estimate()'s are, not amortized).
  std::int64_t finish(int threads);
  // Exact once the constraints are linearised, an estimate before (an upper bound on the
  // re-linearisation steps).
  std::int64_t remaining_work() const;

  // The joined map; valid once done(). Leaves the join empty.
  GaussianMap take_result();
  const JoinReport& report() const { return report_; }
  // The association is done (the pairs are known) and the join is imposing them.
  bool associated() const { return phase_ != Phase::Associate; }
  // Valid once associated.
  const JoinPairingRecord& pairing_record() const { return pairing_record_; }
  const Pairs& pairs() const { return pairs_; }
  // Per pair, whether a rival candidate came close (JoinAssociationResult::doubtful); all false
  // for pairs by id or fixed in advance.
  const std::vector<char>& doubtful() const { return doubtful_; }
  // (id in m2, id in m1) for every matched pair: the m2 feature merged into the m1 one.
  std::vector<std::pair<std::int64_t, std::int64_t>> merged_ids() const;
  // Ids of the tentative features (of m1, then of m2) marginalised out of the result; known
  // once associated.
  const std::vector<std::int64_t>& dropped_ids() const { return layout_.dropped_ids; }

 private:
  enum class Phase { Associate, Relinearise, Constrain, Factor, Solve, Assemble, Fill, Done };
  // The association, JoinAssociator advanced by `budget` (at once by id for "known"); once the
  // pairs are known, the result's layout, and the phase moves on. Returns the work.
  std::int64_t associate_next(std::int64_t budget);
  void finish_association();
  void release_inputs();
  // The fill is done: its result taken, the inputs released.
  void end_fill();

  std::shared_ptr<const GaussianMap> first_, second_;
  JoinOptions options_;
  Phase phase_ = Phase::Associate;
  JoinReport report_;
  JoinPairingRecord pairing_record_;
  Pairs pairs_;
  std::vector<char> doubtful_;
  std::vector<Eigen::Index> first_tentative_;
  std::vector<Eigen::Index> second_tentative_;
  std::vector<std::pair<std::int64_t, std::int64_t>> merged_ids_;
  JoinLayout layout_;
  // The association's frame (m2 moved into B1 at the prior means) and search, while it runs.
  std::unique_ptr<JoinFrame> association_frame_;
  std::unique_ptr<JoinAssociator> associator_;
  bool relinearisation_started_ = false;
  JoinRelinearisation relinearisation_;
  std::unique_ptr<ConstrainedUpdate> update_;
  std::unique_ptr<JoinFill> fill_;
  GaussianMap result_;
};

// Joins two maps at once (no amortization).
GaussianMap join_maps(const GaussianMap& first, const GaussianMap& second,
                      const JoinOptions& options, JoinReport* report = nullptr);

}  // namespace dcslam
