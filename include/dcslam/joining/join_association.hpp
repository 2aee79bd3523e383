#pragma once
// Data association between the two maps of a D&C join without ids (docs/design.md §6): candidate
// pairs through a spatial hash over m1's features, individual compatibility with the pair
// covariance P_ii + P_jj - P_ij - P_ji, then JCBB over the whole overlap ("jcbb") or RJC
// (the paper's Algorithm 3, "rjc"). The individual gate only prunes, at a tenth of the
// decision gate's tail (0.999 for a confidence of 0.99; the overlap counts features with a
// candidate at that level; a thousandth in JoinAssociator's second search); pairs are
// accepted by the joint or conditional test at JoinOptions::rjc.confidence
// (SlamConfig::gate_confidence), or, by RJC on an overlap of at least kLargeOverlap features,
// at JoinOptions::large_overlap_confidence.
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "dcslam/association/chunked_jcbb.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/association/rjc.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/resumable_work.hpp"
#include "dcslam/core/spatial_hash.hpp"
#include "dcslam/joining/join_frame.hpp"
#include "dcslam/joining/join_options.hpp"
#include "dcslam/joining/join_report.hpp"

namespace dcslam {

// RJC runs on an overlap of more than this many samples' worth of features (3 b); a smaller
// one goes to JCBB with the star node, exact and cheap there (docs/design.md §6).
inline constexpr int kRjcMinOverlapSamples = 3;

// From this overlap on, RJC decides at JoinOptions::large_overlap_confidence
// (SlamConfig::large_overlap_confidence). The joins whose relative pose a wider gate let go
// wrong on the simulator's revisit scenes had overlaps of about 20; whole-lap and whole-map
// joins have 100 and more. 50 by measurement (docs/data_association.md, "Large overlaps
// decided at a wider gate").
inline constexpr int kLargeOverlap = 50;

// From this overlap on, RJC leaves out the pairings its rivals dispute when it is given a
// rival margin (JoinOptions::rjc.rival_margin; DCSlam gives it to the last join of estimate()'s
// fold, SlamConfig::join_rival_margin): a loop closure's join. Applied at every join whatever
// its overlap, two of three runs of the paper's loop tried closed wrong, the pairings left out
// at small joins redrawing the later ones (docs/data_association.md, "The fold's last join
// commits only to what its rivals agree on").
inline constexpr int kRivalMinOverlap = 100;

// A slice of the JCBB over the whole overlap ends at the first node boundary after this much
// work (its units, which weigh less than the other stages': a slice of 2^20 took 4.3 ms on
// Victoria Park, where the other stages' slices take about 1 ms).
inline constexpr std::int64_t kJcbbSliceWork = std::int64_t{1} << 18;

// A join whose RJC pairs fewer than this share of its overlap searches again at a wider
// pruning gate (JoinAssociator, "A second search at a wider gate"), unless its candidate lists
// hold more than kWideSearchMaxCandidatesPerFeature candidates per overlap feature. Victoria
// Park's local-map sizes 45 and 80 closed a loop wrongly with 22 % and 27 % of their overlap
// paired; the simulator's lawn joins that pair 59-70 % of theirs gain nothing from a second
// search (docs/data_association.md, "A second search at a wider gate").
inline constexpr double kWideSearchBelowShare = 0.5;
// Crowded candidate lists (the paper's loop closed at large uncertainty: 20-90 candidates per
// feature) mean an ambiguous overlap, which a wider gate only makes more so; the Victoria Park
// joins rescued hold 1.1-2.1.
inline constexpr double kWideSearchMaxCandidatesPerFeature = 4.0;

// Measurement = feature j of the moved m2, feature = feature i of m1; the innovation of the
// pairing is f'_j - f_i, whose covariance is P_ii + P_jj - P_ij - P_ji in the stacked map,
// plus feature_sigma^2 I for each feature the two pairings share (each feature carries its
// own independent error of that size: SlamConfig::join_feature_sigma).
class JoinPairingModel : public PairingModel {
 public:
  explicit JoinPairingModel(const JoinFrame& frame, double feature_sigma = 0.0)
      : frame_(frame), feature_variance_(feature_sigma * feature_sigma) {}
  Vec2 innovation(const Pairing& p) const override;
  Mat2 covariance(const Pairing& a, const Pairing& b) const override;
  // Through JoinFrame::constraint_column(): b's terms once, P read along b's columns.
  void covariances_with(const Pairing* pairings, std::size_t count, const Pairing& b,
                        CrossColumns cross) const override;

