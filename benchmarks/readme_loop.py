"""How often the README's example closes its loop without ids: the paper's simulator, the
400-step loop (no clutter), D&C with ``association="jcbb"`` and ``join_association="rjc"``,
on scene seeds 1-16 and K of RJC's draws each (``SlamConfig.seed`` 1000 k, k = 0..K-1). A
run closes the loop when ``estimate()``'s robot ends within ``--closed`` metres of the true
final pose (the README's seed 1 ends 0.02 m off; an open loop ends metres off). The EKF is
run beside with ``--ekf``.

Usage: python benchmarks/readme_loop.py [--seeds 16] [--rjc-seeds 3] [--closed 0.5] [--ekf]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import dcslam

RJC_SEED_STRIDE = 1000


def final_error(filter_class, sim, config) -> float:
    slam = filter_class(config)
    slam.run(sim.steps)
    return float(np.linalg.norm(slam.estimate().robot[:2] - sim.poses[-1][:2]))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=16, help="scene seeds 1..N")
    parser.add_argument("--rjc-seeds", type=int, default=3, help="RJC draws a scene seed")
    parser.add_argument("--closed", type=float, default=0.5, help="metres: a closed loop ends within this")
    parser.add_argument("--ekf", action="store_true", help="also the EKF, once a scene seed")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.rjc_seeds < 1 or not args.closed > 0:
        parser.error("--seeds and --rjc-seeds must be at least 1 and --closed positive")
    config = dcslam.SlamConfig(association="jcbb", join_association="rjc")
    closed_first = closed_all = runs = 0
    ekf_closed = 0
    for seed in range(1, args.seeds + 1):
        sim = dcslam.simulate("loop", steps=400, seed=seed)
        errors = [final_error(dcslam.DCSlam, sim, dataclasses.replace(config, seed=RJC_SEED_STRIDE * k))
                  for k in range(args.rjc_seeds)]
        closed = [e <= args.closed for e in errors]
        closed_first += closed[0]
        closed_all += sum(closed)
        runs += len(errors)
        line = f"seed {seed:2d}  D&C final error " + " ".join(f"{e:7.2f}" for e in errors) + " m"
        if args.ekf:
            ekf_error = final_error(dcslam.EkfSlam, sim, config)
            ekf_closed += ekf_error <= args.closed
            line += f"   EKF {ekf_error:7.2f} m"
        print(line, flush=True)
    print(f"D&C closes the loop on {closed_first} of {args.seeds} seeds (first draw), "
          f"{closed_all} of {runs} runs over {args.rjc_seeds} draws"
          + (f"; the EKF on {ekf_closed} of {args.seeds}" if args.ekf else ""))


if __name__ == "__main__":
    main()
