#include "dcslam/joining/map_joining.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "dcslam/core/errors.hpp"
#include "dcslam/joining/join_association.hpp"

namespace dcslam {

using Index = Eigen::Index;

namespace {

class ScopedTimer {
 public:
  explicit ScopedTimer(double& total) : total_(total), start_(std::chrono::steady_clock::now()) {}
  ~ScopedTimer() {
    total_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  double& total_;
  std::chrono::steady_clock::time_point start_;
};

// Row of x_{B1 R1} ⊕ p's Jacobian w.r.t. x_{B1 R1}, for a point p of m2 (rotated: Rp).
Eigen::Matrix<double, 2, 3> point_jacobian(const Vec2& rotated) {
  Eigen::Matrix<double, 2, 3> J;
  J << 1, 0, -rotated.y(), 0, 1, rotated.x();
  return J;
}

// One panel [k0, k0 + width) of a right-looking blocked Cholesky factorisation S = L L', in
// place in the lower triangle: factor the diagonal block, solve the panel below it, update the
// trailing lower triangle. Panels in order give the same factor however they are spread over
// calls. Returns the work in units of eight multiply-adds.
std::int64_t factor_panel(Eigen::MatrixXd& S, Eigen::Index k0, Eigen::Index width) {
  const Eigen::Index N = S.rows();
  width = std::min(width, N - k0);
  const Eigen::Index below = N - k0 - width;
  auto diagonal = S.block(k0, k0, width, width);
  const Eigen::LLT<Eigen::MatrixXd> llt(diagonal);
  if (llt.info() != Eigen::Success) {
    throw std::runtime_error(
        "map join: the covariance of the matched-pair constraints is not positive definite "
        "(two matched features are perfectly correlated)");
  }
  diagonal.triangularView<Eigen::Lower>() = llt.matrixL();
  if (below > 0) {
    auto panel = S.block(k0 + width, k0, below, width);
    diagonal.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
    S.block(k0 + width, k0 + width, below, below).selfadjointView<Eigen::Lower>().rankUpdate(panel, -1.0);
  }
  const auto w = static_cast<std::int64_t>(width), b = static_cast<std::int64_t>(below);
  return std::max<std::int64_t>(1, (b * b * w / 2 + b * w * w / 2 + w * w * w / 3) / 8);
}

// What J_2 does to element a of m2's layout [robot (3) | feature pairs up to features_end |
// poses (3 each)]: the x and y of a point or pose are rotated together, headings pass.
enum class Role { X, Y, Heading };
Role second_role(Index a, Index features_end) {
  if (a >= 3 && a < features_end) return (a - 3) % 2 == 0 ? Role::X : Role::Y;
  const Index component = a < 3 ? a : (a - features_end) % 3;
  return component == 0 ? Role::X : component == 1 ? Role::Y : Role::Heading;
}

}  // namespace

// ---------------------------------------------------------------------------------------
JoinFrame::JoinFrame(const GaussianMap& first, const GaussianMap& second)
    : JoinFrame(first, second, first.robot(), second.x()) {}

JoinFrame::JoinFrame(const GaussianMap& first, const GaussianMap& second,
                     const Vec3& first_robot, const Eigen::VectorXd& second_x)
    : first_(first), second_(second), T_(first_robot), second_x_(second_x) {
  if (second_x_.size() != second.dim()) {
    throw InvalidArgument("JoinFrame: the linearisation point of m2 has " +
                          std::to_string(second_x_.size()) + " entries, m2 has " +
                          std::to_string(second.dim()));
  }
  const double c = std::cos(T_.z()), s = std::sin(T_.z());
  rotation_ << c, -s, s, c;
  J_R_.resize(second.dim(), 3);
  const auto pose_rows = [&](Index offset) {
    J_R_.middleRows<3>(offset) << point_jacobian(rotation_ * second_x_.segment<2>(offset)), 0, 0, 1;
  };
  pose_rows(0);
  for (Index j = 0; j < second.num_features(); ++j) {
    J_R_.middleRows<2>(GaussianMap::feature_offset(j)) =
        point_jacobian(rotation_ * second_x_.segment<2>(GaussianMap::feature_offset(j)));
  }
  for (Index q = 0; q < second.num_poses(); ++q) pose_rows(second.pose_offset(q));
}

// G*(x0 - x*) for an element p of m2 (prior mean p0, linearised at p_lin):
// J_R (R1_0 - R1*) + Rot* (p0 - p_lin). Exactly zero at x* = x0, so the one-shot join's moved
// means come out unchanged.
Vec2 JoinFrame::linearisation_offset(const Vec2& p0, const Vec2& p_lin) const {
  const Vec2 rotated = rotation_ * p_lin;
  const Vec3 robot_offset = first_.robot() - T_;
  return robot_offset.head<2>() + Vec2(-rotated.y(), rotated.x()) * robot_offset.z() +
         rotation_ * (p0 - p_lin);
}

Vec2 JoinFrame::moved_second_feature(Index j) const {
  const Vec2 p_lin = second_x_.segment<2>(GaussianMap::feature_offset(j));
  return T_.head<2>() + rotation_ * p_lin + linearisation_offset(second_.feature(j), p_lin);
}

// The heading is linear in the headings: the result is their prior sum, wrapped only at the
// linearisation point (the caller wraps the final value).
Vec3 JoinFrame::moved_second_pose(Index offset) const {
  const Vec3 pose_lin = second_x_.segment<3>(offset);
  const Vec3 pose0 = second_.x().segment<3>(offset);
  Vec3 moved = compose(T_, pose_lin);
  moved.head<2>() += linearisation_offset(pose0.head<2>(), pose_lin.head<2>());
  moved.z() += (first_.robot().z() - T_.z()) + (pose0.z() - pose_lin.z());
  return moved;
}

Mat2 JoinFrame::first_first(Index i, Index k) const {
  return first_.P().block<2, 2>(GaussianMap::feature_offset(i), GaussianMap::feature_offset(k));
}

Mat2 JoinFrame::first_second(Index i, Index j) const {
  return first_.P().block<2, 3>(GaussianMap::feature_offset(i), 0) *
         J_R_.middleRows<2>(GaussianMap::feature_offset(j)).transpose();
}

Mat2 JoinFrame::second_second(Index j, Index l) const {
  const Index oj = GaussianMap::feature_offset(j), ol = GaussianMap::feature_offset(l);
  return J_R_.middleRows<2>(oj) * first_.P().topLeftCorner<3, 3>() *
             J_R_.middleRows<2>(ol).transpose() +
         rotation_ * second_.P().block<2, 2>(oj, ol) * rotation_.transpose();
}

Mat2 JoinFrame::constraint_covariance(Index i, Index j, Index k, Index l) const {
  return first_first(i, k) - first_second(i, l) - first_second(k, j).transpose() +
         second_second(j, l);
}

// ---------------------------------------------------------------------------------------
std::vector<std::pair<Index, Index>> associate_by_id(const GaussianMap& first,
                                                     const GaussianMap& second) {
  std::unordered_map<std::int64_t, Index> index_of;
  index_of.reserve(first.ids().size());
  for (std::size_t i = 0; i < first.ids().size(); ++i) index_of.emplace(first.ids()[i], i);
  std::vector<std::pair<Index, Index>> pairs;
  for (std::size_t j = 0; j < second.ids().size(); ++j) {
    const auto it = index_of.find(second.ids()[j]);
    if (it != index_of.end()) pairs.emplace_back(it->second, static_cast<Index>(j));
  }
  return pairs;
}

// ---------------------------------------------------------------------------------------
MapJoin::MapJoin(std::shared_ptr<const GaussianMap> first,
                 std::shared_ptr<const GaussianMap> second, JoinOptions options,
                 std::vector<Index> first_tentative, std::vector<Index> second_tentative)
    : first_(std::move(first)),
      second_(std::move(second)),
      options_(options),
      first_tentative_(std::move(first_tentative)),
      second_tentative_(std::move(second_tentative)) {
  if (!first_ || !second_) throw InvalidArgument("MapJoin: both maps are required");
  const auto check = [](const std::vector<Index>& indices, Index features, const char* which) {
    for (Index i : indices) {
      if (i < 0 || i >= features) {
        throw InvalidArgument(std::string("MapJoin: tentative feature index ") +
                              std::to_string(i) + " of the " + which + " map out of range");
      }
    }
  };
  check(first_tentative_, first_->num_features(), "first");
  check(second_tentative_, second_->num_features(), "second");
  if (options_.max_iterations < 1) {
    throw InvalidArgument("MapJoin: max_iterations must be >= 1, got " +
                          std::to_string(options_.max_iterations));
  }
  options_.block_columns = std::max<Index>(2, options_.block_columns & ~Index{1});
  options_.work_unit = std::max<Index>(1, options_.work_unit);
  report_.features_first = first_->num_features();
  report_.features_second = second_->num_features();
}

MapJoin::~MapJoin() = default;

// A written element of the result costs a write plus a dot product of length 3 + 2r; one
// unit of work is about eight multiply-adds, so budgets mean time across joins of any r.
std::int64_t MapJoin::fill_element_cost(std::int64_t r) { return 1 + (3 + 2 * r) / 8; }
std::int64_t MapJoin::fill_element_cost() const {
  return fill_element_cost(static_cast<std::int64_t>(pairs_.size()));
}

// A row of the triangular solve costs about (2r)^2 / 2 multiply-adds.
std::int64_t MapJoin::solve_row_cost(std::int64_t r) { return std::max<std::int64_t>(1, r * r / 4); }
std::int64_t MapJoin::solve_row_cost() const {
  return solve_row_cost(static_cast<std::int64_t>(pairs_.size()));
}

// An assembled row: its 6 + 2r low-rank factors, copied between column- and row-major blocks.
std::int64_t MapJoin::assemble_row_cost(std::int64_t r) { return (6 + 2 * r) * kAssembleElementCost / 8; }

// Rows of the solve per unit of work, sized in multiply-adds: with r in the hundreds a fixed
// row count would cost tens of ms in one step. Depends only on the join's sizes, so the
// result never depends on the slicing.
Index MapJoin::solve_rows_per_unit() const {
  const Index r2 = 2 * static_cast<Index>(pairs_.size());
  return std::clamp<Index>(options_.work_unit / std::max<Index>(1, r2 * r2 / 2), 64,
                           4 * options_.block_columns);
}

std::int64_t MapJoin::remaining_work() const {
  if (phase_ == Phase::Done) return 0;
  // The fill writes the lower triangle of the columns not yet done; the assembly writes each
  // result row's 6 + 2r low-rank factors; the solve, once the pairs are known, costs
  // solve_row_cost() a row. Before association the result's size is bounded by the inputs';
  // after, the matched and dropped features are known to go (counting them overstated the
  // snail's 128-leaf join by half, and with it the budget of every step before its fill).
  const Index bound = first_->dim() + second_->dim() -
                      (options_.keep_first_robot ? 0 : GaussianMap::kRobotDim);
  const Index out_dim =
      phase_ == Phase::Fill ? result_.dim()
      : phase_ == Phase::Associate
          ? bound
          : bound - GaussianMap::kFeatureDim *
                        static_cast<Index>(pairs_.size() + dropped_ids_.size());
  const auto left = static_cast<std::int64_t>(out_dim - next_out_col_);
  // The fill and the assembly, for r pairs.
  const auto output_work = [&](std::int64_t r) -> std::int64_t {
    const std::int64_t fill = left * (left + 1) / 2 * fill_element_cost(r);
    if (phase_ == Phase::Fill) return fill;
    const Index rows = phase_ == Phase::Assemble && next_assemble_row_ >= 0
                           ? result_.dim() - next_assemble_row_
                           : out_dim;
    return fill + static_cast<std::int64_t>(rows) * assemble_row_cost(r);
  };
  const std::int64_t work = output_work(static_cast<std::int64_t>(pairs_.size()));
  const Index solve_rows = first_->dim() + second_->dim();
  switch (phase_) {
    case Phase::Associate: {
      // r is unknown until association; the overlap found so far, extrapolated over m2, stands
      // in for it (an upper bound on r once the candidates are known). Counting 0 instead
      // left joins with r in the hundreds (the snail) to catch up in a few steps of 10 ms;
      // a bound from the map sizes would inflate every budget where r is small.
      const std::int64_t r = associator_ ? associator_->expected_overlap() : 0;
      return output_work(r) + static_cast<std::int64_t>(solve_rows) * solve_row_cost(r) +
             (r > 0 ? (options_.max_iterations - 1) * relinearise_step_cost(r) : 0) +
             (associator_ ? associator_->remaining_work()
                          : first_->num_features() + second_->num_features());
    }
    case Phase::Relinearise:
      // At most max_iterations - 1 steps, small next to the fill.
      return work + static_cast<std::int64_t>(solve_rows) * solve_row_cost() +
             (!relinearisation_started_
                  ? (pairs_.empty() ? 0 : (options_.max_iterations - 1) * relinearise_step_cost())
              : gauss_newton_.converged
                  ? 0
                  : (options_.max_iterations - 1 - gauss_newton_.steps) * relinearise_step_cost());
    case Phase::Constrain:
    case Phase::Factor:
      return work + static_cast<std::int64_t>(solve_rows) * solve_row_cost();
    case Phase::Solve:
      return work + static_cast<std::int64_t>(gain_.rows() - next_solve_row_) * solve_row_cost();
    default:
      return work;
  }
}

std::int64_t MapJoin::advance(std::int64_t budget) {
  double& seconds = report_.seconds_total;
  ScopedTimer timer(seconds);
  std::int64_t spent = 0;
  while (phase_ != Phase::Done && (spent == 0 || spent < budget)) {
    switch (phase_) {
      case Phase::Associate:
        spent += associate_next(std::max<std::int64_t>(1, budget - spent));
        break;
      case Phase::Relinearise:
        if (!relinearisation_started_) {
          begin_relinearisation();
          relinearisation_started_ = true;
          spent += 1 + static_cast<std::int64_t>(pairs_.size());
        } else if (!gauss_newton_.converged) {
          spent += relinearise_unit();
        }
        if (gauss_newton_.converged) {
          spent += finish_relinearisation();
          phase_ = Phase::Constrain;
        }
        break;
      case Phase::Constrain:
        if (!frame_) {
          begin_constraints();
          spent += static_cast<std::int64_t>(second_->dim());
        }
        spent += constrain_next_pairs();
        if (next_pair_ == static_cast<Index>(pairs_.size())) {
          begin_factor();
          spent += static_cast<std::int64_t>(pairs_.size() * pairs_.size());
          phase_ = constraint_factor_.rows() > 0 ? Phase::Factor : Phase::Solve;
          next_solve_row_ = 0;
        }
        break;
      case Phase::Factor:
        spent += factor_next_panel();
        if (next_panel_ == constraint_factor_.rows()) phase_ = Phase::Solve;
        break;
      case Phase::Solve:
        spent += solve_next_rows();
        if (next_solve_row_ == gain_.rows()) {
          phase_ = Phase::Assemble;
          next_assemble_row_ = -1;
        }
        break;
      case Phase::Assemble:
        if (next_assemble_row_ < 0) begin_assemble();
        spent += assemble_next_rows();
        if (next_assemble_row_ == result_.dim()) phase_ = Phase::Fill;
        break;
      case Phase::Fill:
        spent += fill_next_block();
        if (next_out_col_ == result_.dim()) {
          release_inputs();
          phase_ = Phase::Done;
        }
        break;
      case Phase::Done:
        break;
    }
  }
  report_.work_units += spent;
  return spent;
}

void MapJoin::finish() { advance(std::numeric_limits<std::int64_t>::max()); }

GaussianMap MapJoin::take_result() {
  if (phase_ != Phase::Done) throw std::logic_error("MapJoin::take_result: join not finished");
  return std::move(result_);
}

std::vector<std::pair<std::int64_t, std::int64_t>> MapJoin::merged_ids() const {
  return merged_ids_;
}

std::int64_t MapJoin::associate_next(std::int64_t budget) {
  ScopedTimer timer(report_.seconds_association);
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  std::int64_t spent = 0;
  if (options_.association == JoinAssociation::Known) {
    pairs_ = associate_by_id(m1, m2);
    report_.overlap = static_cast<int>(pairs_.size());
  } else {
    if (!associator_) {
      association_frame_ = std::make_unique<JoinFrame>(m1, m2);
      associator_ = std::make_unique<JoinAssociator>(*association_frame_, options_);
    }
    spent = associator_->advance(budget);
    if (!associator_->done()) return spent;
    const JoinAssociationResult& result = associator_->result();
    pairs_ = result.pairs;
    for (const JoinTruthAudit& entry : result.truth_audit) {
      pairing_record_.truth_pairs.emplace_back(m1.ids()[static_cast<std::size_t>(entry.first)],
                                               m2.ids()[static_cast<std::size_t>(entry.second)]);
      pairing_record_.truth_distance_sq.push_back(entry.distance_sq);
      pairing_record_.truth_candidate.push_back(entry.candidate ? 1 : 0);
      pairing_record_.truth_consistent.push_back(entry.consistent ? 1 : 0);
    }
    for (const auto& [i, j] : result.own_pairs) {
      pairing_record_.own_pairs.emplace_back(m1.ids()[static_cast<std::size_t>(i)],
                                             m2.ids()[static_cast<std::size_t>(j)]);
    }
    report_.overlap = result.overlap;
    report_.tries = result.tries;
    associator_.reset();
    association_frame_.reset();
  }
  finish_association();
  phase_ = Phase::Relinearise;
  relinearisation_started_ = false;
  return spent + m1.num_features() + m2.num_features();
}

void MapJoin::finish_association() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  report_.pairings = static_cast<int>(pairs_.size());
  merged_ids_.clear();
  pairing_record_.first_ids = m1.ids();
  pairing_record_.second_ids = m2.ids();
  pairing_record_.pairs.clear();
  for (const auto& [i, j] : pairs_) {
    merged_ids_.emplace_back(m2.ids()[static_cast<std::size_t>(j)],
                             m1.ids()[static_cast<std::size_t>(i)]);
    pairing_record_.pairs.emplace_back(m1.ids()[static_cast<std::size_t>(i)],
                                       m2.ids()[static_cast<std::size_t>(j)]);
  }

