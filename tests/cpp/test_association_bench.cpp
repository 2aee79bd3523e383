#include <cmath>

#include <gtest/gtest.h>

#include "association_bench.hpp"
#include "dcslam/core/errors.hpp"

namespace dcslam {
namespace {

TEST(AssociationBench, FittedExponentRecoversAPowerLaw) {
  const std::vector<double> n = {100, 200, 400, 800};
  std::vector<double> t;
  for (double x : n) t.push_back(3e-7 * std::pow(x, 1.5));
  EXPECT_NEAR(fitted_exponent(n, t), 1.5, 1e-12);
  EXPECT_THROW(fitted_exponent({100}, {1.0}), InvalidArgument);
  EXPECT_THROW(fitted_exponent({100, 100}, {1.0, 2.0}), InvalidArgument);
  EXPECT_THROW(fitted_exponent({100, 200}, {0.0, 2.0}), InvalidArgument);
}

// Small sizes only: this checks what the benchmark measures (true pairs found by RJC and
// JCBB, a constant overlap), never how long it takes.
TEST(AssociationBench, JoinsOfGrowingMapsFindTheConstantOverlap) {
  const AssociationBenchResult result = benchmark_join_association({400, 800, 1600}, 60, 1, 3);
  ASSERT_EQ(result.rows.size(), 3u);
  for (const AssociationBenchRow& row : result.rows) {
    EXPECT_EQ(row.true_pairs, 60);
    EXPECT_EQ(row.wrong_rjc, 0);
    EXPECT_EQ(row.wrong_jcbb, 0);
    EXPECT_GE(row.pairs_rjc, 57);
    EXPECT_GE(row.pairs_jcbb, 57);
    EXPECT_LE(row.overlap, 80);  // grows with the overlap, not with n
    EXPECT_GT(row.tries_rjc, 0);
    EXPECT_GE(row.compatible_all_pairs, row.pairs_jcbb - 3);
    EXPECT_GT(row.seconds_rjc, 0.0);
  }
  EXPECT_THROW(benchmark_join_association({100}, 60), InvalidArgument);
}

}  // namespace
}  // namespace dcslam
