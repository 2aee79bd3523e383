"""Filter consistency against ground truth (Paz et al. 2007, §III.C; docs/design.md §7).

The Normalized Estimation Error Squared of an estimate ``(x, P)`` of the true ``x*`` is
``D^2 = (x - x*)' P^-1 (x - x*)``. The estimate passes the chi-squared test when
``D^2 < chi2(r, 1 - alpha)``, ``r = dim x``, and the paper's consistency index is
``CI = D^2 / chi2(r, 1 - alpha)``: below 1 consistent, above 1 optimistic.

The chi-squared quantile is computed here (no scipy at run time): Newton's method on the
regularized incomplete gamma function, started from the Wilson–Hilferty approximation and
kept inside a bisection bracket.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Sequence

import numpy as np

__all__ = ["nees", "chi2_threshold", "consistency_index"]

_EPS = 1e-15
_TINY = 1e-300
_SMALLEST_NORMAL = 2.2250738585072014e-308
_MAX_TERMS = 100_000


def _as_state(value, name: str) -> np.ndarray:
    array = np.atleast_1d(np.asarray(value, dtype=float))
    if array.ndim != 1:
        raise ValueError(f"nees: argument '{name}' must be a vector, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"nees: argument '{name}' contains a non-finite value")
    return array


def _error(x_est, x_true, angle_indices: Sequence[int]) -> np.ndarray:
    x_est = _as_state(x_est, "x_est")
    x_true = _as_state(x_true, "x_true")
    if x_est.shape != x_true.shape:
        raise ValueError(
            f"nees: arguments 'x_est' {x_est.shape} and 'x_true' {x_true.shape} differ in shape"
        )
    error = x_est - x_true
    for i in angle_indices:
        if not -len(error) <= i < len(error):
            raise ValueError(f"nees: angle index {i} out of range for a state of {len(error)}")
        error[i] = math.remainder(error[i], 2 * math.pi)
    return error


def nees(x_est, P, x_true, angle_indices: Sequence[int] = ()) -> float:
    """Normalized Estimation Error Squared ``(x_est - x_true)' P^-1 (x_est - x_true)``.

    Paz et al. 2007, §III.C. The differences at ``angle_indices`` are wrapped to
    [-pi, pi] (e.g. ``angle_indices=(2,)`` for a robot pose ``(x, y, phi)``). Scalars are
    accepted for one-dimensional states (e.g. the heading alone).

    Raises:
        ValueError: mismatched shapes, non-finite values, or ``P`` not positive definite.
    """
    error = _error(x_est, x_true, angle_indices)
    P = np.atleast_2d(np.asarray(P, dtype=float))
    if P.shape != (len(error), len(error)):
        raise ValueError(f"nees: argument 'P' must have shape {(len(error),) * 2}, got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("nees: argument 'P' contains a non-finite value")
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise ValueError("nees: argument 'P' is not positive definite") from None
    whitened = np.linalg.solve(L, error)
    return float(whitened @ whitened)


def _regularized_gamma(a: float, x: float) -> tuple:
    """(P(a, x), Q(a, x)), the regularized lower and upper incomplete gamma functions:
    a power series below x = a + 1 and Lentz's continued fraction above, where each
    converges fast (Numerical Recipes §6.2)."""
    if x <= 0.0:
        return 0.0, 1.0
    log_prefactor = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        denominator = a
        for _ in range(_MAX_TERMS):
            denominator += 1.0
            term *= x / denominator
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        lower = total * math.exp(log_prefactor)
        return lower, 1.0 - lower
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    fraction = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = d if abs(d) > _TINY else _TINY
        c = b + an / c
        c = c if abs(c) > _TINY else _TINY
        d = 1.0 / d
        delta = d * c
        fraction *= delta
        if abs(delta - 1.0) < _EPS:
            break
    upper = math.exp(log_prefactor) * fraction
    return 1.0 - upper, upper


def chi2_threshold(dof: float, alpha: float = 0.05) -> float:
    """The ``1 - alpha`` quantile of the chi-squared distribution with ``dof`` degrees of
    freedom: the NEES bound of Paz et al. 2007, §III.C (``alpha = 0.05`` there).

    Raises:
        ValueError: ``dof <= 0`` or ``alpha`` outside (0, 1).
    """
    dof = float(dof)
    alpha = float(alpha)
    if not (math.isfinite(dof) and dof > 0.0):
        raise ValueError(f"chi2_threshold: argument 'dof' must be > 0, got {dof}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"chi2_threshold: argument 'alpha' must lie in (0, 1), got {alpha}")
    a = dof / 2.0  # chi2(dof) / 2 is Gamma(dof / 2, 1)
    # Solve on the smaller tail, which the gamma functions give to full relative precision.
    use_upper = alpha <= 0.5
    target = alpha if use_upper else 1.0 - alpha

    def residual(x: float) -> float:
        lower, upper = _regularized_gamma(a, x)
        return upper - target if use_upper else target - lower  # decreasing in x

    def density(x: float) -> float:
        return math.exp((a - 1.0) * math.log(x) - x - math.lgamma(a))

    z = NormalDist().inv_cdf(1.0 - alpha)
    h = 2.0 / (9.0 * dof)
    guesses = [0.5 * dof * max(1.0 - h + z * math.sqrt(h), 1e-3) ** 3]
    if not use_upper:
        # Near 0, P(a, x) ~ x^a / Gamma(a + 1): far better than Wilson–Hilferty for small
        # dof and alpha near 1, where the quantile can be as small as 1e-100.
        guesses.append(math.exp((math.log(target) + math.lgamma(a + 1.0)) / a))
    x = min(guesses, key=lambda guess: abs(residual(guess)))
    if x < _SMALLEST_NORMAL:
        return 0.0  # the quantile underflows (tiny dof, alpha near 1)
    lo, hi = 0.0, x
    while residual(hi) > 0.0:
        lo, hi = hi, 2.0 * hi
    # Newton, falling back to bisection whenever a step would leave the bracket.
    for _ in range(2000):
        f = residual(x)
        if f > 0.0:
            lo = x
        else:
            hi = x
        slope = density(x)
        candidate = x + f / slope if slope > 0.0 else math.nan
        if not lo < candidate < hi:  # also catches nan
            candidate = 0.5 * (lo + hi)
        if candidate < _SMALLEST_NORMAL:
            return 0.0
        if abs(candidate - x) <= 1e-14 * x:
            return 2.0 * candidate
        x = candidate
    return 2.0 * x


def consistency_index(
    x_est, P, x_true, angle_indices: Sequence[int] = (), alpha: float = 0.05
) -> float:
    """The consistency index ``CI = D^2 / chi2(r, 1 - alpha)`` of Paz et al. 2007, §III.C
    (``D^2`` the :func:`nees`, ``r = dim x``): below 1 the estimate is consistent with the
    ground truth, above 1 it is optimistic."""
    error_dim = len(_error(x_est, x_true, angle_indices))
    return nees(x_est, P, x_true, angle_indices) / chi2_threshold(error_dim, alpha)