  // Tentative features left unmatched are dropped: deleting their rows and columns is their
  // exact marginal, and the constraints never involve them.
  std::vector<char> dropped(static_cast<std::size_t>(m1.num_features()), 0);
  for (Index i : first_tentative_) dropped[static_cast<std::size_t>(i)] = 1;
  for (const auto& pair : pairs_) dropped[static_cast<std::size_t>(pair.first)] = 0;
  first_kept_rows_.clear();
  first_kept_ids_.clear();
  dropped_ids_.clear();
  for (Index i = 0; i < m1.num_features(); ++i) {
    const std::int64_t id = m1.ids()[static_cast<std::size_t>(i)];
    if (dropped[static_cast<std::size_t>(i)]) {
      dropped_ids_.push_back(id);
      continue;
    }
    first_kept_rows_.push_back(GaussianMap::feature_offset(i));
    first_kept_rows_.push_back(GaussianMap::feature_offset(i) + 1);
    first_kept_ids_.push_back(id);
  }
  // Past poses are never associated: m1's stay as they are, R1 joins them when kept.
  for (Index q = 0; q < m1.num_poses(); ++q) {
    for (Index c = 0; c < GaussianMap::kPoseDim; ++c) first_kept_rows_.push_back(m1.pose_offset(q) + c);
  }
  if (options_.keep_first_robot) {
    for (Index c = 0; c < GaussianMap::kRobotDim; ++c) first_kept_rows_.push_back(c);
  }
  second_dropped_.assign(static_cast<std::size_t>(m2.num_features()), 0);
  for (Index j : second_tentative_) second_dropped_[static_cast<std::size_t>(j)] = 1;
  for (const auto& pair : pairs_) second_dropped_[static_cast<std::size_t>(pair.second)] = 0;
  for (Index j = 0; j < m2.num_features(); ++j) {
    if (second_dropped_[static_cast<std::size_t>(j)]) dropped_ids_.push_back(m2.ids()[static_cast<std::size_t>(j)]);
  }
  report_.dropped_tentative = static_cast<int>(dropped_ids_.size());
}

// One step over s = [R1; matched f_i; matched f_j] (dimension ds = 3 + 4r), as its units
// count it: P_ss H' (5 ds a pair), S's lower triangle (11 r^2 / 2), the Cholesky factor of the
// 2r x 2r S ((2r)^3 / 3 multiply-adds), and the solves and products (2 ds r + 3 r^2).
std::int64_t MapJoin::relinearise_step_cost(std::int64_t r) {
  const std::int64_t ds = 3 + 4 * r;
  return std::max<std::int64_t>(1, 7 * ds * r + 17 * r * r / 2 + r * r * r / 3);
}
std::int64_t MapJoin::relinearise_step_cost() const {
  return relinearise_step_cost(static_cast<std::int64_t>(pairs_.size()));
}

// The iterated EKF with noise-free constraints c(x) = f_i - (R1 ⊕ f_j) = 0, i.e. Gauss–Newton
// on the constrained MAP: x+ = x0 + P0 H' λ, λ = (H P0 H')^-1 (-c(x) - H (x0 - x)), H = dc/dx
// at x. Only s enters c, so the steps are taken in s with its prior covariance P_ss (blocks of
// P1 and P2); m2's other elements then follow as x0 + P0 H' λ with the last λ, O(n r). The
// pipeline takes the final step itself, linearised at the point found here. Each step is
// split into bounded units (amortized D&C spreads them over frames); begin, units, finish.
void MapJoin::begin_relinearisation() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  lin_first_robot_ = options_.linearisation ? options_.linearisation->first_robot : m1.robot();
  lin_second_x_ = options_.linearisation ? options_.linearisation->second_x : m2.x();
  const Index r = static_cast<Index>(pairs_.size());
  report_.iterations = r > 0 ? 1 : 0;
  gauss_newton_.steps = 0;
  gauss_newton_.converged = r == 0 || options_.max_iterations == 1 || options_.linearisation != nullptr;
  if (gauss_newton_.converged) return;

