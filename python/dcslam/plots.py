"""Figures of a SLAM run, after Paz et al. 2007, Fig. 5 (the map) and Fig. 6 (the timing).

matplotlib with the Agg backend: files only, no display needed.
"""

from __future__ import annotations

import os
from typing import Optional, Sequence, Union

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402
from matplotlib.collections import EllipseCollection  # noqa: E402

from .metrics import GpsAlignment  # noqa: E402
from .pipeline import PipelineResult  # noqa: E402

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


def plot_map(
    result: PipelineResult,
    path: PathLike,
    gps=None,
    alignment: Optional[GpsAlignment] = None,
    title: Optional[str] = None,
    truth_poses=None,
    truth_landmarks=None,
) -> None:
    """The map with the 95 % ellipse of every landmark and the trajectory (Fig. 5).

    A D&C run with ``keep_local_map_poses`` also draws its past poses (the robot at each
    local map's end) as triangles, as the paper's Fig. 5 draws D&C's vehicle locations.

    Args:
        result: the run.
        path: PNG file to write.
        gps: (k, 2) GPS positions to draw (e.g. ``alignment.gps_used``), or None.
        alignment: when given, the map and trajectory are moved into the GPS frame with it;
            otherwise they are drawn in the frame of the first pose.
        title: figure title (default: filter name, steps, map size).
        truth_poses, truth_landmarks: (k, 2+) true trajectory and (N, 2) true landmarks to
            draw, in the frame of the first pose (not moved by ``alignment``), or None.
    """
    estimate = result.estimate
    n = len(estimate.landmarks)
    landmarks = estimate.landmarks
    blocks = landmark_blocks(estimate.covariance, n)
    trajectory = result.trajectory
    robot = estimate.robot.reshape(1, 3)
    past_poses = np.asarray(estimate.past_poses, dtype=float).reshape(-1, 3)
    if alignment is not None:
        landmarks = alignment.apply(landmarks) if n else landmarks
        blocks = alignment.apply_covariance(blocks)
        trajectory = alignment.apply_poses(trajectory) if len(trajectory) else trajectory
        robot = alignment.apply_poses(robot)
        past_poses = alignment.apply_poses(past_poses) if len(past_poses) else past_poses
    widths, heights, angles = landmark_ellipses(blocks)

    figure, axes = plt.subplots(figsize=(10, 8), dpi=120)
    if gps is not None and len(gps):
        gps = np.asarray(gps, dtype=float)
        axes.plot(gps[:, 0], gps[:, 1], ".", color="tab:green", markersize=2, alpha=0.6, label="GPS")
    if truth_poses is not None and len(truth_poses):
        truth_poses = np.asarray(truth_poses, dtype=float)
        axes.plot(truth_poses[:, 0], truth_poses[:, 1], "-", color="tab:green", linewidth=0.8, alpha=0.8,
                  label="true trajectory")
    if truth_landmarks is not None and len(truth_landmarks):
        truth_landmarks = np.asarray(truth_landmarks, dtype=float)
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
    axes.plot(robot[0, 0], robot[0, 1], marker=(3, 0, np.degrees(robot[0, 2]) - 90), color="tab:red",
              markersize=9, linestyle="none", label="final robot pose")
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]" + (" (GPS frame; map and trajectory rigidly aligned to GPS)" if alignment is not None else ""))
    axes.set_ylabel("y [m]")
    axes.grid(True, linewidth=0.3)
    label = FILTER_LABELS.get(result.filter_name, result.filter_name)
    default_title = f"{label}: {result.steps} steps, {n} landmarks"
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
