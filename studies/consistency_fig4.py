#!/usr/bin/env python3
"""Fig. 4 of Paz et al. 2007: consistency of the robot heading, EKF vs D&C SLAM.

Monte Carlo runs of the simulated straight trajectory (the paper's noise, range–bearing
sensor, known data association). At every ``--every``-th step each filter's full estimate is
compared with the true pose: the heading's consistency index ``CI = NEES / chi2(1, 1 -
alpha)`` (and the 3-dof pose's, ``chi2(3, 1 - alpha)``), the absolute heading error and the
filter's 2-sigma bound. D&C is measured on ``estimate()``, which joins the whole stack on
copies: the paper's "we emptied the stack and carried out all joins at every step", without
disturbing the run.

The "ideal" 2-sigma bounds (the paper's "theoretical (without noise)" ones) come from the
same filters fed the noise-free odometry and measurements with the same Q and R, so their
Jacobians are evaluated at the true state.

    .venv/bin/python studies/consistency_fig4.py --runs 20 --steps 400 --every 5

Writes the figure (``--png``), the mean curves as CSV (``--csv``) and a JSON summary
(``--json``), and prints the summary.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

import dcslam
from dcslam.consistency import chi2_threshold, nees
from dcslam.geometry import compose, invert, observe
from dcslam.packed import Step

FILTERS = ("ekf", "dc")
LABELS = {"ekf": "EKF SLAM", "dc": "D&C SLAM"}
COLORS = {"ekf": "tab:red", "dc": "tab:blue"}
# Per-run quantities recorded at every checkpoint, for each filter.
QUANTITIES = ("ci_heading", "ci_pose", "abs_heading_error", "heading_sigma", "ideal_heading_sigma")


def noise_free_steps(sim) -> List[Step]:
    """The true relative motions and the exact range–bearing of every measured feature."""
    steps = []
    for k, step in enumerate(sim.steps):
        pose = sim.poses[k + 1]
        u = compose(invert(sim.poses[k]), pose)
        z = np.array(
            [observe("range_bearing", (0.0, 0.0, 0.0), pose, sim.landmarks[i]) for i in step.landmark_ids]
        ).reshape(-1, 2)
        steps.append(Step(u, step.Q, z, step.R, landmark_ids=step.landmark_ids, index=k))
    return steps


def make_filters(local_map_features: int, seed: int, join_iterations: int) -> Dict[str, dcslam.SlamFilter]:
    # The paper's D&C: its estimate is the tree as it ran (tree_relinearisation=0).
    cfg = dcslam.SlamConfig(
        tree_relinearisation=0,
        association="known",
        join_association="known",
        local_map_features=local_map_features,
        join_iterations=join_iterations,
        seed=seed,
    )
    return {"ekf": dcslam.EkfSlam(cfg), "dc": dcslam.DCSlam(cfg)}


def checkpoints(steps: int, every: int) -> np.ndarray:
    """Step numbers (1-based: after that many steps) where the estimates are measured."""
    return np.arange(every, steps + 1, every)


def monte_carlo(runs: int, steps: int, seed: int, every: int, local_map_features: int,
                alpha: float, ideal: bool, join_iterations: int) -> Dict[str, np.ndarray]:
    """Returns ``{"<filter>_<quantity>": (runs, checkpoints) array}`` and ``"step"``."""
    at = checkpoints(steps, every)
    heading_threshold = chi2_threshold(1, alpha)
    pose_threshold = chi2_threshold(3, alpha)
    result = {f"{f}_{q}": np.full((runs, len(at)), np.nan) for f in FILTERS for q in QUANTITIES}
    for run in range(runs):
        sim = dcslam.simulate("straight", steps=steps, seed=seed + run)
        noisy = make_filters(local_map_features, seed + run, join_iterations)
        exact = make_filters(local_map_features, seed + run, join_iterations) if ideal else {}
        exact_steps = noise_free_steps(sim) if ideal else []
        begin = 0
        for c, end in enumerate(at):
            true_pose = sim.poses[end]
            for name in FILTERS:
                slam = noisy[name]
                slam.run(sim.steps[begin:end])
                est = slam.estimate()
                P_robot = est.covariance[:3, :3]
                heading_error = math.remainder(est.robot[2] - true_pose[2], 2 * math.pi)
                result[f"{name}_ci_heading"][run, c] = heading_error**2 / P_robot[2, 2] / heading_threshold
                result[f"{name}_ci_pose"][run, c] = (
                    nees(est.robot, P_robot, true_pose, angle_indices=(2,)) / pose_threshold
                )
                result[f"{name}_abs_heading_error"][run, c] = abs(heading_error)
                result[f"{name}_heading_sigma"][run, c] = math.sqrt(P_robot[2, 2])
                if ideal:
                    exact[name].run(exact_steps[begin:end])
                    ideal_variance = exact[name].estimate().covariance[2, 2]
                    result[f"{name}_ideal_heading_sigma"][run, c] = math.sqrt(ideal_variance)
            begin = end
        print(f"run {run + 1}/{runs} done", file=sys.stderr, flush=True)
    result["step"] = at
    return result


def mean_curves(result: Dict[str, np.ndarray]) -> Dict[str, np.ndarray]:
    curves = {"step": result["step"]}
    for name in FILTERS:
        for q in QUANTITIES:
            curves[f"{name}_{q}"] = result[f"{name}_{q}"].mean(axis=0)
    return curves


def summarize(curves: Dict[str, np.ndarray], runs: int, local_map_features: int) -> dict:
    step = curves["step"]
    last_quarter = step > step[-1] * 0.75
    first_quarter = step <= step[-1] * 0.25
    summary = {"runs": runs, "steps": int(step[-1]), "every": int(step[0]),
               "local_map_features": local_map_features}
    for name in FILTERS:
        ci = curves[f"{name}_ci_heading"]
        above = np.flatnonzero(ci > 1.0)
        summary[name] = {
            "first_step_mean_ci_above_1": int(step[above[0]]) if len(above) else None,
            "max_mean_ci_heading": float(ci.max()),
            "mean_ci_heading_first_quarter": float(ci[first_quarter].mean()),
            "mean_ci_heading_last_quarter": float(ci[last_quarter].mean()),
            "mean_ci_pose_last_quarter": float(curves[f"{name}_ci_pose"][last_quarter].mean()),
            "final_mean_abs_heading_error_deg": float(np.degrees(curves[f"{name}_abs_heading_error"][-1])),
            "final_mean_heading_2sigma_deg": float(np.degrees(2 * curves[f"{name}_heading_sigma"][-1])),
        }
    summary["dc_stays_below_1"] = bool(summary["dc"]["max_mean_ci_heading"] < 1.0)
    return summary


def plot(curves: Dict[str, np.ndarray], summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    step = curves["step"]
    fig, (top, middle, bottom) = plt.subplots(
        3, 1, figsize=(8, 11), sharex=True, gridspec_kw={"height_ratios": [3, 3, 2]}
    )
    for name in FILTERS:
        top.plot(step, curves[f"{name}_ci_heading"], color=COLORS[name], lw=2, label=LABELS[name])
    top.axhline(1.0, color="black", lw=1, ls="--", label="CI = 1 (consistency limit)")
    top.set_ylabel("mean CI, robot heading")
    top.set_title(f"Straight trajectory, {summary['runs']} Monte Carlo runs, known association, "
                  f"D&C local maps of {summary['local_map_features']} features", fontsize=10)
    top.legend(fontsize=8, loc="upper left")
    top.grid(alpha=0.3)

    for name in FILTERS:
        middle.plot(step, np.degrees(curves[f"{name}_abs_heading_error"]), color=COLORS[name], lw=2,
                    label=f"{LABELS[name]}, mean |heading error|")
        middle.plot(step, np.degrees(2 * curves[f"{name}_heading_sigma"]), color=COLORS[name], lw=1,
                    ls="--", label=f"{LABELS[name]}, 2σ computed (with noise)")
        ideal = curves[f"{name}_ideal_heading_sigma"]
        if np.all(np.isfinite(ideal)):
            middle.plot(step, np.degrees(2 * ideal), color=COLORS[name], lw=1, ls=":",
                        label=f"{LABELS[name]}, 2σ theoretical (without noise)")
    middle.set_ylabel("robot heading (deg)")
    middle.legend(fontsize=8, loc="upper left")
    middle.grid(alpha=0.3)

    # The pose CI spans two orders of magnitude between the filters: a log axis keeps both legible.
    for name in FILTERS:
        bottom.semilogy(step, curves[f"{name}_ci_pose"], color=COLORS[name], lw=2, label=LABELS[name])
    bottom.axhline(1.0, color="black", lw=1, ls="--", label="CI = 1")
    bottom.set_ylabel("mean CI, robot pose (3 dof)")
    bottom.legend(fontsize=8, loc="upper left")
    bottom.grid(alpha=0.3, which="both")
    bottom.set_xlabel("step")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_csv(curves: Dict[str, np.ndarray], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(curves)
    with path.open("w", newline="") as out:
        writer = csv.writer(out)
        writer.writerow(names)
        for row in zip(*(curves[n] for n in names)):
            writer.writerow([f"{v:.6g}" for v in row])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0, help="run i uses seed + i")
    parser.add_argument("--every", type=int, default=5, help="measure every k-th step")
    parser.add_argument("--local-map-features", type=int, default=30)
    parser.add_argument("--alpha", type=float, default=0.05)
    parser.add_argument("--join-iterations", type=int, default=dcslam.SlamConfig().join_iterations,
                        help="D&C: linearisation points of each join (1: the one-shot join)")
    parser.add_argument("--no-ideal", action="store_true",
                        help="skip the noise-free runs behind the theoretical 2-sigma bounds")
    parser.add_argument("--png", type=Path, default=Path("results/fig4_consistency.png"))
    parser.add_argument("--csv", type=Path, default=Path("results/fig4_consistency.csv"))
    parser.add_argument("--json", type=Path, default=Path("results/fig4_consistency.json"))
    args = parser.parse_args(argv)
    if args.runs < 1 or args.steps < 1 or not 1 <= args.every <= args.steps:
        parser.error("need --runs >= 1, --steps >= 1 and 1 <= --every <= --steps")

    started = time.perf_counter()
    result = monte_carlo(args.runs, args.steps, args.seed, args.every, args.local_map_features,
                         args.alpha, ideal=not args.no_ideal, join_iterations=args.join_iterations)
    curves = mean_curves(result)
    summary = summarize(curves, args.runs, args.local_map_features)
    summary["seconds"] = round(time.perf_counter() - started, 1)
    plot(curves, summary, args.png)
    write_csv(curves, args.csv)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(summary, indent=2) + "\n")

    for name in FILTERS:
        s = summary[name]
        first = s["first_step_mean_ci_above_1"]
        print(f"{LABELS[name]:9s}: mean heading CI first quarter {s['mean_ci_heading_first_quarter']:.2f}, "
              f"last quarter {s['mean_ci_heading_last_quarter']:.2f} (pose {s['mean_ci_pose_last_quarter']:.2f}); "
              f"max {s['max_mean_ci_heading']:.2f}; first step above 1: {first if first else 'never'}")
    print(f"D&C stays below 1: {'yes' if summary['dc_stays_below_1'] else 'no'}")
    print(f"wrote {args.png}, {args.csv}, {args.json} ({summary['seconds']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
