"""Filter consistency against ground truth (Paz et al. 2007, §III.C; docs/design.md §7).

The Normalized Estimation Error Squared of an estimate ``(x, P)`` of the true ``x*`` is
``D^2 = (x - x*)' P^-1 (x - x*)``. The estimate passes the chi-squared test when
``D^2 < chi2(r, 1 - alpha)``, ``r = dim x``, and the paper's consistency index is
``CI = D^2 / chi2(r, 1 - alpha)``: below 1 consistent, above 1 optimistic.

The chi-squared quantile is the library's own (no scipy at run time), the one the gates use:
Newton's method on the regularized incomplete gamma function, started from the
Wilson–Hilferty approximation and kept inside a bisection bracket (``cpp/core/chi_square.cpp``).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from . import _core

__all__ = ["nees", "chi2_threshold", "consistency_index"]


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


def chi2_threshold(dof: float, alpha: float = 0.05) -> float:
    """The ``1 - alpha`` quantile of the chi-squared distribution with ``dof`` degrees of
    freedom: the NEES bound of Paz et al. 2007, §III.C (``alpha = 0.05`` there). The
    library's one implementation (``cpp/core/chi_square.cpp``, which the gates use), taking the
    upper tail itself so that a tiny ``alpha`` keeps its relative accuracy.

    Raises:
        ValueError: ``dof <= 0`` or ``alpha`` outside (0, 1).
    """
    dof = float(dof)
    alpha = float(alpha)
    if not (math.isfinite(dof) and dof > 0.0):
        raise ValueError(f"chi2_threshold: argument 'dof' must be > 0, got {dof}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"chi2_threshold: argument 'alpha' must lie in (0, 1), got {alpha}")
    return _core.chi2_upper_quantile(dof, alpha)


def consistency_index(
    x_est, P, x_true, angle_indices: Sequence[int] = (), alpha: float = 0.05
) -> float:
    """The consistency index ``CI = D^2 / chi2(r, 1 - alpha)`` of Paz et al. 2007, §III.C
    (``D^2`` the :func:`nees`, ``r = dim x``): below 1 the estimate is consistent with the
    ground truth, above 1 it is optimistic."""
    error_dim = len(_error(x_est, x_true, angle_indices))
    return nees(x_est, P, x_true, angle_indices) / chi2_threshold(error_dim, alpha)
