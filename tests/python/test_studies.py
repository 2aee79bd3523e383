"""The studies' command lines (studies/), run as a user runs them: short runs on small inputs,
checking what they print and the JSON they write. Their numbers are not asserted here; the
solvers behind them are tested as oracles (test_batch_least_squares.py, test_dense_join.py),
and the clustering ceiling's oracle against the simulator's ids."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dcslam
import dcslam.evaluation

ROOT = Path(__file__).resolve().parents[2]


def run_study(script: str, *arguments, check: bool = True) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, str(ROOT / "studies" / script), *map(str, arguments)],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    if check:
        assert run.returncode == 0, run.stdout + run.stderr
    return run


def test_vp_batch_reference_on_a_victoria_park_prefix(tmp_path):
    out = tmp_path / "report.json"
    printed = run_study("vp_batch_reference.py", "--max-steps", 200, "--json", out).stdout
    assert "1. Each filter's map against the batch optimum" in printed
    saved = json.loads(out.read_text())
    assert saved["steps"] == 200
    for name in ("ekf", "dc"):
        f = saved["filters"][name]
        assert f["converged"] and f["chi2"] <= f["chi2_initial"]
        assert f["gradient_max"] < 1e-3
        assert f["batch_landmarks"] > 0
    assert saved["consensus"]["converged"]
    gps = saved["gps_rms"]
    assert all(value is not None and 0.0 < value < 10.0 for value in gps.values()), gps
    # No measurement is disputed on this prefix: D&C's associations without the disputed ones
    # are all of them, the same optimum (solved from another start, to the solver's tolerance).
    assert saved["association_difference"]["both_different"] == 0
    assert gps["dc batch without the disputed measurements"] == pytest.approx(gps["dc batch"], abs=1e-6)


def test_vp_join_linearisation_on_a_victoria_park_prefix(tmp_path):
    out = tmp_path / "report.json"
    printed = run_study("vp_join_linearisation.py", "--max-steps", 600, "--split", 300, "--json", out).stdout
    assert "(A) Same associations" in printed and "(B) One join at step 300" in printed
    saved = json.loads(out.read_text())
    assert saved["steps"] == 600 and saved["seed"] == 0
    same = saved["same_associations"]
    assert {"landmarks", "batch", "ekf", "dc", "bins", "local_maps", "large_joins"} <= set(same)
    assert same["batch"]["converged"] and same["ekf"]["count"] == same["dc"]["count"] == same["landmarks"]
    assert sum(row["dc"]["count"] for row in same["bins"]) == same["landmarks"]
    join = saved["one_join"]
    assert {"split", "m1_features", "m2_features", "pairs", "iterations", "converged", "join_vs_batch",
            "ekf_all_vs_batch", "dc", "costs", "m2_local"} <= set(join)
    assert join["split"] == 300 and join["converged"]
    assert {"join", "ekf_all", "join_from_ekf_all"} <= set(join["costs"])
    assert join["costs"]["join"]["total"] <= join["costs"]["ekf_all"]["total"]
    assert join["m2_local"]["batch"]["converged"]


def test_vp_online_relinearisation_on_a_victoria_park_prefix():
    printed = run_study("vp_online_relinearisation.py", "--max-steps", 600, "--every", 300).stdout
    rows = [line.split() for line in printed.splitlines() if line.strip()[:1].isdigit()]
    assert [int(row[0]) for row in rows] == [300, 600]
    assert all(len(row) == 12 for row in rows)
    assert "anytime robot (plain estimate()) beyond that ellipse at" in printed
    assert "of 2 sampled steps" in printed


def test_revisit_join_linearisation_on_small_loop_laps():
    printed = run_study("revisit_join_linearisation.py", "--scenario", "small_loop_laps", "--seed", 12,
                        "--min-features", 100, "--max-features", 200).stdout
    rows = [line.split() for line in printed.splitlines() if line.strip()[:1].isdigit()]
    # The two whole-lap joins (8 + 8 local maps); the subtrees' Gauss-Newton converged.
    assert [row[1] for row in rows] == ["8+8", "8+8"]
    assert all(int(row[-1]) < 40 for row in rows)


def test_mrclam_association_on_the_bundled_robot():
    printed = run_study("mrclam_association.py", "--robots", 1, "--settings", "0.99:0").stdout
    rows = [line.split() for line in printed.splitlines() if line.strip()[:1].isdigit()]
    assert [row[3] for row in rows] == ["EKF", "D&C"]
    for row in rows:  # precision and recall are shares, features per landmark at least one
        assert 0.0 <= float(row[4]) <= 1.0 and 0.0 <= float(row[5]) <= 1.0 and float(row[6]) >= 1.0


def bench_run(filter_name, step_seconds, features=10, total_seconds=None):
    """One run of a hand-made ``dcslam_bench`` JSON output."""
    return {"steps": len(step_seconds), "filter": filter_name, "features": features,
            "total_seconds": sum(step_seconds) if total_seconds is None else total_seconds,
            "step_seconds": step_seconds, "step_features": [features] * len(step_seconds), "joins": []}


def test_timing_figures_fits_power_laws(tmp_path):
    runs = []
    for n in (100, 200, 400, 800):
        runs.append(bench_run("ekf", [1e-9 * n**3], features=n))
        runs.append(bench_run("dc", [1e-7 * n**2], features=n))
    path = tmp_path / "scaling.json"
    path.write_text(json.dumps({"command": "scaling", "args": {}, "runs": runs}))
    printed = run_study("timing_figures.py", "--fit", path).stdout.splitlines()
    assert printed == ["ekf: total time ~ n^3.00 (n = final map features)",
                       "dc: total time ~ n^2.00 (n = final map features)"]


def test_timing_figures_sorts_sim_files_by_trajectory_and_join_mode(tmp_path):
    immediate = tmp_path / "a.json"
    immediate.write_text(json.dumps({"command": "sim", "args": {"trajectory": "loop", "joins": "immediate"},
                                     "runs": [bench_run("ekf", [0.1, 0.2]),
                                              bench_run("dc", [0.01, 0.3], total_seconds=0.5)]}))
    amortized = tmp_path / "b.json"  # no --trajectory/--joins: the bench's defaults, snail and amortized
    amortized.write_text(json.dumps({"command": "sim", "args": {}, "runs": [bench_run("dc", [0.02, 0.03])]}))
    figure = tmp_path / "fig.png"
    printed = run_study("timing_figures.py", "--json", immediate, amortized, "--png", figure).stdout.splitlines()
    assert printed[0] == ("loop: dc_immediate steps 0.310 s (total with final map 0.500 s), worst step 300.00 ms; "
                          "ekf steps 0.300 s (total with final map 0.300 s), worst step 200.00 ms")
    assert printed[1] == "snail: dc_amortized steps 0.050 s (total with final map 0.050 s), worst step 30.00 ms"
    assert figure.stat().st_size > 0


def test_timing_figures_refuses_a_scaling_file_as_sim_input(tmp_path):
    path = tmp_path / "scaling.json"
    path.write_text(json.dumps({"command": "scaling", "args": {}, "runs": []}))
    run = run_study("timing_figures.py", "--json", path, "--png", tmp_path / "fig.png", check=False)
    assert run.returncode != 0
    assert "not a 'dcslam_bench sim' output" in run.stderr



def test_paired_association_is_zero_for_no_change_and_sees_a_change(tmp_path):
    same, changed = tmp_path / "same.json", tmp_path / "changed.json"
    default_radius = dcslam.SlamConfig().merge_radius
    run_study("paired_association.py", "--seeds", 2, "--scenarios", "small_loop_laps",
              "--b", f"merge_radius={default_radius}", "--json", same)
    printed = run_study("paired_association.py", "--seeds", 2, "--scenarios", "small_loop_laps",
                        "--b", "merge_radius=0", "--json", changed).stdout
    assert "small_loop_laps" in printed
    assert "A: duplicated landmarks" in printed and "B: duplicated landmarks" in printed and "NEES ok" in printed
    runs = json.loads(same.read_text())["runs"]
    assert [run["seed"] for run in runs] == [0, 1]
    assert all(run["a"] == run["b"] for run in runs)  # the same seeds and simulations on both sides
    assert all(run["robot_a"] == run["robot_b"] for run in runs)
    saved = json.loads(changed.read_text())
    assert saved["b"]["merge_radius"] == 0 and saved["a"]["merge_radius"] == default_radius
    assert any(run["a"] != run["b"] for run in saved["runs"])
    assert run_study("paired_association.py", check=False).returncode != 0  # no --b: nothing to compare


def test_paired_association_pairs_each_rjc_draw(tmp_path):
    out = tmp_path / "draws.json"
    run_study("paired_association.py", "--seeds", 1, "--rjc-seeds", 2, "--scenarios", "small_loop_laps",
              "--b", "merge_radius=0", "--json", out)
    runs = json.loads(out.read_text())["runs"]
    assert [(run["seed"], run["config_seed"]) for run in runs] == [(0, 0), (0, 1000)]
    refused = run_study("paired_association.py", "--rjc-seeds", 0, "--b", "merge_radius=0", check=False)
    assert refused.returncode != 0 and "--rjc-seeds must be at least 1" in refused.stderr


def test_local_map_consistency_on_one_seed():
    printed = run_study("local_map_consistency.py", "--seeds", 1, "--sigmas", "0,0.01").stdout
    assert "loop_both_ways, seeds 0..0:" in printed
    assert "sigma 0.000 m: mean NEES" in printed and "sigma 0.010 m: mean NEES" in printed


def test_duplicate_diagnosis_takes_config_overrides():
    """--set reaches the diagnosed run: local maps of 20 features make more joins than 30."""
    def joins_listed(*overrides):
        printed = run_study("duplicate_diagnosis.py", "small_loop_laps", "--joins", *overrides).stdout
        lines = printed.splitlines()
        header = next(k for k, line in enumerate(lines) if line.split()[:2] == ["index", "leaves"])
        rows = [line for line in lines[header + 1:] if line.split() and line.split()[0].isdigit()]
        assert "small_loop_laps seed 0 dc: P" in printed
        return len(rows)

    assert joins_listed("--set", "local_map_features=20") > joins_listed()
    refused = run_study("duplicate_diagnosis.py", "small_loop_laps", "--set", "local_map_features", check=False)
    assert refused.returncode != 0 and "FIELD=VALUE" in refused.stderr


def test_duplicate_diagnosis_classifies_the_small_joins_wrong_pairs():
    """--wrong-pairs: the kinds add up to the joins' wrong pairs, which --joins counts too."""
    printed = run_study("duplicate_diagnosis.py", "small_loop_laps", "--wrong-pairs", 1000).stdout
    lines = printed.splitlines()
    right, wrong = (int(w) for w in lines[0].replace(",", "").split()[-5::3])
    counts = [int(x) for line in lines[2:5] for x in line.split()[-3:]]
    assert right > 0 and wrong == sum(counts) > 0
    joins = run_study("duplicate_diagnosis.py", "small_loop_laps", "--joins").stdout.splitlines()
    header = next(k for k, line in enumerate(joins) if line.split()[:2] == ["index", "leaves"])
    rows = [line.split() for line in joins[header + 1:] if line.split() and line.split()[0].isdigit()]
    assert sum(int(r[8]) for r in rows) == wrong and sum(int(r[7]) for r in rows) == right
    refused = run_study("duplicate_diagnosis.py", "small_loop_laps", "--wrong-pairs", 8, "--filter", "ekf", check=False)
    assert refused.returncode != 0 and "the EKF has none" in refused.stderr


