"""Data association without ids where it matters: places seen again (issue "Landmarks seen
again are recognised"). Runs EKF+JCBB and D&C (JCBB + RJC) on the revisit scenarios and the
paper's four trajectories, 10 % clutter, several seeds, and scores each final map with
``dcslam.evaluation`` (pairwise precision/recall, features per landmark, wrong merges, final
robot error and NEES) after ``estimate()`` and ``resolve()``.

D&C's joins draw RJC's tries from ``SlamConfig.seed`` (the scene's seed by default here), and on
the revisit scenes the final map depends on those draws: ``--rjc-seeds K`` runs D&C K times on
each scene, with ``SlamConfig.seed`` = seed + 1000 k for k = 0..K-1 (k = 0 is the default run),
and the table's D&C row is then over every scene and draw. The EKF draws nothing and runs once
a scene.

Usage: python benchmarks/revisit_association.py [--seeds 10] [--rjc-seeds 1] [--scenarios a,b]
       [--filters ekf,dc] [--json FILE] [--set field=value ...]   (SlamConfig overrides, e.g.
       --set merge_radius=0; --set association=known --set join_association=known runs both
       filters with the simulator's ids, the ceiling of the robot's NEES)
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import json
import sys
import time
from typing import NoReturn

import numpy as np

import dcslam
from dcslam import evaluation

PAPER_TRAJECTORIES = ("straight", "loop", "lawn_mowing", "snail")  # 600 steps, 10 % clutter
TARGETS = dict(precision=0.98, recall=0.95, features_per_landmark=1.05, nees=11.34)
RJC_SEED_STRIDE = 1000  # --rjc-seeds: the k-th draw on scene seed s uses SlamConfig.seed s + 1000 k


def run_one(filter_name: str, sim, config: dcslam.SlamConfig):
    slam = dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)
    start = time.perf_counter()
    returned = []
    # association="known" (the ceiling of every score association could change): the
    # simulator's ids, clutter marked -1.
    known = config.association == "known"
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        returned.append(slam.update(step.z, step.R, step.true_ids) if known else slam.update(step.z, step.R))
    estimate = slam.estimate()
    seconds = time.perf_counter() - start
    scores = evaluation.evaluate_run(slam, estimate, returned, sim)
    return scores, seconds


def simulation(name: str, seed: int):
    """A revisit scenario, or one of the paper's trajectories at 600 steps with 10 % clutter."""
    if name in dcslam.REVISIT_SCENARIOS:
        return dcslam.revisit_scenario(name, seed)
    if name in PAPER_TRAJECTORIES:
        return dcslam.simulate(name, steps=600, seed=seed, clutter=0.1)
    raise SystemExit(f"unknown scene {name!r}: one of {', '.join([*dcslam.REVISIT_SCENARIOS, *PAPER_TRAJECTORIES])}")


def config_seeds(filter_name: str, seed: int, rjc_seeds: int) -> list[int]:
    """The ``SlamConfig.seed`` of each run of ``filter_name`` on the scene ``seed``: D&C's RJC draws
    differ between them, the EKF has none to draw."""
    draws = rjc_seeds if filter_name == "dc" else 1
    return [seed + RJC_SEED_STRIDE * k for k in range(draws)]


def refuse(message: str) -> NoReturn:
    """Ends a command line on bad arguments as argparse does: the message on stderr, status 2."""
    print(message, file=sys.stderr)
    raise SystemExit(2)


def check_run_counts(seeds: int, rjc_seeds: int) -> None:
    """Refuses scene or draw counts below one, naming both options."""
    if seeds < 1 or rjc_seeds < 1:
        refuse(f"--seeds and --rjc-seeds must be at least 1, got {seeds} and {rjc_seeds}")


