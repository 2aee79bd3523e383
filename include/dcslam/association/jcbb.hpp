#pragma once
// Data association by Joint Compatibility Branch and Bound (Neira & Tardós 2001) and the
// simpler individual-compatibility / nearest-neighbour rules (docs/design.md §3.4), generic
// over how innovations and their covariances are computed: an EKF step pairs scan
// measurements with map features, a map join pairs features of the second map with features
// of the first.
#include <cstddef>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/geometry.hpp"

namespace dcslam {

// Measurement `measurement` explained by feature `feature` (both caller-defined indices,
// >= 0). In the interpretation tree a measurement left unpaired is paired with the star node.
struct Pairing {
  int measurement;
  int feature;
};

inline constexpr int kStar = -1;

// The linearised problem behind a set of pairings. For pairings a = (i, j) and b = (k, l):
//   innovation(a)    = nu_a = z_i - h_j(x_hat), 2-vector (angles wrapped by the model);
//   covariance(a, b) = E[nu_a nu_b'] under the current linearisation, 2x2. For an EKF with
//                      nu_a ~ z_i - H_a x: H_a P H_b' + (i == k ? R_i : 0). For a map join with
//                      h = f_j - f_i: P_jl - P_jk - P_il + P_ik, evaluated in the joint P.
// Requirements: covariance(b, a) = covariance(a, b)'; for any pairings of distinct
// measurements the stacked joint covariance is symmetric positive definite. The algorithms
// below only call covariance(a, b) with a == b or a.measurement != b.measurement.
class PairingModel {
 public:
  using CrossColumns = Eigen::Ref<Eigen::Matrix<double, Eigen::Dynamic, 2>, 0, Eigen::OuterStride<>>;

  virtual ~PairingModel() = default;
  virtual Vec2 innovation(const Pairing& pairing) const = 0;
  virtual Mat2 covariance(const Pairing& a, const Pairing& b) const = 0;
  // covariance(pairings[c], b) for c < count, as the c-th 2-row block of `cross` (2 count x 2):
  // a pairing's cross covariance with a hypothesis or a kept set. A model whose blocks share
  // work along b overrides it (the same blocks, up to rounding).
  virtual void covariances_with(const Pairing* pairings, std::size_t count, const Pairing& b,
                                CrossColumns cross) const;
};

// candidates[i] lists the features that measurement i may be paired with (usually the
// individually compatible ones, see individually_compatible()).
using CandidateLists = std::vector<std::vector<int>>;

struct JcbbOptions {
  double confidence = 0.99;         // of the chi-square joint compatibility test
  std::int64_t max_nodes = 100000;  // interpretation-tree nodes visited before giving up
  bool allow_star = true;           // false = JCBB*: every measurement must be paired
};

struct JcbbResult {
  std::vector<int> feature_of;  // per measurement: its feature, or kStar
  int pairings = 0;
  double joint_distance_sq = 0.0;  // D^2 = nu_H' S_H^-1 nu_H of the returned hypothesis
  double score = 0.0;  // its criterion: the pairings, or the sum of the likelihood gains
  std::int64_t nodes_expanded = 0;
  bool bound_hit = false;  // max_nodes reached: the result is the best found so far
};

// The likelihood objective of Jcbb::solve (docs/data_association.md, "Likelihood criterion"):
// a measurement left unpaired is explained by clutter or by a landmark seen for the first
// time, with density lambda_i at z_i in the innovation's units. A pairing a of measurement i
// then gains
//   gain(a) = ln N(nu_a|H; 0, S_a|H) - ln lambda_i
//           = -ln(2 pi) - 1/2 ln det S_a|H - 1/2 d^2_a|H - ln lambda_i,
// conditioned on the pairings H made before it, so that the gains of a hypothesis sum to its
// log-likelihood ratio ln N(nu_H; 0, S_H) - sum ln lambda_i against "nothing paired".
// log_noise_det[i] must be a lower bound on ln det S_a|H for every pairing a of measurement i
// (for an EKF, ln det R_i: the conditional covariance is H P_cond H' + R_i >= R_i); it bounds
// the gain of measurements not yet visited, which is what lets the search prune.
struct JcbbLikelihood {
  std::vector<double> log_unexplained_density;  // ln lambda_i, one per measurement
  std::vector<double> log_noise_det;            // lower bound on ln det S_a|H, one per measurement
};

// JCBB over measurements 0..m-1 in order. A hypothesis H assigns each measurement a candidate
// feature or the star, each feature at most once. H is admissible when it is jointly
// compatible, D^2(H) <= chi2_quantile(2|H|, confidence), and so is each of its prefixes in
// measurement order (the interpretation-tree condition: a branch is cut as soon as the
// growing hypothesis fails the test). Among admissible hypotheses it returns the one with
// most pairings, ties broken by lowest D^2; this equals exhaustive enumeration of admissible
// hypotheses unless the node bound is hit. Candidates are tried in order of increasing
// individual distance, which only matters for exact ties.
//
// The test is incremental: the Cholesky factor L of S_H and the whitened innovation
// L^-1 nu_H grow by one 2-row block per pairing, O(|H|^2) each. Pruning: a subtree is cut
// unless its pairing upper bound beats the best found, or equals it with the current D^2
// (a lower bound for all extensions) below the best's.
//
// With allow_star = false and no hypothesis pairing every measurement, or with the bound
// hit before any is found, the result pairs nothing (pairings = 0, all kStar).
//
// The solver keeps its buffers and gate thresholds between calls; not thread-safe.
class Jcbb {
 public:
  explicit Jcbb(const JcbbOptions& options = JcbbOptions());
  const JcbbOptions& options() const { return options_; }
  JcbbResult solve(const CandidateLists& candidates, const PairingModel& model);
  // The same search and admissibility (every prefix jointly compatible), but the hypothesis
  // returned maximises the sum of its pairings' gains (JcbbLikelihood), ties broken by lowest
  // D^2. A pairing whose likelihood is below lambda_i lowers the sum, so a hypothesis may
  // leave out pairings JCBB's "most pairings" criterion would take. Exact (equal to
  // exhaustive enumeration) unless the node bound is hit.
  JcbbResult solve(const CandidateLists& candidates, const PairingModel& model,
                   const JcbbLikelihood& likelihood);
  // solve() (likelihood criterion when `likelihood` is given) for candidate lists that are
  // already in order of increasing individual distance, as a caller that gated them has them:
  // the same result without computing every individual distance a second time.
  JcbbResult solve_ranked(const CandidateLists& ranked_candidates, const PairingModel& model,
                          const JcbbLikelihood* likelihood = nullptr);
  // The best admissible hypothesis (likelihood criterion, ranked lists) among those that pair
  // `measurement`, if its score is above `score_floor`; otherwise none (pairings = 0). How
  // much less likely than the unrestricted best it is tells whether leaving the measurement
  // unexplained was a clear decision (docs/data_association.md, "Unexplained measurements
  // beside mapped features"). The floor prunes the search: every subtree that cannot reach
  // it is cut, so asking "is there one within t of the best?" costs a fraction of a solve.
  // bound_hit as for solve(): the search stopped before it could say.
  JcbbResult best_pairing(const CandidateLists& ranked_candidates, const PairingModel& model,
                          const JcbbLikelihood& likelihood, int measurement, double score_floor);
  // best_pairing()'s search stopped at the first hypothesis above the floor, which it returns:
  // for a caller that asks only whether one exists. Pairings > 0 exactly when best_pairing()'s
  // would be, unless that search hits the node bound (bound_hit) after this one has stopped.
  // Where one exists it is found after a fraction of the nodes (about a quarter fewer nodes
  // over the EKF's scans on the revisit scenes).
  JcbbResult first_pairing_above(const CandidateLists& ranked_candidates, const PairingModel& model,
                                 const JcbbLikelihood& likelihood, int measurement, double score_floor);

