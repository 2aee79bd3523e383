"""The ``dcslam`` command. It only drives the library's pipelines; no algorithm lives here."""

from __future__ import annotations

import enum
import pickle
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Dict, List, NamedTuple, NoReturn, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ._version import __version__

if TYPE_CHECKING:  # the command imports the library lazily, to start fast
    from .metrics import GpsAlignment

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Divide and Conquer EKF SLAM with data association in linear time.",
)
console = Console()


def _version_callback(value: bool) -> None:
    if value:
        console.print(f"dcslam {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Optional[bool] = typer.Option(
        None, "--version", callback=_version_callback, is_eager=True, help="Print the version."
    ),
) -> None:
    """Divide and Conquer EKF SLAM (Paz, Guivant, Tardós, Neira, RSS 2007)."""


@app.command()
def selfcheck(samples: int = typer.Option(200, "--samples", min=1, help="Random inputs per function.")) -> None:
    """Check the compiled core: analytic Jacobians against central differences."""
    from .selfcheck import geometry_errors

    table = Table(title="Jacobians: max |analytic - central difference|")
    table.add_column("function")
    table.add_column("max error", justify="right")
    table.add_column("status")
    failed = False
    for name, error in geometry_errors(samples):
        ok = error < 1e-5
        failed |= not ok
        table.add_row(escape(name), f"{error:.2e}", "[green]ok" if ok else "[red]FAIL")
    console.print(table)
    if failed:
        raise typer.Exit(code=1)


run_app = typer.Typer(
    no_args_is_help=True,
    help="Run SLAM on a dataset; write the trajectory, the map, statistics and plots.",
)
app.add_typer(run_app, name="run")


class FilterChoice(str, enum.Enum):
    dc = "dc"
    ekf = "ekf"
    both = "both"


class AssociationChoice(str, enum.Enum):
    known = "known"
    nn = "nn"
    jcbb = "jcbb"


class JoinAssociationChoice(str, enum.Enum):
    rjc = "rjc"
    jcbb = "jcbb"
    known = "known"


FILTER_OPTION = typer.Option(FilterChoice.dc, "--filter", help="Which filter to run; 'both' runs EKF, then D&C.")
MAX_STEPS_OPTION = typer.Option(None, "--max-steps", min=0, help="Run only the first N steps.")
PLOTS_OPTION = typer.Option(True, "--plots/--no-plots", help="Write the map and timing PNGs.")
ASSOCIATION_OPTION = typer.Option(None, "--association", help="Data association inside local maps "
                                  "(default: the dataset's choice).")
JOIN_ASSOCIATION_OPTION = typer.Option(None, "--join-association", help="Data association at D&C joins "
                                       "(default: the dataset's choice).")
LOCAL_MAP_OPTION = typer.Option(None, "--local-map-features", min=1, help="D&C: close a local map at this many features.")
JOIN_ITERATIONS_OPTION = typer.Option(None, "--join-iterations", min=1, help="D&C: linearisation points "
                                      "of each join (1: the one-shot join; default: SlamConfig's).")
KEEP_POSES_OPTION = typer.Option(False, "--keep-local-map-poses", help="D&C: keep the robot pose at every "
                                  "local-map boundary in the map (past_poses in map_dc.npz).")
ONLINE_LOCALISATION_OPTION = typer.Option(
    None, "--online-localisation-sigma",
    help="D&C: localise each closed local map against the oldest map where the robot's position std "
    "is at most this many metres, so that the online trajectory files know of places seen again "
    "(10 suited every scene measured; 'inf': always; default: off).")
TREE_RELINEARISATION_OPTION = typer.Option(
    None, "--tree-relinearisation", min=0, max=100,
    help="D&C: at most this many re-linearisation passes through the tree of joins in the final estimate, "
    "towards the batch least-squares optimum of the run's associations with its full covariance (default: "
    "the dataset's, 0; 3 stops after one pass on Victoria Park, two on the iSAM file).")
TREE_TOLERANCE_OPTION = typer.Option(
    None, "--tree-relinearisation-tolerance", min=0.0,
    help="D&C: the passes stop once another could lower the batch objective by at most this much "
    "(default: SlamConfig's, 3.84; 0: every pass).")
