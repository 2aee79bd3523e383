"""keep_local_map_poses: the D&C map keeps the robot pose at every local-map boundary
(docs/design.md §4.5), exposed as Estimate.past_poses, past_pose_ids and joint_covariance."""

import numpy as np
import pytest

import dcslam


def known_config(**values):
    return dcslam.SlamConfig(association="known", join_association="known", local_map_features=12, **values)


def boundary_steps(sim, local_map_features):
    """Steps after which a local map closes, by the rule itself: in "known" mode a local map
    holds every landmark seen since it opened and closes once it holds local_map_features."""
    seen, boundaries = set(), []
    for k, step in enumerate(sim.steps):
        seen.update(int(i) for i in step.true_ids if i >= 0)
        if len(seen) >= local_map_features:
            boundaries.append(k + 1)  # poses[k + 1]: after k + 1 predictions
            seen.clear()
    return boundaries


def test_default_config_keeps_no_past_poses():
    assert dcslam.SlamConfig().keep_local_map_poses is False
    sim = dcslam.simulate("loop", steps=80, seed=1)
    for slam in (dcslam.DCSlam(known_config()), dcslam.EkfSlam(known_config(keep_local_map_poses=True))):
        slam.run(sim.steps)
        est = slam.estimate()
        assert est.past_poses.shape == (0, 3) and est.past_poses.dtype == np.float64
        assert est.past_pose_ids.shape == (0,) and est.past_pose_ids.dtype == np.int64
        n = len(est.landmarks)
        assert est.covariance.shape == (3 + 2 * n, 3 + 2 * n)
        assert est.joint_covariance.shape == est.covariance.shape


@pytest.mark.parametrize("amortize, threaded", [(False, False), (True, False), (False, True)])
def test_past_poses_are_the_local_map_boundaries(amortize, threaded):
    sim = dcslam.simulate("loop", steps=150, seed=2)
    cfg = known_config(keep_local_map_poses=True, amortize=amortize, threaded_joins=threaded)
    slam = dcslam.DCSlam(cfg)
    slam.run(sim.steps)
    est = slam.estimate()
    expected = boundary_steps(sim, cfg.local_map_features)
    assert len(expected) > 4
    np.testing.assert_array_equal(est.past_pose_ids, expected)
    assert est.past_pose_ids.dtype == np.int64
    m, n = len(expected), len(est.landmarks)
    assert est.past_poses.shape == (m, 3) and est.past_poses.dtype == np.float64
    assert est.joint_covariance.shape == (3 + 2 * n + 3 * m, 3 + 2 * n + 3 * m)
    # docs/api.md's covariance is unchanged: the [robot, landmarks] block, a view of the joint one.
    assert est.covariance.shape == (3 + 2 * n, 3 + 2 * n)
    assert np.shares_memory(est.covariance, est.joint_covariance)
    np.testing.assert_array_equal(est.covariance, est.joint_covariance[: 3 + 2 * n, : 3 + 2 * n])
    np.testing.assert_allclose(est.joint_covariance, est.joint_covariance.T, atol=1e-12)
    assert np.linalg.eigvalsh(est.joint_covariance).min() > -1e-9
    # Ground truth: each past pose is within a few of its standard deviations of the true one.
    truth = sim.poses[est.past_pose_ids]
    blocks = 3 + 2 * n + 3 * np.arange(m)
    for q in range(m):
        error = est.past_poses[q] - truth[q]
        error[2] = (error[2] + np.pi) % (2 * np.pi) - np.pi
        P = est.joint_covariance[blocks[q] : blocks[q] + 3, blocks[q] : blocks[q] + 3]
        assert error @ np.linalg.solve(P, error) < 30.0
    # The same run without past poses gives the same map.
    plain = dcslam.DCSlam(known_config(amortize=amortize, threaded_joins=threaded))
    plain.run(sim.steps)
    other = plain.estimate()
    np.testing.assert_array_equal(other.landmark_ids, est.landmark_ids)
    np.testing.assert_allclose(other.landmarks, est.landmarks, rtol=0, atol=1e-9)
    np.testing.assert_allclose(other.covariance, est.covariance, rtol=0, atol=1e-9)


def test_config_round_trips_through_a_dict_and_saved_maps_keep_past_poses(tmp_path):
    cfg = known_config(keep_local_map_poses=True)
    assert dcslam.SlamConfig.from_dict(cfg.to_dict()) == cfg
    sim = dcslam.simulate("loop", steps=80, seed=1)
    slam = dcslam.DCSlam(cfg)
    slam.run(sim.steps)
    est = slam.estimate()
    assert len(est.past_poses) > 0
    from dcslam.io import load_map, save_map

    save_map(tmp_path / "map.npz", est)
    loaded = load_map(tmp_path / "map.npz")
    np.testing.assert_array_equal(loaded.past_poses, est.past_poses)
    np.testing.assert_array_equal(loaded.past_pose_ids, est.past_pose_ids)
    np.testing.assert_array_equal(loaded.joint_covariance, est.joint_covariance)
    np.testing.assert_array_equal(loaded.covariance, est.covariance)


def test_an_estimate_with_past_poses_needs_their_covariance():
    with pytest.raises(ValueError, match="joint_covariance"):
        dcslam.Estimate(robot=np.zeros(3), landmarks=np.zeros((0, 2)), landmark_ids=np.zeros(0, np.int64),
                        covariance=np.zeros((3, 3)), past_poses=np.zeros((1, 3)),
                        past_pose_ids=np.zeros(1, np.int64))