  const Index ds = 3 + 4 * r;
  std::vector<Index>& rows1 = gauss_newton_.first_rows;
  std::vector<Index>& rows2 = gauss_newton_.second_rows;
  rows1 = {0, 1, 2};
  rows2.clear();
  for (const auto& [i, j] : pairs_) {
    rows1.push_back(GaussianMap::feature_offset(i));
    rows1.push_back(GaussianMap::feature_offset(i) + 1);
    rows2.push_back(GaussianMap::feature_offset(j));
    rows2.push_back(GaussianMap::feature_offset(j) + 1);
  }
  gauss_newton_.prior.resize(ds);
  gauss_newton_.covariance.resize(ds, ds);
  gauss_newton_.gathered = 0;
  gauss_newton_.next_build = 0;
  gauss_newton_.next_panel = -1;
}

// One unit of the re-linearisation: first s0 and P_ss gathered a block of columns at a time
// (P_ss is 2r + 3 rows of m1 and 2r of m2, zero between them); then per Gauss–Newton step H at
// the current point and P_ss H' a few pairs at a time, S = H P_ss H' and the right-hand side a
// few pairs at a time; then S's Cholesky factor a panel at a time; then λ and the next point.
// The blocks depend only on r and the work unit, so slicing never changes the result.
std::int64_t MapJoin::relinearise_unit() {
  GaussNewton& gn = gauss_newton_;
  const Index r = static_cast<Index>(pairs_.size());
  const Index ds = 3 + 4 * r, second_begin = 3 + 2 * r;
  const Eigen::VectorXd& s0 = gn.prior;
  Eigen::MatrixXd& P_ss = gn.covariance;
  Eigen::VectorXd& s = gn.point;
  // Pair k's rows of H (-J_R on R1, I on f_i, -Rot on f_j, at this step's point) times X, any
  // matrix or vector indexed like s: the right-hand side, S = H (P_ss H') and Newton's H P U.
  const auto H_rows = [&](Index k, const auto& X) {
    Eigen::Matrix<double, 2, std::decay_t<decltype(X)>::ColsAtCompileTime> rows =
        X.template middleRows<2>(3 + 2 * k);
    rows.noalias() -= gn.robot_jacobians[static_cast<std::size_t>(k)] * X.template topRows<3>();
    rows.noalias() -= gn.rotation * X.template middleRows<2>(second_begin + 2 * k);
    return rows;
  };
  if (gn.gathered < ds) {
    // A gathered element is a strided read: about 24 multiply-adds' worth.
    const Index columns = std::max<Index>(1, options_.work_unit / (24 * ds));
    const Index begin = gn.gathered, end = std::min(ds, begin + columns);
    for (Index b = begin; b < end; ++b) {  // column by column: both are column-major
      const bool second = b >= second_begin;
      const GaussianMap& map = second ? *second_ : *first_;
      const std::vector<Index>& rows = second ? gn.second_rows : gn.first_rows;
      const Index at = second ? second_begin : 0;
      const Index row = rows[static_cast<std::size_t>(b - at)];
      gn.prior(b) = map.x()(row);
      const auto source = map.P().col(row);
      auto column = P_ss.col(b);
      column.setZero();
      for (Index a = 0; a < static_cast<Index>(rows.size()); ++a) {
        column(at + a) = source(rows[static_cast<std::size_t>(a)]);
      }
    }
    gn.gathered = end;
    if (gn.gathered == ds) {
      // Converged when no coordinate moves by more than 1e-9 of its prior standard deviation
      // (or, for one known almost exactly, a few ulps of its value).
      gn.tolerance = 1e-9 * P_ss.diagonal().array().sqrt() + 1e-14 * s0.array().abs();
      gn.point = s0;
      gn.dual.setZero(ds);
    }
    return 3 * static_cast<std::int64_t>((end - begin) * ds);
  }
  if (gn.next_panel < 0) {
    Eigen::MatrixXd& PHt = gn.gain;
    Eigen::MatrixXd& S = gn.factor;
    // Units are sized by multiply-adds (14 ds for a pair's columns of P_ss H', up to 24 r for
    // its column of S); the work they return is calibrated to time (relinearise_step_cost()).
    const Index pairs_per_unit = std::max<Index>(1, options_.work_unit / (14 * ds + 24 * r));
    Mat2& rotation = gn.rotation;
    if (gn.next_build == 0) {
      PHt.resize(ds, 2 * r);
      S.resize(2 * r, 2 * r);
      gn.rhs.resize(2 * r);
      gn.robot_jacobians.resize(static_cast<std::size_t>(r));
      const double c = std::cos(s(2)), sn = std::sin(s(2));
      rotation << c, -sn, sn, c;
    }
    const Index begin = gn.next_build;
    if (begin < r) {
      const Index end = std::min(r, begin + pairs_per_unit);
      for (Index k = begin; k < end; ++k) {
        const Vec2 rotated = rotation * s.segment<2>(second_begin + 2 * k);
        auto& J = gn.robot_jacobians[static_cast<std::size_t>(k)];
        J = point_jacobian(rotated);
        const Vec2 constraint = s.segment<2>(3 + 2 * k) - s.head<2>() - rotated;
        gn.rhs.segment<2>(2 * k) = -constraint - H_rows(k, s0 - s);
        // P_ss is block diagonal (m1's rows, then m2's): only the non-zero blocks are read.
        auto columns = PHt.middleCols<2>(2 * k);
        auto first = columns.topRows(second_begin);
        first.noalias() = P_ss.block(0, 3 + 2 * k, second_begin, 2);
        first.noalias() -= P_ss.topLeftCorner(second_begin, 3) * J.transpose();
        columns.bottomRows(2 * r).noalias() =
            -P_ss.block(second_begin, second_begin + 2 * k, 2 * r, 2) * rotation.transpose();
      }
      gn.next_build = end;
      return std::max<std::int64_t>(1, static_cast<std::int64_t>(5 * ds * (end - begin)));
    }
    // S's lower triangle (all the factor reads), a few of its pair columns per unit: column by
    // column, the reads of P_ss H' are contiguous (row by row they were a cache miss each).
    const Index end = std::min(2 * r, begin + pairs_per_unit);
    std::int64_t work = 0;
    for (Index k = begin - r; k < end - r; ++k) {
      const auto column = PHt.middleCols<2>(2 * k);
      for (Index l = k; l < r; ++l) S.block<2, 2>(2 * l, 2 * k) = H_rows(l, column);
      work += 11 * (r - k);
    }
    gn.next_build = end;
    if (end == 2 * r) {
      gn.next_build = 0;
      gn.next_panel = 0;
    }
    return std::max<std::int64_t>(1, work);
  }
  if (gn.next_panel < gn.factor.rows()) {
    const std::int64_t cost = factor_panel(gn.factor, gn.next_panel, options_.block_columns);
    gn.next_panel += options_.block_columns;
    return cost;
  }
  // The Gauss–Newton step, and Newton's (docs/divide_and_conquer.md): with the last step's
  // multipliers the Lagrangian's curvature Σ λ_k ∇²c_k is U B U', U = [e_θ, a] (a: -Rot_θ' λ_k
  // on each f_j, Rot_θ = dRot/dθ), B = [h 1; 1 0] (h = Σ λ_k' Rot f_j). M = P^-1 - U B U' has
  // M^-1 = P + P U K U'P with K^-1 = B^-1 - U'P U, and Newton's system H M^-1 H' = S + W K W'
  // (W = H P U) is solved by Woodbury on S's factor: both steps cost one factor.
  const auto solve_S = [&](auto& rhs) {
    gn.factor.triangularView<Eigen::Lower>().solveInPlace(rhs);
    gn.factor.triangularView<Eigen::Lower>().transpose().solveInPlace(rhs);
  };
  const Mat2& rotation = gn.rotation;
  // s+ = s0 + P (H'λ + U q) and g+ = H'λ + U q keep s+ - s0 = P g+ (q = 0: Gauss–Newton).
  const auto step_to = [&](const Eigen::VectorXd& lambda, Eigen::VectorXd& point,
                           Eigen::VectorXd& dual) {
    point = s0;
    point.noalias() += gn.gain * lambda;
    dual.resize(ds);
    dual.head<3>().setZero();
    for (Index k = 0; k < r; ++k) {
      const Vec2 lambda_k = lambda.segment<2>(2 * k);
      dual.head<3>().noalias() -= gn.robot_jacobians[static_cast<std::size_t>(k)].transpose() * lambda_k;
      dual.segment<2>(3 + 2 * k) = lambda_k;
      dual.segment<2>(second_begin + 2 * k).noalias() = -rotation.transpose() * lambda_k;
    }
  };
  const auto moved_to = [&](const Eigen::VectorXd& point) {  // in units of the tolerance
    return ((point - s).array().abs() / gn.tolerance.max(std::numeric_limits<double>::min())).maxCoeff();
  };
  Eigen::VectorXd lambda = gn.rhs;  // -c + H (s - s0)
  solve_S(lambda);
  Eigen::VectorXd next, dual;
  step_to(lambda, next, dual);
  double moved = moved_to(next);
  bool newton = false;
  if (gn.steps > 0) {
    constexpr Index kTheta = 2;
    Mat2 rotation_derivative;
    rotation_derivative << -rotation(1, 0), -rotation(0, 0), rotation(0, 0), -rotation(1, 0);
    Eigen::VectorXd a(2 * r);
    double h = 0.0;
    for (Index k = 0; k < r; ++k) {
      const Vec2 lambda_k = gn.multipliers.segment<2>(2 * k);
      a.segment<2>(2 * k).noalias() = -rotation_derivative.transpose() * lambda_k;
      h += lambda_k.dot(rotation * s.segment<2>(second_begin + 2 * k));
    }
    Eigen::Matrix<double, Eigen::Dynamic, 2> PU(ds, 2), W(2 * r, 2);
    PU.col(0) = P_ss.col(kTheta);
    PU.col(1).head(second_begin).setZero();  // a lives on the f_j, m2's block of P_ss
    PU.col(1).tail(2 * r).noalias() = P_ss.bottomRightCorner(2 * r, 2 * r) * a;
    Mat2 K_inverse;
    K_inverse << -PU(kTheta, 0), 1.0 - PU(kTheta, 1), 1.0 - PU(kTheta, 1),
        -h - a.dot(PU.col(1).tail(2 * r));
    for (Index k = 0; k < r; ++k) W.middleRows<2>(2 * k) = H_rows(k, PU);
    Eigen::Matrix<double, Eigen::Dynamic, 2> Z = W;
    solve_S(Z);
    Mat2 capacitance = K_inverse;
    capacitance.noalias() += W.transpose() * Z;
    const auto invertible = [](const Mat2& A) {
      return std::abs(A.determinant()) > 1e-12 * A.squaredNorm();
    };
    if (invertible(K_inverse) && invertible(capacitance)) {
      // λ = (S + W K W')^-1 (-c + H (s - s0) + W K U'P g), with s - s0 = P g.
      const Mat2 K = K_inverse.inverse();
      Eigen::VectorXd newton_lambda = lambda;
      newton_lambda.noalias() += Z * (K * (PU.transpose() * gn.dual));
      newton_lambda.noalias() -= Z * (capacitance.inverse() * (W.transpose() * newton_lambda));
      Eigen::VectorXd newton_next, newton_dual;
      step_to(newton_lambda, newton_next, newton_dual);
      const Vec2 q = K * (PU.transpose() * (newton_dual - gn.dual));
      newton_next.noalias() += PU * q;
      newton_dual(kTheta) += q(0);
      newton_dual.tail(2 * r) += q(1) * a;
      // Far from the solution the curvature can send Newton astray (it did on two Victoria
      // Park joins whose maps disagree by a few σ): its step is taken only while contracting.
      const double newton_moved = moved_to(newton_next);
      if (newton_moved < gn.moved) {
        newton = true;
        lambda = std::move(newton_lambda);
        next = std::move(newton_next);
        dual = std::move(newton_dual);
        moved = newton_moved;
      }
    }
  }
  // Converged when no coordinate moves by more than its tolerance (1e-9 σ), or when Newton is
  // contracting and its next step, about (this step)² in units of σ, would be below that:
  // Newton converges quadratically, with a constant between 0.003 and 0.1 on Victoria Park's
  // joins (1 here), so the confirming step need not be taken.
  gn.converged = moved <= 1.0 || (newton && moved * moved <= 1e9);
  gn.moved = moved;
  gn.multipliers = std::move(lambda);
  gn.dual = std::move(dual);
  s = std::move(next);
  ++gn.steps;
  if (gn.steps + 1 >= options_.max_iterations) gn.converged = true;
  gn.next_panel = -1;
  // Both steps' solves and products, memory-bound: three passes over ds x 2r matrices.
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(2 * ds * r + 3 * r * r));
}