PROGRESS_OPTION = typer.Option(None, "--progress/--no-progress", help="Progress bar (default: on a terminal).")
CHECKPOINT_OPTION = typer.Option(None, "--checkpoint", help="Save the run's state (every filter, every step "
                                 "so far) to this file every --checkpoint-interval steps and when the steps end, "
                                 "to go on later with --resume.")
CHECKPOINT_INTERVAL_OPTION = typer.Option(1000, "--checkpoint-interval", min=1,
                                          help="Steps between two saves of --checkpoint.")
RESUME_OPTION = typer.Option(None, "--resume", help="Go on from this checkpoint of the same run (same data, "
                             "options, --filter and --max-steps); the outputs are bitwise those of a run never "
                             "stopped.")
STOP_AFTER_OPTION = typer.Option(None, "--stop-after", min=0, help="Run each filter's first N steps, save "
                                 "--checkpoint and stop without outputs (e.g. a job with a time limit).")


class _Saving(NamedTuple):
    """The command line's checkpoint options."""

    checkpoint: Optional[Path]
    interval: int
    resume: Optional[Path]
    stop_after: Optional[int]


def _config_with(cfg, association, join_association, local_map_features, join_iterations,
                 keep_local_map_poses, online_localisation_sigma, tree_relinearisation=None,
                 tree_relinearisation_tolerance=None):
    """The dataset's config with the command line's overrides."""
    from .config import SlamConfig

    values = cfg.to_dict()
    if association is not None:
        values["association"] = association.value
    if join_association is not None:
        values["join_association"] = join_association.value
    if local_map_features is not None:
        values["local_map_features"] = local_map_features
    if join_iterations is not None:
        values["join_iterations"] = join_iterations
    if keep_local_map_poses:
        values["keep_local_map_poses"] = True
    if online_localisation_sigma is not None:
        values["online_localisation_sigma"] = online_localisation_sigma
    if tree_relinearisation is not None:
        values["tree_relinearisation"] = tree_relinearisation
    if tree_relinearisation_tolerance is not None:
        values["tree_relinearisation_tolerance"] = tree_relinearisation_tolerance
    return SlamConfig.from_dict(values).validate()  # a bad value named here, not by the filter


def _filters(choice: FilterChoice) -> List[str]:
    return ["ekf", "dc"] if choice is FilterChoice.both else [choice.value]


def _fail(message: str) -> NoReturn:
    console.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)  # one line, unwrapped
    raise typer.Exit(code=2)


def _require_writable_folder(output: Path, option: str = "--output") -> None:
    """Creates ``output`` and writes a file into it, so that a run whose results could not be
    written fails before it starts, not after."""
    try:
        output.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=output):
            pass
    except OSError as error:
        _fail(f"cannot write to {option} {output}: {error.strerror or error}")


def _run_identity(name: str, steps, cfg, filters: List[str], max_steps: Optional[int],
                  checkpoint_every: Optional[int]) -> Dict[str, Any]:
    """What a checkpoint must share with the run that resumes it: the data (a digest of every
    step's motion, measurements and landmark ids), the options and the filters."""
    import hashlib

    import numpy as np

    digest = hashlib.sha256()
    for step in steps:
        for values in (step.u, step.Q, step.z, step.R):
            digest.update(np.ascontiguousarray(values, dtype=float).tobytes())
        if step.landmark_ids is not None:
            digest.update(np.ascontiguousarray(step.landmark_ids, dtype=np.int64).tobytes())
    # In this order the first difference named is the most telling one (the digest last).
    return {"dataset": name, "filters": filters, "max_steps": max_steps, "checkpoint_every": checkpoint_every,
            **cfg.to_dict(), "data digest": digest.hexdigest()}


