"""`dcslam run mrclam` and `dcslam montecarlo` as a user runs them: short runs, their files and
their summary, and the errors they give for bad input."""

import csv
import json
import subprocess
import sys

import numpy as np

import dcslam
from dcslam import io
from dcslam.metrics import map_trajectory
from dcslam.pipeline import SlamPipeline


def run(*args):
    return subprocess.run([sys.executable, "-m", "dcslam", *args], capture_output=True, text=True, timeout=300)


def test_run_mrclam_writes_the_victoria_park_outputs_plus_the_truth(tmp_path):
    out = run("run", "mrclam", "--robot", "1", "--filter", "both", "--max-steps", "300", "--output", str(tmp_path),
              "--no-progress", "--checkpoint-every", "50")
    assert out.returncode == 0, out.stdout + out.stderr
    for label in ("ATE vs truth", "landmark RMS vs truth", "final map NEES", "robot NEES over time"):
        assert label in out.stdout
    assert "pairwise precision" not in out.stdout  # known ids: nothing to score
    data = dcslam.datasets.mrclam()
    t_true, true_poses = io.read_tum(tmp_path / "trajectory_true.tum")
    np.testing.assert_allclose(t_true, data.t[:300])
    np.testing.assert_allclose(true_poses[:, :2], data.poses_true[1:301, :2], atol=1e-6)
    for name in ("ekf", "dc"):
        t, _ = io.read_tum(tmp_path / f"trajectory_{name}.tum")
        np.testing.assert_allclose(t, t_true)
        stats = json.loads((tmp_path / f"stats_{name}.json").read_text())
        scores = stats["truth_scores"]
        assert scores["landmarks_scored"] > 0 and scores["ate_m"] >= 0 and scores["map_dof"] > 0
        assert (tmp_path / f"map_{name}.png").stat().st_size > 10_000
        # the map-refit trajectory: the library's map_trajectory of the same (deterministic)
        # run, read back from both files, and near the truth
        result = SlamPipeline(data.steps, data.slam_config(), filter=name, max_steps=300).run()
        times, poses = map_trajectory(result, data.steps)
        t_map, map_poses = io.read_tum(tmp_path / f"trajectory_map_{name}.tum")
        assert len(t_map) > 5 and np.all(np.isin(t_map, t_true))  # few steps see 3 landmarks here
        np.testing.assert_allclose(t_map, times, atol=1e-9)
        np.testing.assert_allclose(map_poses, poses, atol=1e-8)
        np.testing.assert_allclose(io.read_kitti(tmp_path / f"trajectory_map_{name}.kitti"), poses, atol=1e-8)
        truth_at = true_poses[np.searchsorted(t_true, t_map)]
        assert np.median(np.hypot(*(map_poses[:, :2] - truth_at[:, :2]).T)) < 0.5


def test_run_mrclam_without_ids_scores_the_association(tmp_path):
    out = run("run", "mrclam", "--filter", "ekf", "--association", "jcbb", "--max-steps", "200",
              "--output", str(tmp_path), "--no-plots", "--no-progress")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "pairwise precision / recall" in out.stdout and "features per landmark" in out.stdout
    stats = json.loads((tmp_path / "stats_ekf.json").read_text())
    assert stats["config"]["association"] == "jcbb"
    assert 0 <= stats["truth_scores"]["pairwise_precision"] <= 1


def test_run_mrclam_refuses_bad_robots(tmp_path):
    out = run("run", "mrclam", "--robot", "7", "--output", str(tmp_path))
    assert out.returncode == 2 and "robot" in out.stdout and "1-5" in out.stdout
    out = run("run", "mrclam", "--robot", "2", "--output", str(tmp_path))
    assert out.returncode == 2 and "not bundled" in out.stdout
    out = run("run", "mrclam", "--robot", "2", "--data-dir", str(tmp_path), "--output", str(tmp_path))
    assert out.returncode == 2 and "newRobot2_Groundtruth.txt" in out.stdout and "no such file" in out.stdout


def test_montecarlo_writes_the_table_the_curves_and_the_figure(tmp_path):
    out = run("montecarlo", "--scenario", "straight", "--runs", "2", "--steps", "30", "--every", "10",
              "--workers", "1", "--output", str(tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Monte Carlo: 4 runs, local" in out.stdout
    with open(tmp_path / "runs.csv") as table:
        rows = list(csv.DictReader(table))
    assert len(rows) == 4 and {r["filter"] for r in rows} == {"ekf", "dc"} and {r["seed"] for r in rows} == {"0", "1"}
    curves = np.load(tmp_path / "curves.npz")
    np.testing.assert_array_equal(curves["straight/dc/1/step"], [10, 20, 30])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 4 and summary["workers"] == 1
    assert (tmp_path / "fig4_straight.png").stat().st_size > 10_000


def test_montecarlo_refuses_an_unknown_scenario(tmp_path):
    out = run("montecarlo", "--scenario", "circle", "--runs", "1", "--output", str(tmp_path))
    assert out.returncode == 2 and "unknown scenario 'circle'" in out.stdout
