import json
import subprocess
import sys
from pathlib import Path

import numpy as np

import dcslam
from dcslam import io


def run(*args):
    return subprocess.run([sys.executable, "-m", "dcslam", *args], capture_output=True, text=True, timeout=120)


def test_version_and_help():
    out = run("--version")
    assert out.returncode == 0 and dcslam.__version__ in out.stdout
    out = run("--help")
    assert out.returncode == 0 and "selfcheck" in out.stdout


def test_selfcheck_passes():
    out = run("selfcheck", "--samples", "20")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "compose" in out.stdout and "FAIL" not in out.stdout


ISAM_FILE = Path(__file__).parent.parent / "data" / "isam_victoria_park.txt.gz"


def test_run_isam_writes_outputs(tmp_path):
    out = run("run", "isam", str(ISAM_FILE), "--max-steps", "300", "--filter", "both", "--output", str(tmp_path),
              "--local-map-features", "10", "--join-iterations", "3", "--keep-local-map-poses", "--no-progress")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "features in the final map" in out.stdout and str(tmp_path) in out.stdout
    dc_stats = json.loads((tmp_path / "stats_dc.json").read_text())
    assert dc_stats["config"]["join_iterations"] == 3
    assert dc_stats["config"]["keep_local_map_poses"] is True
    assert dc_stats["joins"] and all(j["iterations"] <= 3 for j in dc_stats["joins"])
    for name in ("ekf", "dc"):
        t, poses = io.read_tum(tmp_path / f"trajectory_{name}.tum")
        np.testing.assert_array_equal(t, np.arange(300))
        np.testing.assert_allclose(io.read_kitti(tmp_path / f"trajectory_{name}.kitti")[:, :2], poses[:, :2], atol=1e-6)
        estimate = io.load_map(tmp_path / f"map_{name}.npz")
        n = len(estimate.landmarks)
        assert n > 0 and estimate.covariance.shape == (3 + 2 * n, 3 + 2 * n)
        m = len(estimate.past_poses)  # the EKF keeps no past poses; D&C one per local map closed
        assert (m > 0) == (name == "dc") and estimate.joint_covariance.shape == (3 + 2 * n + 3 * m,) * 2
        assert np.all(np.diff(estimate.past_pose_ids) > 0) and np.all(estimate.past_pose_ids < 300)
        stats = json.loads((tmp_path / f"stats_{name}.json").read_text())
        assert stats["summary"]["steps"] == 300 and stats["summary"]["map_size"] == n
        assert (tmp_path / f"map_{name}.png").stat().st_size > 0
    dc_document = json.loads((tmp_path / "stats_dc.json").read_text())
    assert dc_document["summary"]["joins"] > 0
    # The final fold's joins, the last of which the summary table reports.
    last = dc_document["fold_joins"][-1]
    assert last["index"] == len(dc_document["fold_joins"]) - 1 > 0
    [row] = [line for line in out.stdout.splitlines() if "fold's last join" in line]
    assert row.split("│")[-2].strip() == f"{last['pairings']} / {last['overlap']}"
    assert json.loads((tmp_path / "stats_ekf.json").read_text())["fold_joins"] == []
    assert (tmp_path / "timing.png").stat().st_size > 0
    # This file's steps see at most 2 landmarks each: no step gets a map-refit pose, and the
    # map-refit files are written without poses (test_cli_mrclam.py has them with poses).
    for name in ("ekf", "dc"):
        assert io.read_tum(tmp_path / f"trajectory_map_{name}.tum")[1].shape == (0, 3)
        assert io.read_kitti(tmp_path / f"trajectory_map_{name}.kitti").shape == (0, 3)