def _resumed(saving: _Saving, identity: Dict[str, Any]) -> Dict[str, Any]:
    """The pipelines' progress saved in --resume's file, or a one-line error when it cannot
    be read or is of another run."""
    from . import io

    if saving.resume is None:
        return {}
    try:
        saved = io.read_run_checkpoint(saving.resume)
    except OSError as error:
        _fail(f"cannot read --resume {saving.resume}: {error.strerror or error}")
    except ValueError as error:
        _fail(f"--resume: {error}")
    if not isinstance(saved, dict) or set(saved) != {"run", "progress"}:
        _fail(f"--resume: {saving.resume}: not a checkpoint of `dcslam run`")
    for key, value in identity.items():
        if saved["run"].get(key) != value:
            _fail(f"--resume: {saving.resume} is of another run: its {key} is {saved['run'].get(key)!r}, "
                  f"this run's {value!r}")
    try:
        return {name: pickle.loads(state) for name, state in saved["progress"].items()}
    except Exception as error:  # the file's checksum held, so this is a file of another dcslam version
        _fail(f"--resume: cannot load {saving.resume}: {type(error).__name__}: {error}")


def _run_dataset(name: str, steps, cfg, filter_choice: FilterChoice, output: Path, max_steps: Optional[int],
                 plots: bool, progress: Optional[bool], gps=None, hint: str = "", truth=None,
                 checkpoint_every: Optional[int] = None, saving: Optional[_Saving] = None) -> None:
    """Checks the output folder and builds every pipeline first (bad options fail before any
    work), runs them, writes and summarises the results. ``hint`` is added to the message of a
    refused configuration. ``truth``: a dataset with ground truth (``poses_true``,
    ``landmarks_true``, ``landmark_ids_true``, ``true_ids``), scored with
    :func:`dcslam.evaluation.score_run` (the association too when the run hid the ids).
    ``saving``: the checkpoint options (--checkpoint, --resume, --stop-after)."""
    from . import io
    from .evaluation import score_run
    from .metrics import gps_alignment, map_agreement, map_trajectory
    from .pipeline import PipelineProgress, SlamPipeline

    saving = saving or _Saving(None, 1, None, None)
    if saving.stop_after is not None and saving.checkpoint is None:
        _fail("--stop-after needs --checkpoint FILE to save the run in")
    _require_writable_folder(output)
    if saving.checkpoint is not None:
        _require_writable_folder(saving.checkpoint.absolute().parent, "--checkpoint")
    filters = _filters(filter_choice)
    identity = _run_identity(name, steps, cfg, filters, max_steps, checkpoint_every) if (
        saving.checkpoint or saving.resume) else {}
    resumed = _resumed(saving, identity)
    show_progress = console.is_terminal if progress is None else progress
    try:
        pipelines = [SlamPipeline(steps, cfg, filter=filter_name, max_steps=max_steps, progress=show_progress,
                                  description=f"{name}: {filter_name}", checkpoint_every=checkpoint_every,
                                  resume=resumed.get(filter_name))
                     for filter_name in filters]
    except ValueError as error:
        _fail(f"cannot build the filter for {name}: {error}{hint}")

    # Each filter's progress pickled when it was saved: a filter that has finished its steps
    # goes on (its final joins and estimate) while the next one runs and saves.
    saved: Dict[str, bytes] = {name: pickle.dumps(progress) for name, progress in resumed.items()}

    save: Optional[Callable[[PipelineProgress], None]] = None
    if saving.checkpoint is not None:
        checkpoint: Path = saving.checkpoint

        def save(progress: PipelineProgress) -> None:
            saved[progress.filter_name] = pickle.dumps(progress, protocol=pickle.HIGHEST_PROTOCOL)
            try:
                io.write_run_checkpoint(checkpoint, {"run": identity, "progress": saved})
            except OSError as error:
                _fail(f"cannot write --checkpoint {checkpoint}: {error.strerror or error}")

    try:
        if saving.stop_after is not None:
            done = [pipeline.run_steps(saving.stop_after, save, saving.interval).steps_done for pipeline in pipelines]
            if any(count < pipeline.step_count for count, pipeline in zip(done, pipelines)):
                console.print(f"Stopped after {', '.join(f'{n} steps of {f}' for n, f in zip(done, filters))}; "
                              f"the run is saved in {saving.checkpoint}: go on with --resume {saving.checkpoint}")
                return
        results = [pipeline.run(save, saving.interval) for pipeline in pipelines]
    except ValueError as error:  # a step the filter refused; the message names it
        _fail(f"{name}: {error}")

    # The map-refit trajectory: each step's pose re-fitted on the final map (written beside the
    # online one, and the GPS comparison on the same footing for both filters).
    refits = {result.filter_name: map_trajectory(result, steps) for result in results}
    alignments: Dict[str, GpsAlignment] = {}
    map_alignments: Dict[str, GpsAlignment] = {}
    if gps is not None:
        for result in results:
            try:
                alignments[result.filter_name] = gps_alignment(result.timestamps, result.trajectory, gps)
                map_alignments[result.filter_name] = gps_alignment(*refits[result.filter_name], gps)
            except ValueError as error:
                console.print(f"[yellow]GPS alignment of {result.filter_name} skipped:[/] {error}")
    agreement = map_agreement(results[0].estimate, results[1].estimate) if len(results) == 2 else None
    scores: Dict[str, object] = {}
    if truth is not None:
        hidden_ids = cfg.association != "known"
        for result in results:
            scores[result.filter_name] = score_run(result, truth.poses_true, truth.landmarks_true,
                                                   truth.landmark_ids_true, truth.true_ids if hidden_ids else None)

    try:
        written = _write_outputs(results, refits, alignments, output, plots, name, truth, scores)
    except OSError as error:  # e.g. the disk filled up during the run
        _fail(f"cannot write the results to --output {output}: {error}")
    console.print(_summary_table(name, results, alignments, map_alignments, agreement, scores))
    console.print(f"Outputs in [bold]{output}[/]:")
    for path in written:
        console.print(f"  {path}")