  // The same search in slices, for a caller that must bound the time of each of its steps
  // (ChunkedJcbb inside an amortized join): start() prepares it (candidates ranked here,
  // every individual distance computed), expand(n) visits at most n more nodes of the
  // interpretation tree and returns whether the search is over, result() is then the
  // solve() result. The nodes are visited in the same order however the search is sliced,
  // so the result is bitwise solve()'s. `candidates`, `model` and `likelihood` must outlive
  // the search.
  void start(const CandidateLists& candidates, const PairingModel& model,
             const JcbbLikelihood* likelihood = nullptr);
  bool expand(std::int64_t nodes);
  JcbbResult result();
  // Work done since start(), in units (resumable_work.hpp): an extension of a hypothesis of
  // d pairings asks the model for d + 1 covariance blocks and solves a triangular system of
  // 2d rows.
  std::int64_t work_done() const { return work_; }

 private:
  // Both criteria maximise a score summed over the pairings, then minimise D^2: one per
  // pairing for "most pairings", the gain for the likelihood criterion.
  // paired_measurement >= 0 takes the star away from that measurement (best_pairing);
  // score_floor is the score a hypothesis must beat to be recorded.
  // stop_at_first: the search ends at the first hypothesis recorded (first_pairing_above()).
  JcbbResult run(const CandidateLists& candidates, const PairingModel& model,
                 const JcbbLikelihood* likelihood, bool ranked, int paired_measurement = -1,
                 double score_floor = -std::numeric_limits<double>::infinity(), bool stop_at_first = false);
  void prepare(const CandidateLists& candidates, const PairingModel& model,
               const JcbbLikelihood* likelihood, bool ranked, int paired_measurement = -1,
               double score_floor = -std::numeric_limits<double>::infinity(), bool stop_at_first = false);
  JcbbResult pairing_above(const CandidateLists& ranked_candidates, const PairingModel& model,
                           const JcbbLikelihood& likelihood, int measurement, double score_floor,
                           bool stop_at_first);
  bool star_allowed(int measurement) const {
    return options_.allow_star && measurement != paired_measurement_;
  }
  // A node of the interpretation tree: the hypothesis of `depth` pairings made for the
  // measurements before `measurement`. Its candidates are tried from `next` on, then the star.
  struct Frame {
    int measurement;
    int depth;
    double distance_sq;
    double score;
    std::size_t next;
    bool star_tried;
  };
  // Visits a node: counts it, records it if it is the best so far and, unless it is a leaf,
  // pushes its frame. At the node bound it ends the search instead.
  void enter(int measurement, int depth, double distance_sq, double score);
  // Tests adding `pairing`, the candidate at `slot` (own_slot_begin_), to the first `depth`
  // pairings of the current hypothesis; on success writes its block row of the factor,
  // returns the new D^2 in `distance_sq` and the pairing's score in `score_gain`.
  bool extend(int depth, const Pairing& pairing, std::size_t slot, double& distance_sq, double& score_gain);
  // A candidate's own C_aa and nu_a, computed the first time a node extends by it and kept for
  // the rest of the search (every node of a subtree extends by the same candidates again).
  struct OwnTerms {
    Mat2 covariance;
    Vec2 innovation;
  };
  const OwnTerms& own_terms(std::size_t slot, const Pairing& pairing);
  bool can_improve(double score_upper_bound, double distance_sq_lower_bound) const;
  bool feature_in_use(int depth, int feature) const;
  void record(int depth, double distance_sq, double score);