std::int64_t MapJoin::finish_relinearisation() {
  const Index r = static_cast<Index>(pairs_.size());
  if (gauss_newton_.steps == 0) return 0;
  report_.iterations = gauss_newton_.steps + 1;
  lin_first_robot_ = gauss_newton_.point.head<3>();
  // m2's rows of P0 g: its prior covariance with each f_j times g's f_j entries (at a KKT
  // point g = H'λ, so these are m2's rows of P0 H' λ; short of one, the mean of m2 given s).
  const auto P2 = second_->P();
  const Index second_begin = 3 + 2 * r;
  for (Index k = 0; k < r; ++k) {
    lin_second_x_.noalias() += P2.middleCols(gauss_newton_.second_rows[static_cast<std::size_t>(2 * k)], 2) *
                               gauss_newton_.dual.segment<2>(second_begin + 2 * k);
  }
  gauss_newton_ = GaussNewton();
  return static_cast<std::int64_t>(second_->dim()) * r / 4;
}

// Kept elements of m2 and the constraints' P H', S = L L' and L^-1 h (O(n r + r^3)), linearised
// at the point relinearise() found.
void MapJoin::begin_constraints() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  frame_ = std::make_unique<JoinFrame>(m1, m2, lin_first_robot_, lin_second_x_);
  rotation_ = frame_->rotation();
  const Index n2 = m2.num_features();
  const Index r = static_cast<Index>(pairs_.size());
  const auto& J_R = frame_->jacobian_first_robot();

  // Kept elements of m2: its robot (R2, the joined map's robot), the features neither
  // matched nor dropped, and its past poses.
  std::vector<char> matched(static_cast<std::size_t>(n2), 0);
  for (const auto& pair : pairs_) matched[static_cast<std::size_t>(pair.second)] = 1;
  second_kept_rows_ = {0, 1, 2};
  second_kept_ids_.clear();
  for (Index j = 0; j < n2; ++j) {
    if (matched[static_cast<std::size_t>(j)] || second_dropped_[static_cast<std::size_t>(j)]) continue;
    second_kept_rows_.push_back(GaussianMap::feature_offset(j));
    second_kept_rows_.push_back(GaussianMap::feature_offset(j) + 1);
    second_kept_ids_.push_back(m2.ids()[static_cast<std::size_t>(j)]);
  }
  for (Index q = 0; q < m2.num_poses(); ++q) {
    for (Index c = 0; c < GaussianMap::kPoseDim; ++c) second_kept_rows_.push_back(m2.pose_offset(q) + c);
  }
  const Index d2k = static_cast<Index>(second_kept_rows_.size());
  J_R_kept_.resize(d2k, 3);
  for (Index a = 0; a < d2k; ++a) {
    J_R_kept_.row(a) = J_R.row(second_kept_rows_[static_cast<std::size_t>(a)]);
  }
  gain_.resize(m1.dim() + m2.dim(), 2 * r);
  whitened_h_.resize(2 * r);
  next_pair_ = 0;
}

