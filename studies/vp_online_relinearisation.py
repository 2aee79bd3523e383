"""Victoria Park without ids: what a re-linearisation during the run could change for the user.

Question (issue "D&C at the batch optimum", "when a join closes a large loop"): the passes of
``tree_relinearisation`` run in ``estimate()``, so the anytime map is the batch optimum of the
run's associations whenever a user asks for it. A pass during the run could change only what
the run itself shows: the online pose ``pose()``, and the maps the later joins start from. Two
filters run the same data with the same seed (the passes do not change the run), one plain,
one with passes; every ``--every`` steps this compares, with the passes' estimate (the batch
optimum of the data so far, to 1e-4 m with 3 passes):

- the plain filter's online pose ``pose()``, and the robot of its ``estimate()``, in metres
  and as a squared Mahalanobis distance d^2 in the optimum's robot covariance (above 11.34,
  the 99 % point of chi-square with 3 degrees of freedom, the user would call it wrong);
- the plain anytime map: landmark RMS and the largest landmark distance, the drift a pass
  removes; and the time of the plain ``estimate()``.

Written up in docs/divide_and_conquer.md ("Re-linearising during the run: measured, not
built") and docs/api.md (``pose()``).

    .venv/bin/python studies/vp_online_relinearisation.py [--every 250] [--passes 3] [--seed 0]
        [--max-steps N]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import dcslam
from dcslam.datasets import victoria_park


def wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def compare(online: np.ndarray, plain: dcslam.Estimate, optimum: dcslam.Estimate) -> dict:
    robot_cov = optimum.covariance[:3, :3]
    d = online - optimum.robot
    d[2] = wrap(d[2])
    e = plain.robot - optimum.robot
    e[2] = wrap(e[2])
    order = {int(i): k for k, i in enumerate(optimum.landmark_ids)}
    rows = [order[int(i)] for i in plain.landmark_ids]
    gaps = np.linalg.norm(plain.landmarks - optimum.landmarks[rows], axis=1)
    return {
        "online_m": float(np.hypot(d[0], d[1])),
        "online_d2": float(d @ np.linalg.solve(robot_cov, d)),
        "anytime_m": float(np.hypot(e[0], e[1])),
        "anytime_d2": float(e @ np.linalg.solve(robot_cov, e)),
        "robot_sigma_m": float(np.sqrt(max(np.linalg.eigvalsh(robot_cov[:2, :2])))),
        "map_rms_m": float(np.sqrt(np.mean(gaps ** 2))) if len(gaps) else 0.0,
        "map_max_m": float(gaps.max()) if len(gaps) else 0.0,
        "landmarks": len(gaps),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--every", type=int, default=250)
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, default=None, help="only the first N scans")
    args = parser.parse_args()

    vp = victoria_park()
    plain = dcslam.DCSlam(vp.slam_config(seed=args.seed))
    passes = dcslam.DCSlam(vp.slam_config(seed=args.seed, tree_relinearisation=args.passes))
    print("step   online pose - optimum: m, d^2   anytime robot - optimum: m, d^2   robot sigma [m]"
          "   map RMS / max [m]  landmarks  joins  estimate() [s]")
    rows = []
    steps = vp.steps if args.max_steps is None else vp.steps[:args.max_steps]
    for k, step in enumerate(steps):
        for f in (plain, passes):
            f.predict(step.u, step.Q)
            f.update(step.z, step.R)
        if (k + 1) % args.every and k + 1 != len(steps):
            continue
        start = time.perf_counter()
        anytime = plain.estimate()
        seconds = time.perf_counter() - start
        row = compare(plain.pose(), anytime, passes.estimate())
        row["estimate_s"] = seconds
        joins = len(plain.stats.joins)
        rows.append((k + 1, row))
        print(f"{k + 1:5d}  {row['online_m']:18.3f} {row['online_d2']:10.2f}  {row['anytime_m']:22.3f} "
              f"{row['anytime_d2']:10.2f}  {row['robot_sigma_m']:15.3f}  "
              f"{row['map_rms_m']:8.3f} / {row['map_max_m']:6.3f}  {row['landmarks']:9d}  {joins:5d}  {seconds:14.4f}")
    d2 = np.array([r["online_d2"] for _, r in rows])
    e2 = np.array([r["anytime_d2"] for _, r in rows])
    print(f"anytime robot (plain estimate()) beyond that ellipse at {int((e2 > 11.34).sum())} of {len(rows)}; "
          f"largest d^2 {e2.max():.2f} at step {rows[int(e2.argmax())][0]}")
    rms = np.array([r["map_rms_m"] for _, r in rows])
    print(f"\nonline pose beyond the optimum's 99 % ellipse (d^2 > 11.34) at {int((d2 > 11.34).sum())} of "
          f"{len(rows)} sampled steps; largest d^2 {d2.max():.2f} at step {rows[int(d2.argmax())][0]}")
    print(f"plain anytime map against the optimum: RMS median {np.median(rms):.3f} m, largest "
          f"{rms.max():.3f} m at step {rows[int(rms.argmax())][0]}")


if __name__ == "__main__":
    main()
