"""dcslam.evaluation against a truth: ATE, NEES over time, the map's scores and score_run, each
against a hand computation or a direct formula."""

import math

import numpy as np
import pytest

import dcslam
from dcslam import evaluation
from dcslam.slam import Estimate


def rotate(points, angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.asarray(points, dtype=float) @ np.array([[c, -s], [s, c]]).T


def test_ate_of_a_hand_case():
    truth = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)
    trajectory = truth + [[0, 0, 0], [3, 4, 0], [0, 0, 1]]   # errors 0, 5 and 0 m
    ate = evaluation.absolute_trajectory_error(trajectory, truth)
    assert ate.alignment == "first_pose"
    assert ate.rmse == pytest.approx(math.sqrt(25 / 3))
    assert ate.mean == pytest.approx(5 / 3) and ate.median == 0 and ate.max == 5
    np.testing.assert_allclose(ate.errors, [0, 5, 0])


def test_rigid_ate_removes_a_rotation_and_translation_but_first_pose_does_not():
    truth = np.column_stack([np.linspace(0, 5, 20), np.sin(np.linspace(0, 3, 20)), np.zeros(20)])
    moved = np.column_stack([rotate(truth[:, :2], 0.3) + [2.0, -1.0], truth[:, 2]])
    assert evaluation.absolute_trajectory_error(moved, truth, "rigid").rmse < 1e-12
    first_pose = evaluation.absolute_trajectory_error(moved, truth, "first_pose")
    assert first_pose.errors[0] == pytest.approx(math.hypot(2.0, -1.0))


def test_ate_refuses_bad_input():
    with pytest.raises(ValueError, match="alignment"):
        evaluation.absolute_trajectory_error([[0, 0]], [[0, 0]], "umeyama")
    with pytest.raises(ValueError, match="'trajectory' has 2 poses, 'truth' 1"):
        evaluation.absolute_trajectory_error([[0, 0], [1, 1]], [[0, 0]])
    with pytest.raises(ValueError, match=r"'truth' must have shape"):
        evaluation.absolute_trajectory_error([[0, 0]], [[0, 0, 0, 0]])
    with pytest.raises(ValueError, match="non-finite"):
        evaluation.absolute_trajectory_error([[0, np.nan]], [[0, 0]])


def test_nees_series_against_the_direct_formula():
    estimates = np.array([[1.0, 2.0, 0.1], [0.0, 0.0, math.pi - 0.05]])
    truth = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -math.pi + 0.05]])   # heading error 0.1 across the wrap
    covariances = np.array([np.diag([1.0, 4.0, 0.01]), np.diag([1.0, 1.0, 0.04])])
    series = evaluation.nees_series(estimates, covariances, truth)
    np.testing.assert_allclose(series.nees, [1 + 1 + 1, 0.01 / 0.04], atol=1e-9)
    assert series.dof == 3 and series.bound == pytest.approx(7.814727903251178, rel=1e-9)
    np.testing.assert_allclose(series.consistency_index, series.nees / 7.814727903251178, rtol=1e-9)
    heading = evaluation.nees_series(estimates, covariances, truth, components=(2,))
    np.testing.assert_allclose(heading.nees, [0.01 / 0.01, 0.01 / 0.04], atol=1e-9)
    assert heading.bound == pytest.approx(3.841458820694124, rel=1e-9)
    assert heading.share_consistent == 1.0 and heading.mean_nees == pytest.approx(0.625)


def test_nees_series_with_a_correlated_covariance():
    P = np.array([[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 1.0]])
    e = np.array([1.0, -1.0, 0.5])
    # inverse of [[2, 1], [1, 2]] is [[2, -1], [-1, 2]] / 3: e' P^-1 e = (2 + 2 + 2) / 3 + 0.25
    series = evaluation.nees_series([e], [P], [np.zeros(3)])
    assert series.nees[0] == pytest.approx(2.25)


def test_nees_series_refuses_bad_input():
    with pytest.raises(ValueError, match="need estimates"):
        evaluation.nees_series(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="components"):
        evaluation.nees_series(np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), components=(3,))
    with pytest.raises(ValueError, match="positive definite"):
        evaluation.nees_series(np.zeros((1, 3)), np.zeros((1, 3, 3)), np.zeros((1, 3)))


def estimate_of(landmarks, ids, covariance):
    landmarks = np.asarray(landmarks, dtype=float)
    full = np.eye(3 + 2 * len(landmarks))
    full[3:, 3:] = covariance
    return Estimate(robot=np.zeros(3), landmarks=landmarks, landmark_ids=np.asarray(ids, dtype=np.int64),
                    covariance=full)


