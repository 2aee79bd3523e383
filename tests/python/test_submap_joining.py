"""The submap-joining oracle (``oracles/submap_joining.py``, used by
``studies/revisit_join_linearisation.py``) on local maps made from a known truth: where every
local map measures the truth exactly, the optimum is the truth whatever the covariances, and
from a perturbed start Gauss-Newton finds it."""

import numpy as np

from oracles import submap_joining


def _between(a, b):
    c, s = np.cos(a[2]), np.sin(a[2])
    d = np.array([[c, s], [-s, c]]) @ (b[:2] - a[:2])
    return np.array([d[0], d[1], submap_joining.wrap(b[2] - a[2])])


def _point_in(a, p):
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([[c, s], [-s, c]]) @ (p - a[:2])


def test_exact_local_maps_give_the_truth_from_a_perturbed_start():
    rng = np.random.default_rng(4)
    poses = [np.zeros(3)]
    for _ in range(4):
        poses.append(poses[-1] + np.array([3.0 * np.cos(poses[-1][2]), 3.0 * np.sin(poses[-1][2]), 0.5]))
    features = {i: rng.uniform(-5, 10, size=2) for i in range(12)}
    local_maps = []
    for k in range(4):  # local map k: base poses[k], robot poses[k + 1], four features shared with the next
        ids = [i for i in features if 3 * k <= i < 3 * k + 6]
        x = np.concatenate([_between(poses[k], poses[k + 1])] + [_point_in(poses[k], features[i]) for i in ids])
        A = rng.normal(size=(len(x), len(x)))
        local_maps.append(submap_joining.LocalMap(x, A @ A.T + 0.1 * np.eye(len(x)), ids))
    start = {i: p + rng.normal(scale=0.3, size=2) for i, p in features.items()}
    boundaries = np.array(poses[1:4]) + rng.normal(scale=0.1, size=(3, 3))
    solution = submap_joining.solve(local_maps, start, boundaries, poses[4] + 0.1)
    assert solution.iterations < 30
    np.testing.assert_allclose(solution.boundaries, np.array(poses[1:4]), atol=1e-8)
    np.testing.assert_allclose(solution.robot, poses[4], atol=1e-8)
    for i, p in features.items():
        np.testing.assert_allclose(solution.features[i], p, atol=1e-8)
