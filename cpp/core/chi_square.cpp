#include "dcslam/core/chi_square.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

constexpr double kEpsilon = std::numeric_limits<double>::epsilon();
constexpr int kMaxTerms = 100000;

// ln Gamma(a) without a data race: std::lgamma also writes the global `signgam`, and the gates
// run on the main thread and on a join worker at once (threaded_joins); glibc's and macOS's
// lgamma_r return the same value and the sign through its argument instead.
double log_gamma(double a) {
#if defined(__GLIBC__) || defined(__APPLE__)
  int sign = 0;
  return ::lgamma_r(a, &sign);
#else
  return std::lgamma(a);
#endif
}

// log(x^a e^-x / Gamma(a)): the common factor of the series and the continued fraction.
double log_gamma_prefactor(double a, double x) { return a * std::log(x) - x - log_gamma(a); }

// P(a, x) by its power series; converges quickly for x < a + 1.
double gamma_p_series(double a, double x) {
  double term = 1.0 / a;
  double sum = term;
  for (int n = 1; n < kMaxTerms; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::fabs(term) < std::fabs(sum) * kEpsilon) break;
  }
  return sum * std::exp(log_gamma_prefactor(a, x));
}

// Q(a, x) by its continued fraction (modified Lentz); converges quickly for x >= a + 1.
double gamma_q_continued_fraction(double a, double x) {
  constexpr double tiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / tiny;
  double d = 1.0 / b;
  double h = d;
  for (int n = 1; n < kMaxTerms; ++n) {
    const double an = -n * (n - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::fabs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < kEpsilon) break;
  }
  return std::exp(log_gamma_prefactor(a, x)) * h;
}

void check_gamma_arguments(double a, double x, const char* function) {
  if (!(a > 0.0) || !std::isfinite(a) || !(x >= 0.0)) {
    throw InvalidArgument(std::string(function) + ": need a > 0 finite and x >= 0");
  }
}

// Wilson–Hilferty start for the quantile; needs a normal quantile only to a few digits, so
// the rational approximation of Abramowitz & Stegun 26.2.23 (|error| < 4.5e-4) suffices.
double approximate_normal_quantile(double p) {
  const double tail = p < 0.5 ? p : 1.0 - p;
  const double t = std::sqrt(-2.0 * std::log(tail));
  const double z =
      t - (2.515517 + t * (0.802853 + t * 0.010328)) /
              (1.0 + t * (1.432788 + t * (0.189269 + t * 0.001308)));
  return p < 0.5 ? -z : z;
}

}  // namespace

double regularized_gamma_p(double a, double x) {
  check_gamma_arguments(a, x, "regularized_gamma_p");
  if (x == 0.0) return 0.0;
  if (std::isinf(x)) return 1.0;
  return x < a + 1.0 ? gamma_p_series(a, x) : 1.0 - gamma_q_continued_fraction(a, x);
}

double regularized_gamma_q(double a, double x) {
  check_gamma_arguments(a, x, "regularized_gamma_q");
  if (x == 0.0) return 1.0;
  if (std::isinf(x)) return 0.0;
  return x < a + 1.0 ? 1.0 - gamma_p_series(a, x) : gamma_q_continued_fraction(a, x);
}

double chi2_cdf(int dof, double x) {
  if (dof < 1) throw InvalidArgument("chi2_cdf: dof must be >= 1");
  if (std::isnan(x)) throw InvalidArgument("chi2_cdf: x is NaN");
  if (x <= 0.0) return 0.0;
  return regularized_gamma_p(0.5 * dof, 0.5 * x);
}

namespace {

// The x = q / 2 in the gamma variable (a = dof / 2) whose tail equals `target`: the upper tail
// Q(a, x) when `upper`, else the lower tail P(a, x), so that a small tail is matched with
// relative accuracy. `start` is a first guess; the bracket makes any positive guess converge.
double gamma_tail_root(double a, bool upper, double target, double start) {
  // residual(x) increases with x in both forms.
  auto residual = [&](double x) {
    return upper ? target - regularized_gamma_q(a, x) : regularized_gamma_p(a, x) - target;
  };
  double x = start;
  // Bracket [lo, hi] with residual(lo) <= 0 <= residual(hi); Newton steps that leave it are
  // replaced by bisection, so the iteration converges even from a poor start.
  double lo = 0.0;
  double hi = std::max(x, a) * 2.0 + 1.0;
  while (residual(hi) < 0.0) {
    lo = hi;
    hi *= 2.0;
  }
  if (!(x > lo && x < hi)) x = 0.5 * (lo + hi);
  for (int iteration = 0; iteration < 400; ++iteration) {
    const double f = residual(x);
    if (f == 0.0) return x;
    (f < 0.0 ? lo : hi) = x;
    const double density = std::exp((a - 1.0) * std::log(x) - x - log_gamma(a));
    double next = x - f / density;
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::fabs(next - x) <= 4.0 * kEpsilon * x || hi - lo <= 4.0 * kEpsilon * hi) return next;
    x = next;
  }
  return x;
}