def test_run_victoria_park_localises_its_online_trajectory_on_request(tmp_path):
    out = run("run", "victoria-park", "--max-steps", "1500", "--output", str(tmp_path), "--no-plots", "--no-progress",
              "--online-localisation-sigma", "5")
    assert out.returncode == 0, out.stdout + out.stderr
    stats = json.loads((tmp_path / "stats_dc.json").read_text())
    assert stats["config"]["online_localisation_sigma"] == 5.0
    assert stats["counters"]["online_localisations"] > 0
    out = run("run", "victoria-park", "--max-steps", "10", "--output", str(tmp_path), "--no-progress",
              "--online-localisation-sigma", "0")
    assert out.returncode != 0
    assert "error: SlamConfig.online_localisation_sigma: must be > 0" in out.stdout + out.stderr


def test_run_isam_refuses_a_bad_file(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("ODOMETRY 0 1 oops\n")
    out = run("run", "isam", str(bad), "--output", str(tmp_path / "out"), "--no-progress")
    assert out.returncode == 2 and "error" in out.stdout and "bad.txt" in out.stdout


def test_run_victoria_park_refuses_known_association(tmp_path):
    out = run("run", "victoria-park", "--association", "known", "--output", str(tmp_path), "--no-progress")
    assert out.returncode == 2 and "no landmark ids" in out.stdout


def test_an_unwritable_output_fails_at_once_in_one_line(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    out = run("run", "isam", str(ISAM_FILE), "--output", str(blocker / "results"), "--no-progress")
    assert out.returncode == 2
    assert "Traceback" not in out.stdout + out.stderr
    assert "features in the final map" not in out.stdout  # refused before running
    message = " ".join(out.stdout.split())
    assert "cannot write to --output" in message and "a_file" in message


def test_selfcheck_refuses_samples_that_check_nothing():
    for samples in ("-5", "0"):
        out = run("selfcheck", "--samples", samples)
        assert out.returncode != 0 and "Traceback" not in out.stdout + out.stderr
        assert "--samples" in out.stdout + out.stderr


def test_a_broken_file_is_one_short_line(tmp_path):
    path = tmp_path / "graph.txt"
    path.write_bytes(b"ODOMETRY 0 1 " + b"9" * 60000 + b"\xff 0 0 1e-4 0 0 4e-6 0 4e-6\n")
    out = run("run", "isam", str(path), "--output", str(tmp_path / "out"), "--no-progress")
    assert out.returncode == 2 and "Traceback" not in out.stdout + out.stderr
    assert "graph.txt:1: field 'dx'" in " ".join(out.stdout.split()) and len(out.stdout) < 600


def test_run_isam_relinearises_the_tree_on_request(tmp_path):
    """--tree-relinearisation reaches the filter: the passes run and stop by the tolerance,
    and the final map is the optimum's (with an unreachable tolerance, one pass only)."""
    args = ("run", "isam", str(ISAM_FILE), "--max-steps", "2000", "--filter", "dc", "--no-plots", "--no-progress")
    out = run(*args, "--output", str(tmp_path / "stopped"), "--tree-relinearisation", "5")
    assert out.returncode == 0, out.stdout + out.stderr
    stopped = json.loads((tmp_path / "stopped" / "stats_dc.json").read_text())
    assert stopped["config"]["tree_relinearisation"] == 5
    counters = stopped["counters"]
    assert 2 <= counters["relinearisation_passes"] < 5
    assert abs(counters["relinearisation_objective"] - counters["relinearisation_predicted_objective"]) <= 3.85
    out = run(*args, "--output", str(tmp_path / "one"), "--tree-relinearisation", "5",
              "--tree-relinearisation-tolerance", "1e9")
    assert out.returncode == 0, out.stdout + out.stderr
    one = json.loads((tmp_path / "one" / "stats_dc.json").read_text())
    assert one["config"]["tree_relinearisation_tolerance"] == 1e9
    assert one["counters"]["relinearisation_passes"] == 1
    assert one["counters"]["relinearisation_objective"] > counters["relinearisation_objective"]
    out = run(*args, "--output", str(tmp_path / "bad"), "--tree-relinearisation", "101")
    assert out.returncode != 0 and "--tree-relinearisation" in out.stdout + out.stderr
