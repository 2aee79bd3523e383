"""Figures of a SLAM run, after Paz et al. 2007, Fig. 5 (the map) and Fig. 6 (the timing).

matplotlib with the Agg backend: files only, no display needed.
"""

from __future__ import annotations

import os
from typing import Optional, Sequence, Tuple, Union

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.collections import EllipseCollection  # noqa: E402

from .metrics import GpsAlignment  # noqa: E402
from .pipeline import PipelineResult  # noqa: E402
from .slam import Estimate  # noqa: E402

__all__ = ["CHI2_2DOF_95", "landmark_blocks", "landmark_ellipses", "plot_map", "plot_timing"]

PathLike = Union[str, "os.PathLike[str]"]

# 95 % quantile of chi-square with 2 degrees of freedom: -2 ln(0.05).
CHI2_2DOF_95 = 5.991464547107979

FILTER_LABELS = {"ekf": "EKF SLAM", "dc": "D&C SLAM"}
FILTER_COLORS = {"ekf": "tab:blue", "dc": "tab:red"}


def landmark_blocks(covariance, n: int) -> np.ndarray:
    """(n, 2, 2) covariance blocks of the landmarks in a (3 + 2n, 3 + 2n) covariance
    ordered [robot, lm 0, lm 1, ...]."""
    covariance = np.asarray(covariance, dtype=float)
    index = 3 + 2 * np.arange(n)
    rows = np.stack([index, index + 1], axis=1)
    return covariance[rows[:, :, None], rows[:, None, :]]


def landmark_ellipses(blocks, quantile: float = CHI2_2DOF_95):
    """Confidence ellipses of 2x2 position covariances.

    Args:
        blocks: (n, 2, 2) covariances.
        quantile: chi-square (2 dof) quantile of the region (default 95 %).

    Returns:
        (widths (n,), heights (n,), angles_deg (n,)): full lengths of the major and minor
        axes and the angle of the major axis from x, in degrees.
    """
    values, vectors = np.linalg.eigh(np.asarray(blocks, dtype=float).reshape(-1, 2, 2))
    values = np.clip(values, 0.0, None)  # rounding can leave a tiny negative eigenvalue
    widths = 2.0 * np.sqrt(quantile * values[:, 1])
    heights = 2.0 * np.sqrt(quantile * values[:, 0])
    angles = np.degrees(np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1]))
    return widths, heights, angles


def _truth_arrays(truth) -> Tuple[np.ndarray, np.ndarray]:
    """(poses (k, 3), landmarks (N, 2)) of a simulation (``poses``, ``landmarks``) or of a
    dataset with ground truth such as :func:`dcslam.datasets.mrclam`'s (``poses_true``,
    ``landmarks_true``)."""
    for poses_name, landmarks_name in (("poses_true", "landmarks_true"), ("poses", "landmarks")):
        if hasattr(truth, poses_name) and hasattr(truth, landmarks_name):
            return getattr(truth, poses_name), getattr(truth, landmarks_name)
    raise ValueError(f"plot_map: truth must be a Simulation or a dataset with poses_true and landmarks_true, "
                     f"got {type(truth).__name__}")