def _write_outputs(results, refits, alignments, output: Path, plots: bool, name: str, truth=None,
                   scores=None) -> List[Path]:
    from . import io

    output.mkdir(parents=True, exist_ok=True)
    written: List[Path] = []
    scores = scores or {}
    if truth is not None and results:
        # The true pose at each step's time, for evo_ape (docs/mrclam.md).
        path = output / "trajectory_true.tum"
        io.write_tum(path, results[0].timestamps, truth.poses_true[1:results[0].steps + 1])
        written.append(path)
    for result in results:
        tag = result.filter_name
        paths = {kind: output / f"{stem}_{tag}.{ext}" for kind, stem, ext in (
            ("tum", "trajectory", "tum"), ("kitti", "trajectory", "kitti"), ("map_tum", "trajectory_map", "tum"),
            ("map_kitti", "trajectory_map", "kitti"), ("map", "map", "npz"), ("stats", "stats", "json"))}
        io.write_tum(paths["tum"], result.timestamps, result.trajectory)
        io.write_kitti(paths["kitti"], result.trajectory)
        refit_times, refit_poses = refits[tag]
        io.write_tum(paths["map_tum"], refit_times, refit_poses)
        io.write_kitti(paths["map_kitti"], refit_poses)
        io.save_map(paths["map"], result.estimate)
        extra: Dict[str, Any] = {"dataset": name}
        alignment = alignments.get(tag)
        if alignment is not None:
            extra["gps_alignment"] = {
                "rms_m": alignment.rms, "yaw_rad": alignment.yaw, "translation_m": alignment.translation,
                "fixes_used": len(alignment.times), "outliers_removed": alignment.outliers,
                "max_residual_m": float(alignment.residuals.max()),
            }
        if tag in scores:
            extra["truth_scores"] = scores[tag].summary()
        io.write_stats_json(paths["stats"], result, extra)
        written += paths.values()
    if plots:
        from .plots import plot_map, plot_timing

        for result in results:
            alignment = alignments.get(result.filter_name)
            path = output / f"map_{result.filter_name}.png"
            plot_map(result, path, gps=None if alignment is None else alignment.gps_used, alignment=alignment,
                     truth_poses=None if truth is None else truth.poses_true[:result.steps + 1],
                     truth_landmarks=None if truth is None else truth.landmarks_true)
            written.append(path)
        path = output / "timing.png"
        plot_timing(results, path, title=name)
        written.append(path)
    return written


