"""NEES, chi-squared quantile and consistency index (Paz et al. 2007, §III.C)."""

import math

import numpy as np
import pytest

import dcslam
from dcslam.consistency import chi2_threshold, consistency_index, nees

scipy_stats = pytest.importorskip("scipy.stats")


@pytest.mark.parametrize("dof", [1, 2, 3, 5, 10, 33, 203, 1000, 40003, 0.5])
@pytest.mark.parametrize("alpha", [0.05, 0.01, 0.5, 0.95, 1e-9, 1 - 1e-9])
def test_chi2_threshold_matches_scipy(dof, alpha):
    expected = scipy_stats.chi2.isf(alpha, dof)
    assert chi2_threshold(dof, alpha) == pytest.approx(expected, rel=1e-11)


def test_chi2_threshold_hand_values():
    # Closed forms: chi2(2) is exponential with mean 2; chi2(1) is a squared standard normal.
    for alpha in (0.05, 0.2, 0.9):
        assert chi2_threshold(2, alpha) == pytest.approx(-2 * math.log(alpha), rel=1e-13)
    assert chi2_threshold(1, 0.05) == pytest.approx(1.959963984540054**2, rel=1e-13)
    assert chi2_threshold(3) == pytest.approx(7.814727903251178, rel=1e-13)  # default alpha


@pytest.mark.parametrize("dof, alpha, name", [(0, 0.05, "dof"), (-1, 0.05, "dof"),
                                              (3, 0.0, "alpha"), (3, 1.0, "alpha")])
def test_chi2_threshold_rejects_bad_arguments(dof, alpha, name):
    with pytest.raises(ValueError, match=name):
        chi2_threshold(dof, alpha)


def test_nees_hand_cases():
    assert nees([1.0, 2.0], np.diag([1.0, 4.0]), [0.0, 0.0]) == pytest.approx(1.0 + 1.0)
    P = np.array([[2.0, 1.0], [1.0, 2.0]])
    e = np.array([1.0, -1.0])
    assert nees(e, P, [0, 0]) == pytest.approx(e @ np.linalg.solve(P, e))
    # The heading alone, as scalars.
    assert nees(0.3, 0.01, 0.1) == pytest.approx(4.0)


def test_nees_wraps_angle_differences():
    P = np.diag([1.0, 1.0, 0.01])
    x_est = [0.0, 0.0, math.pi - 0.05]
    x_true = [0.0, 0.0, -math.pi + 0.05]  # 0.1 rad away across the cut, not 2 pi - 0.1
    assert nees(x_est, P, x_true, angle_indices=(2,)) == pytest.approx(1.0)
    assert nees(x_est, P, x_true) > 1000


def test_nees_is_chi2_distributed_for_a_consistent_estimator():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    samples = rng.multivariate_normal(np.zeros(4), P, size=20000)
    values = np.array([nees(x, P, np.zeros(4)) for x in samples])
    assert values.mean() == pytest.approx(4.0, rel=0.03)
    assert np.mean(values > chi2_threshold(4)) == pytest.approx(0.05, abs=0.006)


def test_consistency_index():
    P = np.diag([0.04, 0.04, 0.001])
    x_true = np.array([1.0, 2.0, 0.5])
    x_est = x_true + np.array([0.2, -0.1, 0.02])
    expected = (0.2**2 / 0.04 + 0.1**2 / 0.04 + 0.02**2 / 0.001) / scipy_stats.chi2.ppf(0.95, 3)
    assert consistency_index(x_est, P, x_true, angle_indices=(2,)) == pytest.approx(expected)
    assert consistency_index(x_est, P, x_true, alpha=0.01) < expected
    assert dcslam.consistency_index is consistency_index


@pytest.mark.parametrize("args, name", [
    (([0.0, 0.0], np.eye(3), [0.0, 0.0]), "P"),
    (([0.0, 0.0], np.eye(2), [0.0, 0.0, 0.0]), "x_true"),
    (([0.0, 0.0], np.diag([1.0, -1.0]), [0.0, 0.0]), "positive definite"),
    (([0.0, np.nan], np.eye(2), [0.0, 0.0]), "x_est"),
])
def test_nees_rejects_bad_arguments(args, name):
    with pytest.raises(ValueError, match=name):
        nees(*args)