def _points(values, name: str, columns: int) -> np.ndarray:
    """``values`` as a finite (k, >= columns) float array, or a ValueError naming it."""
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"plot_map: {name} must be an array of numbers, got {type(values).__name__}") from None
    if array.ndim != 2 or array.shape[1] < columns:
        raise ValueError(f"plot_map: {name} must have shape (k, {columns}{'+' if columns < 3 else ''}), "
                         f"got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"plot_map: {name} contains a non-finite value")
    return array


def plot_map(
    estimate: Union[Estimate, PipelineResult],
    path: PathLike,
    gps=None,
    alignment: Optional[GpsAlignment] = None,
    title: Optional[str] = None,
    truth_poses=None,
    truth_landmarks=None,
    *,
    truth=None,
    trajectory=None,
) -> None:
    """The map with the 95 % ellipse of every landmark and of the robot, the robot and its
    trajectory (Fig. 5).

    Takes any :class:`~dcslam.Estimate` (``slam.estimate()`` after a loop of your own, or
    :func:`dcslam.io.load_map`'s) or a whole run (:class:`~dcslam.pipeline.PipelineResult`,
    whose trajectory and filter name it uses). Past poses (a D&C run with
    ``keep_local_map_poses``: the robot at each local map's end) are drawn as triangles, as
    the paper's Fig. 5 draws D&C's vehicle locations.

    Args:
        estimate: the map, or the run.
        path: PNG file to write.
        gps: (k, 2) GPS positions to draw (e.g. ``alignment.gps_used``), or None.
        alignment: when given, the map and trajectory are moved into the GPS frame with it;
            otherwise they are drawn in the frame of the first pose.
        title: figure title (default: filter name, steps, map size).
        truth_poses, truth_landmarks: (k, 2+) true trajectory and (N, 2) true landmarks to
            draw, in the frame of the first pose (not moved by ``alignment``), or None.
        truth: a :class:`~dcslam.Simulation` (``poses``, ``landmarks``) or a dataset with
            ground truth (``poses_true``, ``landmarks_true``, e.g.
            :func:`dcslam.datasets.mrclam`'s) to draw instead of ``truth_poses`` and
            ``truth_landmarks``. With a ``PipelineResult`` the true trajectory is cut to the
            run's steps; with an ``Estimate`` it is drawn whole (pass ``truth_poses=
            sim.poses[:k + 1]`` for the first k steps).
        trajectory: (k, 2+) the robot's path to draw with an ``Estimate`` (e.g. the poses
            :meth:`~dcslam.SlamFilter.pose` gave, or ``BatchResult.trajectory``); a
            ``PipelineResult`` brings its own.

    Raises:
        ValueError: ``estimate`` is neither an ``Estimate`` nor a ``PipelineResult``, its
            covariance does not match its landmarks, ``truth`` has no truth, ``truth`` is
            given with ``truth_poses`` or ``truth_landmarks``, or an array has a wrong shape
            or a non-finite value (the message names it).
    """
    if isinstance(estimate, PipelineResult):
        if trajectory is not None:
            raise ValueError("plot_map: a PipelineResult brings its own trajectory; pass trajectory= only with an Estimate")
        result: Optional[PipelineResult] = estimate
        trajectory = estimate.trajectory
        estimate = estimate.estimate
    elif isinstance(estimate, Estimate):
        result = None
    else:
        raise ValueError(f"plot_map: estimate must be a dcslam.Estimate or a PipelineResult, got {type(estimate).__name__}")
    if truth is not None:
        if truth_poses is not None or truth_landmarks is not None:
            raise ValueError("plot_map: give truth= or truth_poses=/truth_landmarks=, not both")
        truth_poses, truth_landmarks = _truth_arrays(truth)
        if result is not None:
            truth_poses = truth_poses[:result.steps + 1]
    n = len(estimate.landmarks)
    landmarks = _points(estimate.landmarks, "estimate.landmarks", 2)
    covariance = np.asarray(estimate.covariance, dtype=float)
    if covariance.shape != (3 + 2 * n, 3 + 2 * n):
        raise ValueError(f"plot_map: estimate.covariance must be ({3 + 2 * n}, {3 + 2 * n}) for {n} landmarks, "
                         f"got {covariance.shape}")
    blocks = landmark_blocks(covariance, n)
    robot_block = covariance[:2, :2].reshape(1, 2, 2)
    trajectory = np.zeros((0, 3)) if trajectory is None else _points(trajectory, "trajectory", 2)
    robot = _points(np.reshape(estimate.robot, (1, -1)), "estimate.robot", 3)
    past_poses = np.asarray(estimate.past_poses, dtype=float).reshape(-1, 3)
    if truth_poses is not None:
        truth_poses = _points(truth_poses, "truth poses", 2)
    if truth_landmarks is not None:
        truth_landmarks = _points(truth_landmarks, "truth landmarks", 2)
    if alignment is not None:
        landmarks = alignment.apply(landmarks) if n else landmarks
        blocks = alignment.apply_covariance(blocks)
        robot_block = alignment.apply_covariance(robot_block)
        trajectory = alignment.apply(trajectory[:, :2]) if len(trajectory) else trajectory
        robot = alignment.apply_poses(robot)
        past_poses = alignment.apply_poses(past_poses) if len(past_poses) else past_poses
    widths, heights, angles = landmark_ellipses(blocks)
    robot_ellipse = landmark_ellipses(robot_block)

    figure, axes = plt.subplots(figsize=(10, 8), dpi=120)
    if gps is not None and len(gps):
        gps = np.asarray(gps, dtype=float)
        axes.plot(gps[:, 0], gps[:, 1], ".", color="tab:green", markersize=2, alpha=0.6, label="GPS")
    if truth_poses is not None and len(truth_poses):
        axes.plot(truth_poses[:, 0], truth_poses[:, 1], "-", color="tab:green", linewidth=0.8, alpha=0.8,
                  label="true trajectory")
    if truth_landmarks is not None and len(truth_landmarks):
        axes.plot(truth_landmarks[:, 0], truth_landmarks[:, 1], "x", color="tab:green", markersize=7,
                  linestyle="none", label=f"true landmarks ({len(truth_landmarks)})")
    if len(trajectory):
        axes.plot(trajectory[:, 0], trajectory[:, 1], "-", color="tab:red", linewidth=0.8, label="robot trajectory")
    if n:
        ellipses = EllipseCollection(widths, heights, angles, units="xy", offsets=landmarks,
                                     offset_transform=axes.transData, facecolors="none",
                                     edgecolors="tab:blue", linewidths=0.7)
        axes.add_collection(ellipses)
        axes.plot(landmarks[:, 0], landmarks[:, 1], "+", color="black", markersize=3, markeredgewidth=0.6,
                  label=f"landmarks ({n}) with 95 % ellipses")
    if len(past_poses):
        axes.plot(past_poses[:, 0], past_poses[:, 1], "^", color="tab:red", markersize=4,
                  linestyle="none", label=f"robot at local-map boundaries ({len(past_poses)})")
    axes.add_collection(EllipseCollection(*robot_ellipse, units="xy", offsets=robot[:, :2],
                                          offset_transform=axes.transData, facecolors="none",
                                          edgecolors="tab:red", linewidths=0.9))
    axes.plot(robot[0, 0], robot[0, 1], marker=(3, 0, np.degrees(robot[0, 2]) - 90), color="tab:red",
              markersize=9, linestyle="none", label="robot with its 95 % ellipse")
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]" + (" (GPS frame; map and trajectory rigidly aligned to GPS)" if alignment is not None else ""))
    axes.set_ylabel("y [m]")
    axes.grid(True, linewidth=0.3)
    if result is not None:
        label = FILTER_LABELS.get(result.filter_name, result.filter_name)
        default_title = f"{label}: {result.steps} steps, {n} landmarks"
    else:
        default_title = f"Map: {n} landmarks"
    if alignment is not None:
        default_title += f", GPS RMS {alignment.rms:.2f} m"
    axes.set_title(title or default_title)
    axes.legend(loc="best", fontsize="small", markerscale=1.5)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def plot_timing(results: Sequence[PipelineResult], path: PathLike, title: Optional[str] = None) -> None:
    """Time per step and cumulative time of one or more runs (Fig. 6).

    Panels: (top, only when a run has D&C joins) per-step time with each join's whole cost
    marked at the step it was created, i.e. what the step would cost without amortization;
    (middle) measured per-step time, the EKF against the amortized D&C; (bottom) cumulative
    time, the last point including the final estimate.
    """
    results = list(results)
    if not results:
        raise ValueError("plot_timing: no results")
    with_joins = any(result.joins for result in results)
    panels = 3 if with_joins else 2
    figure, axes = plt.subplots(panels, 1, figsize=(10, 3.2 * panels), dpi=120, sharex=True)
    axes = list(np.atleast_1d(axes))
    per_step_axes, cumulative_axes = axes[-2], axes[-1]

    for result in results:
        label = FILTER_LABELS.get(result.filter_name, result.filter_name)
        color = FILTER_COLORS.get(result.filter_name)
        steps = np.arange(result.steps)
        milliseconds = 1e3 * result.step_seconds
        if with_joins:
            axes[0].plot(steps, milliseconds, color=color, linewidth=0.6, label=f"{label} step")
            joins = result.joins
            if joins:
                created = np.array([join["step_created"] for join in joins])
                cost = 1e3 * np.array([join["seconds"] for join in joins])
                axes[0].vlines(created, 0, cost, color="black", linewidth=0.8)
                axes[0].plot(created, cost, "v", color="black", markersize=4, label="D&C join (all at once)")
        amortized = " (amortized)" if result.joins and result.config.amortize else ""
        per_step_axes.plot(steps, milliseconds, color=color, linewidth=0.6,
                           label=f"{label}{amortized}: worst {result.worst_step_seconds * 1e3:.1f} ms")
        cumulative = np.cumsum(result.step_seconds)
        if len(cumulative):
            cumulative[-1] += result.estimate_seconds
        cumulative_axes.plot(steps, cumulative, color=color, linewidth=1.2,
                             label=f"{label}: total {result.total_seconds:.2f} s")

    if with_joins:
        axes[0].set_title("Time per step, D&C joins at full cost")
        axes[0].set_ylabel("ms")
    per_step_axes.set_title("Time per step")
    per_step_axes.set_ylabel("ms")
    cumulative_axes.set_title("Cumulative time")
    cumulative_axes.set_ylabel("seconds")
    cumulative_axes.set_xlabel("step")
    for panel in axes:
        panel.grid(True, linewidth=0.3)
        panel.set_ylim(bottom=0)
        panel.legend(loc="upper left", fontsize="small")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
