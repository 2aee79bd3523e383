"""A run stopped, saved and resumed ends bitwise as the run never stopped (the oracle: that
same run, uninterrupted): SlamPipeline's progress in the library, `dcslam run --checkpoint
/ --stop-after / --resume` on the command line, across processes; a checkpoint that is
missing, damaged or of another run is one line and a non-zero exit."""

import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dcslam
from dcslam import io
from dcslam.pipeline import SlamPipeline

from test_pipeline import corridor_steps

# MR.CLAM: its steps see enough landmarks for map-refit poses, and --checkpoint-every takes
# robot estimates, so every output a run keeps across the stop is compared.
RUN = ("run", "mrclam", "--max-steps", "150", "--filter", "both", "--local-map-features", "10",
       "--checkpoint-every", "20", "--no-plots", "--no-progress")
# The refusals need no outputs: the iSAM file loads in a tenth of MR.CLAM's time.
ISAM_RUN = ("run", "isam", str(Path(__file__).parent.parent / "data" / "isam_victoria_park.txt.gz"),
            "--max-steps", "100", "--filter", "both", "--local-map-features", "10", "--no-plots", "--no-progress")


def run(*args):
    return subprocess.run([sys.executable, "-m", "dcslam", *args], capture_output=True, text=True, timeout=300)


def assert_same_result(resumed, straight):
    np.testing.assert_array_equal(resumed.trajectory, straight.trajectory)
    np.testing.assert_array_equal(resumed.timestamps, straight.timestamps)
    for a, b in zip(resumed.measurement_ids, straight.measurement_ids, strict=True):
        np.testing.assert_array_equal(a, b)
    for field in ("robot", "landmarks", "landmark_ids", "joint_covariance"):
        np.testing.assert_array_equal(getattr(resumed.estimate, field), getattr(straight.estimate, field))
    for field in ("steps", "robot", "covariance"):
        np.testing.assert_array_equal(getattr(resumed.checkpoints, field), getattr(straight.checkpoints, field))
    np.testing.assert_array_equal(resumed.stats.num_features, straight.stats.num_features)
    assert len(resumed.stats.step_seconds) == len(straight.stats.step_seconds)


@pytest.mark.parametrize("filter_name", ["ekf", "dc"])
def test_a_pipeline_resumed_from_its_pickled_progress_ends_as_the_straight_run(filter_name):
    steps = corridor_steps(steps=160)
    config = dcslam.SlamConfig(observation="point", association="known", join_association="known",
                               local_map_features=8)

    def pipeline(**options):
        return SlamPipeline(steps, config, filter=filter_name, checkpoint_every=25, **options)

    straight = pipeline().run()
    saves = []
    first = pipeline()
    progress = first.run_steps(97, save=lambda p: saves.append(pickle.dumps(p)), save_every=30)
    assert progress.steps_done == 97 and [pickle.loads(s).steps_done for s in saves] == [30, 60, 90, 97]
    resumed = pipeline(resume=pickle.loads(saves[-1])).run()
    assert_same_result(resumed, straight)
    assert resumed.wall_seconds >= progress.wall_seconds
    # an earlier save resumes as well
    assert_same_result(pipeline(resume=pickle.loads(saves[1])).run(), straight)


def test_a_pipeline_refuses_the_progress_of_another_run():
    steps = corridor_steps(steps=30)
    config = dcslam.SlamConfig(observation="point", association="known", join_association="known",
                               local_map_features=8)
    progress = SlamPipeline(steps, config, filter="dc").run_steps(10)
    with pytest.raises(ValueError, match="its filter is 'dc', this run's 'ekf'"):
        SlamPipeline(steps, config, filter="ekf", resume=progress)
    with pytest.raises(ValueError, match="its number of steps is 30, this run's 20"):
        SlamPipeline(steps, config, filter="dc", max_steps=20, resume=progress)
    with pytest.raises(ValueError, match="its checkpoint_every is None, this run's 5"):
        SlamPipeline(steps, config, filter="dc", checkpoint_every=5, resume=progress)
    other = dcslam.SlamConfig(observation="point", association="known", join_association="known",
                              local_map_features=9)
    with pytest.raises(ValueError, match="its options local_map_features is 8, this run's 9"):
        SlamPipeline(steps, other, filter="dc", resume=progress)


