"""Monte Carlo experiments: runs x seeds x filters x scenarios, on local processes or on Dask.

A run is described by a :class:`RunSpec` (plain values, so that it travels to another process
or machine) and done by :func:`run_one`: it builds its data from the seed, runs one filter with
known association through :class:`~dcslam.SlamPipeline`, takes the full estimate every
``every`` steps, and scores everything against the truth (:func:`dcslam.evaluation.score_run`).
Its result is one row of plain numbers and the curves over time (the robot's NEES and
consistency index, the heading error and its computed sigma). The same spec gives the same
result wherever it runs: the data come from the seed alone, and the filters are deterministic.

Scenarios:

- the simulator's trajectories (``"straight"``, ``"loop"``, ``"loop_both_ways"``,
  ``"lawn_mowing"``, ``"snail"``): ``dcslam.simulate(name, steps, seed)``, the paper's noise;
  ``"straight"`` is the run of the paper's Fig. 4;
- ``"mrclam"``: UTIAS MR.CLAM (``robot``, ``data_dir``), each run the real data with simulated
  noise added from its seed (:meth:`dcslam.datasets.MrClam.perturbed`, ``extra_noise``).

:func:`run_experiment` runs a list of specs with joblib's local processes (the default) or on
a Dask cluster (``scheduler`` address, or a ``LocalCluster`` of ``workers`` processes);
:func:`fig4_plot` draws the paper's Fig. 4 with bands over the runs, :func:`write_rows` the
table (runs in rows) as CSV.

::

    specs = plan(["straight"], ["ekf", "dc"], runs=20, steps=400, every=5)
    result = run_experiment(specs, backend="local", workers=2)
    fig4_plot(result, "fig4.png")
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import os
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from .consistency import chi2_threshold

__all__ = ["SIMULATED_SCENARIOS", "SCENARIOS", "FILTERS", "BACKENDS", "RunSpec", "RunResult", "Experiment",
           "plan", "run_one", "run_experiment", "averaged_nees_bounds", "fig4_plot", "write_rows", "summary"]

SIMULATED_SCENARIOS = ("straight", "loop", "loop_both_ways", "lawn_mowing", "snail")
SCENARIOS = SIMULATED_SCENARIOS + ("mrclam",)
FILTERS = ("ekf", "dc")
BACKENDS = ("local", "dask")
DEFAULT_SIMULATED_STEPS = 400  # the length of docs/consistency.md's Fig. 4 runs
# Per-run curves, one value per checkpoint.
CURVES = ("robot_nees", "robot_ci", "heading_ci", "abs_heading_error", "heading_sigma")


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One Monte Carlo run.

    Attributes:
        scenario: one of :data:`SCENARIOS`.
        filter: ``"ekf"`` or ``"dc"``.
        seed: the simulation's (or the perturbation's) seed, and the filter's.
        steps: simulator: number of motions; MR.CLAM: run only the first ``steps`` (None: all).
        every: take the full estimate every this many steps.
        local_map_features: D&C's local map size (None: the scenario's, 30 for the simulator
            as in docs/consistency.md, :data:`dcslam.mrclam.LOCAL_MAP_FEATURES` for MR.CLAM).
        extra_noise: MR.CLAM: the added noise's variance as a share of the model's.
        robot, data_dir: MR.CLAM's robot and folder (None: the bundled robot 1).
    """

    scenario: str
    filter: str
    seed: int
    steps: Optional[int] = DEFAULT_SIMULATED_STEPS
    every: int = 5
    local_map_features: Optional[int] = None
    extra_noise: float = 1.0
    robot: int = 1
    data_dir: Optional[str] = None

    def validate(self) -> "RunSpec":
        if self.scenario not in SCENARIOS:
            raise ValueError(f"experiments: unknown scenario {self.scenario!r} (known: {', '.join(SCENARIOS)})")
        if self.filter not in FILTERS:
            raise ValueError(f"experiments: unknown filter {self.filter!r} (known: {', '.join(FILTERS)})")
        if self.scenario in SIMULATED_SCENARIOS and (self.steps is None or self.steps < 1):
            raise ValueError(f"experiments: scenario {self.scenario!r} needs steps >= 1, got {self.steps}")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"experiments: steps must be >= 1 or None, got {self.steps}")
        if self.local_map_features is not None and self.local_map_features < 1:
            raise ValueError(f"experiments: local_map_features must be >= 1 or None, got {self.local_map_features}")
        if self.every < 1:
            raise ValueError(f"experiments: every must be >= 1, got {self.every}")
        return self