// Columns of P H' (rows [all of m1 (d1); all of m2 (d2)]) and entries of h for the
// constraints f_i - f'_j of the next pairs; O(n) a pair.
std::int64_t MapJoin::constrain_next_pairs() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  const Index d1 = m1.dim(), d2 = m2.dim();
  const Index r = static_cast<Index>(pairs_.size());
  const auto& J_R = frame_->jacobian_first_robot();
  const auto P1 = m1.P();
  const auto P2 = m2.P();
  const Mat3 P1_RR = P1.topLeftCorner<3, 3>();
  const auto A1 = P1.leftCols(3);  // cov(m1, R1)
  auto PHt_first = gain_.topRows(d1);
  auto PHt_second = gain_.bottomRows(d2);
  Eigen::MatrixXd second_col(d2, 2);
  const Index end = std::min<Index>(r, next_pair_ + kPairsPerUnit);
  for (Index k = next_pair_; k < end; ++k) {
    const auto [i, j] = pairs_[static_cast<std::size_t>(k)];
    const Index oi = GaussianMap::feature_offset(i), oj = GaussianMap::feature_offset(j);
    const Eigen::Matrix<double, 2, 3> J_j = J_R.middleRows<2>(oj);
    PHt_first.middleCols<2>(2 * k).noalias() = P1.middleCols(oi, 2);
    PHt_first.middleCols<2>(2 * k).noalias() -= A1 * J_j.transpose();
    // cov(m2 rows, f'_j) = J_R P1_RR J_j' + J_2 P2[:, f_j] Rot'.
    second_col.noalias() = P2.middleCols(oj, 2) * rotation_.transpose();
    rotate_second_rows(second_col, 0, GaussianMap::feature_offset(m2.num_features()));
    PHt_second.middleCols<2>(2 * k).noalias() = J_R * P1.block(0, oi, 3, 2);
    PHt_second.middleCols<2>(2 * k).noalias() -= J_R * (P1_RR * J_j.transpose());
    PHt_second.middleCols<2>(2 * k) -= second_col;
    whitened_h_.segment<2>(2 * k) = m1.feature(i) - frame_->moved_second_feature(j);
  }
  const std::int64_t pairs_done = end - next_pair_;
  next_pair_ = end;
  return pairs_done * 9 * static_cast<std::int64_t>(gain_.rows());
}