def _summary_table(name: str, results, alignments, map_alignments, agreement, scores=None) -> Table:
    table = Table(title=f"{name}: SLAM run")
    table.add_column("")
    for result in results:
        table.add_column(result.filter_name.upper(), justify="right")

    def row(label, values):
        table.add_row(label, *values)

    counts = [result.association_counts() for result in results]
    row("steps", [f"{r.steps}" for r in results])
    row("measurements", [f"{c['measurements']}" for c in counts])
    row("paired / new / rejected", [f"{c['paired']} / {c['new']} / {c['rejected']}" for c in counts])
    row("features in the final map", [f"{r.map_size}" for r in results])
    row("time total (s)", [f"{r.total_seconds:.3f}" for r in results])
    row("time per step, mean (ms)", [f"{1e3 * r.total_seconds / max(r.steps, 1):.3f}" for r in results])
    row("time per step, worst (ms)", [f"{1e3 * r.worst_step_seconds:.2f}" for r in results])
    row("final estimate (ms)", [f"{1e3 * r.estimate_seconds:.2f}" for r in results])
    row("D&C joins (pairings)", [f"{len(r.joins)} ({c['join_pairings']})" if r.filter_name == "dc" else "-"
                                 for r, c in zip(results, counts)])
    row("D&C final fold's last join: pairings / overlap", [_last_fold_join(r) for r in results])
    if alignments:
        row("GPS RMS after rigid alignment (m)",
            [f"{alignments[r.filter_name].rms:.2f}" if r.filter_name in alignments else "-" for r in results])
    if map_alignments:
        row("GPS RMS, poses from the final map (m)",
            [f"{map_alignments[r.filter_name].rms:.2f}" if r.filter_name in map_alignments else "-"
             for r in results])
    if agreement is not None:
        # Row of a filter: share of its landmarks within the radius of one of the other's.
        row(f"landmarks within {agreement.radius:g} m of the other map",
            [f"{100 * agreement.first_in_second:.1f} %", f"{100 * agreement.second_in_first:.1f} %"])
    if scores:
        _truth_rows(row, [scores[r.filter_name] for r in results])
    return table


def _last_fold_join(result) -> str:
    """The join that closes whatever loop a D&C run ends on: its pairs of its overlap, and how
    they were found when not by RJC's first search alone."""
    if not result.fold_joins:
        return "-"
    join = result.fold_joins[-1]
    how = [name for name, made in (("chunked JCBB", join["chunked"]), ("wider search", join["widened"])) if made]
    return f"{join['pairings']} / {join['overlap']}" + (f" ({', '.join(how)})" if how else "")


def _truth_rows(row, scores) -> None:
    """Rows of the scores against a ground truth (:class:`dcslam.evaluation.TruthScores`)."""
    row("ATE vs truth, first pose / rigid (m)",
        [f"{s.ate.rmse:.3f} / {s.ate_rigid.rmse:.3f}" if s.ate_rigid else f"{s.ate.rmse:.3f} / -" for s in scores])
    row("landmark RMS vs truth (m)", [f"{s.map.rms:.3f} ({s.map.landmarks} scored)" for s in scores])
    row("final robot NEES (CI)", [f"{s.robot.nees:.2f} ({s.robot.consistency_index:.2f})" for s in scores])
    if scores[0].robot_nees is not None:
        row("ATE of the full estimate at checkpoints (m)", [f"{s.ate_checkpoints.rmse:.3f}" for s in scores])
        row("robot NEES over time: mean (share <= chi2 95 %)",
            [f"{s.robot_nees.mean_nees:.2f} ({100 * s.robot_nees.share_consistent:.0f} %)" for s in scores])
    row("final map NEES / dof (CI)", [f"{s.map.nees:.1f} / {s.map.dof} ({s.map.consistency_index:.2f})" for s in scores])
    if scores[0].association is not None:
        row("pairwise precision / recall",
            [f"{s.association.pairwise_precision:.4f} / {s.association.pairwise_recall:.4f}" for s in scores])
        row("features per landmark (wrong merges)",
            [f"{s.association.features_per_landmark:.2f} ({s.association.wrong_merges})" for s in scores])


