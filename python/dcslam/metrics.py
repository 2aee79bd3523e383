"""Measures of a run's result where the truth is not known: a real dataset's run against its
GPS track, the trajectory the final map implies, and how far two maps of one run agree.

:func:`gps_alignment` compares a trajectory with a GPS track (the only reference Victoria Park
has) after a rigid 2D fit (:func:`rigid_fit_2d`, with :func:`gps_outliers` removed first);
:func:`map_trajectory` re-estimates every pose from the final map, so that both filters'
trajectories are judged on the same footing; :func:`map_agreement` says how far two maps of the
same run are the same map. Scores against a simulator's ground truth are in
:mod:`dcslam.evaluation`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Sequence, Tuple

import numpy as np

from . import geometry

if TYPE_CHECKING:  # pipeline.py re-exports this module's names, so it cannot be imported here
    from .pipeline import PipelineResult

__all__ = [
    "GpsAlignment",
    "TooFewGpsFixes",
    "gps_outliers",
    "gps_alignment",
    "rigid_fit_2d",
    "MapAgreement",
    "map_agreement",
    "map_trajectory",
]


class TooFewGpsFixes(ValueError):
    """:func:`gps_alignment` found fewer than two usable GPS fixes in the trajectory's time span
    (a short prefix of a run, or a track whose fixes are all outliers)."""


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
        TooFewGpsFixes: fewer than 2 usable fixes (a ``ValueError``).
    """
    timestamps = np.asarray(timestamps, dtype=float)
    positions = np.asarray(trajectory, dtype=float)[:, :2]
    gps = np.asarray(gps, dtype=float).reshape(-1, 3)
    outlier = gps_outliers(gps, max_speed)
    inside = (gps[:, 0] >= timestamps[0]) & (gps[:, 0] <= timestamps[-1]) if len(timestamps) else np.zeros(len(gps), bool)
    used = gps[~outlier & inside]
    if len(used) < 2:
        raise TooFewGpsFixes(f"gps_alignment: {len(used)} usable GPS fixes in the trajectory's time span; need 2")
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


def map_trajectory(result: PipelineResult, dataset_steps: Sequence[Any],
                   min_landmarks: int = 3) -> Tuple[np.ndarray, np.ndarray]:
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