@dataclasses.dataclass(frozen=True)
class RunResult:
    """:func:`run_one`'s result: ``row`` (plain numbers: the spec, the scores, the time) and
    ``curves`` ({name: (c,) array} over the checkpoints, ``"step"`` included)."""

    spec: RunSpec
    row: Dict[str, Any]
    curves: Dict[str, np.ndarray]


@dataclasses.dataclass(frozen=True)
class Experiment:
    """All runs of :func:`run_experiment`, in the order of the specs.

    Attributes:
        results: list of :class:`RunResult`.
        backend: ``"local"`` or ``"dask"``; workers: processes used (None: the cluster's).
        seconds: wall time of the whole experiment.
    """

    results: List[RunResult]
    backend: str
    workers: Optional[int]
    seconds: float

    @property
    def rows(self) -> List[Dict[str, Any]]:
        """The table: one dict per run."""
        return [r.row for r in self.results]

    def curves(self, scenario: str, filter: str, name: str):
        """(steps (c,), values (runs, c)) of one curve over the runs of a scenario and filter."""
        chosen = [r for r in self.results if r.spec.scenario == scenario and r.spec.filter == filter]
        if not chosen:
            return np.zeros(0), np.zeros((0, 0))
        length = min(len(r.curves["step"]) for r in chosen)
        return chosen[0].curves["step"][:length], np.array([r.curves[name][:length] for r in chosen])


def plan(scenarios: Sequence[str], filters: Sequence[str], runs: int, seed: int = 0, **fields) -> List[RunSpec]:
    """The specs of ``runs`` runs of every scenario and filter; run i has seed ``seed + i``, the
    same for both filters (they see the same data). ``fields`` set the other
    :class:`RunSpec` fields for all."""
    if runs < 1:
        raise ValueError(f"experiments: runs must be >= 1, got {runs}")
    return [RunSpec(scenario=s, filter=f, seed=seed + i, **fields).validate()
            for s in scenarios for i in range(runs) for f in filters]


def _scenario_data(spec: RunSpec):
    """(steps, config, poses_true, landmarks_true, landmark_ids_true) of a spec."""
    from .config import SlamConfig

    if spec.scenario in SIMULATED_SCENARIOS:
        from .simulation import simulate

        sim = simulate(spec.scenario, steps=int(spec.steps or 0), seed=spec.seed)  # type: ignore[arg-type]
        cfg = SlamConfig(association="known", join_association="known",
                         local_map_features=spec.local_map_features or SlamConfig().local_map_features,
                         seed=spec.seed)
        return sim.steps, cfg, sim.poses, sim.landmarks, np.arange(len(sim.landmarks))
    data = _mrclam(spec.robot, spec.data_dir).perturbed(spec.seed, spec.extra_noise)
    cfg = data.slam_config(seed=spec.seed, **({} if spec.local_map_features is None else
                                              {"local_map_features": spec.local_map_features}))
    return data.steps, cfg, data.poses_true, data.landmarks_true, data.landmark_ids_true


@functools.lru_cache(maxsize=4)
def _mrclam(robot: int, data_dir: Optional[str]):
    """The robot's data, read once per process (its arrays are read-only; runs perturb copies)."""
    from .mrclam import mrclam

    return mrclam(robot, data_dir)


def run_one(spec: RunSpec) -> RunResult:
    """Does one run (see the module's docstring).

    numpy's BLAS/LAPACK is held to one thread for the run: a blocked factorisation rounds
    differently with another thread count, and a run must give the same numbers in this
    process, in a pool worker and on a Dask worker (the parallelism is across runs). D&C's
    ``estimate()`` runs on one thread too (``estimate_threads=1``, the same numbers).
    """
    from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]

    with threadpool_limits(limits=1):
        return _run(spec.validate())


