"""Run a SLAM filter over a dataset and collect what a user wants to see of the run.

:class:`SlamPipeline` does the work (the CLI only drives it): it feeds a sequence of steps
to an :class:`~dcslam.EkfSlam` or :class:`~dcslam.DCSlam`, records the robot's pose after
every step and the filter's own per-step timings, and ends with the full estimate, all in a
:class:`PipelineResult`. :func:`gps_alignment` compares a trajectory with a GPS track (the
only reference Victoria Park has) after a rigid 2D fit; :func:`map_trajectory` re-estimates
every pose from the final map, so that both filters' trajectories are judged on the same
footing; :func:`map_agreement` says how far two maps of the same run are the same map.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from . import geometry
from .config import SlamConfig
from .slam import DCSlam, DCSlamStats, EkfSlam, Estimate, SlamFilter, SlamStats

__all__ = [
    "FILTERS",
    "PipelineResult",
    "SlamPipeline",
    "GpsAlignment",
    "gps_outliers",
    "gps_alignment",
    "rigid_fit_2d",
    "MapAgreement",
    "map_agreement",
    "map_trajectory",
]

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
    ):
        if filter not in FILTERS:
            raise ValueError(f"SlamPipeline: filter must be one of {', '.join(FILTERS)}, got {filter!r}")
        if max_steps is not None and max_steps < 0:
            raise ValueError(f"SlamPipeline: max_steps must be >= 0, got {max_steps}")
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
        )


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


@dataclasses.dataclass(frozen=True)
class GpsAlignment:
    """A rigid 2D transform (no scale) taking trajectory coordinates onto GPS coordinates.

    ``gps ≈ rotation @ p + translation``.

    Attributes:
        rotation: (2, 2); translation: (2,); yaw: the rotation's angle [rad].
        rms: root mean square of the residual distances [m] over the fixes used.
        residuals: (k,) distance of each used fix from the aligned trajectory [m].
        times: (k,) times of the used fixes.
        gps_used: (k, 2) the fixes used (inliers inside the trajectory's time span).
        trajectory_at_gps: (k, 2) trajectory positions interpolated at ``times``
            (trajectory frame, before alignment).
        outliers: number of fixes removed as outliers (see :func:`gps_outliers`).
    """

    rotation: np.ndarray
    translation: np.ndarray
    yaw: float
    rms: float
    residuals: np.ndarray
    times: np.ndarray
    gps_used: np.ndarray
    trajectory_at_gps: np.ndarray
    outliers: int

    def apply(self, points) -> np.ndarray:
        """(n, 2) points in the trajectory's frame -> GPS frame."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    def apply_poses(self, poses) -> np.ndarray:
        """(n, 3) poses (x, y, phi) in the trajectory's frame -> GPS frame."""
        poses = np.asarray(poses, dtype=float)
        headings = np.arctan2(np.sin(poses[:, 2] + self.yaw), np.cos(poses[:, 2] + self.yaw))
        return np.column_stack([self.apply(poses[:, :2]), headings])

    def apply_covariance(self, covariance) -> np.ndarray:
        """(..., 2, 2) position covariances -> GPS frame (``R C R'``)."""
        return self.rotation @ np.asarray(covariance, dtype=float) @ self.rotation.T


def gps_outliers(gps, max_speed: float = 20.0) -> np.ndarray:
    """Marks GPS fixes that imply an impossible jump.

    A fix is an outlier when reaching it from the last accepted fix needs more than
    ``max_speed`` [m/s] (the car never exceeds 7 m/s; Victoria Park's GPS has 12 jumps above
    20 m/s). Comparing with the last *accepted* fix, not the previous one, keeps a run of bad
    fixes out; the allowed distance grows with the time since that fix, so the track
    recovers after a real jump across a gap.

    Args:
        gps: (k, 3) t, x, y with non-decreasing t; the first fix is trusted.

    Returns:
        (k,) bool, True for outliers.
    """
    gps = np.asarray(gps, dtype=float)
    outlier = np.zeros(len(gps), dtype=bool)
    if len(gps) == 0:
        return outlier
    last = gps[0]
    for k in range(1, len(gps)):
        elapsed = gps[k, 0] - last[0]
        distance = float(np.hypot(*(gps[k, 1:] - last[1:])))
        if distance > max_speed * elapsed:
            outlier[k] = True
        else:
            last = gps[k]
    return outlier


def rigid_fit_2d(source, target):
    """Least-squares rotation and translation (no scale) with ``target ≈ R @ source + t``.

    Umeyama's/Kabsch's closed form: the SVD of the cross-covariance of the centred point
    sets, with the reflection case excluded.

    Args:
        source, target: (n, 2) paired points, n >= 2.

    Returns:
        (R (2, 2), t (2,)).
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 2 or len(source) < 2:
        raise ValueError(f"rigid_fit_2d: need two (n, 2) arrays with n >= 2, got {source.shape} and {target.shape}")
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    cross = (target - target_mean).T @ (source - source_mean)
    u, _, vt = np.linalg.svd(cross)
    flip = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])  # -1 would be a reflection: undo it
    rotation = u @ flip @ vt
    return rotation, target_mean - rotation @ source_mean


def gps_alignment(timestamps, trajectory, gps, max_speed: float = 20.0) -> GpsAlignment:
    """Fits the trajectory onto GPS with a rigid 2D transform and reports the residual.

    GPS outliers are removed (:func:`gps_outliers`), fixes outside the trajectory's time
    span are dropped, trajectory positions are interpolated linearly at the remaining GPS
    times, and :func:`rigid_fit_2d` gives the transform.

    Args:
        timestamps: (k,) increasing times of the trajectory's poses.
        trajectory: (k, 2) or (k, 3) positions (a heading column is ignored).
        gps: (g, 3) t, x, y on the same clock.

    Raises:
        ValueError: fewer than 2 usable fixes.
    """
    timestamps = np.asarray(timestamps, dtype=float)
    positions = np.asarray(trajectory, dtype=float)[:, :2]
    gps = np.asarray(gps, dtype=float).reshape(-1, 3)
    outlier = gps_outliers(gps, max_speed)
    inside = (gps[:, 0] >= timestamps[0]) & (gps[:, 0] <= timestamps[-1]) if len(timestamps) else np.zeros(len(gps), bool)
    used = gps[~outlier & inside]
    if len(used) < 2:
        raise ValueError(f"gps_alignment: {len(used)} usable GPS fixes in the trajectory's time span; need 2")
    at_gps = np.column_stack([np.interp(used[:, 0], timestamps, positions[:, i]) for i in range(2)])
    rotation, translation = rigid_fit_2d(at_gps, used[:, 1:])
    residuals = np.linalg.norm(at_gps @ rotation.T + translation - used[:, 1:], axis=1)
    return GpsAlignment(
        rotation=rotation,
        translation=translation,
        yaw=float(np.arctan2(rotation[1, 0], rotation[0, 0])),
        rms=float(np.sqrt(np.mean(residuals**2))),
        residuals=residuals,
        times=used[:, 0],
        gps_used=used[:, 1:],
        trajectory_at_gps=at_gps,
        outliers=int(outlier.sum()),
    )


def map_trajectory(result: PipelineResult, dataset_steps: Sequence[Any], min_landmarks: int = 3):
    """Each step's robot pose re-estimated from the final map.

    A filter's own trajectory is what it knew at each step. For the EKF that is the
    filtered pose; for D&C it is the chain of local maps, which only holds the joins done by
    then, so loop closures found later never reach it. To compare the two on the same
    footing, every step's measurements are placed in the robot frame (range–bearing or
    points, with the config's sensor offset) and rigidly fitted (:func:`rigid_fit_2d`) onto
    the final-map landmarks their resolved ids point to. The result is what the final map
    says the robot's path was, the same computation for both filters.

    Args:
        result: the run (its ``measurement_ids`` and ``estimate``).
        dataset_steps: the steps it ran on (``s.z`` of each).
        min_landmarks: steps with fewer paired measurements get no pose.

    Returns:
        (timestamps (k,), poses (k, 3)) of the steps that got a pose.
    """
    config = result.config
    position_of = {int(i): p for i, p in zip(result.estimate.landmark_ids, result.estimate.landmarks)}
    origin = np.zeros(3)
    times, poses = [], []
    for k, ids in enumerate(result.measurement_ids):
        paired = [(z, position_of[int(i)]) for z, i in zip(dataset_steps[k].z, ids) if int(i) in position_of]
        if len(paired) < min_landmarks:
            continue
        in_robot = np.array([geometry.inverse_observe(config.observation, config.sensor_offset, origin, z)
                             for z, _ in paired])
        rotation, translation = rigid_fit_2d(in_robot, np.array([p for _, p in paired]))
        poses.append([translation[0], translation[1], np.arctan2(rotation[1, 0], rotation[0, 0])])
        times.append(result.timestamps[k])
    return np.array(times), np.array(poses).reshape(-1, 3)


@dataclasses.dataclass(frozen=True)
class MapAgreement:
    """How far two maps of the same run are the same map (see :func:`map_agreement`).

    Attributes:
        first_in_second: share of the first map's landmarks with a landmark of the second
            within ``radius``; second_in_first: the same the other way round.
        radius: the distance used [m].
        first_size, second_size: landmark counts.
    """

    first_in_second: float
    second_in_first: float
    radius: float
    first_size: int
    second_size: int


def map_agreement(first, second, radius: float = 1.0) -> MapAgreement:
    """Share of each map's landmarks that lie within ``radius`` of a landmark of the other.

    No alignment: both maps must be in the same frame, as two filters' estimates of one run
    are (the first pose's frame). Duplicated landmarks in one map do not lower its own share
    (each copy has a neighbour in the other map) but leave no trace in the other share
    either; compare the sizes as well.

    Args:
        first, second: :class:`~dcslam.Estimate` or (n, 2) landmark positions.
        radius: the largest distance [m] at which two landmarks count as the same.

    Returns:
        :class:`MapAgreement`; a share is 1.0 when its map is empty.
    """
    if radius <= 0:
        raise ValueError(f"map_agreement: radius must be positive, got {radius}")
    first_points = _landmark_positions(first, "first")
    second_points = _landmark_positions(second, "second")
    return MapAgreement(
        first_in_second=_share_near(first_points, second_points, radius),
        second_in_first=_share_near(second_points, first_points, radius),
        radius=float(radius),
        first_size=len(first_points),
        second_size=len(second_points),
    )


def _landmark_positions(map_or_points, name: str) -> np.ndarray:
    points = np.asarray(getattr(map_or_points, "landmarks", map_or_points), dtype=float)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"map_agreement: {name} must be an Estimate or (n, 2) positions, got shape {points.shape}")
    return points


def _share_near(points: np.ndarray, others: np.ndarray, radius: float) -> float:
    if len(points) == 0:
        return 1.0
    if len(others) == 0:
        return 0.0
    # Sorted by x, each point only looks at the others within radius in x: O((n + m) log m)
    # plus the neighbours in the strip, instead of an n x m distance matrix.
    order = np.argsort(others[:, 0])
    sorted_others = others[order]
    lows = np.searchsorted(sorted_others[:, 0], points[:, 0] - radius, side="left")
    highs = np.searchsorted(sorted_others[:, 0], points[:, 0] + radius, side="right")
    near = 0
    for point, low, high in zip(points, lows, highs):
        strip = sorted_others[low:high]
        if len(strip) and np.min(np.hypot(*(strip - point).T)) <= radius:
            near += 1
    return near / len(points)
