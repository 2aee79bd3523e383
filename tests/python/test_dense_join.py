"""The dense join oracle on synthetic maps with a known answer, and the C++ D&C join against it
on a Victoria Park prefix."""

import dataclasses

import numpy as np
import pytest

from dcslam import datasets, geometry
from dcslam.pipeline import SlamPipeline

from oracles import join_inputs
from oracles.dense_join import (dense_join, join_constraints, landmarks_of, shared_pairs, split_costs,
                                stacked_difference, state_from_map)


def two_maps(rng, feature_variance, pose_error, noise=0.0):
    """Two maps of a ring of ten landmarks (ids 0-9) meeting on ids 3-6: m1 (ids 0-6) in the
    global frame ending at the true pose R1, m2 (ids 3-9) in R1's frame. m1's robot mean is
    off by ``pose_error`` (variance 4 m^2 and 0.1 rad^2); the features have variance
    ``feature_variance`` and mean error of standard deviation ``noise``.

    Returns (x1, P1, ids1, x2, P2, ids2, truth by id, true R1)."""
    angles = np.linspace(0.0, 2 * np.pi, 10, endpoint=False)
    truth = {i: np.array([30 + 15 * np.cos(a), 10 + 15 * np.sin(a)]) for i, a in enumerate(angles)}
    R1 = np.array([28.0, 6.0, 0.9])
    robot2 = np.array([5.0, -2.0, 0.3])   # the robot at the end of m2, in R1's frame
    ids1, ids2 = list(range(7)), list(range(3, 10))

    def covariance(size, robot):
        A = rng.normal(size=(size, size))
        P = feature_variance * (np.eye(size) + 0.2 * (A @ A.T) / size)  # correlated features
        P[:3, :] = P[:, :3] = 0.0
        P[:3, :3] = robot
        return P

    x1 = np.concatenate([R1 + pose_error] + [truth[i] + noise * rng.normal(size=2) for i in ids1])
    x2 = np.concatenate([robot2] + [np.asarray(geometry.inverse_transform_point(R1, truth[i]))
                                    + noise * rng.normal(size=2) for i in ids2])
    P1 = covariance(len(x1), np.diag([4.0, 4.0, 0.1]))
    P2 = covariance(len(x2), np.diag([0.5, 0.5, 0.01]))
    return x1, P1, ids1, x2, P2, ids2, truth, R1


def test_dense_join_recovers_the_truth_from_exact_maps():
    # m1's robot is 1.8 m and 0.25 rad off while both maps' features are exact and nearly
    # certain: the constrained MAP must put R1 where m2's shape fits m1's (a non-linear move).
    rng = np.random.default_rng(0)
    x1, P1, ids1, x2, P2, ids2, truth, R1 = two_maps(rng, 1e-10, np.array([1.5, -1.0, -0.25]))
    joined = dense_join(x1, P1, ids1, x2, P2, ids2, tolerance=1e-12)
    assert joined.converged and joined.iterations > 2
    np.testing.assert_allclose(joined.state[:3], R1, atol=1e-6)
    assert sorted(joined.features) == sorted(truth)
    for i, position in truth.items():
        np.testing.assert_allclose(joined.features[i], position, atol=1e-6)
    constraints, _ = join_constraints(joined.state, len(x1), shared_pairs(ids1, ids2))
    assert len(constraints) == 8 and np.max(np.abs(constraints)) < 1e-9
    # Without shared landmarks there is nothing to impose: the prior means come back.
    alone = dense_join(x1, P1, ids1, x2, P2, [100 + i for i in ids2])
    assert alone.iterations == 0 and alone.converged
    np.testing.assert_array_equal(alone.state, np.concatenate([x1, x2]))


