#pragma once
// Randomized Joint Compatibility (Paz et al. 2007, Algorithm 3; docs/design.md §6): data
// association between the two maps of a join in time linear in the overlap, generic over the
// same PairingModel as JCBB (measurement = feature of the second map, feature = feature of
// the first).
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>

#include "dcslam/core/blocked_cholesky.hpp"
#include "dcslam/core/resumable_work.hpp"
#include "dcslam/association/conditioned_model.hpp"
#include "dcslam/association/jcbb.hpp"

namespace dcslam {

// Every setting of RJC, with the defaults D&C's joins run with (SlamConfig's rjc_* fields set
// b, p_good, p_fail and exchange_crossed; JoinOptions holds these settings and hands them down
// as they are).
struct RjcOptions {
  int b = 4;             // measurements drawn per try and paired by JCBB*
  double p_good = 0.8;   // prior probability that an overlap measurement has a true pairing
  double p_fail = 0.001;  // accepted probability of never drawing an all-good sample
  double confidence = 0.99;  // of every gate and joint test RJC makes
  std::uint64_t seed = 0;
  int max_tries = 100;  // cap on t
  // JCBB* node bound of each try's seed: b = 4 measurements make a search of four levels.
  std::int64_t max_nodes_per_try = 5000;
  bool verify = true;  // enforce joint compatibility of the final hypothesis (see rjc())
  // The granularity of the joint test's resumable work (JointCompatibilityEnforcement): the
  // multiply-adds that bound a step of its inverse, and its Cholesky factor's panel width.
  std::int64_t work_unit = kDefaultWorkUnit;
  Eigen::Index panel_width = kDefaultPanelWidth;
  // Optional: per measurement, its position in any one frame (a join's second map). With it,
  // when the uniform tries verify fewer than kConstellationShare of the overlap, max_tries
  // more tries draw local constellations (see rjc()).
  std::shared_ptr<const std::vector<Vec2>> positions;
  // >= 0: the result keeps only the pairings the best try's rivals agree with (see rjc()): a
  // rival is a verified try of at least (best's pairings - rival_margin) pairings fewer than
  // kRivalShare of whose pairings agree with the best try. < 0: the best try as it is.
  int rival_margin = -1;
  // Each try's greedy hypothesis has its crossed pairings exchanged (pairing_exchanges.hpp).
  bool exchange_crossed = true;
};

// A try fewer than this share of whose pairings agree with the best try is another hypothesis,
// not the best one with a pairing more or less (rjc(), RjcOptions::rival_margin).
inline constexpr double kRivalShare = 0.8;

// Share of the overlap that the best uniform try must verify for RJC to stop there when
// positions are given. A loop closure at large uncertainty in a dense map verifies much less
// (23 true of 126 at the README loop's last fold). Chosen by measurement (20 seeds of the
// revisit scenes, 3 of long_revisits): 0.3, 0.5, 0.7 and "always" give D&C recall 0.818 /
// 0.834 / 0.902, 0.819 / 0.843 / 0.905, 0.822 / 0.862 / 0.908 and 0.825 / 0.861 / 0.913 (the
// last at 2-4 times the time); long_revisits 0.593 at 0.5, 0.720 at 0.7.
inline constexpr double kConstellationShare = 0.7;

struct RjcResult {
  std::vector<int> feature_of;  // per measurement: its feature, or kStar
  int pairings = 0;
  int overlap_size = 0;  // measurements with at least one candidate
  int tries = 0;
  int dropped = 0;  // pairings removed by the final verification
  int completed = 0;  // pairings added by the completion against all kept pairings
  int rivals = 0;  // tries that rival the best one (RjcOptions::rival_margin)
  std::vector<Pairing> disputed;  // the best try's pairings left out because a rival disagrees
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
// A try's pairings are scored once verified: taken again in the order the try accepted them,
// each must pass the gate conditioned on all those kept before it (accept_sequentially();
// O(k^3) for k pairings). Unverified, a wrong seed whose conditional gates are wide (a
// compact seed leaves the rotation loose) collects chance pairings in a dense map and can
// outnumber the truth. A verification only removes pairings, so a try whose count cannot beat
// the best try's is not verified, and a verification stops once its removals leave it unable
// to: the best try is the same, and on large overlaps (a revisit) most tries' O(k^3) is saved.
// After each try p_good = max(p_good, pairings(best) / |O|) and the
// number of tries becomes t = log(p_fail) / log(1 - p_good^b); tries continue while
// tries < min(t, max_tries) (9 tries at the defaults).
//
// Constellation tries (options.positions given): if then the best try verifies fewer than
// kConstellationShare of O, up to max_tries more tries each draw one measurement of O and take
// its b - 1 nearest measurements of O as the seed. Where only a small patch of O has true
// partners (a loop closed at large uncertainty), b independent draws are all in it with
// probability share^b (about 1/900 at the README loop's last fold); a constellation is, once
// its first draw is. The best try over both phases wins.
//
// The conditional gate tests each pairing against H only, not against the other added
// pairings, so with verify on the best hypothesis is re-tested by accept_sequentially() (each
// pairing against all those kept before it, in the order the try accepted them). That is the
// test the try was scored by, so a verified best try's own result is taken, not computed
// again; its steps are still counted, which keeps an amortized join's schedule as it was.
// The factor it grows holds the kept pairings' joint D^2 (chain rule); only if that fails the
// joint test is the hypothesis made jointly compatible by enforce_joint_compatibility(). That costs
// O(k^3) for k pairings, no more than the O(n^2 k) join update that consumes them.
//
// Between the two, with verify on, the overlap measurements left unpaired get a second
// chance (the completion): each candidate is tested conditioned on all the kept pairings, not
// on the seed alone. Conditioned on a few pairings the relative pose of the two maps is still
// loose, so in a dense map a true pairing can fail its gate or lose to a neighbour; on all of
// them only the features' own uncertainty is left. A candidate is added only if it is
// unambiguous: the nearest of its measurement's and of its feature's conditional candidates,
// each runner-up at least kCompletionMargin further in D^2 (a likelihood ratio of e^2), then
// re-tested against the pairings added before it. O(c k^2) for c candidates.
//
// Rivals (options.rival_margin >= 0): every try within rival_margin pairings of the best one
// is verified too, and a verified try is the best one's rival when fewer than kRivalShare of
// its pairings agree with the best try (made by it too, or compatible with all its pairings:
// tries that each pair a part of one alignment agree): another alignment of the two maps that
// the data support nearly as well. Then the best try's pairings that some rival does not make
// are left out before the final verification, so the join commits only to what every near
// hypothesis agrees on; the completion may add back a pairing that is unambiguous given the
// rest. A loop closed at the end of a run by a few pairings is the case (docs/
// data_association.md, "The paper's loop closure"): a shifted alignment collects as many
// chance pairings in a dense map as the truth has, and a closure left open keeps the robot's
// uncertainty, where a wrong one is off by tens of metres with a covariance of centimetres.
// The extra verifications cost O(k^3) each, like the best try's.
inline constexpr double kCompletionMargin = 4.0;

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

// accept_sequentially() as resumable work (ResumableWork): a step tests a panel of pairings
// (ConditionedPairingModel::keep_each_within(), O(k^2) each) within `work_unit` multiply-adds
// (ConditionedPairingModel::panel_pairings()): the panel depends on the pairings kept so far
// and the unit alone, never on the budget.
// The referenced arguments must outlive it.
class SequentialAcceptance : public ResumableWork<SequentialAcceptance> {
 public:
  SequentialAcceptance(const std::vector<Pairing>& order, int seed_size,
                       std::vector<int>& feature_of, const PairingModel& model, double gate,
                       std::int64_t work_unit = kDefaultWorkUnit);
  std::int64_t step(std::int64_t budget);
  bool done() const { return next_ == static_cast<Eigen::Index>(order_.size()); }
  std::int64_t remaining_work() const;
  // What step() counts for a pairing tested against `kept` kept pairings, and what
  // remaining_work() counts for `left` pairings still to test after `kept` were kept.
  static std::int64_t step_work(std::int64_t kept);
  static std::int64_t work_left(std::int64_t kept, std::int64_t left);
  int removed() const { return removed_; }
  // Tests no pairing after the one whose refusal makes `removals` (one that a caller ends the
  // verification at: a step's panel would otherwise test past it).
  void stop_after_removals(int removals) { removal_limit_ = removals; }
  // D^2 of the pairings kept so far, in the order kept: the sum of their distances each
  // conditioned on those before it (the chain rule), so no joint factor is needed for it.
  double joint_distance_sq() const;
  int kept() const { return conditioned_.kept(); }
  // After done(): D^2 of `pairing` conditioned on all the kept pairings (infinity if its
  // conditional covariance is not positive definite), and adding it to them if it passes the
  // gate. O(k^2) each.
  double conditional_distance_sq(const Pairing& pairing);
  bool append(const Pairing& pairing);