// S = H P H' from the rows of P H' (O(r^2)); the factorisation then runs a panel at a time.
void MapJoin::begin_factor() {
  const Index d1 = first_->dim();
  const Index r = static_cast<Index>(pairs_.size());
  Eigen::MatrixXd& S = constraint_factor_;
  S.resize(2 * r, 2 * r);
  for (Index a = 0; a < r; ++a) {
    const auto [i, j] = pairs_[static_cast<std::size_t>(a)];
    S.middleRows<2>(2 * a) = gain_.middleRows<2>(GaussianMap::feature_offset(i)) -
                             gain_.middleRows<2>(d1 + GaussianMap::feature_offset(j));
  }
  S = 0.5 * (S + S.transpose()).eval();
  next_panel_ = 0;
}

// One panel of a right-looking blocked Cholesky factorisation S = L L', in place in the
// lower triangle: factor the diagonal block, solve the panel below it, update the trailing
// lower triangle. The order of operations is fixed, so slicing never changes the result.
std::int64_t MapJoin::factor_next_panel() {
  const std::int64_t cost = factor_panel(constraint_factor_, next_panel_, options_.block_columns);
  next_panel_ = std::min<Index>(constraint_factor_.rows(), next_panel_ + options_.block_columns);
  if (next_panel_ == constraint_factor_.rows()) {
    constraint_factor_.triangularView<Eigen::Lower>().solveInPlace(whitened_h_);
    next_solve_row_ = 0;
  }
  return cost;
}

// W = P H' L^-T, in place, one block of rows at a time (rows are independent).
std::int64_t MapJoin::solve_next_rows() {
  const Index r2 = constraint_factor_.rows();
  const Index rows = std::min<Index>(solve_rows_per_unit(), gain_.rows() - next_solve_row_);
  if (r2 > 0) {
    auto block = gain_.middleRows(next_solve_row_, rows);
    constraint_factor_.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(block);
  }
  next_solve_row_ += rows;
  return static_cast<std::int64_t>(rows) * solve_row_cost();
}