  JcbbOptions options_;
  ChiSquareGate gate_;
  const PairingModel* model_ = nullptr;
  int num_measurements_ = 0;
  CandidateLists ordered_candidates_;        // the caller's lists, ranked by the solver
  const CandidateLists* ordered_ = nullptr;  // the lists searched: those, or the caller's own
  const JcbbLikelihood* likelihood_ = nullptr;  // null: "most pairings"
  int paired_measurement_ = -1;                 // the measurement that may not take the star
  bool stop_at_first_ = false;
  // Upper bound on the score that measurements >= i can still add (their count of pairable
  // measurements for "most pairings").
  std::vector<double> score_bound_from_;
  std::vector<Pairing> hypothesis_;
  Eigen::MatrixXd factor_;      // lower Cholesky factor of S_H, one 2-row block per pairing
  Eigen::VectorXd whitened_;    // L^-1 nu_H
  Eigen::MatrixXd cross_;       // scratch: L^-1 C_Ha
  std::vector<std::pair<double, int>> ranked_;  // scratch for candidate ordering
  // A slot per candidate of the lists searched: measurement i's k-th at own_slot_begin_[i] + k.
  std::vector<std::size_t> own_slot_begin_;
  std::vector<OwnTerms> own_terms_;
  std::vector<char> own_known_;
  std::vector<Frame> frames_;  // the path from the root to the node being expanded
  std::vector<Pairing> best_;
  double best_score_ = 0.0;
  double best_distance_sq_ = 0.0;
  std::int64_t nodes_ = 0;
  std::int64_t work_ = 0;
  bool bound_hit_ = false;
};

JcbbResult jcbb(const CandidateLists& candidates, const PairingModel& model,
                const JcbbOptions& options = JcbbOptions());

// Individual Mahalanobis distance nu_a' C_aa^-1 nu_a of one pairing (+inf if C_aa is not
// positive definite).
double individual_distance_sq(const PairingModel& model, const Pairing& pairing);

// The candidate lists restricted (order kept) to pairings that pass the 2-dof gate at
// `confidence`.
CandidateLists individually_compatible(const CandidateLists& candidates,
                                       const PairingModel& model, double confidence);

// Nearest neighbour: every individually compatible pairing ranked by individual distance,
// then accepted greedily from the closest, skipping measurements and features already used.
// Returns feature_of per measurement (kStar if unpaired).
std::vector<int> nearest_neighbour(const CandidateLists& candidates, const PairingModel& model,
                                   double confidence);

// The pairings of a hypothesis with their stacked innovation nu_H and joint covariance S_H,
// built directly from the model a pairing (a block row) at a time: the one way a hypothesis is
// stacked, by stack_hypothesis(), RJC's seeds and its resumable joint test.
struct StackedHypothesis {
  StackedHypothesis() = default;
  // The pairings of feature_of (kStar skipped, in measurement order), sized but not stacked.
  explicit StackedHypothesis(const std::vector<int>& feature_of);
  // Sizes innovation and covariance for the pairings (their entries unset).
  void resize();
  // Pairing a's entries of the innovation and its covariance blocks with pairings 0..a, in
  // both triangles: O(a) blocks.
  void stack(Eigen::Index a, const PairingModel& model);

  std::vector<Pairing> pairings;
  Eigen::VectorXd innovation;
  Eigen::MatrixXd covariance;
};
// The pairings of feature_of stacked whole (O(|H|^2) blocks).
StackedHypothesis stack_hypothesis(const std::vector<int>& feature_of, const PairingModel& model);

// Joint Mahalanobis distance of a whole hypothesis computed directly (stacked nu and S,
// O(|H|^3)); 0 for an empty one, +inf if S_H is not positive definite.
double joint_distance_sq(const std::vector<int>& feature_of, const PairingModel& model);

}  // namespace dcslam