 private:
  const std::vector<Pairing>& order_;
  int seed_size_;
  std::vector<int>& feature_of_;
  double gate_;
  std::int64_t work_unit_;
  ConditionedPairingModel conditioned_;  // on the pairings kept so far
  Eigen::Index next_ = 0;
  int removed_ = 0;
  int removal_limit_ = std::numeric_limits<int>::max();
  std::vector<Pairing> panel_;  // the step's pairings, their gates and whether each was kept
  std::vector<double> panel_gates_;
  std::vector<char> panel_kept_;
};

// enforce_joint_compatibility() as resumable work (ResumableWork): S's blocks a pairing at a
// time, its Cholesky factor a panel at a time (ResumableCholesky), then, only if the hypothesis
// fails, S^-1 a block of columns at a time and one removal per step. `panel_width` and
// `work_unit` (multiply-adds, for the inverse's blocks) set the panels and blocks from the
// sizes alone, so the result never depends on the slicing.
class JointCompatibilityEnforcement : public ResumableWork<JointCompatibilityEnforcement> {
 public:
  JointCompatibilityEnforcement(std::vector<int>& feature_of, const PairingModel& model,
                                double confidence, Eigen::Index panel_width,
                                std::int64_t work_unit);
  // InvalidArgument if S is not positive definite.
  std::int64_t step(std::int64_t budget);
  bool done() const { return stage_ == Stage::Done; }
  std::int64_t remaining_work() const;
  int removed() const { return removed_; }
  double joint_distance_sq() const { return distance_sq_; }

