"""The batch least-squares oracle: residual Jacobians, the filters' model, and Gauss-Newton on
small synthetic problems with a known answer."""

import types

import numpy as np
import pytest

from dcslam import geometry

from oracles import batch_least_squares as oracle

OFFSET = (3.78, 0.5, 0.0)


def synthetic(steps=60, landmarks=12, noise=True, seed=1, fixed_first=True):
    """A robot driving a circle of radius 10 m past a ring of trees, seen with the VP
    sensor offset. Returns (steps, ids per step, true poses (N, 3), true landmarks {id: (2,)})."""
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-np.pi, np.pi, landmarks)
    radii = rng.uniform(4.0, 16.0, landmarks)
    truth = {100 + j: np.array([radii[j] * np.cos(a), 10.0 + radii[j] * np.sin(a)]) for j, a in enumerate(angles)}
    Q = np.diag([0.05**2, 0.03**2, 0.01**2])
    R = np.diag([0.2**2, 0.016**2])
    pose = np.zeros(3)
    out, ids_out, poses = [], [], []
    for k in range(steps):
        if k == 0 and fixed_first:  # Victoria Park's first step: no motion, Q = 0
            u_true, u, Q_k = np.zeros(3), np.zeros(3), np.zeros((3, 3))
        else:
            u_true, Q_k = np.array([1.0, 0.0, 0.1]), Q
            u = u_true + (rng.multivariate_normal(np.zeros(3), Q) if noise else 0.0)
        pose = np.asarray(geometry.compose(pose, u_true))
        poses.append(pose)
        z, ids = [], []
        for landmark, position in truth.items():
            z_true = np.asarray(geometry.observe("range_bearing", OFFSET, pose, position))
            if z_true[0] < 25.0 and abs(z_true[1]) < np.pi / 2:
                measured = z_true + (rng.multivariate_normal(np.zeros(2), R) if noise else 0.0)
                measured[1] = geometry.wrap_angle(measured[1])
                z.append(measured)
                ids.append(landmark)
        z = np.array(z).reshape(-1, 2)
        out.append(types.SimpleNamespace(u=u, Q=Q_k, z=z, R=np.repeat(R[None], len(z), axis=0)))
        ids_out.append(np.array(ids, dtype=np.int64))
    return out, ids_out, np.array(poses), truth


def dead_reckoning(steps):
    pose, poses = np.zeros(3), []
    for step in steps:
        pose = np.asarray(geometry.compose(pose, step.u))
        poses.append(pose)
    return np.array(poses)


def test_residual_jacobians_match_central_differences():
    assert oracle.check_jacobians(OFFSET, trials=30, seed=3) < 1e-6


def test_residuals_follow_the_filters_model():
    previous, u = np.array([1.0, -2.0, 0.4]), np.array([0.8, 0.1, -0.05])
    current = np.asarray(geometry.compose(previous, u))
    np.testing.assert_allclose(oracle.odometry_residual(previous, current, u), 0.0, atol=1e-12)
    # The angle of the odometry residual is wrapped: a full turn is no error.
    turned = current + np.array([0.0, 0.0, 2 * np.pi])
    np.testing.assert_allclose(oracle.odometry_residual(previous, turned, u), 0.0, atol=1e-9)
    robot, landmark = np.array([2.0, 1.0, 3.0]), np.array([-10.0, 3.0])
    z = np.asarray(geometry.observe("range_bearing", OFFSET, robot, landmark))
    np.testing.assert_allclose(oracle.observation_residual(OFFSET, robot, landmark, z), 0.0, atol=1e-12)