def _run(spec: RunSpec) -> RunResult:
    from .evaluation import score_run
    from .pipeline import SlamPipeline

    started = time.perf_counter()
    steps, cfg, poses_true, landmarks_true, landmark_ids_true = _scenario_data(spec)
    # The runs already fill the cores; estimate() gives the same numbers on one thread.
    cfg = dataclasses.replace(cfg, estimate_threads=1)
    max_steps = spec.steps if spec.scenario == "mrclam" else None
    result = SlamPipeline(steps, cfg, filter=spec.filter, max_steps=max_steps, checkpoint_every=spec.every).run()
    scores = score_run(result, poses_true, landmarks_true, landmark_ids_true)
    checkpoints = result.checkpoints
    # checkpoint_every=spec.every (>= 1) records at least the last step
    assert checkpoints is not None and scores.robot_nees is not None and scores.heading_nees is not None
    truth = np.asarray(poses_true)[checkpoints.steps]
    heading_error = np.abs(np.arctan2(np.sin(checkpoints.robot[:, 2] - truth[:, 2]),
                                      np.cos(checkpoints.robot[:, 2] - truth[:, 2])))
    curves = {
        "step": checkpoints.steps,
        "robot_nees": scores.robot_nees.nees,
        "robot_ci": scores.robot_nees.consistency_index,
        "heading_ci": scores.heading_nees.consistency_index,
        "abs_heading_error": heading_error,
        "heading_sigma": np.sqrt(checkpoints.covariance[:, 2, 2]),
    }
    row = {**dataclasses.asdict(spec), "steps_run": result.steps, "map_size": result.map_size, "joins": len(result.joins),
           **scores.summary(), "seconds": time.perf_counter() - started}
    return RunResult(spec=spec, row=row, curves=curves)


def run_experiment(specs: Sequence[RunSpec], backend: str = "local", workers: Optional[int] = None,
                   scheduler: Optional[str] = None) -> Experiment:
    """Runs every spec; results in the order of ``specs``.

    Args:
        backend: ``"local"`` (joblib's process pool; ``workers=1`` runs in this process) or
            ``"dask"`` (``dask.distributed``).
        workers: local processes, or the ``LocalCluster``'s worker processes when ``backend``
            is ``"dask"`` without ``scheduler`` (default: the CPU count).
        scheduler: address of a running Dask scheduler (``tcp://host:8786``); implies Dask.

    Raises:
        ValueError: an unknown backend, a bad spec, ``workers < 1``.
        ImportError: joblib, dask.distributed or threadpoolctl is not installed
            (``pip install dcslam[cluster]``).
    """
    if scheduler is not None:
        backend = "dask"
    if backend not in BACKENDS:
        raise ValueError(f"experiments: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if workers is not None and workers < 1:
        raise ValueError(f"experiments: workers must be >= 1, got {workers}")
    specs = [spec.validate() for spec in specs]
    count = workers or os.cpu_count() or 1
    started = time.perf_counter()
    if backend == "local":
        if count == 1:
            results = [run_one(spec) for spec in specs]
        else:
            from joblib import Parallel, delayed  # type: ignore[import-untyped]

            results = Parallel(n_jobs=count, backend="loky")(delayed(run_one)(spec) for spec in specs)
    else:
        results = _run_on_dask(specs, scheduler, count)
    return Experiment(results=list(results), backend=backend, workers=None if scheduler else count,
                      seconds=time.perf_counter() - started)


def _run_on_dask(specs: List[RunSpec], scheduler: Optional[str], workers: int) -> List[RunResult]:
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        with Client(scheduler) as client:
            return client.gather(client.map(run_one, specs, pure=False))
    # One thread per worker process: a run is one C++ call after another, and the GIL would
    # serialise threads of one process. The dashboard takes any free port (":0"), so that a
    # second cluster on the machine does not fight over the default one.
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        return client.gather(client.map(run_one, specs, pure=False))


def averaged_nees_bounds(dof: int, runs: int, confidence: float = 0.95):
    """Two-sided bounds of the mean NEES of ``runs`` independent consistent runs:
    ``chi2(dof runs, (1 -+ confidence) / 2) / runs`` (Bar-Shalom et al., Estimation with
    Applications to Tracking and Navigation, §5.4)."""
    if runs < 1 or dof < 1 or not 0 < confidence < 1:
        raise ValueError(f"averaged_nees_bounds: need dof >= 1, runs >= 1 and confidence in (0, 1); "
                         f"got {dof}, {runs}, {confidence}")
    tail = (1 - confidence) / 2
    return (chi2_threshold(dof * runs, 1 - tail) / runs, chi2_threshold(dof * runs, tail) / runs)


def write_rows(rows: Sequence[Dict[str, Any]], path) -> None:
    """The table as CSV, one run per line, the columns of the first row."""
    if not rows:
        raise ValueError("write_rows: no rows")
    names = list(rows[0])
    with open(path, "w", newline="") as out:
        writer = csv.DictWriter(out, fieldnames=names)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in row.items()})


