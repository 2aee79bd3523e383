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
#include <cstdint>
#include <limits>
#include <memory>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/config.hpp"
#include "dcslam/core/gaussian_map.hpp"

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

// A linearisation point chosen outside the join (JoinTree::relinearise(), join_tree.hpp): R1
// in m1's base and m2's state vector, as JoinFrame takes them. The join linearises ⊕ there
// once, without Gauss–Newton steps of its own.
struct JoinLinearisation {
  Vec3 first_robot = Vec3::Zero();
  Eigen::VectorXd second_x;
};

struct JoinOptions {
  JoinAssociation association = JoinAssociation::Known;
  double gate_confidence = 0.99;
  double feature_sigma = 0.0;  // SlamConfig::join_feature_sigma
  int rjc_b = 4;
  double rjc_p_good = 0.8;
  double rjc_p_fail = 0.01;
  std::uint64_t seed = 0;
  // Width of the column blocks the result is written in (and of the Cholesky panels).
  Eigen::Index block_columns = 64;
  // Multiply-adds that bound one unit of resumable work (rows of a fill tile, of the solve, of
  // the assembly): small units keep amortized steps short when r is in the hundreds.
  Eigen::Index work_unit = Eigen::Index{1} << 20;
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
};

struct JoinReport {
  Eigen::Index features_first = 0;
  Eigen::Index features_second = 0;
  Eigen::Index features_joined = 0;
  int overlap = 0;   // features of m2 with at least one individually compatible candidate
  int pairings = 0;  // matched pairs imposed as constraints
  int tries = 0;     // RJC hypotheses tried (0 for other modes)
  int dropped_tentative = 0;  // tentative features left unmatched (marginalised)
  int iterations = 0;  // linearisation points of the constraint update (0 when r = 0)
  double seconds_association = 0.0;
  double seconds_total = 0.0;  // summed over all the slices the join was run in
  std::int64_t work_units = 0;  // covariance elements written plus association/preparation
};

// Covariance blocks of the stacked map [R1; F1; Q1; R2'; F2'; Q2'] (m2 moved into B1 by
// x_{B1 R1} ⊕ ·), computed on demand in O(1) each, without building the stacked matrix.
// Feature indices are local: i indexes m1's features, j indexes m2's.
//
// ⊕ is linearised at a point x* = (R1*, m2*), by default the prior means. The moved means
// are then the linearised values g(x*) + G*(x0 - x*), which with x* = x0 are g(x0).
class JoinFrame {
 public:
  JoinFrame(const GaussianMap& first, const GaussianMap& second);
  // Linearised at R1 = first_robot and m2's state vector = second_x (sized as second.x()).
  JoinFrame(const GaussianMap& first, const GaussianMap& second, const Vec3& first_robot,
            const Eigen::VectorXd& second_x);

  const GaussianMap& first() const { return first_; }
  const GaussianMap& second() const { return second_; }

  Vec2 first_feature(Eigen::Index i) const { return first_.feature(i); }
  // m2's feature j, robot, and the pose at state offset `offset` (0: the robot; or a past
  // pose's pose_offset) moved into B1 (the linearised values above).
  Vec2 moved_second_feature(Eigen::Index j) const;
  Vec3 moved_second_robot() const { return moved_second_pose(0); }
  Vec3 moved_second_pose(Eigen::Index offset) const;

  // cov(f_i, f_k), cov(f_i, f'_j), cov(f'_j, f'_l) of the stacked map.
  Mat2 first_first(Eigen::Index i, Eigen::Index k) const;
  Mat2 first_second(Eigen::Index i, Eigen::Index j) const;
  Mat2 second_second(Eigen::Index j, Eigen::Index l) const;

  // cov(h_a, h_b) for the constraints h_a = f_i - f'_j and h_b = f_k - f'_l.
  Mat2 constraint_covariance(Eigen::Index i, Eigen::Index j, Eigen::Index k,
                             Eigen::Index l) const;

  // J_R: d(x_{B1 R1} ⊕ e)/d x_{B1 R1} for every element e of m2, stacked (d2 x 3).
  const Eigen::Matrix<double, Eigen::Dynamic, 3>& jacobian_first_robot() const { return J_R_; }
  // The rotation of R1: d(x_{B1 R1} ⊕ p)/dp for a point p.
  const Mat2& rotation() const { return rotation_; }

 private:
  Vec2 linearisation_offset(const Vec2& p0, const Vec2& p_lin) const;

  const GaussianMap& first_;
  const GaussianMap& second_;
  Vec3 T_;  // x_{B1 R1} at the linearisation point
  Eigen::VectorXd second_x_;  // m2's state at the linearisation point
  Mat2 rotation_;
  Eigen::Matrix<double, Eigen::Dynamic, 3> J_R_;
};

