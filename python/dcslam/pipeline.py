"""Run a SLAM filter over a dataset and collect what a user wants to see of the run.

:class:`SlamPipeline` does the work (the CLI only drives it): it feeds a sequence of steps
to an :class:`~dcslam.EkfSlam` or :class:`~dcslam.DCSlam`, records the robot's pose after
every step and the filter's own per-step timings, and ends with the full estimate, all in a
:class:`PipelineResult`. Measuring the result (GPS alignment, the map's trajectory, map
agreement) is :mod:`dcslam.metrics`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

import numpy as np

from . import metrics as _metrics
from .config import SlamConfig
# The evaluation of a result lived here before metrics.py, and user code imports it from
# dcslam.pipeline: every name metrics exports stays importable from here.
from .metrics import *  # noqa: F401,F403
from .slam import DCSlam, DCSlamStats, EkfSlam, Estimate, SlamFilter, SlamStats

__all__ = ["FILTERS", "PipelineProgress", "PipelineResult", "RobotCheckpoints", "SlamPipeline", *_metrics.__all__]


@dataclasses.dataclass(frozen=True)
class RobotCheckpoints:
    """The robot of the full estimate at some steps, with its covariance (for its NEES over
    time against a truth: :func:`dcslam.evaluation.nees_series`).

    Attributes:
        steps: (c,) number of steps done at each checkpoint (``poses_true[steps]`` is the
            matching true pose).
        robot: (c, 3); covariance: (c, 3, 3), from :meth:`~dcslam.SlamFilter.estimate` (for
            D&C the anytime full map, every local map joined on copies).
    """

    steps: np.ndarray
    robot: np.ndarray
    covariance: np.ndarray

FILTERS = {"dc": DCSlam, "ekf": EkfSlam}


@dataclasses.dataclass(frozen=True)
class PipelineProgress:
    """A :class:`SlamPipeline`'s run after its first ``steps_done`` steps: what a pipeline
    built with ``resume=`` needs to go on and end bitwise as the run never stopped would.
    It pickles (the filter as its versioned checkpoint; ``dcslam run --checkpoint`` writes it).

    Attributes:
        filter_name, config, step_count, checkpoint_every: the run it belongs to (checked
            on resume).
        steps_done: steps already run (``step_count``: every step; only the final estimate
            is left).
        slam: the filter after those steps (the pipeline's own object, not a copy: pickle it
            before the next step to keep this point).
        timestamps, trajectory: (steps_done,) and (steps_done, 3), as in
            :class:`PipelineResult`.
        returned_ids: the ids each step's ``update`` returned (not yet resolved).
        checkpoints: (steps, robot, robot covariance) of the robot checkpoints taken so far.
        wall_seconds: wall time spent so far, in every process the run went through.
    """

    filter_name: str
    config: SlamConfig
    step_count: int
    checkpoint_every: Optional[int]
    steps_done: int
    slam: SlamFilter
    timestamps: np.ndarray
    trajectory: np.ndarray
    returned_ids: List[np.ndarray]
    checkpoints: List[tuple]
    wall_seconds: float


@dataclasses.dataclass(frozen=True)
class PipelineResult:
    """One filter's run over a dataset.

    Attributes:
        filter_name: ``"dc"`` or ``"ekf"``.
        config: the filter's options.
        estimate: the final map with its full covariance (for D&C, every pending join done).
        timestamps: (k,) time of each step: the dataset's ``s.t`` when it has one, else the
            step index.
        trajectory: (k, 3) robot pose (x, y, phi) right after each step, as the filter knew
            it then (a filter's past poses are never revised; for D&C this is the chain of
            local maps, with only the joins done so far: see :func:`map_trajectory`).
        measurement_ids: per step, the (m,) feature ids :meth:`~dcslam.SlamFilter.update`
            returned, resolved at the end of the run to the features of the final map
            (-1: rejected, or a feature removed later).
        stats: the filter's per-step statistics (:class:`~dcslam.DCSlamStats` for D&C).
        estimate_seconds: time of the final :meth:`~dcslam.SlamFilter.estimate` call; for
            D&C it includes the joins still queued (run by ``finish_joins()``, so that
            ``resolve()`` reflects them) and the joins of the maps left on the stack.
        wall_seconds: wall time of the whole run, Python loop included.
        checkpoints: the robot and its covariance every ``checkpoint_every`` steps and at the
            end (:class:`RobotCheckpoints`), or ``None``.
    """

    filter_name: str
    config: SlamConfig
    estimate: Estimate
    timestamps: np.ndarray
    trajectory: np.ndarray
    measurement_ids: List[np.ndarray]
    stats: SlamStats
    estimate_seconds: float
    wall_seconds: float
    checkpoints: Optional[RobotCheckpoints] = None

    @property
    def steps(self) -> int:
        return len(self.trajectory)

    @property
    def step_seconds(self) -> np.ndarray:
        return self.stats.step_seconds

    @property
    def total_seconds(self) -> float:
        """Filter time of every step plus the final estimate (the cost of the whole map)."""
        return float(self.stats.step_seconds.sum()) + self.estimate_seconds

    @property
    def worst_step_seconds(self) -> float:
        return float(self.stats.step_seconds.max()) if self.steps else 0.0

    @property
    def joins(self) -> list:
        """D&C join events (see :class:`~dcslam.DCSlamStats`); empty for the EKF."""
        return list(self.stats.joins) if isinstance(self.stats, DCSlamStats) else []

    @property
    def fold_joins(self) -> list:
        """The joins of D&C's final fold (``DCSlamStats.fold_joins``; the last one closes a loop
        the run ends on); empty for the EKF."""
        return list(self.stats.fold_joins) if isinstance(self.stats, DCSlamStats) else []

    @property
    def map_size(self) -> int:
        return len(self.estimate.landmarks)

    def association_counts(self) -> Dict[str, int]:
        """Totals over the run: measurements, paired (with a feature of the local map),
        new (started a feature), rejected, join_pairings (features merged at D&C joins)."""
        stats = self.stats
        return {
            "measurements": int(stats.measurements.sum()),
            "paired": int(stats.paired.sum()),
            "new": int(stats.new_features.sum()),
            "rejected": int(stats.rejected.sum()),
            "join_pairings": int(sum(join["pairings"] for join in self.joins)),
        }

    def summary(self) -> Dict[str, Any]:
        """Plain numbers of the run (JSON-ready)."""
        return {
            "filter": self.filter_name,
            "steps": self.steps,
            "map_size": self.map_size,
            "total_seconds": self.total_seconds,
            "worst_step_seconds": self.worst_step_seconds,
            "estimate_seconds": self.estimate_seconds,
            "wall_seconds": self.wall_seconds,
            "joins": len(self.joins),
            **self.association_counts(),
        }


class SlamPipeline:
    """Runs one filter over a sequence of steps (``s.u, s.Q, s.z, s.R`` each).

    Args:
        dataset_steps: the steps, e.g. ``victoria_park().steps`` or ``read_isam2d(p).steps``.
        cfg: the filter's options (e.g. ``dataset.slam_config()``).
        filter: ``"dc"`` (:class:`~dcslam.DCSlam`) or ``"ekf"`` (:class:`~dcslam.EkfSlam`).
        max_steps: run only the first ``max_steps`` steps (None: all).
        progress: show a progress bar on the terminal.
        description: label of the progress bar.
        checkpoint_every: take the full estimate every this many steps (and after the last)
            and keep its robot and covariance (``result.checkpoints``); ``None``: never. Its
            time (the estimate's) counts in ``wall_seconds`` but not in the filter's steps.
        resume: a :class:`PipelineProgress` of the same run (same filter, options and
            number of steps) to go on from, instead of a new filter.

    Raises:
        ValueError: unknown filter name, or options the filter refuses (raised when the
            filter is built, before any step runs); a ``resume`` of another run (the
            message names what differs).
    """

    def __init__(
        self,
        dataset_steps: Sequence[Any],
        cfg: SlamConfig,
        filter: str = "dc",
        max_steps: Optional[int] = None,
        progress: bool = False,
        description: Optional[str] = None,
        checkpoint_every: Optional[int] = None,
        resume: Optional[PipelineProgress] = None,
    ):
        if filter not in FILTERS:
            raise ValueError(f"SlamPipeline: filter must be one of {', '.join(FILTERS)}, got {filter!r}")
        if max_steps is not None and max_steps < 0:
            raise ValueError(f"SlamPipeline: max_steps must be >= 0, got {max_steps}")
        if checkpoint_every is not None and checkpoint_every < 1:
            raise ValueError(f"SlamPipeline: checkpoint_every must be >= 1, got {checkpoint_every}")
        self.checkpoint_every = checkpoint_every
        self.dataset_steps = dataset_steps
        self.step_count = len(dataset_steps) if max_steps is None else min(max_steps, len(dataset_steps))
        self.config = cfg
        self.filter_name = filter
        self.progress = progress
        self.description = description or f"{filter} SLAM"
        if resume is not None:
            theirs = (resume.filter_name, resume.step_count, resume.checkpoint_every, resume.config)
            for what, mine, other in zip(("filter", "number of steps", "checkpoint_every", "options"),
                                         (filter, self.step_count, checkpoint_every, cfg), theirs):
                if mine != other:
                    raise ValueError(f"SlamPipeline: resume is of another run: its {what} "
                                     f"{_difference(other, mine)}")
            self.slam: SlamFilter = resume.slam
        else:
            # Built here so that refused options fail before a long run starts.
            self.slam = FILTERS[filter](cfg)
        self._finished = False
        # The run so far (from resume, or empty), grown by run_steps().
        self._timestamps = np.empty(self.step_count)
        self._trajectory = np.empty((self.step_count, 3))
        self._returned_ids: List[np.ndarray] = []
        self._checkpoints: List[tuple] = []
        self._done, self._wall_seconds = 0, 0.0
        if resume is not None:
            self._done, self._wall_seconds = resume.steps_done, resume.wall_seconds
            self._timestamps[:self._done], self._trajectory[:self._done] = resume.timestamps, resume.trajectory
            self._returned_ids, self._checkpoints = list(resume.returned_ids), list(resume.checkpoints)

    def snapshot(self) -> PipelineProgress:
        """The run so far (copies, except the filter itself)."""
        done = self._done
        return PipelineProgress(
            filter_name=self.filter_name, config=self.config, step_count=self.step_count,
            checkpoint_every=self.checkpoint_every, steps_done=done,
            slam=self.slam, timestamps=self._timestamps[:done].copy(), trajectory=self._trajectory[:done].copy(),
            returned_ids=list(self._returned_ids), checkpoints=list(self._checkpoints),
            wall_seconds=self._wall_seconds)

    def run_steps(self, until: int, save: Optional[Callable[[PipelineProgress], None]] = None,
                  save_every: Optional[int] = None) -> PipelineProgress:
        """Runs the steps not done yet up to step ``until`` (at most every step), without the
        final estimate; :meth:`run` or another ``run_steps`` goes on from there.

        Args:
            until: number of the run's steps done when it returns.
            save: called with :meth:`snapshot` after every ``save_every``-th step (counted
                from the run's first step) and when it returns; e.g. to pickle it to a file.
            save_every: see ``save`` (None: only when it returns).

        Returns:
            :meth:`snapshot`.

        Raises:
            RuntimeError: after :meth:`run` (the filter already holds the whole run).
        """
        if self._finished:
            raise RuntimeError("SlamPipeline: this pipeline already ran; build a new one")
        if save_every is not None and save_every < 1:
            raise ValueError(f"SlamPipeline: save_every must be >= 1, got {save_every}")
        slam = self.slam
        use_ids = self.config.association == "known"
        timestamps, trajectory = self._timestamps, self._trajectory
        returned_ids, checkpoints = self._returned_ids, self._checkpoints
        first, last = self._done, max(self._done, min(until, self.step_count))
        started = time.perf_counter()
        with _progress_bar(self.progress, self.description, last - first) as advance:
            for k in range(first, last):
                step = self.dataset_steps[k]
                slam.predict(step.u, step.Q)
                returned_ids.append(slam.update(step.z, step.R, step.landmark_ids if use_ids else None))
                trajectory[k] = slam.pose()
                when = getattr(step, "t", None)
                timestamps[k] = k if when is None else when
                if self.checkpoint_every and ((k + 1) % self.checkpoint_every == 0 or k + 1 == self.step_count):
                    full = slam.estimate()
                    checkpoints.append((k + 1, full.robot, full.covariance[:3, :3]))
                if save is not None and save_every and (k + 1) % save_every == 0 and k + 1 < last:
                    self._done = k + 1
                    self._wall_seconds += time.perf_counter() - started
                    started = time.perf_counter()
                    save(self.snapshot())
                advance()
        self._done = last
        self._wall_seconds += time.perf_counter() - started
        progress = self.snapshot()
        if save is not None:
            save(progress)
        return progress

    def run(self, save: Optional[Callable[[PipelineProgress], None]] = None,
            save_every: Optional[int] = None) -> PipelineResult:
        """Runs every step not done yet (from where ``resume`` or :meth:`run_steps` stood),
        then takes the final estimate. ``save`` and ``save_every``: as in :meth:`run_steps`.

        Raises:
            RuntimeError: when called a second time (the filter already holds the run).
        """
        self.run_steps(self.step_count, save, save_every)
        self._finished = True
        slam = self.slam
        estimate_started = time.perf_counter()
        if isinstance(slam, DCSlam):
            # Joins still queued at the end (their deadlines lie past the last step) are run
            # for real, so that resolve() and stats.joins include them; estimate() then only
            # folds the stack.
            slam.finish_joins()
        estimate = slam.estimate()
        finished = time.perf_counter()
        returned_ids = self._returned_ids
        counts = [len(ids) for ids in returned_ids]
        resolved = slam.resolve(np.concatenate(returned_ids)) if counts else np.empty(0, np.int64)
        measurement_ids = np.split(resolved, np.cumsum(counts)[:-1]) if counts else []
        return PipelineResult(
            filter_name=self.filter_name,
            config=self.config,
            estimate=estimate,
            timestamps=self._timestamps,
            trajectory=self._trajectory,
            measurement_ids=measurement_ids,
            stats=slam.stats,
            estimate_seconds=finished - estimate_started,
            wall_seconds=self._wall_seconds + finished - estimate_started,
            checkpoints=_checkpoints(self._checkpoints) if self.checkpoint_every else None,
        )


def _difference(theirs: Any, mine: Any) -> str:
    """'is X, this run's Y', or for two configs the first field that differs."""
    if isinstance(theirs, SlamConfig) and isinstance(mine, SlamConfig):
        for field in dataclasses.fields(SlamConfig):
            if getattr(theirs, field.name) != getattr(mine, field.name):
                return f"{field.name} is {getattr(theirs, field.name)!r}, this run's {getattr(mine, field.name)!r}"
    return f"is {theirs!r}, this run's {mine!r}"


def _checkpoints(rows: List[tuple]) -> RobotCheckpoints:
    return RobotCheckpoints(steps=np.array([r[0] for r in rows], dtype=np.int64),
                            robot=np.array([r[1] for r in rows]).reshape(-1, 3),
                            covariance=np.array([r[2] for r in rows]).reshape(-1, 3, 3))


@contextlib.contextmanager
def _progress_bar(enabled: bool, description: str, total: int):
    """Yields ``advance()`` for a rich progress bar on the terminal; a no-op when disabled."""
    if not enabled:
        yield lambda: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn()) as progress:
        task = progress.add_task(description, total=total)
        yield lambda: progress.advance(task)
