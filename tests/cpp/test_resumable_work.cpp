#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <gtest/gtest.h>

#include "dcslam/core/blocked_cholesky.hpp"
#include "dcslam/core/resumable_work.hpp"

namespace dcslam {
namespace {

// Steps of known costs, recorded as they run: what advance() does is visible in `taken`.
class CountedSteps : public ResumableWork<CountedSteps> {
 public:
  explicit CountedSteps(std::vector<std::int64_t> costs) : costs_(std::move(costs)) {}
  std::int64_t step(std::int64_t budget) {
    budgets.push_back(budget);
    return costs_[taken++];
  }
  bool done() const { return taken == costs_.size(); }
  std::int64_t remaining_work() const {
    std::int64_t left = 0;
    for (std::size_t k = taken; k < costs_.size(); ++k) left += costs_[k];
    return left;
  }

  std::size_t taken = 0;
  std::vector<std::int64_t> budgets;

 private:
  std::vector<std::int64_t> costs_;
};

TEST(ResumableWork, AdvanceStopsOnceTheBudgetIsSpentAndHandsTheRestToEachStep) {
  CountedSteps work({3, 0, 4, 5, 2});
  EXPECT_EQ(work.advance(6), 7);  // 3, then a free step, then 4 crosses the budget
  EXPECT_EQ(work.taken, 3u);
  EXPECT_EQ(work.budgets, (std::vector<std::int64_t>{6, 3, 3}));
  EXPECT_EQ(work.remaining_work(), 7);
  // A budget of nothing still takes one step.
  EXPECT_EQ(work.advance(0), 5);
  EXPECT_EQ(work.budgets.back(), 1);
  EXPECT_EQ(work.finish(), 2);
  EXPECT_TRUE(work.done());
  EXPECT_EQ(work.advance(10), 0);
}

Eigen::MatrixXd spd_matrix(Eigen::Index size) {
  const Eigen::MatrixXd A = Eigen::MatrixXd::Random(size, size);
  return A * A.transpose() + static_cast<double>(size) * Eigen::MatrixXd::Identity(size, size);
}

TEST(ResumableCholesky, SlicedFactorIsBitwiseTheWholeOneAndMatchesLlt) {
  const Eigen::MatrixXd S = spd_matrix(37);
  ResumableCholesky whole(S, 8);
  EXPECT_EQ(whole.remaining_work(), work_units(37 * 37 * 37 / 3));
  whole.finish();
  ResumableCholesky sliced(S, 8);
  int steps = 0;
  while (!sliced.done()) {
    const std::int64_t before = sliced.remaining_work();
    EXPECT_GT(sliced.advance(1), 0);
    EXPECT_LT(sliced.remaining_work(), before);
    ++steps;
  }
  EXPECT_EQ(steps, 5);  // panels of 8 columns
  EXPECT_FALSE(sliced.failed());
  const Eigen::MatrixXd L = sliced.matrix().triangularView<Eigen::Lower>();
  EXPECT_EQ(L, Eigen::MatrixXd(whole.matrix().triangularView<Eigen::Lower>()));
  EXPECT_TRUE(L.isApprox(Eigen::MatrixXd(Eigen::LLT<Eigen::MatrixXd>(S).matrixL())));
}

TEST(ResumableCholesky, StopsAtAPanelThatIsNotPositiveDefinite) {
  Eigen::MatrixXd S = spd_matrix(12);
  S.row(9).setZero();
  S.col(9).setZero();
  ResumableCholesky cholesky(S, 4);
  cholesky.finish();
  EXPECT_TRUE(cholesky.done());
  EXPECT_TRUE(cholesky.failed());
  EXPECT_EQ(cholesky.remaining_work(), 0);
}

}  // namespace
}  // namespace dcslam