 private:
  Mat2 with_feature_variance(const Pairing& a, const Pairing& b, Mat2 covariance) const;
  const JoinFrame& frame_;
  double feature_variance_;
};

// A pair is doubtful when a rival candidate comes within this much of its marginal D^2: another
// feature of m1 individually compatible with its m2 feature, or another feature of m2 with its
// m1 feature. A large join leaves its doubtful pairs to the next join's decision
// (join_alternatives.hpp); 0.5 by measurement (docs/data_association.md, "Large joins' doubtful
// pairs").
inline constexpr double kDoubtfulPairMargin = 0.5;

struct JoinAssociationResult {
  std::vector<std::pair<Eigen::Index, Eigen::Index>> pairs;  // (i in m1, j in m2)
  std::vector<char> doubtful;  // per pair: a rival candidate within kDoubtfulPairMargin
  int overlap = 0;
  int tries = 0;
  bool chunked = false;  // the pairs are chunked JCBB's, which paired more than RJC
  bool widened = false;  // the pairs are the second search's, at the wider pruning gate
  // RJC's pairings (i in m1, j in m2) left out because a rival hypothesis disagrees
  // (JoinOptions::rjc.rival_margin).
  std::vector<std::pair<Eigen::Index, Eigen::Index>> disputed;
  std::vector<JoinTruthAudit> truth_audit;  // only with a JoinOracle
  // With a JoinOracle: the association's own pairs, before the oracle corrected them.
  std::vector<std::pair<Eigen::Index, Eigen::Index>> own_pairs;
};

// JoinOptions::association_memo: the association of two maps, kept by the join that made it
// for a join of the same maps with the same options (estimate()'s fold, which makes a join
// again while it compares a weak fold join's versions). The search depends on its inputs
// alone, so the result taken is bitwise the one the search would find.
struct JoinAssociationMemo {
  std::optional<JoinAssociationResult> result;
};

// Pairs (i in m1, j in m2) of features with the same id ("known" association).
std::vector<std::pair<Eigen::Index, Eigen::Index>> associate_by_id(const GaussianMap& first,
                                                                   const GaussianMap& second);

JoinAssociationResult associate_maps(const JoinFrame& frame, const JoinOptions& options);

// associate_maps() as resumable work (ResumableWork), so that an amortized join spreads its
// association over many steps: a step is the search radii and the spatial hash over m1, the
// candidates of one m2 feature, RjcSearch or ChunkedJcbb advanced by the step's budget, or a
// slice of the JCBB over the whole overlap (its start, then nodes up to kJcbbSliceWork), which
// only runs on small overlaps, where every RJC try failed (node-bounded) or in "jcbb" mode.
// The steps are the computation associate_maps() does, in the same order, so
// the result is bitwise the same however the work is sliced. `frame` must outlive the
// associator, which is neither copied nor moved.
//
// At an overlap of at least JoinOptions::chunked_jcbb_min_overlap features, once RJC has paired
// some, chunked JCBB (chunked_jcbb.hpp) decides too, over the same candidates at the same
// confidence, and the hypothesis with more pairings is kept (RJC's on a tie). RJC's tries
// seed the relative pose on a few pairs drawn from the whole overlap; at a whole-lap join the
// maps have drifted apart along the lap, so pairs that fit near the junction do not fit far
// from it, and the tries pair a fraction of the overlap. Chunked JCBB starts at the junction
// (m2's features in map order) and lets each chunk correct the relative pose for the next,
// as the EKF does sighting by sighting. Neither wins everywhere: chunks alone collapse where
// an early chunk goes wrong (docs/data_association.md, "The EKF's order at large joins").
//
// A second search at a wider gate: where RJC ran and paired fewer than kWideSearchBelowShare
// of the overlap over uncrowded candidates, the association is made again from the start with
// the pruning gate at a thousandth of the decision gate's tail instead of a tenth, and its
// hypothesis is kept if it pairs more (JoinAssociationResult::widened). Where the maps'
// relative pose is off by more than its covariance allows (a large loop closed after a drift
// that the linearised covariances understate), every true pair sits at about the same
// marginal D^2, beyond the first gate: the first search sees only the pairs near the junction
// and chance neighbours, while the joint and conditional tests, which explain a shared offset
// away, accept the true hypothesis once its pairs are candidates. The decisions stay at the
// same confidence; only what is offered to them grows.
class JoinAssociator : public ResumableWork<JoinAssociator> {
 public:
  JoinAssociator(const JoinFrame& frame, const JoinOptions& options);
  JoinAssociator(const JoinAssociator&) = delete;
  JoinAssociator& operator=(const JoinAssociator&) = delete;

