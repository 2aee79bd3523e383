"""D&C with its tree re-linearised in ``estimate()`` (``SlamConfig.tree_relinearisation``)
against plain D&C: how far each map lies from the optimum it approximates, what it does to
accuracy and consistency against the truth, and what it costs.

- ``vp``: Victoria Park without ids (``slam_config(seed=S)``), seeds 0-7 by default. The same
  run (the passes change only the estimate) ends in maps of 0, 1, 2 and ``--converged`` passes;
  each is compared with the batch least-squares optimum of the run's own associations (every
  pose and landmark, Gauss-Newton: the tests' oracle ``oracles/batch_least_squares.py``),
  RMS and max over landmarks, with the time of ``estimate()``, the passes used, the line
  search's halvings, and the batch objective the passes end at next to the oracle's.
- ``mrclam``: MR.CLAM robot 1 (bundled), known ids: landmark RMS and final robot error
  against the Vicon truth for 0, 1, 2, 5 and ``--converged`` passes, the passes used, the
  line search's halvings and the batch objective before and after the passes.
- ``sim``: the paper's four trajectories, known ids, seeds 0-7: landmark RMS against the
  truth, final robot error, and the final estimate's consistency index (heading, and the
  3-dof pose: NEES / chi2(dof, 0.95), Fig. 4's measure), averaged over the seeds.

Every count is run as given (``tree_relinearisation_tolerance`` 0) unless ``--tolerance T``
lets the passes stop early, as the library's default (3.84) does; ``passes_used`` says how many
ran.

Usage: python benchmarks/tree_relinearisation.py [vp|sim|mrclam|both] [--seeds 8] [--steps 500]
       [--passes 0,1,2] [--converged 20] [--tolerance 0] [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

import dcslam
from dcslam.consistency import chi2_threshold, nees

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from oracles.batch_least_squares import batch_optimum  # noqa: E402

TRAJECTORIES = ("straight", "loop", "lawn_mowing", "snail")


def landmarks_by_id(estimate) -> Dict[int, np.ndarray]:
    return {int(i): np.array(p) for i, p in zip(estimate.landmark_ids, estimate.landmarks)}


def victoria_park(seeds: List[int], passes: List[int], tolerance: float) -> List[dict]:
    from dcslam.pipeline import SlamPipeline

    vp = dcslam.datasets.victoria_park()
    rows = []
    for seed in seeds:
        results = {}
        for count in passes:
            config = vp.slam_config(seed=seed, tree_relinearisation=count, tree_relinearisation_tolerance=tolerance)
            results[count] = SlamPipeline(vp.steps, config, filter="dc").run()
        last = results[passes[-1]]
        ids = [np.asarray(i, dtype=np.int64) for i in last.measurement_ids]
        batch = batch_optimum(vp.steps, ids, vp.sensor_offset, last.trajectory, landmarks_by_id(last.estimate))
        for count in passes:
            mapped = landmarks_by_id(results[count].estimate)
            distance = np.array([np.linalg.norm(mapped[i] - batch.landmarks[i]) for i in mapped])
            counters = results[count].stats.counters
            rows.append(dict(seed=seed, passes=count, landmarks=len(mapped),
                             rms_to_optimum=float(np.sqrt(np.mean(distance ** 2))),
                             max_to_optimum=float(distance.max()),
                             estimate_seconds=results[count].estimate_seconds,
                             passes_used=counters.get("relinearisation_passes", 0.0),
                             halvings=counters.get("relinearisation_halvings", 0.0),
                             objective=counters.get("relinearisation_objective", float("nan")),
                             batch_chi2=float(batch.chi2),
                             batch_converged=bool(batch.converged)))
            print(rows[-1], flush=True)
    return rows


def mrclam(passes: List[int], tolerance: float) -> List[dict]:
    dataset = dcslam.datasets.mrclam(robot=1)
    truth = {int(i): p for i, p in zip(dataset.landmark_ids_true, dataset.landmarks_true)}
    rows = []
    for count in passes:
        slam = dcslam.DCSlam(dataset.slam_config(tree_relinearisation=count, tree_relinearisation_tolerance=tolerance))
        for step in dataset.steps:
            slam.predict(step.u, step.Q)
            slam.update(step.z, step.R, step.landmark_ids)
        estimate = slam.estimate()
        error = np.array([p - truth[int(i)] for i, p in zip(estimate.landmark_ids, estimate.landmarks)])
        rows.append(dict(passes=count, landmark_rms=float(np.sqrt(np.mean(np.sum(error ** 2, axis=1)))),
                         robot_error=float(np.linalg.norm(estimate.robot[:2] - dataset.poses_true[-1][:2])),
                         passes_used=slam.stats.counters.get("relinearisation_passes", 0.0),
                         halvings=slam.stats.counters.get("relinearisation_halvings", 0.0),
                         first_objective=slam.stats.counters.get("relinearisation_first_objective", float("nan")),
                         objective=slam.stats.counters.get("relinearisation_objective", float("nan"))))
        print(rows[-1], flush=True)
    return rows


def simulations(seeds: List[int], passes: List[int], steps: int, tolerance: float) -> List[dict]:
    rows = []
    for trajectory in TRAJECTORIES:
        for seed in seeds:
            sim = dcslam.simulate(trajectory, steps=steps, seed=seed)
            base = dcslam.SlamConfig(association="known", join_association="known", seed=seed,
                                     tree_relinearisation_tolerance=tolerance)
            filters = {count: dcslam.DCSlam(dataclasses.replace(base, tree_relinearisation=count)) for count in passes}
            for step in sim.steps:
                for slam in filters.values():
                    slam.predict(step.u, step.Q)
                    slam.update(step.z, step.R, step.true_ids)
            truth = sim.poses[-1]
            for count, slam in filters.items():
                started = time.perf_counter()
                estimate = slam.estimate()
                seconds = time.perf_counter() - started
                error = np.array([p - sim.landmarks[int(i)] for i, p in zip(estimate.landmark_ids, estimate.landmarks)])
                P = estimate.covariance[:3, :3]
                heading_error = math.remainder(estimate.robot[2] - truth[2], 2 * math.pi)
                rows.append(dict(
                    trajectory=trajectory, seed=seed, passes=count,
                    passes_used=slam.stats.counters.get("relinearisation_passes", 0.0),
                    landmark_rms=float(np.sqrt(np.mean(np.sum(error ** 2, axis=1)))),
                    robot_error=float(np.linalg.norm(estimate.robot[:2] - truth[:2])),
                    ci_heading=heading_error ** 2 / P[2, 2] / chi2_threshold(1, 0.05),
                    ci_pose=nees(estimate.robot, P, truth, angle_indices=(2,)) / chi2_threshold(3, 0.05),
                    estimate_seconds=seconds))
        print(trajectory, "done", file=sys.stderr, flush=True)
    return rows


def summarise(rows: List[dict], group: tuple, fields: tuple) -> List[dict]:
    keys = sorted({tuple(r[g] for g in group) for r in rows}, key=lambda k: tuple(str(x) for x in k))
    out = []
    for key in keys:
        chosen = [r for r in rows if tuple(r[g] for g in group) == key]
        out.append({**dict(zip(group, key)), "seeds": len(chosen),
                    **{f: float(np.mean([r[f] for r in chosen])) for f in fields}})
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", default="both", choices=("vp", "sim", "mrclam", "both"))
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--steps", type=int, default=500, help="simulated steps per run")
    parser.add_argument("--passes", default="0,1,2", help="pass counts to compare (0: plain D&C)")
    parser.add_argument("--converged", type=int, default=20, help="one more count, run to convergence")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="SlamConfig.tree_relinearisation_tolerance of every run (0: the counts as given)")
    parser.add_argument("--json", dest="json_out")
    args = parser.parse_args(argv)
    seeds = list(range(args.seeds))
    passes = [int(p) for p in args.passes.split(",")] + [args.converged]
    report = {}
    if args.what in ("vp", "both"):
        rows = victoria_park(seeds, passes, args.tolerance)
        report["vp"] = {"rows": rows, "summary": summarise(rows, ("passes",), ("rms_to_optimum", "max_to_optimum",
                                                                         "estimate_seconds", "passes_used"))}
        for line in report["vp"]["summary"]:
            print("vp", line)
    if args.what == "mrclam":
        report["mrclam"] = mrclam(sorted(set([0, 1, 2, 5] + passes)), args.tolerance)
    if args.what in ("sim", "both"):
        rows = simulations(seeds, passes, args.steps, args.tolerance)
        report["sim"] = {"rows": rows, "summary": summarise(rows, ("trajectory", "passes"),
                                                            ("landmark_rms", "robot_error", "ci_heading", "ci_pose",
                                                             "estimate_seconds", "passes_used"))}
        for line in report["sim"]["summary"]:
            print("sim", line)
    if args.json_out:
        with open(args.json_out, "w") as out:
            json.dump(report, out, indent=1)
    return report


if __name__ == "__main__":
    main()
