#pragma once
// Resumable work (docs/design.md §4.4, §5.3): computations that run in steps so that an
// amortized join spreads over many filter steps. A step is bounded by a work unit where the
// computation's sizes allow, and its boundaries depend on the sizes and the unit alone, never
// on how the steps are spread over calls, so a result is bitwise the same however it is
// sliced. Every resumable computation (DecidingJoin, MapJoin, JoinAssociator, RjcSearch,
// SequentialAcceptance, JointCompatibilityEnforcement, ChunkedJcbb, ResumableCholesky) is a
// ResumableWork.
#include <algorithm>
#include <cstdint>
#include <limits>

#include <Eigen/Core>

namespace dcslam {

// Work is counted in units of about eight multiply-adds, so that budgets mean time across
// computations of every kind and size (join_cost.hpp holds the join's calibration).
inline constexpr std::int64_t kMultiplyAddsPerUnit = 8;
constexpr std::int64_t work_units(std::int64_t multiply_adds) {
  return multiply_adds / kMultiplyAddsPerUnit;
}

// Work of one PairingModel::covariance() block (a map join's is a few 2x3 by 3x2 products), in
// which the association's searches count theirs.
inline constexpr std::int64_t kPairingCovarianceUnits = 16;

// Multiply-adds that bound one step (JoinOptions::work_unit, RjcOptions::work_unit): small
// enough that an amortized step stays short when a join imposes hundreds of pairs.
inline constexpr std::int64_t kDefaultWorkUnit = std::int64_t{1} << 20;

// Width of the panels of a blocked Cholesky factorisation and of the column blocks a join
// writes its result in (JoinOptions::block_columns, RjcOptions::panel_width).
inline constexpr Eigen::Index kDefaultPanelWidth = 64;

// The contract a resumable computation `Work : ResumableWork<Work>` fulfils:
//   std::int64_t step(std::int64_t budget);  // one step, if !done(); returns its work in units
//   bool done() const;
//   std::int64_t remaining_work() const;     // in units, an estimate where the sizes are not known
// `budget` is what is left of the current advance() (at least 1): a step that runs another
// resumable computation (a join's association, RJC inside it) advances that one by it, so the
// nested steps are the ones a flat loop would take; every other step ignores it.
template <class Work>
class ResumableWork {
 public:
  // Steps until done() or until `budget` units are spent, at least one step if not done.
  // Returns the work done.
  std::int64_t advance(std::int64_t budget) {
    Work& work = static_cast<Work&>(*this);
    std::int64_t spent = 0;
    while (!work.done() && (spent == 0 || spent < budget)) {
      spent += work.step(std::max<std::int64_t>(1, budget - spent));
    }
    return spent;
  }
  // Runs to completion.
  std::int64_t finish() { return advance(std::numeric_limits<std::int64_t>::max()); }

 protected:
  ResumableWork() = default;
  ~ResumableWork() = default;
  ResumableWork(const ResumableWork&) = default;
  ResumableWork& operator=(const ResumableWork&) = default;
};

}  // namespace dcslam
