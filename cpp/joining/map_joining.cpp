#include "dcslam/joining/map_joining.hpp"

#include <algorithm>
#include <chrono>
#include <limits>
#include <stdexcept>
#include <string>

#include "dcslam/core/errors.hpp"
#include "dcslam/joining/constrained_update.hpp"
#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/join_cost.hpp"
#include "dcslam/joining/join_fill.hpp"

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

}  // namespace

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

std::int64_t MapJoin::remaining_work() const {
  if (phase_ == Phase::Done) return 0;
  // The fill writes the lower triangle of the columns not yet done; the assembly writes each
  // result row's 6 + 2r low-rank factors; the solve, once the pairs are known, costs
  // join_cost::solve_row() a row. Before association the result's size is bounded by the
  // inputs'; after, the matched and dropped features are known to go (counting them overstated
  // the snail's 128-leaf join by half, and with it the budget of every step before its fill).
  const Index bound = first_->dim() + second_->dim() -
                      (options_.keep_first_robot ? 0 : GaussianMap::kRobotDim);
  const Index out_dim =
      phase_ == Phase::Associate
          ? bound
          : bound - GaussianMap::kFeatureDim *
                        static_cast<Index>(pairs_.size() + layout_.dropped_ids.size());
  const auto left = static_cast<std::int64_t>(phase_ == Phase::Fill ? fill_->columns_left() : out_dim);
  // The fill and the assembly, for r pairs.
  const auto output_work = [&](std::int64_t r) -> std::int64_t {
    const std::int64_t fill = left * (left + 1) / 2 * join_cost::fill_element(r);
    if (phase_ == Phase::Fill) return fill;
    const Index rows = phase_ == Phase::Assemble && update_->assembling()
                           ? update_->assembly_rows_left()
                           : out_dim;
    return fill + static_cast<std::int64_t>(rows) * join_cost::assemble_row(r);
  };
  const auto r = static_cast<std::int64_t>(pairs_.size());
  const std::int64_t work = output_work(r);
  const Index solve_rows = first_->dim() + second_->dim();
  const std::int64_t relinearise_steps = options_.max_iterations - 1;
  switch (phase_) {
    case Phase::Associate: {
      // r is unknown until association; the overlap found so far, extrapolated over m2, stands
      // in for it (an upper bound on r once the candidates are known). Counting 0 instead
      // left joins with r in the hundreds (the snail) to catch up in a few steps of 10 ms;
      // a bound from the map sizes would inflate every budget where r is small.
      const std::int64_t expected = associator_ ? associator_->expected_overlap() : 0;
      return output_work(expected) +
             static_cast<std::int64_t>(solve_rows) * join_cost::solve_row(expected) +
             (expected > 0 ? relinearise_steps * join_cost::relinearise_step(expected) : 0) +
             join_cost::kAssociationUnitCost * (associator_ ? associator_->remaining_work()
                                                            : first_->num_features() + second_->num_features());
    }
    case Phase::Relinearise:
      // At most max_iterations - 1 steps, small next to the fill.
      return work + static_cast<std::int64_t>(solve_rows) * join_cost::solve_row(r) +
             (!relinearisation_started_
                  ? (pairs_.empty() ? 0 : relinearise_steps * join_cost::relinearise_step(r))
              : relinearisation_.converged()
                  ? 0
                  : (relinearise_steps - relinearisation_.steps()) * join_cost::relinearise_step(r));
    case Phase::Constrain:
    case Phase::Factor:
      return work + static_cast<std::int64_t>(solve_rows) * join_cost::solve_row(r);
    case Phase::Solve:
      return work + static_cast<std::int64_t>(update_->solve_rows_left()) * join_cost::solve_row(r);
    default:
      return work;
  }
}

