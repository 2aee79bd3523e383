"""Does a configuration change help data association, seed by seed? Runs one filter twice on
the same simulations without ids (10 % clutter), once as configured (A) and once with the
given SlamConfig overrides (B), and reports per scene the means of both, the paired
difference B - A of recall and precision with its standard error, and how many seeds went up
or down; then, per side, the duplicated landmarks a run (mean), the runs whose final robot
lies within its 99 % ellipse (NEES <= 11.34), and the medians of the final robot error and
NEES. A single change moves a 10-seed mean by up to +-0.03 through seed chaos alone
(docs/data_association.md), which a paired difference over 20 or more seeds sees through.
With ``--rjc-seeds K`` each scene is run with K draws of RJC's tries (``SlamConfig.seed`` =
seed + 1000 k, as ``benchmarks/revisit_association.py --rjc-seeds`` runs them) on both sides,
each draw a pair: on long_revisits one run depends on its draw ("D&C's map depends on RJC's
draws"), and more draws show whether a change moved the lottery or the scene.

Usage: python studies/paired_association.py --b merge_confidence=0.9999 [--a FIELD=VALUE ...]
       [--seeds 20] [--rjc-seeds 1] [--scenarios small_loop_laps,loop_both_ways,lawn_overlap]
       [--filter dc] [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys

import numpy as np

import dcslam

# The revisit benchmark's runner and its overrides, so that both score a run the same way.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
from revisit_association import TARGETS, check_run_counts, config_seeds, parse_overrides, run_one, simulation  # noqa: E402

DEFAULT_SCENES = "small_loop_laps,loop_both_ways,lawn_overlap"


def standard_error(d: np.ndarray) -> float:
    return float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--a", action="append", default=[], metavar="FIELD=VALUE", help="overrides of run A")
    parser.add_argument("--b", action="append", default=[], metavar="FIELD=VALUE", help="overrides of run B")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--rjc-seeds", type=int, default=1, help="D&C runs per scene and side, each with other RJC draws")
    parser.add_argument("--scenarios", default=DEFAULT_SCENES, help="comma-separated scene names: revisit scenarios or the paper's trajectories (600 steps, 10 %% clutter)")
    parser.add_argument("--filter", choices=("dc", "ekf"), default="dc")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    if not args.b:
        sys.exit("paired_association.py: give at least one --b FIELD=VALUE (the change to measure)")
    check_run_counts(args.seeds, args.rjc_seeds)

    base = dict(association="jcbb", join_association="rjc")
    overrides_a = parse_overrides(args.a)
    config_a = dcslam.SlamConfig(**{**base, **overrides_a})
    config_b = dcslam.SlamConfig(**{**base, **overrides_a, **parse_overrides(args.b)})
    draws = f", {args.rjc_seeds} RJC draws a scene (up/down count runs)" if args.rjc_seeds > 1 else ""
    print(f"{args.filter}, seeds 0..{args.seeds - 1}{draws}; A: {args.a or 'defaults'}; B: A with {args.b}")
    print(f"{'scenario':16s} {'R A':>6s} {'R B':>6s} {'dR':>7s} {'+-':>6s} {'up':>3s} {'down':>4s} "
          f"{'P A':>6s} {'P B':>6s} {'dP':>8s} {'+-':>7s}")
    rows = []
    for name in args.scenarios.split(","):
        pairs, robots = [], []
        for seed in range(args.seeds):
            sim = simulation(name, seed)
            for config_seed in config_seeds(args.filter, seed, args.rjc_seeds):
                a = run_one(args.filter, sim, dataclasses.replace(config_a, seed=config_seed))[0]
                b = run_one(args.filter, sim, dataclasses.replace(config_b, seed=config_seed))[0]
                pairs.append((a.association, b.association))
                robots.append((a.robot, b.robot))
                rows.append(dict(scenario=name, seed=seed, config_seed=config_seed, a=dataclasses.asdict(a.association),
                                 b=dataclasses.asdict(b.association), robot_a=dataclasses.asdict(a.robot),
                                 robot_b=dataclasses.asdict(b.robot)))
        recall = np.array([[a.pairwise_recall, b.pairwise_recall] for a, b in pairs])
        precision = np.array([[a.pairwise_precision, b.pairwise_precision] for a, b in pairs])
        d_recall, d_precision = recall[:, 1] - recall[:, 0], precision[:, 1] - precision[:, 0]
        print(f"{name:16s} {recall[:, 0].mean():6.3f} {recall[:, 1].mean():6.3f} {d_recall.mean():+7.3f} "
              f"{standard_error(d_recall):6.3f} {int((d_recall > 0).sum()):3d} {int((d_recall < 0).sum()):4d} "
              f"{precision[:, 0].mean():6.3f} {precision[:, 1].mean():6.3f} {d_precision.mean():+8.4f} "
              f"{standard_error(d_precision):7.4f}", flush=True)
        for side, k in (("A", 0), ("B", 1)):
            robot = [r[k] for r in robots]
            nees_ok = sum(r.nees <= TARGETS["nees"] for r in robot)
            print(f"{'':16s} {side}: duplicated landmarks {np.mean([p[k].duplicated_landmarks for p in pairs]):.1f} a run, "
                  f"NEES ok {nees_ok}/{len(robot)}, robot error median {np.median([r.position_error for r in robot]):.2f} m, "
                  f"NEES median {np.median([r.nees for r in robot]):.1f}", flush=True)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(
            dict(filter=args.filter, a=dataclasses.asdict(config_a), b=dataclasses.asdict(config_b), runs=rows),
            indent=1))


if __name__ == "__main__":
    main()
