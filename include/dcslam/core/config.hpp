#pragma once
// The configuration of a SLAM run (docs/api.md's SlamConfig), as a plain struct. The Python
// dataclass dcslam.SlamConfig mirrors it field for field.
#include <cstdint>
#include <optional>
#include <string>

#include "dcslam/core/geometry.hpp"
#include "dcslam/core/observation.hpp"

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
  // Chi-square confidence of every individual and joint compatibility test (the scans', the
  // joins', the merges'). 0.999 since the margin below: the wider gate puts more first
  // sightings in a neighbour's gate, which new_feature_margin then maps instead of rejecting
  // (docs/data_association.md, "Unexplained measurements beside mapped features").
  double gate_confidence = 0.999;
  // "jcbb": expected measurements per scan and per m^2 (in the plane) that no mapped feature
  // explains, clutter and first sightings together. 0 = JCBB returns the hypothesis with most
  // pairings; > 0 = the one with the highest likelihood ratio against leaving measurements
  // unexplained (JcbbLikelihood), which declines pairings less likely than that density.
  // 0.02: a pairing whose gate is wide (an uncertain robot back at a place) loses to
  // "unexplained" unless its innovation is small; measured on the revisit scenes
  // (docs/data_association.md, "The default density").
  double unexplained_density = 0.02;
  // "jcbb" with unexplained_density > 0: a measurement JCBB leaves unpaired although it is
  // compatible with mapped features starts a (tentative) feature when every hypothesis that
  // pairs it is less likely than the chosen one by more than this log-likelihood ratio (e^5,
  // about 150 to 1, by default), and is rejected otherwise. infinity = always rejected.
  // Measured on the revisit scenes (docs/data_association.md, "Unexplained measurements
  // beside mapped features").
  double new_feature_margin = 5.0;
  // "nn"/"jcbb" with tentative features (min_sightings > 1): a measurement left unpaired whose
  // compatible features are all still tentative starts a feature on probation instead of being
  // rejected, whatever new_feature_margin says. Most tentative features are clutter, and a
  // rejection beside them loses a landmark's first sighting, or, in D&C's local maps, which
  // start afresh every ~30 features, a sighting again. On probation the first sighting, a close
  // call, does not count: min_sightings more confirm the feature, and the duplicate merges'
  // scan counts leave it out (counted, MR.CLAM's D&C map merged such features wrongly).
  // Off by default: on the simulated scenes it raises recall by 0.01-0.02 but maps more
  // landmarks twice and leaves D&C's robot further off on the paper's straight trajectory
  // (docs/data_association.md, "Unpaired beside tentative features only"). false: rejected.
  bool new_feature_beside_tentative = false;
  // "nn"/"jcbb" with tentative features (min_sightings > 1): a measurement that lies within
  // this confidence region (chi-square, 2 dof) of a confirmed feature is not offered to the
  // tentative ones, so it cannot confirm one. A clutter point beside a landmark starts a
  // tentative feature (new_feature_margin), whose wide covariance then takes the landmark's
  // next measurement from the landmark's own feature, tighter and, after many sightings,
  // optimistic: a second feature of the landmark for good. Only close calls are restricted: a
  // measurement far out in its landmark's gate is left free to pair with a tentative feature,
  // which on MR.CLAM, whose sightings carry biases the models leave out, is often the only
  // way a landmark is recognised at all (0.9 keeps MR.CLAM's EKF as without the rule; the
  // whole gate, gate_confidence, costs it). Beside no confirmed feature, tentative features
  // are offered as before (docs/data_association.md, "Confirmed features first"). None: every
  // compatible feature is offered.
  std::optional<double> confirmed_first_confidence = 0.9;
  // "jcbb": interpretation-tree nodes per scan before JCBB returns its best hypothesis so far.
  std::int64_t jcbb_max_nodes = 20000;
  // Spurious measurements ("nn"/"jcbb" only; docs/data_association.md): a new feature stays
  // tentative until it has been seen min_sightings times (1 = confirmed at birth, policy off);
  // a tentative feature not seen for more than tentative_window steps is removed.
  int min_sightings = 2;
  int tentative_window = 5;
  // "nn"/"jcbb": two features of one map are merged (the constraint f_a = f_b imposed as an
  // exact update, then f_b marginalised) when they were never paired in one scan, lie within
  // this distance (m), and each is the other's only feature compatible with it at
  // gate_confidence (docs/data_association.md, "Duplicated features"). 0 = never merge.
  double merge_radius = 2.0;
  // Confidence of the same test in the duplicate merge that D&C's estimate() runs on the
  // folded map; unset: gate_confidence. That merge decides last, on the whole map, so a wrong
  // one bends no later decision (an EKF's merge after an update does): on the simulator's
  // revisit scenes 0.999 merges more duplicates at little cost in precision, which the
  // same confidence in the local maps' merges does not (docs/data_association.md,
  // "Duplicates merged in D&C's estimate"). The EKF has no final merge and ignores it.
  std::optional<double> final_merge_confidence;
  // D&C's final merge only: two features seen together in at most this many scans may still
  // be one landmark, when each was also seen in a scan without the other. One clutter point or
  // neighbour paired into a duplicate in the same scan as its twin would otherwise keep the two
  // apart for good, while two distinct landmarks close enough to pass the test are seen
  // together in nearly every scan that sees the less seen one (docs/data_association.md,
  // "Duplicates merged in D&C's estimate"). 0: never merge features seen in one scan, the
  // rule of every merge inside a map. The EKF ignores it.
  int final_merge_shared_scans = 1;
  // D&C: after each real join whose result spans at most this many local maps (and that keeps
  // no alternative for the next join to decide), the joined map's duplicates are merged with
  // the final merge's test (the confidence, shared scans and feature error above), features
  // still tentative left out. A duplicate a small join left unpaired otherwise enters every
  // larger join twice (docs/data_association.md, "Duplicates merged after small joins"). 0
  // (the default): never. 4 gains a little on runs that keep coming back, with fewer runs whose
  // robot is within its 99 % bound (measured 2026-12-06); a larger value adds O(k n^2) for k
  // merges outside the amortized schedule.
  int join_merge_max_leaves = 0;
  // D&C: a join of 8 local maps or more that makes at most this many pairs is weak: it also
  // builds its result without its pairs that have a feature seen once, and the next join
  // (or estimate()'s fold) joins whichever version scores higher: twice the pairs it makes
  // itself plus the version's (docs/data_association.md, "Weak joins decided by the next
  // join", "Own pairs count twice"). A join of 16 local maps or more that makes more pairs
  // keeps its result without its doubtful pairs (when they are at least a tenth of its pairs),
  // decided the same way ("Large joins' doubtful pairs, decided by the next join"). 0: off,
  // every join's pairs are final when made.
  int weak_join_pairings = 30;
  int local_map_features = 30;
  JoinAssociation join_association = JoinAssociation::Rjc;
  int rjc_b = 4;
  double rjc_p_good = 0.8;
  double rjc_p_fail = 0.001;
  // D&C: each RJC try's greedy hypothesis exchanges the features of two pairings whose sum of
  // distances then falls (close landmarks paired crosswise; pairing_exchanges.hpp). On by
  // measurement: recall as high or higher on every simulated scene (docs/data_association.md,
  // "Crossed pairings exchanged"); false: the greedy hypothesis as it is.
  bool rjc_exchange_crossed = true;
  // D&C: linearisation points of each join's constraint update (iterated EKF; 1 = the
  // one-shot join linearised at the prior means).
  int join_iterations = 10;
  // D&C joins' compatibility tests only: a per-feature position error (m) that repeated
  // sightings do not average out (a local EKF's linearisation; on real data, e.g. a trunk
  // centre seen from different sides), added as join_feature_sigma^2 I to each feature of a
  // tested pair. The update still imposes the pairs exactly. 0.01 by measurement: the error of
  // a feature relative to another of its local map, against the truth, is consistent with its
  // covariance only with it (docs/data_association.md, "A feature error at the joins").
  double join_feature_sigma = 0.01;
  // D&C: the confidence of RJC's tests at a join whose overlap holds at least 50 features
  // (join_association.hpp's kLargeOverlap); gate_confidence's at every other join. There the
  // relative pose is settled by many pairings, so a wrong one gathers no more chance pairings
  // than the true one: a tight gate only turns true pairs away, and a true pair turned away at
  // a join is a landmark mapped twice for good, where the EKF's rejected sighting is one
  // sighting. 0.999 by measurement; on small overlaps a wider gate does let a wrong relative
  // pose win (docs/data_association.md, "Large overlaps decided at a wider gate"). Measured
  // when the gate was 0.99; equal to the default gate since.
  double large_overlap_confidence = 0.999;
  // D&C: from this overlap (features of the second map with a candidate) on, a join that RJC
  // has paired is also decided by chunked JCBB, the second map's features in map order, 32 at
  // a time, each chunk conditioned on the pairings of those before it (the EKF's order); the
  // hypothesis with more pairings is kept. At a whole-lap join the maps have drifted apart
  // along the lap and RJC's tries, seeded on a few pairs drawn from the whole overlap, pair a
  // fraction of it. 0: RJC alone. 100 by measurement (docs/data_association.md, "The EKF's
  // order at large joins").
  int chunked_jcbb_min_overlap = 100;
  // D&C: at the last join of estimate()'s fold (the newest local maps against the rest of the
  // map, which no later join decides), when its overlap holds at least 100 features
  // (kRivalMinOverlap), every RJC try within this many pairings of the best is verified, and a
  // try that agrees with fewer than 80 % of its own pairings (made by the best too, or
  // compatible with all the best's) is a rival: another alignment of the maps that the data
  // support nearly as well. The join then keeps only the best's pairings that every rival makes
  // too (nor does chunked JCBB, which decides by count, replace them). A loop closed by a few
  // pairings at the end of a run stays open instead of closing wrong: the robot keeps its
  // uncertainty rather than ending tens of metres off with a covariance of centimetres. unset:
  // the best try as it is. 3 by measurement (docs/data_association.md, "The fold's last join
  // commits only to what its rivals agree on").
  std::optional<int> join_rival_margin = 3;
  // D&C: damped Gauss–Newton passes that estimate() makes through the whole tree of joins,
  // rebuilding every kept local map from its own odometry and measurements and redoing every
  // join, all linearised at the previous pass's map (join_tree.hpp, leaf_relinearisation.hpp);
  // converged, the batch optimum of the run's associations. 0 (the paper's D&C; nothing is
  // kept) by measurement: one pass costs about as much again as the whole plain run
  // (docs/divide_and_conquer.md).
  int tree_relinearisation = 0;
  // D&C: the passes stop before tree_relinearisation once a pass, taken whole, predicts that
  // another could lower the batch objective (a sum of squared whitened residuals) by at most
  // this much: its result's objective less the minimum of the problem it linearised. The map
  // is then within sqrt(this) standard deviations of the optimum in every direction (each
  // landmark, pose, or combination of them). 3.84, chi-square's 95 % point for one degree of
  // freedom, by measurement: one pass on Victoria Park (its map 0.019 m from the optimum), two
  // on the iSAM file (docs/divide_and_conquer.md, "When the passes stop"). 0: every pass, or
  // until no mean moves by more than 1e-9.
  double tree_relinearisation_tolerance = 3.841458820694124;
  std::uint64_t seed = 0;
  bool amortize = true;
  // D&C: run joins on a background worker thread instead (the multi-core form of the
  // amortized schedule); results are bitwise identical to immediate and amortized joins.
  bool threaded_joins = false;
  // D&C: threads that estimate() may use for the parts of its fold that do not depend on each
  // other (the associations of a join's candidate versions, the rest of the fold carried
  // through each version of a weak fold join, each join's fill a column block per thread) and
  // of the re-linearisation passes (the leaves' fits and rebuilds, the joins of disjoint
  // subtrees); bitwise the same estimate for every count.
  // 0: every hardware thread; 1: the calling thread only.
  int estimate_threads = 0;
  // D&C: keep the robot pose at every local-map boundary in the joined map
  // (docs/design.md §4.5), as past poses with their full covariance (Estimate::past_poses);
  // the EKF keeps none.
  bool keep_local_map_poses = false;
  // D&C: when a local map closes, its features are paired with the oldest map's and its end
  // pose (the next local map's base) is conditioned on the pairs, through the chain of maps
  // between them (online_localisation.hpp), if that chain leaves the pose with a position
  // standard deviation of at most this many metres: pose() then knows of a place seen again
  // before the joins reach it. The maps and estimate() are unchanged. Above it the pairing
  // would be a loop closure at large uncertainty, left to the joins. unset (the paper's D&C):
  // pose() composes the stack's maps. 10 m suited the simulated scenes and Victoria Park; off
  // by default for its cost on the schedule, a localisation being a step's work
  // (docs/divide_and_conquer.md, "The online pose on places seen again").
  std::optional<double> online_localisation_sigma;

  // Throws InvalidArgument naming the first field that is out of range.
  void validate() const;
};

}  // namespace dcslam
