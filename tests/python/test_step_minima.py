"""benchmarks/step_minima.py against hand-made dcslam_bench JSON runs: the per-run ratios and
the worst of the element-wise per-step minima, and a clear error for a run without both
filters' steps."""

import json
import subprocess
import sys

import pytest

from script_loader import ROOT

SCRIPT = ROOT / "benchmarks" / "step_minima.py"


def write_run(path, ekf_steps, dc_steps):
    runs = [dict(filter=name, total_seconds=float(sum(steps)), step_seconds=steps)
            for name, steps in (("ekf", ekf_steps), ("dc", dc_steps))]
    path.write_text(json.dumps(dict(command="vp", args={}, runs=runs)))
    return path


def run(*paths):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, paths)], capture_output=True, text=True)


def test_the_worst_of_the_per_step_minima_ignores_a_spike_of_one_run(tmp_path):
    # D&C's step 1 spikes in run a only, step 2 is slow in both: its minimum is the worst.
    a = write_run(tmp_path / "a.json", [0.010, 0.020, 0.030], [0.001, 0.009, 0.004])
    b = write_run(tmp_path / "b.json", [0.012, 0.018, 0.040], [0.001, 0.002, 0.005])
    result = run(a, b)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    # run a: total ratio 0.060 / 0.014, worst ratio 30 / 9 ms.
    assert lines[1].split()[1:] == ["0.060", "0.014", "4.3", "30.00", "9.000", "3.3"]
    assert "worst EKF 30.000 ms, worst D&C 4.000 ms (step 2), ratio 7.5" in lines[-1]


def test_a_run_without_both_filters_is_refused_by_name(tmp_path):
    only_dc = tmp_path / "dc.json"
    only_dc.write_text(json.dumps(dict(runs=[dict(filter="dc", total_seconds=1.0, step_seconds=[1.0])])))
    result = run(only_dc)
    assert result.returncode != 0
    assert "dc.json: no step_seconds for ekf" in result.stderr


@pytest.mark.parametrize("content", ["not json", ""])
def test_a_file_that_is_not_json_is_refused_by_name(tmp_path, content):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    result = run(bad)
    assert result.returncode != 0
    assert "bad.json: not a dcslam_bench JSON file" in result.stderr