 private:
  enum class Stage { Stack, Factor, Test, Invert, Remove, Done };
  std::vector<int>& feature_of_;
  const PairingModel& model_;
  double confidence_;
  Eigen::Index panel_width_;
  std::int64_t work_unit_;
  Stage stage_ = Stage::Stack;
  StackedHypothesis stacked_;  // its covariance S is then factored by cholesky_
  ResumableCholesky cholesky_;
  Eigen::MatrixXd information_;  // S^-1, then the information of the pairings still active
  std::vector<bool> active_;
  Eigen::Index next_ = 0;  // next pairing to stack, or next column of S^-1
  Eigen::Index remaining_ = 0;
  int removed_ = 0;
  double distance_sq_ = 0.0;
};

// rjc() as resumable work (ResumableWork), for map joins spread over many steps: a step is a
// try's seed, one overlap measurement's conditional test, a try's completion or one step of the
// verification. Every step is the same computation in the same order as rjc() runs at once, so
// the result is bitwise identical however the work is sliced, random draws included. The
// arguments must outlive the search, which is neither copied nor moved (its steps keep
// references into it).
class RjcSearch : public ResumableWork<RjcSearch> {
 public:
  RjcSearch(const CandidateLists& candidates, const PairingModel& model,
            const RjcOptions& options = RjcOptions());
  RjcSearch(const RjcSearch&) = delete;
  RjcSearch& operator=(const RjcSearch&) = delete;

  std::int64_t step(std::int64_t budget);
  bool done() const { return stage_ == Stage::Done; }
  // An estimate until the tries are over.
  std::int64_t remaining_work() const;
  // Valid once done().
  const RjcResult& result() const { return result_; }