def test_sparse_jacobian_matches_finite_differences_of_all_residuals():
    steps, ids, poses, truth = synthetic(steps=25, landmarks=6, seed=4)
    problem = oracle.build_problem(steps, ids, OFFSET, list(truth))
    assert problem.pose_column[0] == -1 and problem.pose_column[1] == -1  # Q = 0 first step: fixed
    rng = np.random.default_rng(0)
    start = {i: p + rng.normal(0, 0.5, 2) for i, p in truth.items()}
    state = oracle.initial_state(problem, poses + rng.normal(0, 0.1, poses.shape), start)
    residuals, J = oracle.linearize(problem, state)
    np.testing.assert_allclose(oracle.linearize(problem, state, jacobian=False), residuals)
    assert J.shape == (problem.residual_count, problem.dimension)
    numeric = np.empty(J.shape)
    eps = 1e-6
    for column in range(problem.dimension):
        plus, minus = state.copy(), state.copy()
        plus[column] += eps
        minus[column] -= eps
        numeric[:, column] = (oracle.linearize(problem, plus, jacobian=False)
                              - oracle.linearize(problem, minus, jacobian=False)) / (2 * eps)
    np.testing.assert_allclose(J.toarray(), numeric, atol=1e-5)


def test_noise_free_problem_recovers_the_truth():
    steps, ids, poses, truth = synthetic(noise=False, seed=2)
    rng = np.random.default_rng(5)
    start_poses = poses + rng.normal(0, [0.5, 0.5, 0.05], poses.shape)
    start_landmarks = {i: p + rng.normal(0, 1.0, 2) for i, p in truth.items()}
    result = oracle.batch_optimum(steps, ids, OFFSET, start_poses, start_landmarks, tolerance=1e-9)
    assert result.converged
    assert result.chi2 < 1e-12 < result.chi2_initial
    np.testing.assert_allclose(result.poses, poses, atol=1e-7)
    for i, p in truth.items():
        np.testing.assert_allclose(result.landmarks[i], p, atol=1e-7)


def test_gauss_newton_reaches_a_stationary_point_of_a_noisy_problem():
    steps, ids, poses, truth = synthetic(steps=80, landmarks=15, seed=7)
    start_poses = dead_reckoning(steps)
    start_landmarks = {i: p + np.array([0.8, -0.6]) for i, p in truth.items()}
    result = oracle.batch_optimum(steps, ids, OFFSET, start_poses, start_landmarks, tolerance=1e-10)
    assert result.converged and result.iterations < 20
    assert result.chi2 < result.chi2_initial
    assert all(later <= earlier * (1 + 1e-12) for earlier, later in zip(result.history, result.history[1:]))
    # Independent oracle: the gradient J'r of the cost, rebuilt at the returned answer, vanishes,
    # and no small move along random directions lowers the cost.
    problem = oracle.build_problem(steps, ids, OFFSET, list(truth))
    state = oracle.initial_state(problem, result.poses, result.landmarks)
    residuals, J = oracle.linearize(problem, state)
    assert residuals @ residuals == pytest.approx(result.chi2, rel=1e-9)
    start_residuals, start_J = oracle.linearize(problem, oracle.initial_state(problem, start_poses, start_landmarks))
    gradient, start_gradient = J.T @ residuals, start_J.T @ start_residuals
    assert np.max(np.abs(gradient)) < 1e-9 * np.max(np.abs(start_gradient))
    assert np.max(np.abs(gradient)) == pytest.approx(result.gradient_norm, abs=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(5):
        moved = state + 1e-4 * rng.normal(size=state.shape)
        moved_residuals = oracle.linearize(problem, moved, jacobian=False)
        assert moved_residuals @ moved_residuals >= result.chi2
    # Correct noise model: chi2 about its degrees of freedom, and the answer near the truth.
    assert result.degrees_of_freedom == problem.residual_count - problem.dimension
    assert 0.7 < result.chi2_per_dof < 1.3
    errors = [np.linalg.norm(result.landmarks[i] - p) for i, p in truth.items()]
    assert max(errors) < 0.5


def test_measurements_without_a_landmark_are_left_out():
    steps, ids, poses, truth = synthetic(steps=30, landmarks=8, seed=3)
    ids = [i.copy() for i in ids]
    ids[5][:] = -1                         # rejected
    ids[6][0] = 999                        # an id not in the map
    problem = oracle.build_problem(steps, ids, OFFSET, list(truth))
    assert problem.dropped_measurements == 1
    used = sum(int(np.sum(i >= 0)) for i in ids) - 1
    assert len(problem.observation_pose) == used