// Data association between the two maps of a join: pairs (i in m1, j in m2) of features
// that are the same landmark. Implementations: by id ("known") and by joint compatibility.
std::vector<std::pair<Eigen::Index, Eigen::Index>> associate_by_id(const GaussianMap& first,
                                                                   const GaussianMap& second);

class JoinAssociator;  // join_association.hpp

class MapJoin {
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

  // Does at least one unit of work (if not done) and stops once `budget` work units are
  // spent. Returns the work done.
  std::int64_t advance(std::int64_t budget);
  void finish();
  bool done() const { return phase_ == Phase::Done; }
  // Work left, in the units of advance(); exact once the constraints are linearised, an
  // estimate before (an upper bound on the re-linearisation steps).
  std::int64_t remaining_work() const;

  // The joined map; valid once done(). Leaves the join empty.
  GaussianMap take_result();
  const JoinReport& report() const { return report_; }
  // Valid once associated.
  const JoinPairingRecord& pairing_record() const { return pairing_record_; }
  // (id in m2, id in m1) for every matched pair: the m2 feature merged into the m1 one.
  std::vector<std::pair<std::int64_t, std::int64_t>> merged_ids() const;
  // Ids of the tentative features (of m1, then of m2) marginalised out of the result; known
  // once associated.
  const std::vector<std::int64_t>& dropped_ids() const { return dropped_ids_; }

 private:
  enum class Phase { Associate, Relinearise, Constrain, Factor, Solve, Assemble, Fill, Done };
  // The association a step of JoinAssociator at a time (at once by id for "known"); once the
  // pairs are known, the kept and dropped features, and the phase moves on. Returns the work.
  std::int64_t associate_next(std::int64_t budget);
  void finish_association();
  // Gauss–Newton on the constrained MAP over the variables the constraints involve, one step
  // per unit of work; finishing sets the linearisation point (lin_first_robot_,
  // lin_second_x_) and returns the work it did.
  void begin_relinearisation();
  std::int64_t relinearise_unit();
  std::int64_t finish_relinearisation();
  // Costs for r pairings (the members use this join's r, once associated).
  static std::int64_t relinearise_step_cost(std::int64_t r);
  std::int64_t relinearise_step_cost() const;
  // The constraints at the linearisation point: kept elements of m2, then P H' and h a few
  // pairs per unit of work (O(n) a pair), then S = H P H' factored a panel at a time.
  void begin_constraints();
  std::int64_t constrain_next_pairs();
  void begin_factor();
  std::int64_t factor_next_panel();
  std::int64_t solve_next_rows();
  void begin_assemble();
  std::int64_t assemble_next_rows();
  std::int64_t fill_next_block();
  // Writes J_2 P2 J_2' for m2's kept elements, local rows [row_begin, row_begin + rows) x
  // local columns [col_begin, col_begin + width), into the output at (out_row, out_col).
  void write_moved_second_block(Eigen::Index row_begin, Eigen::Index rows, Eigen::Index col_begin,
                                Eigen::Index width, Eigen::Index out_row, Eigen::Index out_col);
  // Writes P1 for m1's kept features, local rows [row_begin, row_begin + rows) x local columns
  // [col_begin, col_begin + width) (indices into first_kept_rows_), at (out_row, out_col).
  void write_first_block(Eigen::Index row_begin, Eigen::Index rows, Eigen::Index col_begin,
                         Eigen::Index width, Eigen::Index out_row, Eigen::Index out_col);
  // J_2 from the left (rows) or J_2' from the right (columns) on a block of m2's elements
  // (all of them or the kept ones: the robot, feature pairs up to local index features_end,
  // then poses) starting at local index `local_begin`. The block must not split an (x, y)
  // pair: it starts on an x or a heading and ends after a y or a heading.
  void rotate_second_rows(Eigen::Ref<Eigen::MatrixXd> block, Eigen::Index local_begin,
                          Eigen::Index features_end) const;
  void rotate_second_columns(Eigen::Ref<Eigen::MatrixXd> block, Eigen::Index local_begin,
                             Eigen::Index features_end) const;
  void release_inputs();
  static std::int64_t fill_element_cost(std::int64_t r);
  static std::int64_t solve_row_cost(std::int64_t r);
  static std::int64_t assemble_row_cost(std::int64_t r);
  std::int64_t fill_element_cost() const;
  std::int64_t solve_row_cost() const;

