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
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from . import metrics as _metrics
from .config import SlamConfig
# The evaluation of a result lived here before metrics.py, and user code imports it from
# dcslam.pipeline: every name metrics exports stays importable from here.
from .metrics import *  # noqa: F401,F403
from .slam import DCSlam, DCSlamStats, EkfSlam, Estimate, SlamFilter, SlamStats

__all__ = ["FILTERS", "PipelineResult", "RobotCheckpoints", "SlamPipeline", *_metrics.__all__]


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
        ids_field: step attribute holding landmark ids, used in ``"known"`` association
            (``"landmark_ids"`` for iSAM files, ``"true_ids"`` for the simulator).
        progress: show a progress bar on the terminal.
        description: label of the progress bar.
        checkpoint_every: take the full estimate every this many steps (and after the last)
            and keep its robot and covariance (``result.checkpoints``); ``None``: never. Its
            time (the estimate's) counts in ``wall_seconds`` but not in the filter's steps.

    Raises:
        ValueError: unknown filter name, or options the filter refuses (raised when the
            filter is built, before any step runs).
    """

    def __init__(
        self,
        dataset_steps: Sequence[Any],
        cfg: SlamConfig,
        filter: str = "dc",
        max_steps: Optional[int] = None,
        ids_field: str = "landmark_ids",
        progress: bool = False,
        description: Optional[str] = None,
        checkpoint_every: Optional[int] = None,
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
        self.ids_field = ids_field
        self.progress = progress
        self.description = description or f"{filter} SLAM"
        # Built here so that refused options fail before a long run starts.
        self.slam: SlamFilter = FILTERS[filter](cfg)
        self._ran = False

    def run(self) -> PipelineResult:
        """Runs every step, then takes the final estimate.

        Raises:
            RuntimeError: when called a second time (the filter already holds the run).
        """
        if self._ran:
            raise RuntimeError("SlamPipeline.run: this pipeline already ran; build a new one")
        self._ran = True
        slam = self.slam
        use_ids = self.config.association == "known"
        timestamps = np.empty(self.step_count)
        trajectory = np.empty((self.step_count, 3))
        returned_ids = []
        checkpoints: List[tuple] = []
        started = time.perf_counter()
        with _progress_bar(self.progress, self.description, self.step_count) as advance:
            for k in range(self.step_count):
                step = self.dataset_steps[k]
                slam.predict(step.u, step.Q)
                ids = getattr(step, self.ids_field) if use_ids else None
                returned_ids.append(slam.update(step.z, step.R, ids))
                trajectory[k] = slam.pose()
                when = getattr(step, "t", None)
                timestamps[k] = k if when is None else when
                if self.checkpoint_every and ((k + 1) % self.checkpoint_every == 0 or k + 1 == self.step_count):
                    full = slam.estimate()
                    checkpoints.append((k + 1, full.robot, full.covariance[:3, :3]))
                advance()
        estimate_started = time.perf_counter()
        if isinstance(slam, DCSlam):
            # Joins still queued at the end (their deadlines lie past the last step) are run
            # for real, so that resolve() and stats.joins include them; estimate() then only
            # folds the stack.
            slam.finish_joins()
        estimate = slam.estimate()
        finished = time.perf_counter()
        counts = [len(ids) for ids in returned_ids]
        resolved = slam.resolve(np.concatenate(returned_ids)) if counts else np.empty(0, np.int64)
        measurement_ids = np.split(resolved, np.cumsum(counts)[:-1]) if counts else []
        return PipelineResult(
            filter_name=self.filter_name,
            config=self.config,
            estimate=estimate,
            timestamps=timestamps,
            trajectory=trajectory,
            measurement_ids=measurement_ids,
            stats=slam.stats,
            estimate_seconds=finished - estimate_started,
            wall_seconds=finished - started,
            checkpoints=_checkpoints(checkpoints) if self.checkpoint_every else None,
        )


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