@run_app.command("victoria-park")
def run_victoria_park(
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="Folder with the vp_*.csv.gz files "
                                            "(default: the copy bundled with the package)."),
    filter: FilterChoice = FILTER_OPTION,
    output: Path = typer.Option(Path("results/victoria_park"), "--output", help="Folder for the outputs."),
    max_steps: Optional[int] = MAX_STEPS_OPTION,
    plots: bool = PLOTS_OPTION,
    association: Optional[AssociationChoice] = ASSOCIATION_OPTION,
    join_association: Optional[JoinAssociationChoice] = JOIN_ASSOCIATION_OPTION,
    local_map_features: Optional[int] = LOCAL_MAP_OPTION,
    join_iterations: Optional[int] = JOIN_ITERATIONS_OPTION,
    keep_local_map_poses: bool = KEEP_POSES_OPTION,
    online_localisation_sigma: Optional[float] = ONLINE_LOCALISATION_OPTION,
    tree_relinearisation: Optional[int] = TREE_RELINEARISATION_OPTION,
    tree_relinearisation_tolerance: Optional[float] = TREE_TOLERANCE_OPTION,
    progress: Optional[bool] = PROGRESS_OPTION,
    checkpoint: Optional[Path] = CHECKPOINT_OPTION,
    checkpoint_interval: int = CHECKPOINT_INTERVAL_OPTION,
    resume: Optional[Path] = RESUME_OPTION,
    stop_after: Optional[int] = STOP_AFTER_OPTION,
) -> None:
    """SLAM on Victoria Park (ACFR): trees as landmarks, no ids, GPS as the reference.

    Writes per filter trajectory_<f>.tum / .kitti (the online trajectory),
    trajectory_map_<f>.tum / .kitti (each step's pose re-fitted on the final map),
    map_<f>.npz, stats_<f>.json and map_<f>.png, plus timing.png, into --output.
    """
    from .datasets import victoria_park

    if "known" in (getattr(association, "value", None), getattr(join_association, "value", None)):
        _fail("Victoria Park has no landmark ids: use --association nn|jcbb and --join-association rjc|jcbb")
    try:
        dataset = victoria_park(data_dir)
        cfg = _config_with(dataset.slam_config(), association, join_association, local_map_features,
                           join_iterations, keep_local_map_poses, online_localisation_sigma,
                           tree_relinearisation, tree_relinearisation_tolerance)
    except ValueError as error:
        _fail(str(error))
    _run_dataset("Victoria Park", dataset.steps, cfg, filter, output, max_steps, plots, progress, gps=dataset.gps,
                 hint=f". Victoria Park has no landmark ids: it needs association 'nn' or 'jcbb' inside local "
                      f"maps (this run asked for {cfg.association!r}) and 'rjc' or 'jcbb' at joins.",
                 saving=_Saving(checkpoint, checkpoint_interval, resume, stop_after))


@run_app.command("isam")
def run_isam(
    file: Path = typer.Argument(..., help="iSAM/GTSAM 2D text file (ODOMETRY / LANDMARK lines; gzip is fine)."),
    filter: FilterChoice = FILTER_OPTION,
    output: Path = typer.Option(Path("results/isam"), "--output", help="Folder for the outputs."),
    max_steps: Optional[int] = MAX_STEPS_OPTION,
    plots: bool = PLOTS_OPTION,
    association: Optional[AssociationChoice] = ASSOCIATION_OPTION,
    join_association: Optional[JoinAssociationChoice] = JOIN_ASSOCIATION_OPTION,
    local_map_features: Optional[int] = LOCAL_MAP_OPTION,
    join_iterations: Optional[int] = JOIN_ITERATIONS_OPTION,
    keep_local_map_poses: bool = KEEP_POSES_OPTION,
    online_localisation_sigma: Optional[float] = ONLINE_LOCALISATION_OPTION,
    tree_relinearisation: Optional[int] = TREE_RELINEARISATION_OPTION,
    tree_relinearisation_tolerance: Optional[float] = TREE_TOLERANCE_OPTION,
    progress: Optional[bool] = PROGRESS_OPTION,
    checkpoint: Optional[Path] = CHECKPOINT_OPTION,
    checkpoint_interval: int = CHECKPOINT_INTERVAL_OPTION,
    resume: Optional[Path] = RESUME_OPTION,
    stop_after: Optional[int] = STOP_AFTER_OPTION,
) -> None:
    """SLAM on an iSAM/GTSAM 2D graph replayed as steps, with the file's landmark ids.

    Timestamps in the trajectory files are step indices. Same outputs as victoria-park,
    without GPS.
    """
    from .datasets import read_isam2d

    try:
        dataset = read_isam2d(file)
        cfg = _config_with(dataset.slam_config(), association, join_association, local_map_features,
                           join_iterations, keep_local_map_poses, online_localisation_sigma,
                           tree_relinearisation, tree_relinearisation_tolerance)
    except ValueError as error:
        _fail(str(error))
    _run_dataset(file.name, dataset.steps, cfg, filter, output, max_steps, plots, progress,
                 saving=_Saving(checkpoint, checkpoint_interval, resume, stop_after))


