"""D&C's online pose on places seen again, with and without ``SlamConfig.online_localisation_sigma``.

D&C's online pose (``pose()``, the trajectory of ``run()``) composes the robots of the stack's
maps; it learns that the robot is back in a mapped place only once the joins reach that
place's map. ``online_localisation_sigma`` localises each closed local map against the oldest
map when the chain between them leaves the pose with a position standard deviation of at
most that many metres. This compares, without ids:

- on the simulated scenes (10 % clutter, ``--seeds`` each), the online trajectory against the
  simulator's truth (RMS, largest and final error, means over the seeds), for the EKF, plain
  D&C and D&C with each ``--sigma``, and the run's time;
- with ``--vp``, Victoria Park (the bundled data, its preset), where there is no truth: every
  250 scans, the online pose against the robot of the plain filter's ``estimate()`` (within
  the batch optimum's 99 % ellipse at every such sample, docs/divide_and_conquer.md), and the
  whole run's time.

The maps and estimates are the same with and without the option (tests/python/
test_online_localisation.py); only the online pose moves. Written up in
docs/divide_and_conquer.md ("The online pose on places seen again").

    .venv/bin/python studies/online_pose.py [--scenarios small_loop_laps,...] [--seeds 5]
        [--sigma 1.0] [--sigma inf] [--vp]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import dcslam

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from revisit_association import simulation  # noqa: E402

SCENES = "small_loop_laps,loop_both_ways,lawn_overlap,lawn_mowing,loop"


def simulated(scene: str, seeds: int, sigmas: list[float]) -> None:
    variants = [("EKF", None), ("D&C", None)] + [(f"D&C, sigma {s:g} m", s) for s in sigmas]
    rows: dict[str, list] = {name: [] for name, _ in variants}
    for seed in range(seeds):
        sim = simulation(scene, seed)
        truth = np.asarray(sim.poses)[:, :2]
        for name, sigma in variants:
            config = dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=seed,
                                       online_localisation_sigma=sigma)
            slam = dcslam.EkfSlam(config) if name == "EKF" else dcslam.DCSlam(config)
            start = time.process_time()
            result = slam.run(sim)
            seconds = time.process_time() - start
            error = np.linalg.norm(result.trajectory[:, :2] - truth, axis=1)
            rows[name].append((np.sqrt(np.mean(error ** 2)), error.max(), error[-1],
                               slam.stats.counters.get("online_localisations", 0.0), seconds))
    for name, values in rows.items():
        m = np.mean(np.array(values), axis=0)
        print(f"{scene:16s} {name:20s} {m[0]:8.2f} {m[1]:8.2f} {m[2]:8.2f} {m[3]:8.1f} {m[4]:8.2f}")


def victoria_park(sigmas: list[float]) -> None:
    from dcslam.datasets import victoria_park as load

    vp = load()
    variants = [("D&C", None)] + [(f"D&C, sigma {s:g} m", s) for s in sigmas]
    filters = {name: dcslam.DCSlam(vp.slam_config(seed=0, online_localisation_sigma=s)) for name, s in variants}
    seconds = {name: 0.0 for name in filters}
    gaps: dict[str, list[float]] = {name: [] for name in filters}
    for k, step in enumerate(vp.steps):
        for name, slam in filters.items():
            start = time.process_time()
            slam.predict(step.u, step.Q)
            slam.update(step.z, step.R)
            seconds[name] += time.process_time() - start
        if (k + 1) % 250 and k + 1 != len(vp.steps):
            continue
        reference = filters["D&C"].estimate().robot
        for name, slam in filters.items():
            gaps[name].append(float(np.linalg.norm(slam.pose()[:2] - reference[:2])))
    print(f"\nVictoria Park, {len(gaps['D&C'])} samples: online pose - plain estimate()'s robot [m]")
    print(f"{'':20s} {'median':>8s} {'largest':>8s} {'final':>8s} {'localised':>9s} {'steps s':>8s}")
    for name, slam in filters.items():
        g = np.array(gaps[name])
        print(f"{name:20s} {np.median(g):8.2f} {g.max():8.2f} {g[-1]:8.2f} "
              f"{slam.stats.counters.get('online_localisations', 0.0):9.0f} {seconds[name]:8.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default=SCENES, help="comma-separated; '' for none")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--sigma", type=float, action="append", default=None,
                        help="SlamConfig.online_localisation_sigma values to compare [m] (default: 1.0 and inf)")
    parser.add_argument("--vp", action="store_true", help="also Victoria Park")
    args = parser.parse_args()
    sigmas = args.sigma or [1.0, float("inf")]
    if args.scenarios:
        print("online trajectory - truth, means over seeds 0.." + str(args.seeds - 1) + " (10 % clutter, no ids)")
        print(f"{'scene':16s} {'filter':20s} {'RMS m':>8s} {'max m':>8s} {'final m':>8s} {'localised':>8s} {'run s':>8s}")
        for scene in args.scenarios.split(","):
            simulated(scene, args.seeds, sigmas)
    if args.vp:
        victoria_park(sigmas)


if __name__ == "__main__":
    main()
