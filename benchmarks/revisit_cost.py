"""Where a run's time goes on scenes seen again, without ids: per run, the steps (``predict`` +
``update``, timed from Python), the worst step, the final ``estimate()``, and the association
scores, so that a cost and what it buys are read side by side. The revisit scenes and the
paper's trajectories (600 steps) at 10 % clutter, JCBB in the EKF and the local maps, RJC at
the joins, as ``revisit_association.py`` runs them.

``--estimate-every N`` also calls ``estimate()`` after every N-th step, as a user watching the
map during the run does, and reports those calls' total ("anytime s", outside "steps s") and,
for D&C, how many pending joins they computed on the side and how many of those an earlier
call had already computed ("pending" and "reused", ``stats.counters``).

Usage: python benchmarks/revisit_cost.py [--scenarios long_revisits,loop] [--seeds 3]
       [--filters ekf,dc] [--estimate-every N] [--set FIELD=VALUE ...]   (SlamConfig overrides)
"""

from __future__ import annotations

import argparse
import time

import dcslam
from dcslam import evaluation
from revisit_association import parse_overrides, simulation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default="long_revisits,loop")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--filters", default="ekf,dc")
    parser.add_argument("--estimate-every", type=int, default=0, metavar="N",
                        help="also call estimate() after every N-th step (0: only at the end)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    args = parser.parse_args()
    if args.estimate_every < 0:
        parser.error(f"--estimate-every must be 0 or more, got {args.estimate_every}")
    overrides = {"association": "jcbb", "join_association": "rjc", **parse_overrides(args.set)}
    print(f"{'scene':16s} {'seed':>4s} {'filter':6s} {'steps s':>8s} {'worst ms':>8s} {'estimate s':>10s} "
          f"{'R':>6s} {'P':>6s}" + (f" {'anytime s':>9s} {'pending':>7s} {'reused':>6s}" if args.estimate_every else ""))
    for name in args.scenarios.split(","):
        for seed in range(args.seeds):
            sim = simulation(name, seed)
            for filter_name in args.filters.split(","):
                config = dcslam.SlamConfig(seed=seed, **overrides)
                slam = dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)
                returned, steps, anytime = [], [], 0.0
                for k, step in enumerate(sim.steps, 1):
                    start = time.perf_counter()
                    slam.predict(step.u, step.Q)
                    returned.append(slam.update(step.z, step.R))
                    steps.append(time.perf_counter() - start)
                    if args.estimate_every and k % args.estimate_every == 0:
                        start = time.perf_counter()
                        slam.estimate()
                        anytime += time.perf_counter() - start
                start = time.perf_counter()
                estimate = slam.estimate()
                estimate_seconds = time.perf_counter() - start
                scores = evaluation.evaluate_run(slam, estimate, returned, sim).association
                row = (f"{name:16s} {seed:4d} {filter_name:6s} {sum(steps):8.2f} {max(steps) * 1e3:8.1f} "
                       f"{estimate_seconds:10.2f} {scores.pairwise_recall:6.3f} {scores.pairwise_precision:6.3f}")
                if args.estimate_every:
                    counters = slam.stats.counters
                    row += (f" {anytime:9.2f} {counters.get('estimate_pending_joins', 0):7.0f}"
                            f" {counters.get('estimate_pending_joins_reused', 0):6.0f}")
                print(row, flush=True)


if __name__ == "__main__":
    main()
