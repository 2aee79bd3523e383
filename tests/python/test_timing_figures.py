"""studies/timing_figures.py on small hand-made dcslam_bench outputs."""

import json

import numpy as np
import pytest

from script_loader import load_script


@pytest.fixture(scope="module")
def timing_figures():
    return load_script("studies/timing_figures.py")


def bench_run(filter_name, step_seconds, features=10, total_seconds=None):
    return {"steps": len(step_seconds), "filter": filter_name, "features": features,
            "total_seconds": sum(step_seconds) if total_seconds is None else total_seconds,
            "step_seconds": step_seconds, "step_features": [features] * len(step_seconds), "joins": []}


def test_fit_recovers_power_laws(timing_figures, tmp_path):
    sizes = [100, 200, 400, 800]
    runs = []
    for n in sizes:
        runs.append(bench_run("ekf", [1e-9 * n**3], features=n))
        runs.append(bench_run("dc", [1e-7 * n**2], features=n))
    path = tmp_path / "scaling.json"
    path.write_text(json.dumps({"command": "scaling", "args": {}, "runs": runs}))
    exponents = timing_figures.fitted_exponents(path)
    assert exponents["ekf"] == pytest.approx(3.0)
    assert exponents["dc"] == pytest.approx(2.0)


def test_sim_files_are_sorted_by_trajectory_and_join_mode(timing_figures, tmp_path):
    immediate = tmp_path / "a.json"
    immediate.write_text(json.dumps({"command": "sim", "args": {"trajectory": "loop", "joins": "immediate"},
                                     "runs": [bench_run("ekf", [0.1, 0.2]), bench_run("dc", [0.01, 0.3], total_seconds=0.5)]}))
    amortized = tmp_path / "b.json"  # no --trajectory/--joins: the bench's defaults, snail and amortized
    amortized.write_text(json.dumps({"command": "sim", "args": {}, "runs": [bench_run("dc", [0.02, 0.03])]}))
    curves = timing_figures.load_sim_runs([immediate, amortized])
    assert sorted(curves) == ["loop", "snail"]
    assert sorted(curves["loop"]) == ["dc_immediate", "ekf"]
    np.testing.assert_allclose(curves["loop"]["dc_immediate"].step_seconds, [0.01, 0.3])
    assert curves["loop"]["dc_immediate"].total_seconds == 0.5
    assert list(curves["snail"]) == ["dc_amortized"]
    timing_figures.plot_timings(curves, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 0


def test_scaling_file_is_refused_as_sim_input(timing_figures, tmp_path):
    path = tmp_path / "scaling.json"
    path.write_text(json.dumps({"command": "scaling", "args": {}, "runs": []}))
    with pytest.raises(ValueError, match="not a 'dcslam_bench sim' output"):
        timing_figures.load_sim_runs([path])
