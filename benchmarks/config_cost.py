"""What does a configuration change cost D&C? Process CPU time of whole runs (every step and the
final estimate), configuration A against B, pair by pair and alternating, so that a loaded
machine slows both alike: Victoria Park through the batch call with its preset, then the
simulator's revisit scenes seed by seed (no ids, 10 % clutter). Prints the B/A ratio of each
pair and their median and range; a ratio, never a time, is the result.

Usage: python benchmarks/config_cost.py --a weak_join_pairings=0 --b weak_join_pairings=30
       [--pairs 7] [--scenarios small_loop_laps,long_revisits] [--seeds 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import dcslam
from dcslam.datasets import victoria_park
from revisit_association import parse_overrides


def cpu_seconds(run) -> float:
    start = time.process_time()
    run()
    return time.process_time() - start


def run_source(config: dcslam.SlamConfig, source) -> None:
    slam = dcslam.DCSlam(config)
    slam.run(source)
    slam.estimate()


def summary(name: str, ratios: list[float]) -> str:
    return f"{name}: B/A CPU median {np.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}), {len(ratios)} pairs"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--a", action="append", default=[], metavar="FIELD=VALUE", help="overrides of run A")
    parser.add_argument("--b", action="append", default=[], metavar="FIELD=VALUE", help="overrides of run B")
    parser.add_argument("--pairs", type=int, default=7, help="Victoria Park pairs")
    parser.add_argument("--scenarios", default="small_loop_laps,long_revisits")
    parser.add_argument("--seeds", type=int, default=10, help="seeds a revisit scene (one pair each)")
    args = parser.parse_args()
    if not args.b:
        raise SystemExit("config_cost.py: give at least one --b FIELD=VALUE (the change to time)")
    a, b = parse_overrides(args.a), {**parse_overrides(args.a), **parse_overrides(args.b)}
    print(f"A: {args.a or 'defaults'}; B: A with {args.b}")

    vp = victoria_park()
    ratios = []
    for k in range(args.pairs):
        seconds_a = cpu_seconds(lambda: run_source(dataclasses.replace(vp.slam_config(), **a), vp))
        seconds_b = cpu_seconds(lambda: run_source(dataclasses.replace(vp.slam_config(), **b), vp))
        ratios.append(seconds_b / seconds_a)
        print(f"victoria_park pair {k}: A {seconds_a:.3f} s, B {seconds_b:.3f} s", flush=True)
    print(summary("victoria_park", ratios), flush=True)

    base = dict(association="jcbb", join_association="rjc")
    for name in filter(None, args.scenarios.split(",")):
        ratios = []
        for seed in range(args.seeds):
            sim = dcslam.revisit_scenario(name, seed)
            seconds_a = cpu_seconds(lambda: run_source(dcslam.SlamConfig(**{**base, **a}, seed=seed), sim))
            seconds_b = cpu_seconds(lambda: run_source(dcslam.SlamConfig(**{**base, **b}, seed=seed), sim))
            ratios.append(seconds_b / seconds_a)
        print(summary(name, ratios), flush=True)


if __name__ == "__main__":
    main()