// Wilson–Hilferty's start in the gamma variable, for the normal quantile z of the lower tail
// probability; below the cube's zero (small dof, small lower tails), the series' first term.
double wilson_hilferty_start(double dof, double z, double lower_tail) {
  const double k = 2.0 / (9.0 * dof);
  const double cube = 1.0 - k + z * std::sqrt(k);
  return cube > 0.0 ? 0.5 * dof * cube * cube * cube : 0.5 * std::pow(lower_tail, 2.0 / dof);
}

}  // namespace

double chi2_quantile(int dof, double p) {
  if (dof < 1) throw InvalidArgument("chi2_quantile: dof must be >= 1");
  if (!(p >= 0.0 && p <= 1.0)) throw InvalidArgument("chi2_quantile: p must be in [0, 1]");
  if (p == 0.0) return 0.0;
  if (p == 1.0) return std::numeric_limits<double>::infinity();
  if (dof == 2) return -2.0 * std::log1p(-p);
  const bool upper = p > 0.5;
  const double start = wilson_hilferty_start(dof, approximate_normal_quantile(p), p);
  return 2.0 * gamma_tail_root(0.5 * dof, upper, upper ? 1.0 - p : p, start);
}

double chi2_upper_quantile(double dof, double alpha) {
  if (!(dof > 0.0) || !std::isfinite(dof)) {
    throw InvalidArgument("chi2_upper_quantile: dof must be > 0 and finite, got " + number_text(dof));
  }
  if (!(alpha > 0.0 && alpha < 1.0)) {
    throw InvalidArgument("chi2_upper_quantile: alpha must lie in (0, 1), got " + number_text(alpha));
  }
  if (dof == 2.0) return -2.0 * std::log(alpha);
  const double a = 0.5 * dof;
  const bool upper = alpha <= 0.5;
  const double target = upper ? alpha : 1.0 - alpha;
  // The normal quantile of the lower tail 1 - alpha, from whichever tail is small.
  const double z = upper ? -approximate_normal_quantile(alpha) : approximate_normal_quantile(1.0 - alpha);
  double start = wilson_hilferty_start(dof, z, 1.0 - alpha);
  if (!upper) {
    // Near 0, P(a, x) ~ x^a / Gamma(a + 1): far better for a small dof and a lower tail near 0,
    // where the quantile can be as small as 1e-100.
    const double series = std::exp((std::log(target) + log_gamma(a + 1.0)) / a);
    const auto miss = [&](double x) { return std::fabs(regularized_gamma_p(a, x) - target); };
    if (series > 0.0 && miss(series) < miss(start)) start = series;
  }
  if (!(start >= std::numeric_limits<double>::min())) return 0.0;  // the quantile underflows
  return 2.0 * gamma_tail_root(a, upper, target, start);
}

ChiSquareGate::ChiSquareGate(double confidence) : confidence_(confidence) {
  if (!(confidence > 0.0 && confidence < 1.0)) {
    throw InvalidArgument("ChiSquareGate: confidence must be in (0, 1)");
  }
}

double ChiSquareGate::threshold(int dof) {
  if (dof < 1) throw InvalidArgument("ChiSquareGate::threshold: dof must be >= 1");
  const auto index = static_cast<std::size_t>(dof);
  if (index >= threshold_of_dof_.size()) {
    // Doubling keeps the number of reallocations logarithmic as hypotheses grow.
    threshold_of_dof_.resize(std::max(index + 1, 2 * threshold_of_dof_.size()),
                             std::numeric_limits<double>::quiet_NaN());
  }
  double& threshold = threshold_of_dof_[index];
  if (std::isnan(threshold)) threshold = chi2_quantile(dof, confidence_);
  return threshold;
}

}  // namespace dcslam
