"""SlamPipeline, output writers and plots, on short synthetic runs."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

import dcslam
from dcslam import geometry as g
from dcslam import io
from dcslam.pipeline import SlamPipeline
from dcslam.plots import CHI2_2DOF_95, landmark_blocks, landmark_ellipses, plot_map, plot_timing


def rotation(phi):
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def corridor_steps(steps=120, seed=3):
    """A robot driving forward and gently turning past a double row of landmarks; point
    observations, known ids, a timestamp per step (0.25 s apart)."""
    rng = np.random.default_rng(seed)
    xs = np.arange(-2.0, 70.0, 2.0)
    landmarks = np.concatenate([np.stack([xs, np.full_like(xs, 3.0)], 1), np.stack([xs + 1, np.full_like(xs, -3.0)], 1)])
    u_true = np.array([0.5, 0.0, 0.004])
    Q = np.diag([0.02**2, 0.01**2, 0.002**2])
    R = np.diag([0.05**2, 0.05**2])
    pose = np.zeros(3)
    out = []
    for k in range(steps):
        pose = g.compose(pose, u_true)
        z, ids = [], []
        for i, landmark in enumerate(landmarks):
            point = g.observe("point", np.zeros(3), pose, landmark)
            if 0.5 < np.linalg.norm(point) < 6.0:
                z.append(point + rng.multivariate_normal(np.zeros(2), R))
                ids.append(i)
        out.append(SimpleNamespace(
            t=10.0 + 0.25 * k, u=u_true + rng.multivariate_normal(np.zeros(3), Q), Q=Q,
            z=np.array(z).reshape(-1, 2), R=R, landmark_ids=np.array(ids, dtype=np.int64)))
    return out


@pytest.fixture(scope="module")
def corridor():
    return corridor_steps()


@pytest.fixture(scope="module")
def config():
    return dcslam.SlamConfig(observation="point", association="known", join_association="known",
                             local_map_features=8)


@pytest.fixture(scope="module")
def results(corridor, config):
    return {name: SlamPipeline(corridor, config, filter=name).run() for name in ("ekf", "dc")}


def test_pipeline_records_every_step(results, corridor):
    measurements = sum(len(s.z) for s in corridor)
    for result in results.values():
        assert result.steps == len(corridor)
        assert result.trajectory.shape == (len(corridor), 3)
        np.testing.assert_allclose(result.timestamps, [s.t for s in corridor])
        assert len(result.step_seconds) == len(corridor) and np.all(result.step_seconds > 0)
        counts = result.association_counts()
        assert counts["measurements"] == measurements
        assert counts["paired"] + counts["new"] + counts["rejected"] == measurements
        assert counts["rejected"] == 0
        assert result.map_size == len(np.unique(np.concatenate([s.landmark_ids for s in corridor])))
        assert result.total_seconds >= result.worst_step_seconds > 0
        # The last pose of the run is the final estimate's robot; for D&C only up to the
        # final joins, which correct the robot through the features they merge.
        tolerance = 1e-9 if result.filter_name == "ekf" else 0.2
        np.testing.assert_allclose(result.trajectory[-1], result.estimate.robot, atol=tolerance)
        summary = result.summary()
        assert summary["steps"] == len(corridor) and summary["map_size"] == result.map_size


def test_dc_joins_and_agrees_with_ekf(results):
    ekf, dc = results["ekf"], results["dc"]
    assert ekf.joins == [] and len(dc.joins) >= 3
    assert dc.association_counts()["join_pairings"] > 0
    order = np.argsort(dc.estimate.landmark_ids)
    np.testing.assert_array_equal(dc.estimate.landmark_ids[order], np.sort(ekf.estimate.landmark_ids))
    ekf_order = np.argsort(ekf.estimate.landmark_ids)
    np.testing.assert_allclose(dc.estimate.landmarks[order], ekf.estimate.landmarks[ekf_order], atol=0.02)


def test_pipeline_options(corridor, config):
    pipeline = SlamPipeline(corridor, config, filter="ekf", max_steps=7)
    short = pipeline.run()
    assert short.steps == 7 and short.stats.step_seconds.shape == (7,)
    with pytest.raises(RuntimeError):
        pipeline.run()
    untimed = [SimpleNamespace(u=s.u, Q=s.Q, z=s.z, R=s.R, landmark_ids=s.landmark_ids) for s in corridor[:4]]
    np.testing.assert_array_equal(SlamPipeline(untimed, config, filter="ekf").run().timestamps, np.arange(4))
    with pytest.raises(ValueError, match="filter"):
        SlamPipeline(corridor, config, filter="ukf")
    with pytest.raises(ValueError, match="max_steps"):
        SlamPipeline(corridor, config, max_steps=-1)
    with pytest.raises(ValueError):
        SlamPipeline(corridor, dcslam.SlamConfig(association="psychic"))


def test_tum_round_trip_and_format(tmp_path):
    t = np.linspace(0, 5, 11)
    poses = np.column_stack([np.arange(11.0), -np.arange(11.0) / 2, np.linspace(-3.1, 3.1, 11)])
    path = tmp_path / "trajectory.tum"
    io.write_tum(path, t, poses)
    rows = np.loadtxt(path)
    assert rows.shape == (11, 8)
    np.testing.assert_array_equal(rows[:, 3], 0.0)                 # z
    np.testing.assert_array_equal(rows[:, 4:6], 0.0)               # qx, qy: a pure yaw
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-9)
    read_t, read_poses = io.read_tum(path)
    np.testing.assert_allclose(read_t, t, atol=1e-9)
    np.testing.assert_allclose(read_poses[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (read_poses[:, 2] - poses[:, 2]))), 0.0, atol=1e-8)
    with pytest.raises(ValueError, match="timestamps"):
        io.write_tum(path, t[:3], poses)


def test_kitti_round_trip_and_se3_embedding(tmp_path):
    poses = np.array([[1.0, 2.0, 0.3], [-4.0, 0.5, -2.0], [0.0, 0.0, math.pi]])
    path = tmp_path / "trajectory.kitti"
    io.write_kitti(path, poses)
    rows = np.loadtxt(path)
    assert rows.shape == (3, 12)
    matrices = rows.reshape(3, 3, 4)
    for matrix, pose in zip(matrices, poses):
        np.testing.assert_allclose(matrix[:2, :2], rotation(pose[2]), atol=1e-9)
        np.testing.assert_allclose(matrix[:, 3], [pose[0], pose[1], 0.0], atol=1e-9)
        np.testing.assert_array_equal(matrix[2, :3], [0.0, 0.0, 1.0])
        np.testing.assert_array_equal(matrix[:2, 2], 0.0)
    read = io.read_kitti(path)
    np.testing.assert_allclose(read[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(read[:, 2] - poses[:, 2]), 1.0, atol=1e-12)


def test_map_and_stats_files(tmp_path, results):
    result = results["dc"]
    io.save_map(tmp_path / "map.npz", result.estimate)
    loaded = io.load_map(tmp_path / "map.npz")
    for field in ("robot", "landmarks", "landmark_ids", "covariance"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(result.estimate, field))
    io.write_stats_json(tmp_path / "stats.json", result, {"dataset": "corridor"})
    document = json.loads((tmp_path / "stats.json").read_text())
    assert document["dataset"] == "corridor"
    assert document["summary"]["map_size"] == result.map_size
    assert document["summary"]["joins"] == len(result.joins) == len(document["joins"])
    assert len(document["per_step"]["seconds"]) == result.steps
    assert document["config"]["local_map_features"] == 8


def test_landmark_ellipses_axes():
    blocks = np.array([[[4.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 9.0]]])
    widths, heights, angles = landmark_ellipses(blocks)
    np.testing.assert_allclose(widths, 2 * np.sqrt(CHI2_2DOF_95 * np.array([4.0, 9.0])))
    np.testing.assert_allclose(heights, 2 * np.sqrt(CHI2_2DOF_95 * np.array([1.0, 1.0])))
    np.testing.assert_allclose(np.abs(np.cos(np.radians(angles))), [1.0, 0.0], atol=1e-12)
    covariance = np.zeros((7, 7))
    covariance[3:5, 3:5], covariance[5:7, 5:7] = blocks
    np.testing.assert_array_equal(landmark_blocks(covariance, 2), blocks)


def test_map_plot_draws_the_past_poses_of_a_run_that_keeps_them(tmp_path, corridor, config, monkeypatch):
    import dataclasses

    from dcslam import plots

    result = SlamPipeline(corridor, dataclasses.replace(config, keep_local_map_poses=True), filter="dc").run()
    past = result.estimate.past_poses
    assert len(past) >= 2
    figures = []
    monkeypatch.setattr(plots.plt, "close", figures.append)  # keep the figure to inspect it
    plot_map(result, tmp_path / "map.png")
    handles, labels = figures[0].axes[0].get_legend_handles_labels()
    drawn = handles[labels.index(f"robot at local-map boundaries ({len(past)})")]
    np.testing.assert_array_equal(drawn.get_xdata(), past[:, 0])
    np.testing.assert_array_equal(drawn.get_ydata(), past[:, 1])
    plain = SlamPipeline(corridor, config, filter="dc").run()
    assert plain.estimate.past_poses.shape == (0, 3)
    plot_map(plain, tmp_path / "plain.png")
    assert not any("local-map boundaries" in label for label in figures[1].axes[0].get_legend_handles_labels()[1])


def test_plots_write_pngs(tmp_path, results):
    plot_map(results["dc"], tmp_path / "map.png")
    plot_timing([results["ekf"], results["dc"]], tmp_path / "timing.png", title="corridor")
    plot_timing([results["ekf"]], tmp_path / "timing_ekf.png")
    for name in ("map.png", "timing.png", "timing_ekf.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