def parse_overrides(items):
    """``["field=value", ...]`` -> SlamConfig overrides (values read as JSON, else as numbers
    such as ``inf``, else as strings). A name that is no SlamConfig field is refused with the
    fields closest to it."""
    fields = [field.name for field in dataclasses.fields(dcslam.SlamConfig)]
    overrides = {}
    for item in items:
        name, separator, value = item.partition("=")
        if not separator:
            refuse(f"an override must read FIELD=VALUE, got {item!r}")
        if name not in fields:
            close = difflib.get_close_matches(name, fields, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else "; see docs/api.md for the fields"
            refuse(f"{name!r} in {item!r} is not a SlamConfig field{hint}")
        try:
            overrides[name] = json.loads(value)
        except json.JSONDecodeError:
            try:
                overrides[name] = float(value)  # inf, which JSON spells Infinity
            except ValueError:
                overrides[name] = value  # an option string, e.g. join_association=jcbb
    return overrides


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--rjc-seeds", type=int, default=1,
                        help="D&C runs per scene, each with other RJC draws (SlamConfig.seed + 1000 k)")
    parser.add_argument("--scenarios", default=None, help="comma-separated names (default: all)")
    parser.add_argument("--filters", default="ekf,dc")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    check_run_counts(args.seeds, args.rjc_seeds)

    names = args.scenarios.split(",") if args.scenarios else [*dcslam.REVISIT_SCENARIOS, *PAPER_TRAJECTORIES]
    config = dcslam.SlamConfig(**{"association": "jcbb", "join_association": "rjc", **parse_overrides(args.set)})
    rows = []
    header = (f"{'scenario':16s} {'filter':6s} {'P':>6s} {'R':>6s} {'feat/lm':>7s} {'dup':>5s} {'wrong':>5s} "
              f"{'err m':>6s} {'NEES':>7s} {'NEES ok':>7s} {'all met':>7s} {'s':>5s} {'R min':>6s}")
    print(f"seeds 0..{args.seeds - 1}, {args.rjc_seeds} RJC draw(s) a scene for D&C; means over runs; "
          f"'NEES ok' and 'all met' count runs; 'R min' the lowest recall of a run; config overrides: {args.set}")
    print(header)
    for name in names:
        per_filter = {f: [] for f in args.filters.split(",")}
        for seed in range(args.seeds):
            sim = simulation(name, seed)
            for filter_name in per_filter:
                for config_seed in config_seeds(filter_name, seed, args.rjc_seeds):
                    scores, seconds = run_one(filter_name, sim, dataclasses.replace(config, seed=config_seed))
                    per_filter[filter_name].append((scores, seconds))
                    rows.append(dict(scenario=name, filter=filter_name, seed=seed, config_seed=config_seed, seconds=seconds,
                                     association=dataclasses.asdict(scores.association),
                                     robot=dataclasses.asdict(scores.robot),
                                     majority=dataclasses.asdict(scores.majority), map_size=scores.map_size))
        for filter_name, results in per_filter.items():
            a = [r.association for r, _ in results]
            robot = [r.robot for r, _ in results]
            met = sum(
                x.pairwise_precision >= TARGETS["precision"] and x.pairwise_recall >= TARGETS["recall"]
                and x.features_per_landmark <= TARGETS["features_per_landmark"] and y.nees <= TARGETS["nees"]
                for x, y in zip(a, robot))
            print(f"{name:16s} {filter_name:6s} {np.mean([x.pairwise_precision for x in a]):6.3f} "
                  f"{np.mean([x.pairwise_recall for x in a]):6.3f} {np.mean([x.features_per_landmark for x in a]):7.3f} "
                  f"{np.mean([x.duplicated_landmarks for x in a]):5.1f} {np.mean([x.wrong_merges for x in a]):5.1f} "
                  f"{np.mean([y.position_error for y in robot]):6.2f} {np.median([y.nees for y in robot]):7.1f} "
                  f"{sum(y.consistent99 for y in robot):4d}/{len(robot):<2d} {met:4d}/{len(robot):<2d} "
                  f"{np.mean([s for _, s in results]):5.2f} {min(x.pairwise_recall for x in a):6.3f}", flush=True)
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(dict(config=dataclasses.asdict(config), targets=TARGETS, runs=rows), handle, indent=1)


if __name__ == "__main__":
    main()