 private:
  enum class Stage { Start, Seed, Conditional, CompleteTry, VerifyTry, Sequential, Completion, CompletionAdd, Joint, Done };
  std::int64_t start();
  std::int64_t seed();
  std::int64_t conditional_next();
  std::int64_t complete_try();
  void end_of_tries();
  void end_of_try();  // the try's verified score against the best
  // Whether a try of `pairings` pairings (and the current try's score) would replace the best.
  bool can_beat_best(int pairings) const;
  // Whether a try of `pairings` pairings is verified: it could beat the best, or rival it.
  bool worth_verifying(int pairings) const;
  // The best try's pairings that a rival disagrees with, left out of its hypothesis.
  void leave_out_disputed();
  void draw_uniform_sample();
  bool draw_constellation();  // false if fewer than b measurements of O
  std::int64_t completion_next();
  void begin_completion_adds();
  std::int64_t completion_add_next();
  std::int64_t verify_next(std::int64_t budget);
  void end_of_verification();
  void take_verified_hypothesis();  // the verified hypothesis into the result, and done
  std::int64_t try_cost() const;

  // A try's pairings in the order it accepted them, its hypothesis, and their verification
  // (which reads the one and thins the other), held together so that the best try's finished
  // verification can be kept for the final one instead of being computed again.
  struct TryVerification {
    std::vector<Pairing> order;
    std::vector<int> feature_of;
    std::optional<SequentialAcceptance> acceptance;
  };
  // Copies of a try's pairings and hypothesis into `verification`, and their test begun.
  void begin_verification(TryVerification& verification, const std::vector<Pairing>& order,
                          const std::vector<int>& feature_of) const;

  const CandidateLists& candidates_;
  const PairingModel& model_;
  RjcOptions options_;
  Stage stage_ = Stage::Start;
  RjcResult result_;
  std::vector<int> overlap_;
  Jcbb star_free_;
  double gate_ = 0.0;
  std::mt19937_64 rng_;
  std::vector<int> pool_;
  std::vector<int> sample_;
  CandidateLists sample_candidates_;
  std::vector<int> feature_of_;
  std::vector<int> used_features_;
  // The current try's verification (its buffers reused from try to try), and the best try's
  // once verified (null while the best try is one that needed none).
  std::unique_ptr<TryVerification> try_verification_, best_verification_;
  int try_pairings_ = 0;
  double try_score_ = 0.0;
  std::vector<char> feature_used_;  // per feature of m1, during the verification
  std::vector<std::tuple<double, int, int>> conditional_;  // (distance^2, measurement, feature)
  StackedHypothesis seed_;  // the try's seed hypothesis H; its covariance S_H, then S_H's factor
  Eigen::VectorXd seed_whitened_;
  double seed_distance_sq_ = 0.0;
  Eigen::MatrixXd cross_;
  std::size_t next_overlap_ = 0;  // next overlap measurement of the conditional test
  int best_pairings_ = 0;
  double best_score_ = 0.0;
  std::vector<Pairing> order_, best_order_;  // pairings in the order the try accepted them
  // With rival_margin >= 0: the pairings each verified try kept, to find the best try's rivals.
  std::vector<std::vector<Pairing>> verified_tries_;
  double p_good_ = 0.0;
  double tries_wanted_ = 0.0;
  int constellation_tries_end_ = -1;  // -1: uniform tries; else the try count to stop at
  std::vector<std::pair<double, int>> nearest_;  // scratch of draw_constellation()
  // The completion: (D^2, measurement, feature) of the unpaired measurements' candidates
  // conditioned on all kept pairings, and the next one to test or add.
  std::vector<std::tuple<double, int, int>> completion_;
  std::size_t next_completion_ = 0;
  // The final verification: best_verification_, run now if the best try had none, else its
  // steps only counted again (verify_next()); then the completion and the joint test work on
  // its hypothesis, which becomes result_.feature_of.
  bool verification_replayed_ = false;
  std::size_t replayed_ = 0;  // pairings of the order counted so far
  std::int64_t replayed_kept_ = 0;  // and how many of them the verification kept
  std::optional<JointCompatibilityEnforcement> joint_;
};

}  // namespace dcslam
