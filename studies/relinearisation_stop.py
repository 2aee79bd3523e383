"""When can D&C's re-linearisation passes stop? Each pass predicts the minimum ``m`` of the
linearised batch problem it solves (``stats.counters["relinearisation_predicted_objective"]``);
``F(X) - m``, its objective's departure from that prediction, is the rule's estimate of what
another pass could gain (``SlamConfig.tree_relinearisation_tolerance``). Here it is set beside
the truth of it, ``F(X) - F*``, with ``F*`` the batch least-squares optimum of the run's own
associations solved by the tests' oracle (``tests/python/oracles/batch_least_squares.py``),
after each of the first passes, on simulated scenes with and without ids.

Usage: python studies/relinearisation_stop.py [--passes 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import dcslam

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from oracles.batch_least_squares import batch_optimum  # noqa: E402

# (scene, steps, seed, ids known): the paper's loop with known ids, revisit scenes without.
SCENES = [("loop", 300, 3, True), ("loop", 200, 1, True), ("small_loop_laps", 160, 3, False),
          ("loop_both_ways", 200, 1, False), ("loop_both_ways", 300, 3, False)]


def simulate(scene, steps, seed):
    if scene in dcslam.simulation.REVISIT_SCENARIOS:
        return dcslam.simulation.revisit_scenario(scene, seed=seed, steps=steps)
    return dcslam.simulate(scene, steps=steps, seed=seed)


def run(sim, passes, ids):
    """D&C with exactly `passes` passes: its counters, and what the oracle needs."""
    options = dict(association="known", join_association="known") if ids else {}
    slam = dcslam.DCSlam(dcslam.SlamConfig(tree_relinearisation=passes, tree_relinearisation_tolerance=0.0,
                                           **options))
    returned, trajectory = [], []
    for s in sim.steps:
        slam.predict(s.u, s.Q)
        returned.append(slam.update(s.z, s.R, s.true_ids if ids else None))
        trajectory.append(slam.pose())
    estimate = slam.estimate()
    return slam, estimate, returned, np.array(trajectory)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--passes", type=int, default=3, help="the passes to report, 1 to this many")
    args = parser.parse_args(argv)
    print(f"{'scene':<16} {'steps':>5} {'seed':>4} {'ids':>5} {'pass':>4} {'F - m':>10} {'F - F*':>10}")
    for scene, steps, seed, ids in SCENES:
        sim = simulate(scene, steps, seed)
        optimum = None
        for passes in range(1, args.passes + 1):
            slam, estimate, returned, trajectory = run(sim, passes, ids)
            if optimum is None:
                final_ids = [np.asarray(slam.resolve(np.asarray(i, dtype=np.int64))) for i in returned]
                start = {int(i): np.array(p) for i, p in zip(estimate.landmark_ids, estimate.landmarks)}
                optimum = batch_optimum(sim.steps, final_ids, sim.config.sensor_offset, trajectory, start,
                                        max_iterations=100, tolerance=1e-11)
            counters = slam.stats.counters
            objective = counters["relinearisation_objective"]
            print(f"{scene:<16} {steps:>5} {seed:>4} {str(ids):>5} {passes:>4} "
                  f"{objective - counters['relinearisation_predicted_objective']:>10.3f} "
                  f"{objective - optimum.chi2:>10.3f}", flush=True)


if __name__ == "__main__":
    main()
