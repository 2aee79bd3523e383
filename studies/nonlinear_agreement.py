"""D&C against the EKF in the non-linear setting (issue 5): do their maps agree within their
covariances, and which of the two is right? (docs/consistency.md)

Straight trajectory, the paper's noise, known association, both filters on the same runs.
For every landmark:
- its NEES against the simulator's truth, e' P_ii^-1 e, for each filter (chi-square(2) when the
  filter is consistent: median 1.39, 95 % below 5.99);
- the D&C - EKF difference d in the metric of each filter's covariance, d' P_ii^-1 d.
A difference that is large in both filters' metrics while D&C's NEES is chi-square(2) and the
EKF's is not says the EKF is the one that is off.

Usage: python studies/nonlinear_agreement.py [--runs 5] [--steps 400] [--trajectory straight]
"""

from __future__ import annotations

import argparse

import numpy as np

import dcslam


def landmark_distances(estimate, positions_by_id, reference_by_id):
    """d' P_ii^-1 d per landmark, d = estimate - reference, P_ii from the estimate."""
    index = {int(i): k for k, i in enumerate(estimate.landmark_ids)}
    out = []
    for landmark_id, reference in reference_by_id.items():
        k = index[landmark_id]
        block = slice(3 + 2 * k, 5 + 2 * k)
        d = positions_by_id[landmark_id] - reference
        out.append(float(d @ np.linalg.solve(estimate.covariance[block, block], d)))
    return np.array(out)


def by_id(estimate):
    return {int(i): p for i, p in zip(estimate.landmark_ids, estimate.landmarks)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--trajectory", default="straight")
    args = parser.parse_args()
    cfg = dcslam.SlamConfig(association="known", join_association="known")
    print("| run | NEES vs truth, EKF (median / share < 5.99) | D&C | D&C - EKF in EKF's covariance "
          "| in D&C's covariance |")
    print("|---|---|---|---|---|")
    pooled = {key: [] for key in ("ekf", "dc", "diff_ekf", "diff_dc")}
    for run in range(args.runs):
        sim = dcslam.simulate(args.trajectory, steps=args.steps, seed=run)
        estimates = {}
        for name, filter_class in (("ekf", dcslam.EkfSlam), ("dc", dcslam.DCSlam)):
            slam = filter_class(cfg)
            for step in sim.steps:
                slam.predict(step.u, step.Q)
                slam.update(step.z, step.R, step.true_ids)
            estimates[name] = slam.estimate()
        truth = {int(i): sim.landmarks[int(i)] for i in estimates["ekf"].landmark_ids}
        ekf, dc = by_id(estimates["ekf"]), by_id(estimates["dc"])
        values = {
            "ekf": landmark_distances(estimates["ekf"], ekf, truth),
            "dc": landmark_distances(estimates["dc"], dc, truth),
            "diff_ekf": landmark_distances(estimates["ekf"], ekf, dc),
            "diff_dc": landmark_distances(estimates["dc"], dc, ekf),
        }
        cells = [f"{np.median(v):.2f} / {np.mean(v < 5.99):.2f}" for v in values.values()]
        print(f"| {run} | " + " | ".join(cells) + " |")
        for key, v in values.items():
            pooled[key].append(v)
    cells = [f"{np.median(np.concatenate(v)):.2f} / {np.mean(np.concatenate(v) < 5.99):.2f}"
             for v in pooled.values()]
    print("| all | " + " | ".join(cells) + " |")
    print("chi-square(2): median 1.39, share below 5.99: 0.95")


if __name__ == "__main__":
    main()
