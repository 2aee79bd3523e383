#pragma once
// Chi-square distribution for the Mahalanobis gates of data association: CDF through the
// regularized incomplete gamma function and its inverse (quantile), accurate to about 1e-12
// relative for dof 1..several thousand.
#include <vector>

namespace dcslam {

// Regularized lower and upper incomplete gamma functions P(a, x) and Q(a, x) = 1 - P(a, x),
// a > 0, x >= 0 (InvalidArgument otherwise). Each is computed directly (series or continued
// fraction) where it is small, so a tail keeps its relative accuracy.
double regularized_gamma_p(double a, double x);
double regularized_gamma_q(double a, double x);

// P(X <= x) for X ~ chi2(dof).
double chi2_cdf(int dof, double x);

// The x with chi2_cdf(dof, x) = p: dof >= 1, 0 <= p <= 1 (p = 1 gives +inf).
double chi2_quantile(int dof, double p);

// The x with P(X > x) = alpha for X ~ chi2(dof): any real dof > 0, 0 < alpha < 1
// (InvalidArgument otherwise), taking the upper tail itself so that a tiny alpha keeps its
// relative accuracy; 0 where the quantile underflows. dcslam.chi2_threshold() in Python.
double chi2_upper_quantile(double dof, double alpha);

// Gate thresholds chi2_quantile(dof, confidence) at a fixed confidence, computed once per dof
// and cached: JCBB asks for dof = 2, 4, ..., 2k over and over. Not thread-safe (the cache
// grows on demand); give each thread its own gate.
class ChiSquareGate {
 public:
  // 0 < confidence < 1, else InvalidArgument.
  explicit ChiSquareGate(double confidence);

  double confidence() const { return confidence_; }
  double threshold(int dof);

 private:
  double confidence_;
  std::vector<double> threshold_of_dof_;  // NaN = not computed yet
};

}  // namespace dcslam
