"""Picks Victoria Park's noise values from the data itself (docs/victoria_park.md).

Trees re-observed a few scans apart are the only local reference the run offers (GPS is too
sparse and noisy). For every scan k and window w, the trees of scan k are moved into scan
k+w's laser frame with the dead-reckoned motion, and paired with the nearest tree of scan
k+w when the pairing is unambiguous (nearest < 1 m, second nearest > 3 m). Then:

1. Measurement noise: at w = 1 the motion is short and nearly noise-free, so the range and
   bearing residuals are about two measurement noises: sigma ≈ robust std / sqrt(2).
2. Odometry noise: at w = 1..40 the residual also carries the motion's error. With the
   chosen (sigma_speed, sigma_steering, floors) the normalised innovation squared
   nu' (H Q_w H' + 2R)^-1 nu must be chi-square(2): its median ≈ 1.39 at every window.

Usage: python tools/vp_noise_study.py [--steering recalibrated|raw] [--scale 1.0]
"""

from __future__ import annotations

import argparse

import numpy as np

import dcslam
from dcslam import geometry as G

MODEL = "range_bearing"


def compose_window(u, Q, first, last):
    pose, cov = np.zeros(3), np.zeros((3, 3))
    for k in range(first, last + 1):
        pose, J_pose, J_u = G.compose(pose, u[k], jacobians=True)
        cov = J_pose @ cov @ J_pose.T + J_u @ Q[k] @ J_u.T
    return pose, cov


def pair_residuals(vp, window, stride):
    """Innovations of trees re-observed `window` scans later, with their NIS."""
    offset = np.asarray(vp.sensor_offset)
    residuals, nis = [], []
    for k in range(0, len(vp.steps) - window, stride):
        before, after = vp.steps[k], vp.steps[k + window]
        if len(before.z) == 0 or len(after.z) < 2:
            continue
        motion, motion_cov = compose_window(vp.u, vp.Q, k + 1, k + window)
        for z_before, R_before in zip(before.z, before.R):
            tree, _, J_z = G.inverse_observe(MODEL, offset, np.zeros(3), z_before, jacobians=True)
            tree_cov = J_z @ R_before @ J_z.T
            predicted, J_robot, J_tree = G.observe(MODEL, offset, motion, tree, jacobians=True)
            points = np.array([G.inverse_observe(MODEL, offset, motion, z) for z in after.z])
            distances = np.sort(np.hypot(*(points - tree).T))
            if distances[0] > 1.0 or distances[1] < 3.0:
                continue
            j = int(np.argmin(np.hypot(*(points - tree).T)))
            nu = G.innovation(MODEL, after.z[j], predicted)
            S = J_robot @ motion_cov @ J_robot.T + J_tree @ tree_cov @ J_tree.T + after.R[j]
            residuals.append(nu)
            nis.append(float(nu @ np.linalg.solve(S, nu)))
    return np.array(residuals), np.array(nis)


def robust_std(values):
    return 1.4826 * np.median(np.abs(values - np.median(values)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steering", default="recalibrated", choices=["recalibrated", "raw"])
    parser.add_argument("--scale", type=float, default=1.0,
                        help="multiplies every odometry sigma (to see the NIS move)")
    parser.add_argument("--sigma-range", type=float, default=None)
    parser.add_argument("--sigma-bearing", type=float, default=None)
    args = parser.parse_args()
    defaults = dcslam.datasets.VICTORIA_PARK_DEFAULTS
    odometry = {name: defaults[name] * args.scale for name in
                ("sigma_speed", "sigma_steering", "floor_sigma_xy", "floor_sigma_phi")}
    measurement = {"sigma_range": args.sigma_range or defaults["sigma_range"],
                   "sigma_bearing": args.sigma_bearing or defaults["sigma_bearing"]}
    vp = dcslam.datasets.victoria_park(steering=args.steering, **odometry, **measurement)

    residuals, _ = pair_residuals(vp, 1, 1)
    range_std, bearing_std = robust_std(residuals[:, 0]), robust_std(residuals[:, 1])
    print(f"w=1: {len(residuals)} pairs; residual robust std: range {range_std:.3f} m, "
          f"bearing {bearing_std:.4f} rad -> per measurement sigma_range ≈ "
          f"{range_std / np.sqrt(2):.3f} m, sigma_bearing ≈ {bearing_std / np.sqrt(2):.4f} rad")
    print(f"NIS with {odometry}, {measurement} (chi2(2): median 1.39, 95% 5.99)")
    for window in (1, 5, 10, 20, 40):
        residuals, nis = pair_residuals(vp, window, 3)
        print(f"  w={window:2d} ({window * 0.214:4.1f} s): {len(nis):5d} pairs, "
              f"median NIS {np.median(nis):5.2f}, share below 5.99: {np.mean(nis < 5.99):.2f}, "
              f"range/bearing robust std {robust_std(residuals[:, 0]):.3f} m / "
              f"{robust_std(residuals[:, 1]):.4f} rad")


if __name__ == "__main__":
    main()