  std::int64_t step(std::int64_t budget);
  bool done() const { return stage_ == Stage::Done; }
  // The decision's share is only known once the overlap is (counted as 0 before, as the join
  // counts the constraints' before association).
  std::int64_t remaining_work() const;
  // The overlap (features of m2 with a candidate, at least the pairings to come): counted
  // once the candidates are known, extrapolated over m2 while they are searched, 0 before.
  std::int64_t expected_overlap() const;
  // Valid once done().
  const JoinAssociationResult& result() const { return result_; }

 private:
  enum class Stage { Prepare, Candidates, Rjc, Chunked, Jcbb, Done };
  std::int64_t prepare();
  std::int64_t candidates_of_next();
  std::int64_t advance_rjc(std::int64_t budget);
  std::int64_t advance_chunked(std::int64_t budget);
  // RJC's hypothesis or chunked JCBB's, whichever pairs more (RJC's on a tie).
  void choose_hypothesis();
  bool chunked_wanted() const;
  // Chunked JCBB's settings at this join (the hypothesis to beat is RJC's, set once known).
  ChunkedJcbbOptions chunked_options() const;
  std::int64_t advance_jcbb();
  // The search's end: the second search started, or the result made from `feature_of`.
  void conclude(std::vector<int> feature_of);
  bool wider_gate_wanted(const std::vector<int>& feature_of) const;
  void search_again_wider(std::vector<int> feature_of);
  // Marks each pair of result_.pairs doubtful or not, from the candidate lists.
  void mark_doubtful();
  // JoinOracle: its pairing (per m2 feature, its m1 partner or kStar), the audit of that
  // pairing, and the decision corrected with it.
  std::vector<int> oracle_pairing() const;
  // Whether m1's feature `first` (or kStar) is among the candidates of m2's feature `second`.
  bool is_candidate(std::size_t second, int first) const;
  void audit_oracle(const std::vector<int>& truth);
  void apply_oracle(const std::vector<int>& truth, std::vector<int>& feature_of) const;

  const JoinFrame& frame_;
  JoinOptions options_;
  JoinPairingModel model_;
  Stage stage_ = Stage::Prepare;
  JoinAssociationResult result_;
  double pruning_gate_ = 0.0;  // the individual gate, chi2(2) at the pruning confidence
  double confidence_ = 0.0;    // of the decision: rjc.confidence, or large_overlap_confidence
  double gate_radius_ = 0.0;
  double sigma_first_ = 0.0;
  std::vector<double> sigma_second_;
  std::optional<SpatialHash> hash_;
  std::vector<int> nearby_;
  CandidateLists candidates_;
  std::int64_t candidate_count_ = 0;  // in all the lists
  Eigen::Index next_second_ = 0;  // next m2 feature whose candidates are searched
  std::optional<RjcSearch> rjc_;
  std::optional<ChunkedJcbb> chunked_;
  std::optional<Jcbb> jcbb_;  // the whole overlap's JCBB, while it runs
  // The first search, while the second one runs.
  struct NarrowSearch {
    std::vector<int> feature_of;
    JoinAssociationResult result;
    CandidateLists candidates;
    double confidence = 0.0;
  };
  std::optional<NarrowSearch> narrow_;
};

}  // namespace dcslam