std::int64_t MapJoin::step(std::int64_t budget) {
  ScopedTimer timer(report_.seconds_total);
  std::int64_t spent = 0;
  switch (phase_) {
    case Phase::Associate:
      spent += associate_next(budget);
      break;
    case Phase::Relinearise:
      if (!relinearisation_started_) {
        relinearisation_.begin(*first_, *second_, pairs_, options_);
        report_.iterations = relinearisation_.iterations();
        relinearisation_started_ = true;
        spent += join_cost::relinearise_begin(static_cast<std::int64_t>(pairs_.size()));
      } else if (!relinearisation_.converged()) {
        spent += relinearisation_.unit();
      }
      if (relinearisation_.converged()) {
        spent += relinearisation_.finish();
        report_.iterations = relinearisation_.iterations();
        phase_ = Phase::Constrain;
      }
      break;
    case Phase::Constrain:
      if (!update_) {
        update_ = std::make_unique<ConstrainedUpdate>(*first_, *second_, pairs_, layout_, options_,
                                                      relinearisation_.first_robot(),
                                                      relinearisation_.second_x());
        spent += static_cast<std::int64_t>(second_->dim());
      }
      spent += update_->constrain_next_pairs(budget - spent);
      if (update_->constrained()) {
        update_->begin_factor();
        spent += join_cost::begin_factor(static_cast<std::int64_t>(pairs_.size()));
        phase_ = update_->factored() ? Phase::Solve : Phase::Factor;
      }
      break;
    case Phase::Factor:
      spent += update_->factor_next_panel();
      if (update_->factored()) phase_ = Phase::Solve;
      break;
    case Phase::Solve:
      spent += update_->solve_next_rows();
      if (update_->solve_rows_left() == 0) phase_ = Phase::Assemble;
      break;
    case Phase::Assemble:
      if (!update_->assembling()) {
        update_->begin_assemble();
        report_.features_joined = update_->result().num_features();
        report_.constraint_distance_sq = update_->constraint_distance_sq();
      }
      spent += update_->assemble_next_rows();
      if (update_->assembled()) {
        fill_ = std::make_unique<JoinFill>(*first_, *second_, layout_, options_, update_->rotation(),
                                           static_cast<Index>(pairs_.size()),
                                           update_->take_correction(), update_->take_result());
        update_.reset();
        phase_ = Phase::Fill;
      }
      break;
    case Phase::Fill:
      spent += fill_->fill_next_tile();
      if (fill_->done()) end_fill();
      break;
    case Phase::Done:
      break;
  }
  report_.work_units += spent;
  return spent;
}

std::int64_t MapJoin::finish(int threads) {
  std::int64_t spent = 0;
  while (!done() && !(phase_ == Phase::Fill && threads > 1)) {
    spent += step(std::numeric_limits<std::int64_t>::max() - spent);
  }
  if (done()) return spent;
  ScopedTimer timer(report_.seconds_total);
  const std::int64_t filled = fill_->fill_rest(threads);
  report_.work_units += filled;
  end_fill();
  return spent + filled;
}

void MapJoin::end_fill() {
  result_ = fill_->take_result();
  release_inputs();
  phase_ = Phase::Done;
}

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
  if (options_.fixed_pairs) {
    pairs_ = *options_.fixed_pairs;
  } else if (options_.association == JoinAssociation::Known) {
    pairs_ = associate_by_id(m1, m2);
    report_.overlap = static_cast<int>(pairs_.size());
  } else {
    JoinAssociationMemo* const memo = options_.association_memo.get();
    if (!(memo && memo->result)) {
      if (!associator_) {
        association_frame_ = std::make_unique<JoinFrame>(m1, m2);
        associator_ = std::make_unique<JoinAssociator>(*association_frame_, options_);
      }
      spent = join_cost::kAssociationUnitCost *
              associator_->advance(std::max<std::int64_t>(1, budget / join_cost::kAssociationUnitCost));
      if (!associator_->done()) return spent;
      if (memo) memo->result = associator_->result();
    }
    const JoinAssociationResult& result = memo ? *memo->result : associator_->result();
    pairs_ = result.pairs;
    doubtful_ = result.doubtful;
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
    report_.chunked = result.chunked;
    report_.widened = result.widened;
    for (const auto& [i, j] : result.disputed) {
      pairing_record_.disputed.emplace_back(m1.ids()[static_cast<std::size_t>(i)], m2.ids()[static_cast<std::size_t>(j)]);
    }
    associator_.reset();
    association_frame_.reset();
  }
  doubtful_.resize(pairs_.size(), 0);
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
  layout_ = JoinLayout(m1, m2, pairs_, first_tentative_, second_tentative_, options_.keep_first_robot);
  report_.dropped_tentative = static_cast<int>(layout_.dropped_ids.size());
}

void MapJoin::release_inputs() {
  // The fill's matrices stay until the join is destroyed, which D&C spreads over later steps.
  first_.reset();
  second_.reset();
  relinearisation_.release();
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