def load_study(script: str):
    spec = importlib.util.spec_from_file_location(script.removesuffix(".py"), ROOT / "studies" / script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_clustering_ceiling_is_exact_on_nearly_noise_free_measurements():
    # With 0.01 % range noise and no clutter, every measurement is nearest to its own landmark
    # (these scenes' landmarks are centimetres apart at the least), and a gate at 1 - 1e-9 keeps
    # every draw of the noise, so both oracles must return the simulator's ids themselves: the
    # independent check of the study's geometry.
    study = load_study("clustering_ceiling.py")
    sim = dcslam.revisit_scenario("small_loop_laps", 3, clutter=0.0, range_sigma_fraction=1e-4,
                                  bearing_sigma=1e-5)
    for method in study.METHODS:
        ids = study.oracle_ids(sim, method, 1 - 1e-9)
        np.testing.assert_array_equal(ids, sim.true_ids)
        scores = dcslam.evaluation.association_scores(sim.true_ids, ids)
        assert scores.pairwise_precision == scores.pairwise_recall == scores.features_per_landmark == 1.0


def test_clustering_ceiling_command_line():
    printed = run_study("clustering_ceiling.py", "--seeds", 1, "--scenarios", "small_loop_laps").stdout
    rows = [line for line in printed.splitlines() if line.startswith("| small_loop_laps")]
    assert [row.split("|")[2].strip() for row in rows] == ["nearest", "assignment"]
    assert run_study("clustering_ceiling.py", "--scenarios", "nowhere", check=False).returncode == 2


def test_relinearisation_stop_prints_the_rules_estimate_beside_the_truth():
    printed = run_study("relinearisation_stop.py", "--passes", 1).stdout.splitlines()
    header, rows = printed[0].split(), [line.split() for line in printed[1:]]
    assert header[-2:] == ["-", "F*"] and len(rows) == 5
    for row in rows:
        estimated, excess = float(row[-2]), float(row[-1])
        # After one pass every scene still has something to gain, and the oracle's optimum
        # lies below the pass's objective.
        assert excess > 0 and np.isfinite(estimated)
