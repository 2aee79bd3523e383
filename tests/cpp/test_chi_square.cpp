#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "dcslam/core/chi_square.hpp"
#include "dcslam/core/errors.hpp"

namespace dcslam {
namespace {

struct TableValue {
  int dof;
  double p;
  double quantile;
};

// Reference values from scipy.stats.chi2.ppf (double precision).
constexpr TableValue kTable[] = {
    {2, 0.95, 5.991464547107979},      {1, 0.99, 6.6348966010212145},
    {10, 0.95, 18.307038053275146},    {100, 0.99, 135.80672317102676},
    {1, 0.5, 0.454936423119572},       {1, 1e-6, 1.5707963267957187e-12},
    {3, 0.999999, 30.66484970615427},  {50, 0.01, 29.706682698841284},
    {500, 0.95, 553.1268089342569},    {2000, 0.99, 2150.06566417287},
    {2000, 0.05, 1897.1196987673022},  {7, 0.5, 6.345811195521515},
    {1, 0.999999999, 37.32489310651872},
};

TEST(ChiSquare, QuantileMatchesTable) {
  for (const TableValue& row : kTable) {
    EXPECT_NEAR(chi2_quantile(row.dof, row.p), row.quantile, 1e-10 * row.quantile)
        << "dof " << row.dof << " p " << row.p;
  }
}

TEST(ChiSquare, QuantileInvertsCdfAndIsMonotone) {
  for (int dof = 1; dof <= 2000; dof += (dof < 40 ? 1 : 37)) {
    double previous = 0.0;
    for (double p : {1e-9, 0.001, 0.05, 0.3, 0.5, 0.7, 0.95, 0.99, 0.999, 1.0 - 1e-9}) {
      const double q = chi2_quantile(dof, p);
      ASSERT_GT(q, previous) << "dof " << dof << " p " << p;
      previous = q;
      if (p <= 0.5) {
        ASSERT_NEAR(chi2_cdf(dof, q), p, 1e-10 * p) << "dof " << dof;
      } else {
        ASSERT_NEAR(regularized_gamma_q(0.5 * dof, 0.5 * q), 1.0 - p, 1e-9 * (1.0 - p))
            << "dof " << dof << " p " << p;
      }
    }
    ASSERT_LT(chi2_quantile(dof, 0.99), chi2_quantile(dof + 1, 0.99));
  }
}

TEST(ChiSquare, ClosedFormsAndEdges) {
  EXPECT_DOUBLE_EQ(chi2_quantile(2, 0.99), -2.0 * std::log(0.01));
  EXPECT_NEAR(chi2_cdf(2, 3.0), 1.0 - std::exp(-1.5), 1e-15);
  EXPECT_NEAR(chi2_cdf(1, 4.0), std::erf(std::sqrt(2.0)), 1e-15);
  EXPECT_EQ(chi2_quantile(5, 0.0), 0.0);
  EXPECT_TRUE(std::isinf(chi2_quantile(5, 1.0)));
  EXPECT_EQ(chi2_cdf(5, -1.0), 0.0);
  EXPECT_THROW(chi2_quantile(0, 0.5), InvalidArgument);
  EXPECT_THROW(chi2_quantile(3, 1.5), InvalidArgument);
  EXPECT_THROW(chi2_quantile(3, std::numeric_limits<double>::quiet_NaN()), InvalidArgument);
  EXPECT_THROW(regularized_gamma_p(-1.0, 1.0), InvalidArgument);
}

TEST(ChiSquare, UpperQuantileInvertsTheUpperTail) {
  // Against the tail it inverts, on real and integer dof, in both tails and far out in them.
  for (double dof : {0.5, 1.0, 3.0, 7.5, 40.0, 1000.0}) {
    for (double alpha : {1e-12, 1e-6, 0.01, 0.05, 0.5, 0.9, 0.999}) {
      const double x = chi2_upper_quantile(dof, alpha);
      const double tail = regularized_gamma_q(0.5 * dof, 0.5 * x);
      const double lower = regularized_gamma_p(0.5 * dof, 0.5 * x);
      if (alpha <= 0.5) {
        EXPECT_NEAR(tail / alpha, 1.0, 1e-10) << "dof " << dof << " alpha " << alpha;
      } else {
        EXPECT_NEAR(lower / (1.0 - alpha), 1.0, 1e-9) << "dof " << dof << " alpha " << alpha;
      }
    }
  }
  // Closed forms: chi2(2) is exponential with mean 2; chi2(1) is a squared standard normal.
  EXPECT_DOUBLE_EQ(chi2_upper_quantile(2.0, 1e-9), -2.0 * std::log(1e-9));
  EXPECT_NEAR(chi2_upper_quantile(1.0, 0.05), 1.959963984540054 * 1.959963984540054, 1e-12);
  // Where both exist, the same value as the gates' quantile.
  EXPECT_NEAR(chi2_upper_quantile(4.0, 0.01) / chi2_quantile(4, 0.99), 1.0, 1e-13);
  EXPECT_THROW(chi2_upper_quantile(0.0, 0.05), InvalidArgument);
  EXPECT_THROW(chi2_upper_quantile(3.0, 0.0), InvalidArgument);
  EXPECT_THROW(chi2_upper_quantile(3.0, 1.0), InvalidArgument);
  EXPECT_THROW(chi2_upper_quantile(std::numeric_limits<double>::infinity(), 0.5), InvalidArgument);
}

TEST(ChiSquare, GateCachesQuantiles) {
  ChiSquareGate gate(0.95);
  EXPECT_EQ(gate.confidence(), 0.95);
  EXPECT_DOUBLE_EQ(gate.threshold(10), chi2_quantile(10, 0.95));
  EXPECT_DOUBLE_EQ(gate.threshold(2), chi2_quantile(2, 0.95));
  EXPECT_DOUBLE_EQ(gate.threshold(300), chi2_quantile(300, 0.95));
  EXPECT_DOUBLE_EQ(gate.threshold(10), chi2_quantile(10, 0.95));
  EXPECT_THROW(gate.threshold(0), InvalidArgument);
  EXPECT_THROW(ChiSquareGate(1.0), InvalidArgument);
}

}  // namespace
}  // namespace dcslam
