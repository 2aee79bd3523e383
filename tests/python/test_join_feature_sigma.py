"""The default join_feature_sigma (0.01 m) against the simulator's truth.

D&C's joins test a feature of one local map against a feature of another with the two maps'
covariances. A local map is an EKF that linearises the range-bearing model at its own
estimate, so its features carry an error its covariance does not hold; the default is the
per-feature term that makes the difference of two features of one local map consistent with
its covariance (docs/data_association.md, "A feature error at the joins"). The oracle: the
simulator's true landmarks, in the local map's base frame (the true pose it starts from).
"""

import numpy as np
import pytest

import dcslam

STEPS_PER_LOCAL_MAP = 5  # about what 30 features take on the revisit scenes


def relative_errors(seed: int, scene: str = "loop_both_ways"):
    """(error, covariance) of f_a - f_b for every two clean features of every local map
    (also run by studies/local_map_consistency.py)."""
    sim = dcslam.revisit_scenario(scene, seed)
    pairs = []
    for start in range(0, len(sim.steps) - STEPS_PER_LOCAL_MAP, STEPS_PER_LOCAL_MAP):
        slam = dcslam.EkfSlam(dcslam.SlamConfig(association="jcbb", seed=seed))
        returned, truth = [], []
        for step in sim.steps[start:start + STEPS_PER_LOCAL_MAP]:
            slam.predict(step.u, step.Q)
            returned.append(slam.update(step.z, step.R))
            truth.append(step.true_ids)
        estimate = slam.estimate()
        ids, true_ids = slam.resolve(np.concatenate(returned)), np.concatenate(truth)
        base = sim.poses[start]
        c, s = np.cos(base[2]), np.sin(base[2])
        to_base = np.array([[c, s], [-s, c]])
        features = []
        for k, feature in enumerate(estimate.landmark_ids):
            landmarks = true_ids[ids == feature]
            # Seen at least twice, every sighting of one landmark: no association error.
            if len(landmarks) < 2 or landmarks[0] < 0 or np.any(landmarks != landmarks[0]):
                continue
            error = estimate.landmarks[k] - to_base @ (sim.landmarks[landmarks[0]] - base[:2])
            features.append((3 + 2 * k, error))
        P = estimate.covariance
        for a in range(len(features)):
            for b in range(a + 1, len(features)):
                (i, error_a), (j, error_b) = features[a], features[b]
                S = P[i:i + 2, i:i + 2] + P[j:j + 2, j:j + 2] - P[i:i + 2, j:j + 2] - P[j:j + 2, i:i + 2]
                pairs.append((error_a - error_b, S))
    return pairs


@pytest.fixture(scope="module")
def pairs():
    return relative_errors(0) + relative_errors(1)


def mean_nees(pairs, sigma: float) -> float:
    return float(np.mean([d @ np.linalg.solve(S + 2 * sigma**2 * np.eye(2), d) for d, S in pairs]))


def test_the_local_maps_are_overconfident_without_it(pairs):
    assert len(pairs) > 10000
    # Consistent: 2 (two dof). Measured 2.14 over seeds 0-4 (studies/local_map_consistency.py).
    assert mean_nees(pairs, 0.0) > 2.08


def test_the_default_makes_them_consistent(pairs):
    sigma = dcslam.SlamConfig().join_feature_sigma
    assert sigma == 0.01
    assert 1.9 < mean_nees(pairs, sigma) < 2.08
    # Twice the default would make them clearly under-confident: the term is not a free margin.
    assert mean_nees(pairs, 2 * sigma) < 1.75