@run_app.command("mrclam")
def run_mrclam(
    robot: int = typer.Option(1, "--robot", help="Robot 1-5 (robot 1 is bundled; others need --data-dir)."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="Folder with newRobot<N>_*.txt[.gz], "
                                            "Barcodes.dat and Landmark_Groundtruth.dat (default: the bundled copy)."),
    filter: FilterChoice = FILTER_OPTION,
    output: Path = typer.Option(Path("results/mrclam"), "--output", help="Folder for the outputs."),
    max_steps: Optional[int] = MAX_STEPS_OPTION,
    plots: bool = PLOTS_OPTION,
    association: Optional[AssociationChoice] = typer.Option(
        None, "--association", help="'known' (default: the barcodes) or 'nn'/'jcbb' (barcodes hidden from the "
        "filter, used only to score; joins then default to RJC)."),
    join_association: Optional[JoinAssociationChoice] = JOIN_ASSOCIATION_OPTION,
    local_map_features: Optional[int] = LOCAL_MAP_OPTION,
    join_iterations: Optional[int] = JOIN_ITERATIONS_OPTION,
    checkpoint_every: int = typer.Option(10, "--checkpoint-every", min=1, help="Take the full estimate every N "
                                         "steps for the robot's NEES over time."),
    online_localisation_sigma: Optional[float] = ONLINE_LOCALISATION_OPTION,
    tree_relinearisation: Optional[int] = TREE_RELINEARISATION_OPTION,
    tree_relinearisation_tolerance: Optional[float] = TREE_TOLERANCE_OPTION,
    progress: Optional[bool] = PROGRESS_OPTION,
    checkpoint: Optional[Path] = CHECKPOINT_OPTION,
    checkpoint_interval: int = CHECKPOINT_INTERVAL_OPTION,
    resume: Optional[Path] = RESUME_OPTION,
    stop_after: Optional[int] = STOP_AFTER_OPTION,
) -> None:
    """SLAM on UTIAS MR.CLAM dataset 2: 15 barcoded landmarks, Vicon ground truth.

    Same outputs as victoria-park (no GPS), plus trajectory_true.tum and the truth in the map
    plots; the summary scores each filter against the truth (ATE, landmark RMS, NEES and
    consistency index; pairwise precision/recall when the ids are hidden).
    """
    from .mrclam import mrclam

    try:
        dataset = mrclam(robot, data_dir)
        cfg = dataset.slam_config()
        if association is not None and association is not AssociationChoice.known and join_association is None:
            join_association = JoinAssociationChoice.rjc
        cfg = _config_with(cfg, association, join_association, local_map_features, join_iterations, False,
                           online_localisation_sigma, tree_relinearisation, tree_relinearisation_tolerance)
    except ValueError as error:
        _fail(str(error))
    _run_dataset(f"MR.CLAM robot {robot}", dataset.steps, cfg, filter, output, max_steps, plots, progress,
                 truth=dataset, checkpoint_every=checkpoint_every,
                 saving=_Saving(checkpoint, checkpoint_interval, resume, stop_after))