// The result's means and the low-rank factors of the fill (see the header), O(n r) in all,
// a block of output rows per unit of work: output row o belongs to a segment of m1's or m2's
// kept elements, and each row only reads its own row of P H' (now W).
void MapJoin::begin_assemble() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  const Index d1k = static_cast<Index>(first_kept_rows_.size());
  const Index d2k = static_cast<Index>(second_kept_rows_.size());
  const Index d1f = 2 * static_cast<Index>(first_kept_ids_.size());
  const Index d2f = 2 * static_cast<Index>(second_kept_ids_.size());
  const Index k = 2 * static_cast<Index>(pairs_.size());
  const Index out_dim = d1k + d2k;
  const Index poses = (d1k - d1f + d2k - 3 - d2f) / GaussianMap::kPoseDim;
  result_ = GaussianMap::uninitialized((d1f + d2f) / GaussianMap::kFeatureDim, poses);
  segments_ = {Segment{0, 3, true, 0}, Segment{3, d1f, false, 0}, Segment{3 + d1f, d2f, true, 3},
               Segment{3 + d1f + d2f, d1k - d1f, false, d1f},
               Segment{3 + d1k + d2f, d2k - 3 - d2f, true, 3 + d2f}};
  left_.resize(out_dim, 6 + k);
  right_second_.resize(d2k, 3 + k);
  right_first_.resize(d1k, 3 + k);
  auto& ids = result_.ids();
  std::copy(first_kept_ids_.begin(), first_kept_ids_.end(), ids.begin());
  std::copy(second_kept_ids_.begin(), second_kept_ids_.end(),
            ids.begin() + static_cast<std::ptrdiff_t>(first_kept_ids_.size()));
  std::vector<std::int64_t> pose_ids = m1.pose_ids();
  if (options_.keep_first_robot) pose_ids.push_back(options_.first_robot_id);
  pose_ids.insert(pose_ids.end(), m2.pose_ids().begin(), m2.pose_ids().end());
  result_.pose_ids() = std::move(pose_ids);
  report_.features_joined = result_.num_features();
  next_assemble_row_ = 0;
}

const MapJoin::Segment& MapJoin::segment_of(Index out_row) const {
  for (const Segment& segment : segments_) {
    if (out_row >= segment.out_begin && out_row < segment.out_begin + segment.size) return segment;
  }
  throw std::logic_error("MapJoin: output row " + std::to_string(out_row) + " out of range");
}

Index MapJoin::second_kept_features_end() const {
  return GaussianMap::feature_offset(static_cast<Index>(second_kept_ids_.size()));
}

std::int64_t MapJoin::assemble_next_rows() {
  const GaussianMap& m1 = *first_;
  const GaussianMap& m2 = *second_;
  const JoinFrame& frame = *frame_;
  const Index d1 = m1.dim();
  const Index first_features_end = 2 * static_cast<Index>(first_kept_ids_.size());
  const Index second_features_end = second_kept_features_end();
  const Index second_poses_begin = GaussianMap::feature_offset(m2.num_features());
  const Index k = 2 * static_cast<Index>(pairs_.size());
  const Index out_dim = result_.dim();
  const auto P1 = m1.P();
  const Mat3 P1_RR = P1.topLeftCorner<3, 3>();
  const Eigen::VectorXd& v = whitened_h_;
  auto x = result_.x();
  const Index rows = std::max<Index>(16, options_.work_unit / (kAssembleElementCost * (6 + k)));
  const Index end = std::min(out_dim, next_assemble_row_ + rows);
  // Runs of rows whose sources are consecutive rows of one input are copied as blocks: a row
  // at a time, the reads of the column-major W and the writes of N were one cache miss each.
  for (Index o = next_assemble_row_; o < end;) {
    const Segment& segment = segment_of(o);
    const Index a = segment.local_begin + (o - segment.out_begin);
    const std::vector<Index>& kept = segment.second ? second_kept_rows_ : first_kept_rows_;
    const Index src = kept[static_cast<std::size_t>(a)];
    Index length = 1;
    const Index segment_end = std::min(end, segment.out_begin + segment.size);
    while (o + length < segment_end && kept[static_cast<std::size_t>(a + length)] == src + length) {
      ++length;
    }
    auto L = left_.middleRows(o, length);
    auto xs = x.segment(o, length);
    if (!segment.second) {  // m1 elements: L = [A1 | W | 0], N = [-W | A1]
      const auto W = gain_.middleRows(src, length);
      L.leftCols<3>() = P1.block(src, 0, length, 3);
      L.middleCols(3, k) = W;
      L.rightCols<3>().setZero();
      right_first_.block(a, 0, length, k) = -W;
      right_first_.block(a, k, length, 3) = P1.block(src, 0, length, 3);
      xs = m1.x().segment(src, length);
      xs.noalias() -= W * v;
      // The headings of m1's poses (and of R1) are corrected too: wrapped again.
      for (Index e = 0; e < length; ++e) {
        if (a + e >= first_features_end && (a + e - first_features_end) % 3 == 2) xs(e) = wrap_angle(xs(e));
      }
    } else {  // m2's robot, features or poses: L = [J_R P1_RR | W | J_R], N = [J_R | -W]
      const auto W = gain_.middleRows(d1 + src, length);
      const auto J = J_R_kept_.middleRows(a, length);
      L.leftCols<3>().noalias() = J * P1_RR;
      L.middleCols(3, k) = W;
      L.rightCols<3>() = J;
      right_second_.block(a, 0, length, 3) = J;
      right_second_.block(a, 3, length, k) = -W;
      for (Index e = 0; e < length; ++e) {
        const Index s = src + e;
        if (s >= 3 && s < second_poses_begin) {
          xs(e) = frame.moved_second_feature((s - 3) / 2)((s - 3) % 2);
        } else {
          const Index offset = s < 3 ? 0 : s - (s - second_poses_begin) % 3;
          xs(e) = frame.moved_second_pose(offset)(s - offset);
        }
      }
      xs.noalias() -= W * v;
      for (Index e = 0; e < length; ++e) {
        if (second_role(a + e, second_features_end) == Role::Heading) xs(e) = wrap_angle(xs(e));
      }
    }
    o += length;
  }
  const std::int64_t done = end - next_assemble_row_;
  next_assemble_row_ = end;
  if (end == out_dim) {
    gain_ = Eigen::MatrixXd();
    next_out_col_ = 0;
    next_fill_row_ = 0;
  }
  return done * assemble_row_cost(static_cast<std::int64_t>(pairs_.size())) + 1;
}

// Applies J_2 (block-diagonal rotations: Rot on the (x, y) of the robot, of each feature and
// of each pose, identity on headings) from the left to rows [local_begin, ...) of m2's
// elements.
void MapJoin::rotate_second_rows(Eigen::Ref<Eigen::MatrixXd> block, Index local_begin,
                                 Index features_end) const {
  const double c = rotation_(0, 0), s = rotation_(1, 0);
  for (Index a = 0; a < block.rows(); ++a) {
    if (second_role(local_begin + a, features_end) != Role::X) continue;
    for (Index col = 0; col < block.cols(); ++col) {
      const double u = block(a, col), w = block(a + 1, col);
      block(a, col) = c * u - s * w;
      block(a + 1, col) = s * u + c * w;
    }
    ++a;
  }
}

