#!/usr/bin/env python3
"""Fig. 3, rows 2-4, of Paz et al. 2007 from ``dcslam_bench`` JSON: EKF vs D&C SLAM timings.

One column per trajectory:

- time per step, EKF vs D&C with immediate joins (``--joins immediate``);
- cumulative (total) time, EKF vs D&C with immediate joins;
- time per step, EKF vs D&C with amortized joins (``--joins amortized``).

Either run the bench (it writes one JSON per trajectory and join mode into ``--out-dir``)::

    .venv/bin/python studies/timing_figures.py --bench build/dev/benchmarks/dcslam_bench --steps 800

or plot JSON files written before by ``dcslam_bench sim ... --json FILE`` (the trajectory and
join mode are read from each file's ``args``; the EKF curve is taken from any file of the
trajectory, since the EKF does not depend on the join mode)::

    .venv/bin/python studies/timing_figures.py --json results/timing/*.json

``--fit FILE`` prints, for a ``dcslam_bench scaling --json FILE`` output, the exponent of the
least-squares fit of log(total time) against log(final map size), per filter (the paper:
3 for the EKF, 2 for D&C).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional

import numpy as np

TRAJECTORIES = ("straight", "loop", "lawn_mowing", "snail")
JOIN_MODES = ("immediate", "amortized")
# dcslam_bench's defaults, for files written without these options.
BENCH_DEFAULTS = {"trajectory": "snail", "joins": "amortized"}
COLORS = {"ekf": "tab:red", "dc": "tab:blue"}


def bench_option(document: dict, name: str) -> str:
    return document.get("args", {}).get(name, BENCH_DEFAULTS[name])


def run_bench(bench: Path, steps: int, trajectories: List[str], out_dir: Path, seed: int) -> List[Path]:
    """One run per trajectory and join mode; the amortized run skips the EKF (same as immediate)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for trajectory in trajectories:
        for joins in JOIN_MODES:
            path = out_dir / f"{trajectory}_{joins}.json"
            command = [str(bench), "sim", "--trajectory", trajectory, "--steps", str(steps),
                       "--joins", joins, "--filter", "both" if joins == "immediate" else "dc",
                       "--seed", str(seed), "--json", str(path)]
            print(" ".join(command), file=sys.stderr, flush=True)
            subprocess.run(command, check=True, stdout=sys.stderr)
            paths.append(path)
    return paths


class Timing(NamedTuple):
    step_seconds: np.ndarray
    total_seconds: float  # the steps plus the final map (D&C: the last stack joins), as timed by the bench


def load_sim_runs(paths: List[Path]) -> Dict[str, Dict[str, Timing]]:
    """{trajectory: {"ekf" | "dc_immediate" | "dc_amortized": Timing}}."""
    curves: Dict[str, Dict[str, Timing]] = {}
    for path in paths:
        document = json.loads(Path(path).read_text())
        if document.get("command") != "sim":
            raise ValueError(f"{path}: not a 'dcslam_bench sim' output (command {document.get('command')!r})")
        trajectory = bench_option(document, "trajectory")
        joins = bench_option(document, "joins")
        for run in document["runs"]:
            key = "ekf" if run["filter"] == "ekf" else f"dc_{joins}"
            timing = Timing(np.asarray(run["step_seconds"], dtype=float), float(run["total_seconds"]))
            curves.setdefault(trajectory, {})[key] = timing
    return curves


def plot_timings(curves: Dict[str, Dict[str, Timing]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = [t for t in TRAJECTORIES if t in curves] + sorted(set(curves) - set(TRAJECTORIES))
    fig, axes = plt.subplots(3, len(columns), figsize=(4.2 * len(columns), 9.5), squeeze=False)
    rows = (
        ("time per step (s)", "dc_immediate", "D&C", False),
        ("total time (s)", "dc_immediate", "D&C", True),
        ("time per step (s)", "dc_amortized", "D&C amortized", False),
    )
    for column, trajectory in enumerate(columns):
        runs = curves[trajectory]
        for row, (ylabel, dc_key, dc_label, cumulative) in enumerate(rows):
            ax = axes[row, column]
            for key, label, color in (("ekf", "EKF", COLORS["ekf"]), (dc_key, dc_label, COLORS["dc"])):
                if key not in runs:
                    continue
                step_seconds = runs[key].step_seconds
                seconds = np.cumsum(step_seconds) if cumulative else step_seconds
                steps = np.arange(1, len(seconds) + 1)
                ax.plot(steps, seconds, color=color, lw=1.5 if cumulative else 0.8, label=label)
                if cumulative:
                    ax.plot(steps[-1], runs[key].total_seconds, "o", color=color, ms=5,
                            label=f"{label} with final map")
            ax.grid(alpha=0.3)
            if ax.lines:
                ax.legend(fontsize=8, loc="upper left")
            if column == 0:
                ax.set_ylabel(ylabel)
            if row == 0:
                ax.set_title(trajectory.replace("_", " "))
            if row == 2:
                ax.set_xlabel("step")
    fig.suptitle("EKF vs D&C SLAM: time per step (immediate joins), total time, "
                 "time per step (amortized joins)", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def print_summary(curves: Dict[str, Dict[str, Timing]]) -> None:
    for trajectory, runs in curves.items():
        parts = [f"{key} steps {t.step_seconds.sum():.3f} s (total with final map {t.total_seconds:.3f} s), "
                 f"worst step {t.step_seconds.max() * 1e3:.2f} ms"
                 for key, t in sorted(runs.items())]
        print(f"{trajectory}: " + "; ".join(parts))


def fitted_exponents(path: Path) -> Dict[str, float]:
    """Slope of log(total seconds) vs log(final features) over the runs of a scaling file."""
    document = json.loads(Path(path).read_text())
    if document.get("command") != "scaling":
        raise ValueError(f"{path}: not a 'dcslam_bench scaling' output")
    by_filter: Dict[str, list] = {}
    for run in document["runs"]:
        by_filter.setdefault(run["filter"], []).append((run["features"], run["total_seconds"]))
    exponents = {}
    for name, points in by_filter.items():
        features, seconds = np.log(np.array(points, dtype=float)).T
        exponents[name] = float(np.polyfit(features, seconds, 1)[0])
    return exponents


def main(argv: Optional[list] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--json", type=Path, nargs="+", help="dcslam_bench sim JSON files to plot")
    source.add_argument("--bench", type=Path, help="run this dcslam_bench binary first")
    parser.add_argument("--steps", type=int, default=800, help="steps per bench run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trajectories", nargs="+", choices=TRAJECTORIES, default=list(TRAJECTORIES))
    parser.add_argument("--out-dir", type=Path, default=Path("results/timing"),
                        help="where --bench writes its JSON files")
    parser.add_argument("--png", type=Path, default=Path("results/fig3_timing.png"))
    parser.add_argument("--fit", type=Path, help="print fitted exponents of a 'dcslam_bench scaling' JSON")
    args = parser.parse_args(argv)
    if args.fit is None and args.json is None and args.bench is None:
        parser.error("give --json FILES, --bench PATH or --fit FILE")

    if args.fit is not None:
        for name, exponent in fitted_exponents(args.fit).items():
            print(f"{name}: total time ~ n^{exponent:.2f} (n = final map features)")
    if args.json is not None or args.bench is not None:
        paths = args.json or run_bench(args.bench, args.steps, args.trajectories, args.out_dir, args.seed)
        curves = load_sim_runs(paths)
        plot_timings(curves, args.png)
        print_summary(curves)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