LABELS = {"ekf": "EKF SLAM", "dc": "D&C SLAM"}
COLORS = {"ekf": "tab:red", "dc": "tab:blue"}


def fig4_plot(experiment: Experiment, path, scenario: str = "straight", band=(10, 90)) -> None:
    """The paper's Fig. 4 for one scenario, with bands over the runs.

    Top: mean heading consistency index per filter, the ``band`` percentiles shaded, CI = 1.
    Middle: mean robot NEES (3 dof), shaded band, and the two-sided 95 % bounds of the mean of
    that many consistent runs (:func:`averaged_nees_bounds`). Bottom: mean absolute heading
    error and the mean computed 2-sigma bound.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8, 11), sharex=True)
    runs = 0
    for name in FILTERS:
        step, ci = experiment.curves(scenario, name, "heading_ci")
        if ci.size == 0:
            continue
        runs = len(ci)
        low, high = np.percentile(ci, band, axis=0)
        top.plot(step, ci.mean(axis=0), color=COLORS[name], lw=2, label=LABELS[name])
        top.fill_between(step, low, high, color=COLORS[name], alpha=0.2)
        _, robot = experiment.curves(scenario, name, "robot_nees")
        low, high = np.percentile(robot, band, axis=0)
        middle.semilogy(step, robot.mean(axis=0), color=COLORS[name], lw=2, label=LABELS[name])
        middle.fill_between(step, low, high, color=COLORS[name], alpha=0.2)
        _, error = experiment.curves(scenario, name, "abs_heading_error")
        _, sigma = experiment.curves(scenario, name, "heading_sigma")
        bottom.plot(step, np.degrees(error.mean(axis=0)), color=COLORS[name], lw=2,
                    label=f"{LABELS[name]}, mean |heading error|")
        bottom.plot(step, np.degrees(2 * sigma.mean(axis=0)), color=COLORS[name], lw=1, ls="--",
                    label=f"{LABELS[name]}, mean computed 2σ")
    top.axhline(1.0, color="black", lw=1, ls="--", label="CI = 1")
    top.set_ylabel("heading CI (mean, band %d-%d %%)" % band)
    top.set_title(f"{scenario}: {runs} Monte Carlo runs, known association", fontsize=10)
    if runs:
        lower, upper = averaged_nees_bounds(3, runs)
        middle.axhline(upper, color="black", lw=1, ls="--", label=f"95 % bounds of the mean of {runs} runs")
        middle.axhline(lower, color="black", lw=1, ls="--")
    middle.set_ylabel("robot NEES, 3 dof")
    bottom.set_ylabel("robot heading (deg)")
    bottom.set_xlabel("step")
    for axis in (top, middle, bottom):
        axis.grid(alpha=0.3, which="both")
        axis.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary(experiment: Experiment) -> Dict[str, Any]:
    """Means of the main scores per scenario and filter, and the experiment's time."""
    out: Dict[str, Any] = {"runs": len(experiment.results), "backend": experiment.backend,
                           "workers": experiment.workers, "seconds": experiment.seconds,
                           "run_seconds_sum": float(sum(r.row["seconds"] for r in experiment.results))}
    groups: Dict[str, Dict[str, Any]] = {}
    for scenario in dict.fromkeys(r.spec.scenario for r in experiment.results):
        for name in FILTERS:
            rows = [r.row for r in experiment.results if r.spec.scenario == scenario and r.spec.filter == name]
            if not rows:
                continue
            step, heading = experiment.curves(scenario, name, "heading_ci")
            last_quarter = step > step[-1] * 0.75
            groups[f"{scenario}/{name}"] = {
                "runs": len(rows),
                "mean_heading_ci_max": float(heading.mean(axis=0).max()),
                "mean_heading_ci_last_quarter": float(heading.mean(axis=0)[last_quarter].mean()),
                "mean_robot_ci_last_quarter": float(
                    experiment.curves(scenario, name, "robot_ci")[1].mean(axis=0)[last_quarter].mean()),
                **{f"mean_{k}": float(np.nanmean([row[k] for row in rows]))
                   for k in ("ate_m", "landmark_rms_m", "map_ci", "final_robot_ci")},
            }
    out["groups"] = groups
    return out