void MapJoin::rotate_second_columns(Eigen::Ref<Eigen::MatrixXd> block, Index local_begin,
                                    Index features_end) const {
  const double c = rotation_(0, 0), s = rotation_(1, 0);
  for (Index a = 0; a < block.cols(); ++a) {
    if (second_role(local_begin + a, features_end) != Role::X) continue;
    for (Index row = 0; row < block.rows(); ++row) {
      const double u = block(row, a), w = block(row, a + 1);
      block(row, a) = c * u - s * w;
      block(row, a + 1) = s * u + c * w;
    }
    ++a;
  }
}

void MapJoin::write_moved_second_block(Index row_begin, Index rows, Index col_begin,
                                       Index width, Index out_row, Index out_col) {
  const auto P2 = second_->P();
  const Index features_end = second_kept_features_end();
  // J_2 mixes the x and y of a pair: where the block splits one, it is gathered widened by
  // the missing partner, so tiles and column blocks may start and end anywhere.
  const auto widened = [&](Index begin, Index size) {
    return std::make_pair(begin - (second_role(begin, features_end) == Role::Y ? 1 : 0),
                          begin + size + (second_role(begin + size - 1, features_end) == Role::X ? 1 : 0));
  };
  const auto [row0, row1] = widened(row_begin, rows);
  const auto [col0, col1] = widened(col_begin, width);
  scratch_.resize(row1 - row0, col1 - col0);
  for (Index b = col0; b < col1; ++b) {
    const Index src_col = second_kept_rows_[static_cast<std::size_t>(b)];
    for (Index a = row0; a < row1; ++a) {
      scratch_(a - row0, b - col0) = P2(second_kept_rows_[static_cast<std::size_t>(a)], src_col);
    }
  }
  rotate_second_rows(scratch_, row0, features_end);
  rotate_second_columns(scratch_, col0, features_end);
  result_.P().block(out_row, out_col, rows, width) =
      scratch_.block(row_begin - row0, col_begin - col0, rows, width);
}

void MapJoin::write_first_block(Index row_begin, Index rows, Index col_begin, Index width,
                                Index out_row, Index out_col) {
  const auto P1 = first_->P();
  auto out = result_.P().block(out_row, out_col, rows, width);
  for (Index b = 0; b < width; ++b) {
    const Index src_col = first_kept_rows_[static_cast<std::size_t>(col_begin + b)];
    for (Index a = 0; a < rows; ++a) {
      out(a, b) = P1(first_kept_rows_[static_cast<std::size_t>(row_begin + a)], src_col);
    }
  }
}

// One block of columns [col, col + width) inside one segment: the lower part (rows >= col)
// is computed as base + L N', then mirrored into the rows above the diagonal of later
// columns. The base is a block of P1 or of J_2 P2 J_2' where rows and columns come from the
// same map, 0 across the maps.
std::int64_t MapJoin::fill_next_block() {
  const Index out_dim = result_.dim();
  const Index k = static_cast<Index>(right_first_.cols()) - 3;
  const Index col = next_out_col_;
  auto out = result_.P();
  const Segment& columns = segment_of(col);
  const Index width = std::min(options_.block_columns, columns.out_begin + columns.size - col);
  const Index local_col = columns.local_begin + (col - columns.out_begin);
  // The block is written a tile of rows at a time, rows from the diagonal down: the tiles
  // keep the block's width (so the GEMM streams the low-rank factor once per block, as
  // unsliced) and bound a unit of work when r is large.
  const Index row0 = next_fill_row_ > col ? next_fill_row_ : col;
  // A tile element costs its base (a gather, and for m2 a rotation: about 16 multiply-adds'
  // worth) plus its dot product of length 3 + k.
  const Index tile = std::max<Index>(64, options_.work_unit / (width * (19 + k)));
  const Index row1 = std::min(out_dim, row0 + tile);
  const Index rows = row1 - row0;
  if (row0 == col && col > 0) {
    // The rows above the diagonal are the earlier blocks' transposed. Written here, with the
    // block, rather than by each earlier block into every later column: a fresh result's pages
    // are then first touched a block at a time, not all in one unit of work.
    // In square tiles: one long transposed copy runs at a fraction of the speed.
    for (Index c0 = 0; c0 < col; c0 += options_.block_columns) {
      const Index tile_width = std::min(options_.block_columns, col - c0);
      out.block(c0, col, tile_width, width) = out.block(col, c0, width, tile_width).transpose();
    }
  }
  for (const Segment& segment : segments_) {
    const Index begin = std::max(row0, segment.out_begin);
    const Index end = std::min(row1, segment.out_begin + segment.size);
    if (begin >= end) continue;
    const Index local_row = segment.local_begin + (begin - segment.out_begin);
    if (segment.second != columns.second) {
      out.block(begin, col, end - begin, width).setZero();
    } else if (segment.second) {
      write_moved_second_block(local_row, end - begin, local_col, width, begin, col);
    } else {
      write_first_block(local_row, end - begin, local_col, width, begin, col);
    }
  }
  if (columns.second) {
    out.block(row0, col, rows, width).noalias() +=
        left_.leftCols(3 + k).middleRows(row0, rows) *
        right_second_.middleRows(local_col, width).transpose();
  } else {
    out.block(row0, col, rows, width).noalias() +=
        left_.rightCols(3 + k).middleRows(row0, rows) *
        right_first_.middleRows(local_col, width).transpose();
  }
  if (row0 == col) {
    // The diagonal square was computed whole, and base + L N' is symmetric only up to
    // rounding there: its lower triangle, like every other entry below the diagonal, is the
    // one kept, so that P is exactly symmetric (as the EKF keeps it).
    auto diagonal = out.block(col, col, width, width);
    diagonal.triangularView<Eigen::StrictlyUpper>() = diagonal.transpose();
  }
  next_fill_row_ = row1;
  if (row1 == out_dim) {
    next_out_col_ += width;
    next_fill_row_ = 0;
  }
  return static_cast<std::int64_t>(rows) * width * fill_element_cost();
}

void MapJoin::release_inputs() {
  frame_.reset();
  first_.reset();
  second_.reset();
  lin_second_x_ = Eigen::VectorXd();
  left_ = decltype(left_)();
  right_first_ = Eigen::MatrixXd();
  right_second_ = Eigen::MatrixXd();
  scratch_ = Eigen::MatrixXd();
}
GaussianMap join_maps(const GaussianMap& first, const GaussianMap& second,
                      const JoinOptions& options, JoinReport* report) {
  // Aliasing shared_ptrs: the join only reads the maps, which outlive this call.
  MapJoin join(std::shared_ptr<const GaussianMap>(std::shared_ptr<void>(), &first),
               std::shared_ptr<const GaussianMap>(std::shared_ptr<void>(), &second), options);
  join.finish();
  if (report) *report = join.report();
  return join.take_result();
}

}  // namespace dcslam