  std::shared_ptr<const GaussianMap> first_, second_;
  JoinOptions options_;
  Phase phase_ = Phase::Associate;
  JoinReport report_;
  JoinPairingRecord pairing_record_;
  Pairs pairs_;
  std::vector<Eigen::Index> first_tentative_;
  std::vector<Eigen::Index> second_tentative_;
  std::vector<std::pair<std::int64_t, std::int64_t>> merged_ids_;
  std::vector<std::int64_t> dropped_ids_;
  std::vector<char> second_dropped_;  // per m2 feature: a tentative one left unmatched
  Vec3 lin_first_robot_ = Vec3::Zero();
  Eigen::VectorXd lin_second_x_;
  struct GaussNewton {  // state kept between the units of the re-linearisation
    Eigen::VectorXd prior, point, multipliers;  // s0, s, λ of the last step
    Eigen::VectorXd dual;                       // g with s - s0 = P_ss g (H'λ at a KKT point)
    Eigen::MatrixXd covariance;                 // P_ss
    Eigen::Index gathered = 0;                  // columns of s0 and P_ss gathered so far
    Eigen::MatrixXd gain, factor;               // P_ss H' and S (becoming L) of this step
    Eigen::VectorXd rhs;
    std::vector<Eigen::Matrix<double, 2, 3>> robot_jacobians;  // J_R of each pair, this step
    Eigen::Index next_build = 0;   // pairs done: < r of P_ss H', then r + those of S's rows
    Eigen::Index next_panel = -1;               // -1: the step's S is not built yet
    Eigen::ArrayXd tolerance;
    std::vector<Eigen::Index> first_rows;       // rows of R1 and the matched f_i in m1
    std::vector<Eigen::Index> second_rows;      // rows of the matched f_j in m2
    Mat2 rotation = Mat2::Identity();           // R1's rotation where the last step linearised
    double moved = 0.0;                         // the last step, in units of tolerance
    int steps = 0;
    bool converged = true;
  } gauss_newton_;

  // Prepared for the fill. Every block of the result is a "base" (a block of P1, or of
  // J_2 P2 J_2') plus a low-rank term L N' with inner dimension 3 + 2r:
  //   columns of m2's kept elements: L = [J_R P1_RR or cov(E1, R1) | W], N = [J_R | -W];
  //   columns of m1's kept elements: L = [W | J_R or 0],               N = [-W | cov(E1, R1)]
  // (E1: m1's kept elements, R1 among them when kept). left_ holds [JP | W | J] in output row
  // order; right_* hold N for each column kind.
  // m1's kept elements: features not dropped, then its past poses, then R1 when kept.
  std::vector<Eigen::Index> first_kept_rows_;   // rows of P1
  std::vector<std::int64_t> first_kept_ids_;    // of the kept features
  // m2's kept elements: the robot, then unmatched features, then its past poses.
  std::vector<Eigen::Index> second_kept_rows_;  // rows of P2
  std::vector<std::int64_t> second_kept_ids_;   // of the kept features
  // The result's rows are runs of consecutive kept elements of one map (see the top of the
  // file): robot R2', F1, F2', Q1 and R1, Q2'.
  struct Segment {
    Eigen::Index out_begin = 0, size = 0;
    bool second = false;  // from m2 (else m1)
    Eigen::Index local_begin = 0;  // index into first_kept_rows_ or second_kept_rows_
  };
  std::vector<Segment> segments_;
  const Segment& segment_of(Eigen::Index out_row) const;
  Eigen::Index second_kept_features_end() const;  // local index of m2's first kept pose
  Eigen::Matrix<double, Eigen::Dynamic, 3> J_R_kept_;  // rows of J_R for the kept elements
  static constexpr Eigen::Index kPairsPerUnit = 16;
  // Multiply-adds' worth of an assembled element (copies between column- and row-major blocks).
  static constexpr Eigen::Index kAssembleElementCost = 48;
  Eigen::Index solve_rows_per_unit() const;
  bool relinearisation_started_ = false;
  // The association's frame (m2 moved into B1 at the prior means) and search, while it runs.
  std::unique_ptr<JoinFrame> association_frame_;
  std::unique_ptr<JoinAssociator> associator_;
  std::unique_ptr<JoinFrame> frame_;   // m2 moved into B1 at the linearisation point
  Eigen::Index next_pair_ = 0;
  Eigen::Index next_panel_ = 0;
  Eigen::MatrixXd gain_;               // P H' (rows: F1, then all of m2), then W in place
  Eigen::MatrixXd constraint_factor_;  // S, becoming L (S = L L') in its lower triangle
  Eigen::VectorXd whitened_h_;         // h, then L^-1 h
  Eigen::Index next_solve_row_ = 0;
  // Row-major: the assembly writes it a row at a time, so its pages are first touched a few
  // rows per unit of work rather than all of them by the first row.
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> left_;
  Eigen::MatrixXd right_second_;
  Eigen::MatrixXd right_first_;
  Mat2 rotation_;
  GaussianMap result_;
  Eigen::Index next_out_col_ = 0;
  Eigen::Index next_fill_row_ = 0;      // next row of the column block being filled
  Eigen::Index next_assemble_row_ = -1;  // -1: assembly not begun
  Eigen::MatrixXd scratch_;
};

// Joins two maps at once (no amortization).
GaussianMap join_maps(const GaussianMap& first, const GaussianMap& second,
                      const JoinOptions& options, JoinReport* report = nullptr);

}  // namespace dcslam