@app.command()
def montecarlo(
    scenario: List[str] = typer.Option(["straight"], "--scenario", help="Scenario, repeatable: straight, loop, "
                                       "loop_both_ways, lawn_mowing, snail (the simulator) or mrclam."),
    filter: FilterChoice = typer.Option(FilterChoice.both, "--filter", help="Which filter; 'both' runs both."),
    runs: int = typer.Option(20, "--runs", min=1, help="Runs per scenario (run i has seed --seed + i)."),
    seed: int = typer.Option(0, "--seed"),
    steps: Optional[int] = typer.Option(None, "--steps", min=1, help="Simulator: motions per run (default 400); "
                                        "mrclam: only the first N steps (default: all)."),
    every: int = typer.Option(5, "--every", min=1, help="Take the full estimate every N steps."),
    local_map_features: Optional[int] = typer.Option(None, "--local-map-features", min=1, help="D&C's local "
                                                     "map size (default: 30 on the simulator, 8 on mrclam)."),
    extra_noise: float = typer.Option(1.0, "--extra-noise", min=0.0, help="mrclam: added noise's variance as a "
                                      "share of the model's."),
    robot: int = typer.Option(1, "--robot", help="mrclam: the robot."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="mrclam: folder with the robot's files."),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="Processes (default: the CPU count); "
                                          "with --dask, the LocalCluster's workers."),
    dask: bool = typer.Option(False, "--dask", help="Run on Dask distributed (a LocalCluster of --workers "
                              "processes unless --scheduler is given)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Address of a Dask scheduler "
                                            "(tcp://host:8786); implies --dask."),
    output: Path = typer.Option(Path("results/montecarlo"), "--output", help="Folder for the outputs."),
    plots: bool = PLOTS_OPTION,
) -> None:
    """Monte Carlo runs x seeds x filters x scenarios, known association; the paper's Fig. 4 with bands.

    Writes runs.csv (one run per row: the spec, the scores, the time), curves.npz (each run's
    NEES and consistency index over time), summary.json and fig4_<scenario>.png into --output.
    """
    import json

    import numpy as np

    from . import experiments
    from .io import _plain

    _require_writable_folder(output)
    try:
        specs = [spec for name in dict.fromkeys(scenario) for spec in experiments.plan(
            [name], _filters(filter), runs, seed=seed,
            steps=steps if steps or name == "mrclam" else experiments.DEFAULT_SIMULATED_STEPS,
            every=every, local_map_features=local_map_features, extra_noise=extra_noise, robot=robot,
            data_dir=None if data_dir is None else str(data_dir))]
        result = experiments.run_experiment(specs, backend="dask" if dask else "local", workers=workers,
                                            scheduler=scheduler)
    except ValueError as error:
        _fail(str(error))
    except ImportError as error:
        _fail(f"{error}; install the cluster extra: pip install 'dcslam[cluster]'")
    summary = experiments.summary(result)
    try:
        experiments.write_rows(result.rows, output / "runs.csv")
        curves: Dict[str, Any] = {f"{r.spec.scenario}/{r.spec.filter}/{r.spec.seed}/{name}": values
                                  for r in result.results for name, values in r.curves.items()}
        np.savez_compressed(output / "curves.npz", **curves)
        (output / "summary.json").write_text(json.dumps(_plain(summary), indent=1) + "\n")
        if plots:
            for name in dict.fromkeys(scenario):
                experiments.fig4_plot(result, output / f"fig4_{name}.png", scenario=name)
    except OSError as error:
        _fail(f"cannot write the results to --output {output}: {error}")

    table = Table(title=f"Monte Carlo: {len(result.results)} runs, {result.backend}, {result.seconds:.1f} s")
    table.add_column("scenario/filter", no_wrap=True)
    for column in ("runs", "max mean heading CI", "heading CI last quarter", "pose CI last quarter", "ATE (m)",
                   "landmark RMS (m)", "map CI"):
        table.add_column(column, justify="right")
    for group, values in summary["groups"].items():
        table.add_row(group, str(values["runs"]), f"{values['mean_heading_ci_max']:.2f}",
                      f"{values['mean_heading_ci_last_quarter']:.2f}", f"{values['mean_robot_ci_last_quarter']:.2f}",
                      f"{values['mean_ate_m']:.3f}", f"{values['mean_landmark_rms_m']:.3f}",
                      f"{values['mean_map_ci']:.2f}")
    console.print(table)
    console.print(f"Outputs in [bold]{output}[/]: runs.csv, curves.npz, summary.json"
                  + (", fig4_*.png" if plots else ""))


def main() -> None:
    app(prog_name="dcslam")
