"""plot_map on any Estimate: a user's own loop draws its map, ellipses, robot and the truth;
bad input is a ValueError naming it. The drawn ellipses are checked against the closed-form
eigenvalues of each 2x2 block, not against plots.landmark_ellipses."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.collections import EllipseCollection

import dcslam
from dcslam import plots
from dcslam.pipeline import SlamPipeline
from dcslam.plots import CHI2_2DOF_95, plot_map


@pytest.fixture(scope="module")
def own_loop():
    """A simulated loop run by hand: predict, update and pose per step, then estimate()."""
    sim = dcslam.simulate("loop", steps=80, seed=2, side_steps=10)
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="known", join_association="known", local_map_features=10))
    poses = [slam.pose()]
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R, step.true_ids)
        poses.append(slam.pose())
    return sim, slam.estimate(), np.array(poses)


@pytest.fixture
def figures(monkeypatch):
    """The figures plot_map draws, kept open to be inspected."""
    kept = []
    monkeypatch.setattr(plots.plt, "close", kept.append)
    return kept


def lines_by_label(axes):
    handles, labels = axes.get_legend_handles_labels()
    return dict(zip(labels, handles))


def axis_lengths(block):
    """Full major and minor axes of the 95 % ellipse of a 2x2 covariance, in closed form."""
    a, b, c = block[0, 0], block[0, 1], block[1, 1]
    middle, radius = (a + c) / 2, math.hypot((a - c) / 2, b)
    return 2 * math.sqrt(CHI2_2DOF_95 * (middle + radius)), 2 * math.sqrt(CHI2_2DOF_95 * max(middle - radius, 0.0))


def test_an_estimate_from_a_users_loop_is_drawn_with_its_ellipses_robot_and_truth(tmp_path, own_loop, figures):
    sim, estimate, poses = own_loop
    n = len(estimate.landmarks)
    assert n > 10
    plot_map(estimate, tmp_path / "map.png", truth=sim, trajectory=poses)
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (axes,) = figures[0].axes
    landmark_ellipses, robot_ellipse = [c for c in axes.collections if isinstance(c, EllipseCollection)]
    np.testing.assert_array_equal(landmark_ellipses.get_offsets(), estimate.landmarks)
    # matplotlib keeps half axes
    expected = np.array([axis_lengths(estimate.covariance[3 + 2 * i:5 + 2 * i, 3 + 2 * i:5 + 2 * i])
                         for i in range(n)])
    np.testing.assert_allclose(2 * landmark_ellipses._widths, expected[:, 0], rtol=1e-9)
    np.testing.assert_allclose(2 * landmark_ellipses._heights, expected[:, 1], rtol=1e-9)
    np.testing.assert_array_equal(robot_ellipse.get_offsets(), estimate.robot[None, :2])
    np.testing.assert_allclose(2 * robot_ellipse._widths, [axis_lengths(estimate.covariance[:2, :2])[0]], rtol=1e-9)

    drawn = lines_by_label(axes)
    np.testing.assert_array_equal(drawn[f"landmarks ({n}) with 95 % ellipses"].get_xydata(), estimate.landmarks)
    np.testing.assert_array_equal(drawn["robot trajectory"].get_xydata(), poses[:, :2])
    np.testing.assert_array_equal(drawn["robot with its 95 % ellipse"].get_xydata(), estimate.robot[None, :2])
    np.testing.assert_array_equal(drawn["true trajectory"].get_xydata(), sim.poses[:, :2])
    np.testing.assert_array_equal(drawn[f"true landmarks ({len(sim.landmarks)})"].get_xydata(), sim.landmarks)
    assert axes.get_title() == f"Map: {n} landmarks"


def test_an_estimate_alone_and_a_loaded_map_are_drawn(tmp_path, own_loop, figures):
    _, estimate, _ = own_loop
    dcslam.io.save_map(tmp_path / "map.npz", estimate)
    plot_map(dcslam.io.load_map(tmp_path / "map.npz"), tmp_path / "map.png", title="mine")
    (axes,) = figures[0].axes
    assert axes.get_title() == "mine"
    assert not any("true" in label or "trajectory" in label for label in lines_by_label(axes))


def test_a_pipeline_result_cuts_a_datasets_truth_to_its_steps(tmp_path, figures):
    sim = dcslam.simulate("straight", steps=60, seed=1)
    config = dcslam.SlamConfig(association="known", join_association="known", local_map_features=10)
    result = SlamPipeline(sim.steps, config, filter="ekf", max_steps=40).run()
    # a dataset with ground truth names it poses_true / landmarks_true (dcslam.datasets.mrclam)
    truth = SimpleNamespace(poses_true=sim.poses, landmarks_true=sim.landmarks)
    plot_map(result, tmp_path / "map.png", truth=truth)
    drawn = lines_by_label(figures[0].axes[0])
    np.testing.assert_array_equal(drawn["true trajectory"].get_xydata(), sim.poses[:41, :2])
    np.testing.assert_array_equal(drawn["robot trajectory"].get_xydata(), result.trajectory[:, :2])
    assert figures[0].axes[0].get_title() == f"EKF SLAM: 40 steps, {result.map_size} landmarks"


def test_bad_input_is_a_value_error_naming_it(tmp_path, own_loop):
    sim, estimate, poses = own_loop
    path = tmp_path / "map.png"
    cases = [
        (dict(estimate={"robot": estimate.robot}), "estimate must be a dcslam.Estimate"),
        (dict(truth=object()), "truth must be a Simulation"),
        (dict(truth=sim, truth_poses=sim.poses), "not both"),
        (dict(trajectory=poses[:, 0]), r"trajectory must have shape \(k, 2\+\)"),
        (dict(trajectory=np.where(np.arange(len(poses))[:, None] == 3, np.nan, poses)), "trajectory contains a non-finite"),
        (dict(trajectory=[["a", "b"]]), "trajectory must be an array of numbers"),
        (dict(truth_landmarks=np.zeros(4)), "truth landmarks must have shape"),
        (dict(estimate=dcslam.Estimate(robot=np.zeros(3), landmarks=np.zeros((2, 2)), landmark_ids=np.arange(2),
                                       covariance=np.eye(5))), r"covariance must be \(7, 7\) for 2 landmarks"),
    ]
    for overrides, message in cases:
        arguments = {"estimate": estimate, "path": path, **overrides}
        with pytest.raises(ValueError, match=message):
            plot_map(**arguments)
    assert not path.exists()  # refused before drawing