def test_dense_join_meets_the_optimality_conditions_of_noisy_maps():
    rng = np.random.default_rng(1)
    x1, P1, ids1, x2, P2, ids2, _, _ = two_maps(rng, 0.05, np.array([0.8, 0.5, 0.1]), noise=0.3)
    joined = dense_join(x1, P1, ids1, x2, P2, ids2)
    assert joined.converged
    pairs = shared_pairs(ids1, ids2)
    assert [(ids1[i], ids2[j]) for i, j in pairs] == [(3, 3), (4, 4), (5, 5), (6, 6)]
    constraints, C = join_constraints(joined.state, len(x1), pairs)
    assert np.max(np.abs(constraints)) < 1e-9
    # Lagrange: the cost's gradient P0^-1 (x - x0) lies in the row space of dc/dx.
    P0 = np.block([[P1, np.zeros((len(x1), len(x2)))], [np.zeros((len(x2), len(x1))), P2]])
    difference = joined.state - np.concatenate([x1, x2])
    gradient = np.linalg.solve(P0, difference)
    multipliers = np.linalg.lstsq(C.T, gradient, rcond=None)[0]
    assert np.max(np.abs(C.T @ multipliers - gradient)) < 1e-8 * np.max(np.abs(gradient))
    costs = split_costs(joined.state, x1, P1, x2, P2)
    assert costs["total"] == pytest.approx(difference @ gradient, rel=1e-9)
    assert costs["m1"] > 0 and costs["m2"] > 0
    # From a perturbed start Gauss-Newton lands on the same answer.
    start = joined.state + 0.5 * rng.normal(size=len(difference))
    np.testing.assert_allclose(dense_join(x1, P1, ids1, x2, P2, ids2, initial=start).state, joined.state,
                               atol=1e-8)
    # The joined global map, moved back into the two frames, is the stacked solution.
    R1 = joined.state[:3]
    robot = geometry.compose(R1, joined.state[len(x1):len(x1) + 3])
    rebuilt = state_from_map(joined.features, R1, robot, ids1, ids2)
    np.testing.assert_allclose(stacked_difference(rebuilt, joined.state, len(x1)), 0.0, atol=1e-9)


def test_known_id_replay_and_split():
    steps = datasets.victoria_park().steps[:3]
    ids = [np.full(len(s.z), -1, dtype=np.int64) for s in steps]
    ids[1][:2] = [7, 8]
    ids[2][:1] = [8]
    known = join_inputs.known_steps(steps, ids)
    assert [len(s.z) for s in known] == [0, 2, 1] and len(known[1].R) == 2
    np.testing.assert_array_equal(known[1].landmark_ids, [7, 8])
    np.testing.assert_array_equal(known[1].z, np.asarray(steps[1].z)[:2])
    assert join_inputs.first_seen([s.landmark_ids for s in known]) == {7: 1, 8: 1}
    assert join_inputs.reproducible_split(known, 3) == 2


def largest_distance(first, second):
    """The largest distance between the same landmark in two maps with the same ids."""
    return max(float(np.linalg.norm(first[i] - second[i])) for i in second)


@pytest.fixture(scope="module")
def victoria_park_prefix():
    """The first 1200 steps with D&C's resolved ids as known ids, and the known-id config."""
    vp = datasets.victoria_park()
    steps = vp.steps[:1200]
    config = vp.slam_config(seed=0)
    unknown = SlamPipeline(steps, config, filter="dc").run()
    known = dataclasses.replace(config, association="known", join_association="known")
    return join_inputs.known_steps(steps, unknown.measurement_ids), known


def test_dc_join_equals_the_dense_join_on_victoria_park(victoria_park_prefix):
    steps, config = victoria_park_prefix
    split = join_inputs.reproducible_split(steps, 750)
    x1, P1, ids1, _ = join_inputs.ekf_map(steps[:split], config)
    x2, P2, ids2, _ = join_inputs.ekf_map(steps[split:], config)
    joined = dense_join(x1, P1, ids1, x2, P2, ids2)
    assert joined.converged and len(shared_pairs(ids1, ids2)) > 20
    dc = SlamPipeline(steps, dataclasses.replace(config, local_map_features=len(ids1), keep_local_map_poses=True),
                      filter="dc").run().estimate
    np.testing.assert_array_equal(dc.past_pose_ids, [split])
    dc_map = {int(i): p for i, p in zip(dc.landmark_ids, dc.landmarks)}
    assert sorted(dc_map) == sorted(joined.features)
    assert largest_distance(dc_map, joined.features) < 1e-6
    # Not vacuous: the join moved the maps well beyond that (m2 placed at its prior means).
    unjoined = {**{i: np.asarray(geometry.transform_point(x1[:3], p)) for i, p in landmarks_of(x2, ids2).items()},
                **landmarks_of(x1, ids1)}
    assert largest_distance(unjoined, joined.features) > 0.1
