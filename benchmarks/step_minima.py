"""The worst step of a schedule, seen through a noisy machine: reads several runs of
``dcslam_bench vp --filter both --json FILE`` (or any of its commands that write both
filters' ``step_seconds``) and reports, per run, each filter's total and worst step and the
EKF/D&C ratios, then the element-wise minimum of each filter's ``step_seconds`` over all the
runs and its worst entry. A single run's worst step is one sample of the machine's noise
(an interrupt, a page fault); the per-step minima say what the schedule itself costs.

Usage: python benchmarks/step_minima.py run1.json run2.json [...]
       (e.g. four runs: for i in 1 2 3 4; do build/dev/benchmarks/dcslam_bench vp --filter both
       --json /tmp/vp$i.json; done)
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

FILTERS = ("ekf", "dc")


def load_runs(path: pathlib.Path) -> dict[str, dict]:
    try:
        document = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise SystemExit(f"{path}: not a dcslam_bench JSON file ({error})") from error
    runs = {run.get("filter"): run for run in document.get("runs", [])}
    missing = [name for name in FILTERS if name not in runs or "step_seconds" not in runs[name]]
    if missing:
        raise SystemExit(f"{path}: no step_seconds for {', '.join(missing)} (run dcslam_bench with --filter both)")
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=pathlib.Path, metavar="RUN.json")
    args = parser.parse_args()
    loaded = [load_runs(path) for path in args.runs]
    steps = {name: [np.asarray(runs[name]["step_seconds"], dtype=float) for runs in loaded] for name in FILTERS}
    for name in FILTERS:
        lengths = {len(s) for s in steps[name]}
        if len(lengths) != 1:
            raise SystemExit(f"the runs differ in their number of {name} steps ({sorted(lengths)}): not the same data")

    print(f"{'run':28s} {'EKF total s':>11s} {'D&C total s':>11s} {'total ratio':>11s} "
          f"{'EKF worst ms':>12s} {'D&C worst ms':>12s} {'worst ratio':>11s}")
    for path, runs in zip(args.runs, loaded):
        ekf, dc = runs["ekf"], runs["dc"]
        ekf_worst, dc_worst = max(ekf["step_seconds"]), max(dc["step_seconds"])
        print(f"{path.name:28s} {ekf['total_seconds']:11.3f} {dc['total_seconds']:11.3f} "
              f"{ekf['total_seconds'] / dc['total_seconds']:11.1f} {1e3 * ekf_worst:12.2f} {1e3 * dc_worst:12.3f} "
              f"{ekf_worst / dc_worst:11.1f}")

    minima = {name: np.minimum.reduce(steps[name]) for name in FILTERS}
    worst = {name: float(minima[name].max()) for name in FILTERS}
    at = int(minima["dc"].argmax())
    print(f"per-step minima over {len(loaded)} runs: worst EKF {1e3 * worst['ekf']:.3f} ms, "
          f"worst D&C {1e3 * worst['dc']:.3f} ms (step {at}), ratio {worst['ekf'] / worst['dc']:.1f}")


if __name__ == "__main__":
    main()
