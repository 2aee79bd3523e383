#pragma once
// What a join is given besides its two maps (docs/design.md §4): the association mode and its
// settings, the block and work-unit sizes of the resumable pass, the iterated join's
// linearisation, past poses, and the research oracle.
#include <cstdint>
#include <limits>
#include <memory>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/association/rjc.hpp"
#include "dcslam/core/config.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

// A research instrument, never set in a real run: the landmark each feature id stands for
// (from a simulator; < 0 for clutter) and how a join's decision is corrected with it, to
// measure how far the join association is from what its two maps allow
// (studies/join_association_ceiling.py, docs/data_association.md). The oracle pairing: each
// feature of m2, in order, with the first unused feature of m1 of its landmark.
struct JoinOracle {
  enum class Mode {
    Truth,            // the oracle pairing, whatever the gates say
    AmongCandidates,  // the oracle pairing where it is among the individually compatible candidates
    RemoveWrong,      // the association's own pairs, less those the oracle pairing does not hold
    Audit,            // the association's own pairs, unchanged; the oracle pairing only audited
  };
  Mode mode = Mode::Truth;
  std::unordered_map<std::int64_t, std::int64_t> landmark_of;
  // The decision is corrected only at joins whose m1 holds between these many features (the
  // others are audited and left as they are): to tell which joins' mistakes decide the map.
  Eigen::Index min_first_features = 0;
  Eigen::Index max_first_features = std::numeric_limits<Eigen::Index>::max();
};

// A linearisation point chosen outside the join (JoinTree::relinearise(), join_tree.hpp): R1
// in m1's base and m2's state vector, as JoinFrame takes them. The join linearises ⊕ there
// once, without Gauss–Newton steps of its own.
struct JoinLinearisation {
  Vec3 first_robot = Vec3::Zero();
  Eigen::VectorXd second_x;
};

struct JoinAssociationMemo;  // join_association.hpp

struct JoinOptions {
  JoinAssociation association = JoinAssociation::Known;
  // The association's settings, RJC's handed to it as they are (JoinAssociator adds only m2's
  // feature positions). rjc.confidence is the confidence of every test the association makes,
  // in every mode (JCBB's too, and the pruning gate's is derived from it); rjc.seed is the
  // join's random stream.
  RjcOptions rjc;
  // RJC's confidence instead of rjc.confidence on an overlap of at least kLargeOverlap
  // features (join_association.hpp; SlamConfig::large_overlap_confidence).
  double large_overlap_confidence = 0.999;
  // From this overlap on, the RJC hypothesis is compared with chunked JCBB's and the one with
  // more pairings is kept (join_association.hpp; SlamConfig::chunked_jcbb_min_overlap); 0: RJC's
  // alone.
  int chunked_jcbb_min_overlap = 100;
  double feature_sigma = 0.0;  // SlamConfig::join_feature_sigma
  // Interpretation-tree nodes of the JCBB that decides in "rjc" mode when every RJC try failed,
  // so that the fallback stays bounded whatever the overlap. ("jcbb" mode: JcbbOptions' bound.)
  std::int64_t fallback_jcbb_nodes = 20000;
  // Width of the column blocks the result is written in (and of the Cholesky panels).
  Eigen::Index block_columns = kDefaultPanelWidth;
  // Multiply-adds that bound one unit of resumable work (rows of a fill tile, of the solve, of
  // the assembly): small units keep amortized steps short when r is in the hundreds.
  Eigen::Index work_unit = kDefaultWorkUnit;
  // Linearisation points of the constraint update (Gauss–Newton steps of the iterated EKF,
  // docs/divide_and_conquer.md): 1 linearises ⊕ once at the prior means (the one-shot join);
  // more re-linearise at the constrained estimate until the step is negligible.
  int max_iterations = 10;
  // Set: ⊕ linearised at this point instead (max_iterations is then not used).
  std::shared_ptr<const JoinLinearisation> linearisation;
  // Keep R1 in the result as a past pose with id first_robot_id (a sparse trajectory at
  // local-map boundaries, docs/design.md §4.5). Past poses the inputs hold are always kept.
  bool keep_first_robot = false;
  std::int64_t first_robot_id = -1;
  std::shared_ptr<const JoinOracle> oracle;  // research only (JoinOracle); null in real runs
  // Set: these pairs (i in m1, j in m2) are imposed and no association runs (a weak join's
  // alternative: the pairs its association chose less the deferred ones, join_alternatives.hpp).
  std::shared_ptr<const std::vector<std::pair<Eigen::Index, Eigen::Index>>> fixed_pairs;
  // Set: the association of this join's two maps with these options, kept in (or taken from,
  // once kept) this memo, so that a join made again on the same maps does not search again.
  std::shared_ptr<JoinAssociationMemo> association_memo;
};

// The settings a SlamConfig gives every join of a DCSlam: the association and its gates, RJC's
// draws, the join's feature error and iterations (DCSlam adds each join's own random stream,
// R1's id and the oracle). A benchmark of joins alone starts from it to test what a run tests.
JoinOptions join_options_of(const SlamConfig& config);

}  // namespace dcslam
