"""dcslam.experiments: runs are reproducible from their spec, their curves are the filter's own
numbers, and the joblib and Dask backends (a real 2-worker LocalCluster) give the local
results exactly."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

import dcslam
from dcslam import experiments

# Small runs: the point is equality, not the figures.
SMALL = dict(steps=40, every=10, local_map_features=10)


def small_plan():
    specs = experiments.plan(["straight"], ["ekf", "dc"], runs=2, seed=5, **SMALL)
    specs += experiments.plan(["mrclam"], ["dc"], runs=1, seed=1, steps=120, every=40)
    return specs


def comparable(result):
    """A run's numbers without its time, NaN-safe for equality."""
    row = {k: v for k, v in result.row.items() if k != "seconds"}
    return repr(row), {k: v.tolist() for k, v in result.curves.items()}


def test_plan_runs_every_scenario_filter_and_seed():
    specs = experiments.plan(["straight", "mrclam"], ["ekf", "dc"], runs=3, seed=10, steps=50)
    assert len(specs) == 2 * 3 * 2
    assert sorted({s.seed for s in specs}) == [10, 11, 12]
    assert {(s.scenario, s.filter) for s in specs} == {(a, b) for a in ("straight", "mrclam") for b in ("ekf", "dc")}


@pytest.mark.parametrize("fields, message", [
    (dict(scenario="circle", filter="dc", seed=0), "unknown scenario"),
    (dict(scenario="loop", filter="ukf", seed=0), "unknown filter"),
    (dict(scenario="loop", filter="dc", seed=0, steps=None), "needs steps"),
    (dict(scenario="loop", filter="dc", seed=0, every=0), "every must be"),
])
def test_bad_specs_are_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        experiments.RunSpec(**fields).validate()


def test_bad_backends_and_workers_are_refused():
    spec = experiments.RunSpec("straight", "dc", 0, **SMALL)
    with pytest.raises(ValueError, match="backend"):
        experiments.run_experiment([spec], backend="mpi")
    with pytest.raises(ValueError, match="workers"):
        experiments.run_experiment([spec], workers=0)


def test_a_run_is_its_filter_run_by_hand():
    spec = experiments.RunSpec("loop", "ekf", seed=3, **SMALL)
    result = experiments.run_one(spec)
    sim = dcslam.simulate("loop", steps=40, seed=3)
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="known", join_association="known", local_map_features=10,
                                            seed=3))
    slam.run(sim.steps[:20])
    est = slam.estimate()
    P = est.covariance[:3, :3]
    nees = dcslam.nees(est.robot, P, sim.poses[20], angle_indices=(2,))
    np.testing.assert_array_equal(result.curves["step"], [10, 20, 30, 40])
    assert result.curves["robot_nees"][1] == pytest.approx(nees, rel=1e-9)
    heading_error = math.remainder(est.robot[2] - sim.poses[20][2], 2 * math.pi)
    assert result.curves["heading_ci"][1] == pytest.approx(heading_error**2 / P[2, 2] / chi2.ppf(0.95, 1), rel=1e-6)
    assert result.curves["heading_sigma"][1] == pytest.approx(math.sqrt(P[2, 2]))
    assert result.row["scenario"] == "loop" and result.row["seed"] == 3 and result.row["steps_run"] == 40


def test_the_same_spec_gives_the_same_run():
    spec = experiments.RunSpec("mrclam", "dc", seed=2, steps=80, every=20)
    assert comparable(experiments.run_one(spec)) == comparable(experiments.run_one(spec))
    other = experiments.run_one(experiments.RunSpec("mrclam", "dc", seed=3, steps=80, every=20))
    assert comparable(other) != comparable(experiments.run_one(spec))


def test_averaged_nees_bounds_are_the_chi_square_quantiles():
    low, high = experiments.averaged_nees_bounds(3, 20)
    assert low == pytest.approx(chi2.ppf(0.025, 60) / 20, rel=1e-6)
    assert high == pytest.approx(chi2.ppf(0.975, 60) / 20, rel=1e-6)
    with pytest.raises(ValueError):
        experiments.averaged_nees_bounds(3, 0)


def test_joblib_and_a_dask_local_cluster_give_the_local_results():
    pytest.importorskip("joblib")
    pytest.importorskip("dask.distributed")
    specs = small_plan()
    local = experiments.run_experiment(specs, workers=1)
    processes = experiments.run_experiment(specs, backend="local", workers=2)
    cluster = experiments.run_experiment(specs, backend="dask", workers=2)
    assert [r.spec for r in cluster.results] == specs
    assert [comparable(r) for r in processes.results] == [comparable(r) for r in local.results]
    assert [comparable(r) for r in cluster.results] == [comparable(r) for r in local.results]
    assert cluster.backend == "dask" and cluster.workers == 2


def test_the_table_and_the_figure_are_written(tmp_path):
    specs = experiments.plan(["straight"], ["ekf", "dc"], runs=2, **SMALL)
    result = experiments.run_experiment(specs, workers=1)
    experiments.write_rows(result.rows, tmp_path / "runs.csv")
    lines = (tmp_path / "runs.csv").read_text().splitlines()
    assert len(lines) == 1 + 4 and lines[0].startswith("scenario,filter,seed")
    experiments.fig4_plot(result, tmp_path / "fig4.png")
    assert (tmp_path / "fig4.png").stat().st_size > 10_000
    summary = experiments.summary(result)
    assert set(summary["groups"]) == {"straight/ekf", "straight/dc"}
    assert summary["groups"]["straight/dc"]["runs"] == 2


def test_a_running_scheduler_is_used_by_its_address():
    distributed = pytest.importorskip("dask.distributed")
    specs = experiments.plan(["straight"], ["dc"], runs=1, **SMALL)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster:
        remote = experiments.run_experiment(specs, scheduler=cluster.scheduler_address)
    assert remote.backend == "dask" and remote.workers is None
    assert [comparable(r) for r in remote.results] == [comparable(r) for r in experiments.run_experiment(specs, workers=1).results]


def test_mrclam_runs_use_the_dataset_s_local_map_size_unless_told():
    mrclam = experiments.run_one(experiments.RunSpec("mrclam", "dc", seed=0, steps=400, every=100))
    told = experiments.run_one(experiments.RunSpec("mrclam", "dc", seed=0, steps=400, every=100,
                                                   local_map_features=30))
    # 8 features (the dataset's choice) close local maps within 400 steps; 30 never do with 15 landmarks.
    assert experiments.RunSpec("mrclam", "dc", 0).local_map_features is None
    assert mrclam.row["joins"] > 0 and told.row["joins"] == 0
    assert told.row["local_map_features"] == 30 and mrclam.row["local_map_features"] is None