def timing_free(stats):
    """A stats_<f>.json without the fields that are wall times."""
    stats["per_step"].pop("seconds")
    for key in ("total_seconds", "worst_step_seconds", "estimate_seconds", "wall_seconds"):
        stats["summary"].pop(key)
    for join in stats["joins"] + stats["fold_joins"]:
        for key in ("seconds", "seconds_association"):
            join.pop(key)
    stats["counters"] = {k: v for k, v in stats["counters"].items() if "seconds" not in k}
    return stats


def test_the_cli_stopped_and_resumed_in_new_processes_writes_the_straight_runs_outputs(tmp_path):
    straight, resumed, checkpoint = tmp_path / "straight", tmp_path / "resumed", tmp_path / "run.ckpt"
    out = run(*RUN, "--output", str(straight))
    assert out.returncode == 0, out.stdout + out.stderr
    out = run(*RUN, "--output", str(resumed), "--checkpoint", str(checkpoint), "--checkpoint-interval", "30",
              "--stop-after", "75")
    assert out.returncode == 0, out.stdout + out.stderr
    message = " ".join(out.stdout.split())
    assert "Stopped after 75 steps of ekf, 75 steps of dc" in message and "--resume" in message
    assert not list(resumed.glob("trajectory_*"))  # stopped: no outputs yet
    saved = io.read_run_checkpoint(checkpoint)["progress"]
    assert {name: pickle.loads(p).steps_done for name, p in saved.items()} == {"ekf": 75, "dc": 75}
    out = run(*RUN, "--output", str(resumed), "--resume", str(checkpoint), "--checkpoint", str(checkpoint))
    assert out.returncode == 0, out.stdout + out.stderr
    names = sorted(p.name for p in straight.iterdir())
    assert names == sorted(p.name for p in resumed.iterdir())
    for name in names:
        if name.endswith((".tum", ".kitti")):
            assert (resumed / name).read_bytes() == (straight / name).read_bytes(), name
        elif name.endswith(".npz"):
            with np.load(straight / name) as a, np.load(resumed / name) as b:
                assert sorted(a) == sorted(b)
                for key in a:
                    np.testing.assert_array_equal(a[key], b[key])
        elif name.endswith(".json"):
            assert timing_free(json.loads((resumed / name).read_text())) == \
                timing_free(json.loads((straight / name).read_text())), name
    # the checkpoint now holds the whole run: resuming it only takes the final estimates
    saved = io.read_run_checkpoint(checkpoint)["progress"]
    assert {name: pickle.loads(p).steps_done for name, p in saved.items()} == {"ekf": 150, "dc": 150}


def assert_one_line_error(out, *fragments):
    text = " ".join(out.stdout.split())
    assert out.returncode == 2 and "Traceback" not in out.stdout + out.stderr, out.stdout + out.stderr
    assert text.startswith("error:") and out.stdout.strip().count("\n") == 0, out.stdout
    for fragment in fragments:
        assert fragment in text, text


def test_a_missing_damaged_or_foreign_checkpoint_is_one_line(tmp_path):
    checkpoint = tmp_path / "run.ckpt"
    output = str(tmp_path / "out")
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--resume", str(checkpoint)),
                          "cannot read --resume", "run.ckpt", "No such file")
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--stop-after", "5"), "--stop-after needs --checkpoint")
    out = run(*ISAM_RUN, "--output", output, "--checkpoint", str(checkpoint), "--stop-after", "20")
    assert out.returncode == 0, out.stdout + out.stderr
    whole = checkpoint.read_bytes()
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--resume", str(checkpoint), "--local-map-features",
                              "12"), "is of another run: its local_map_features is 10, this run's 12")
    assert_one_line_error(run(*ISAM_RUN[:4], "50", *ISAM_RUN[5:], "--output", output, "--resume", str(checkpoint)),
                          "its max_steps is 100, this run's 50")
    damaged = tmp_path / "damaged.ckpt"
    damaged.write_bytes(whole[:len(whole) // 2])
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--resume", str(damaged)), "damaged checkpoint")
    flipped = bytearray(whole)
    flipped[len(whole) // 3] ^= 0x01  # one byte changed
    damaged.write_bytes(bytes(flipped))
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--resume", str(damaged)), "damaged checkpoint")
    damaged.write_bytes(b"ODOMETRY 0 1 0 0 0\n")
    assert_one_line_error(run(*ISAM_RUN, "--output", output, "--resume", str(damaged)), "not a dcslam checkpoint")