def test_map_scores_of_a_hand_case():
    truth = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]])
    covariance = np.diag([1.0, 1.0, 4.0, 4.0])
    estimate = estimate_of([[1.0, 0.0], [4.0, 2.0]], [10, 11], covariance)
    scores = evaluation.map_scores(estimate, truth, [10, 11, 12])
    assert scores.landmarks == 2 and scores.missing == 1 and scores.dof == 4
    assert scores.rms == pytest.approx(math.sqrt((1 + 4) / 2)) and scores.max_error == 2
    assert scores.nees == pytest.approx(1.0 + 4.0 / 4.0)
    assert scores.consistency_index == pytest.approx(2.0 / 9.487729036781154, rel=1e-9)


def test_map_scores_through_a_feature_to_landmark_table():
    truth = np.array([[0.0, 0.0], [4.0, 0.0]])
    estimate = estimate_of([[0.5, 0.0], [4.0, 0.0], [9.0, 9.0]], [70, 71, 72], np.eye(6))
    # Features 70 and 71 stand for landmark 1 (a duplicate), 72 for nothing known.
    scores = evaluation.map_scores(estimate, truth, [0, 1], feature_landmark=([70, 71, 72], [1, 1, -1]))
    assert scores.landmarks == 2 and scores.missing == 1
    assert scores.rms == pytest.approx(math.sqrt(3.5**2 / 2))


def test_rigid_map_scores_remove_a_rotation():
    truth = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0], [5.0, 5.0]])
    estimate = estimate_of(rotate(truth, 0.2) + [1.0, 1.0], [0, 1, 2, 3], 0.01 * np.eye(8))
    assert evaluation.map_scores(estimate, truth, [0, 1, 2, 3], alignment="rigid").rms < 1e-12
    assert evaluation.map_scores(estimate, truth, [0, 1, 2, 3]).rms > 1.0


def test_map_scores_with_nothing_to_score_are_nan():
    estimate = estimate_of([[1.0, 1.0]], [5], np.eye(2))
    scores = evaluation.map_scores(estimate, [[0.0, 0.0]], [0])
    assert scores.landmarks == 0 and scores.missing == 1 and math.isnan(scores.rms)


def test_score_run_on_a_simulation_uses_the_filter_s_own_numbers():
    sim = dcslam.simulate("loop", steps=60, seed=2)
    cfg = dcslam.SlamConfig(association="known", join_association="known", local_map_features=10)
    result = dcslam.SlamPipeline(sim.steps, cfg, filter="dc", checkpoint_every=20).run()
    scores = evaluation.score_run(result, sim.poses, sim.landmarks, np.arange(len(sim.landmarks)))
    np.testing.assert_array_equal(result.checkpoints.steps, [20, 40, 60])
    # The last checkpoint is the final estimate's robot.
    np.testing.assert_allclose(result.checkpoints.robot[-1], result.estimate.robot, atol=1e-9)
    direct = dcslam.nees(result.estimate.robot, result.estimate.covariance[:3, :3], sim.poses[60], angle_indices=(2,))
    assert scores.robot.nees == pytest.approx(direct) and scores.robot_nees.nees[-1] == pytest.approx(direct)
    errors = np.linalg.norm(result.trajectory[:, :2] - sim.poses[1:61, :2], axis=1)
    assert scores.ate.rmse == pytest.approx(np.sqrt(np.mean(errors**2)))
    at_checkpoints = np.linalg.norm(result.checkpoints.robot[:, :2] - sim.poses[[20, 40, 60], :2], axis=1)
    assert scores.ate_checkpoints.rmse == pytest.approx(np.sqrt(np.mean(at_checkpoints**2)))
    seen = result.estimate.landmark_ids
    landmark_errors = np.linalg.norm(result.estimate.landmarks - sim.landmarks[seen], axis=1)
    assert scores.map.rms == pytest.approx(np.sqrt(np.mean(landmark_errors**2)))
    assert scores.map.landmarks == len(seen) and scores.association is None


def test_score_run_scores_the_association_of_a_run_without_ids():
    sim = dcslam.simulate("loop", steps=60, seed=2)
    result = dcslam.SlamPipeline(sim.steps, dcslam.SlamConfig(association="jcbb"), filter="ekf").run()
    scores = evaluation.score_run(result, sim.poses, sim.landmarks, np.arange(len(sim.landmarks)), sim.true_ids)
    direct = evaluation.association_scores(sim.true_ids, np.concatenate(result.measurement_ids))
    assert scores.association == direct
    assert scores.map.landmarks > 0 and scores.robot_nees is None


def test_score_run_refuses_a_short_truth():
    sim = dcslam.simulate("straight", steps=10, seed=0)
    result = dcslam.SlamPipeline(sim.steps, dcslam.SlamConfig(association="known")).run()
    with pytest.raises(ValueError, match="'poses_true' has 5 poses for a run of 10 steps"):
        evaluation.score_run(result, sim.poses[:5], sim.landmarks, np.arange(len(sim.landmarks)))
