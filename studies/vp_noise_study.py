"""Picks Victoria Park's noise values from the data itself (docs/victoria_park.md).

Trees re-observed a few scans apart are the only local reference the run offers (GPS is too
sparse and noisy). For every scan k and window w, the trees of scan k are moved into scan
k+w's laser frame with the dead-reckoned motion, and paired with the nearest tree of scan
k+w when the pairing is unambiguous (nearest < 1 m, second nearest > 3 m). Then:

1. Measurement noise: at w = 1 the motion is short and nearly noise-free, so the range and
   bearing residuals are about two measurement noises: sigma ≈ robust std / sqrt(2).
   This is a lower bound: consecutive detections of one trunk share the viewpoint and
   the trunk side, so their errors are correlated.
2. Odometry noise: at w = 1..40 the residual also carries the motion's error. With the
   chosen (sigma_speed, sigma_steering, floors) the normalised innovation squared
   nu' (H Q_w H' + 2R)^-1 nu should be about chi-square(2) (median 1.39).
3. The test that decides: what D&C's joins see. Consecutive local maps are built as D&C
   builds them (a fresh EKF per map, closed at 30 features, the dataset's SLAM config) and
   their unambiguous pairs (< 1 m apart, next candidate > 3 m) get the join's squared
   Mahalanobis distance with the pair covariance of map joining. A filter averages every
   detection of a trunk as if independent, so correlated detection errors and systematic
   odometry errors show up here, not in 1-2: the distances must be chi-square(2) too
   (median 1.39, 99 % below 9.21, the join gate at gate_confidence 0.99).

   Maps of 30 to 240 features test the model over longer and longer stretches of the drive,
   as D&C's larger joins do (pairs count as unambiguous within sqrt(size / 30) m, with the
   next candidate beyond three times that).

Usage: python studies/vp_noise_study.py [--steering recalibrated|raw] [--scale 1.0]
       [--sigma-range R] [--sigma-bearing B] [--floor-xy F] [--floor-phi F]
       [--map-sizes 30,60,120,240]
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


def local_maps(vp, cfg, features_per_map, max_steps):
    """Consecutive local maps built as D&C builds them: a fresh EKF from the previous map's
    last pose, closed when it holds `features_per_map` features. Yields estimates."""
    slam = dcslam.EkfSlam(cfg)
    for k in range(min(max_steps, len(vp.steps))):
        step = vp.steps[k]
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R)
        if slam.stats.num_features[-1] >= features_per_map:
            yield slam.estimate()
            slam = dcslam.EkfSlam(cfg)


def join_pair_distances(vp, features_per_map=30, max_steps=3000, near=1.0, far=3.0,
                        feature_sigma=0.0):
    """Squared Mahalanobis distances of unambiguous pairs between consecutive local maps,
    with the join's own pair covariance (plus 2 feature_sigma^2 I, the joins'
    `join_feature_sigma`); chi-square(2) when the noise model is right. Returns the marginal
    distances, the separations, and the conditional distances: each pair given all the other
    pairs of its join, as RJC's re-test and the joint test judge it."""
    cfg = vp.slam_config()
    distances, separations, conditional = [], [], []
    maps = local_maps(vp, cfg, features_per_map, max_steps)
    first = next(maps)
    for second in maps:
        robot = first.robot
        P_first = first.covariance
        rows, second_blocks, innovations = [], [], []
        for j, feature in enumerate(second.landmarks):
            point, J_robot, J_feature = G.transform_point(robot, feature, jacobians=True)
            gaps = np.hypot(*(first.landmarks - point).T)
            order = np.argsort(gaps)
            if len(gaps) < 2 or gaps[order[0]] > near or gaps[order[1]] < far:
                continue
            i = int(order[0])
            # h = f_i - robot ⊕ f_j: the robot and f_i are correlated in the first map.
            J = np.zeros((2, len(P_first)))
            J[:, :3] = -J_robot
            J[:, 3 + 2 * i:5 + 2 * i] = np.eye(2)
            block = slice(3 + 2 * j, 5 + 2 * j)
            S = J @ P_first @ J.T + J_feature @ second.covariance[block, block] @ J_feature.T
            S += 2 * feature_sigma**2 * np.eye(2)
            nu = first.landmarks[i] - point
            distances.append(float(nu @ np.linalg.solve(S, nu)))
            separations.append(float(np.hypot(*nu)))
            G_row = np.zeros((2, len(second.covariance)))
            G_row[:, block] = J_feature
            rows.append((J, G_row))
            innovations.append(nu)
        if len(rows) >= 3:  # enough pairs to pin the relative pose of the two maps
            J_all = np.vstack([J for J, _ in rows])
            G_all = np.vstack([G for _, G in rows])
            S_all = J_all @ P_first @ J_all.T + G_all @ second.covariance @ G_all.T
            S_all += 2 * feature_sigma**2 * np.eye(len(S_all))
            conditional.extend(leave_one_out_distances(S_all, np.concatenate(innovations)))
        first = second
    return np.array(distances), np.array(separations), np.array(conditional)


def leave_one_out_distances(S, nu):
    """Each pair's squared distance conditioned on all the others of its stack:
    y_a' (L_aa)^-1 y_a with L = S^-1 and y = L nu."""
    information = np.linalg.inv(S)
    weighted = information @ nu
    return [float(weighted[a:a + 2] @ np.linalg.solve(information[a:a + 2, a:a + 2], weighted[a:a + 2]))
            for a in range(0, len(nu), 2)]


def robust_std(values):
    return 1.4826 * np.median(np.abs(values - np.median(values)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steering", default="recalibrated", choices=["recalibrated", "raw"])
    parser.add_argument("--scale", type=float, default=1.0,
                        help="multiplies every odometry sigma (to see the NIS move)")
    parser.add_argument("--sigma-range", type=float, default=None)
    parser.add_argument("--sigma-bearing", type=float, default=None)
    parser.add_argument("--floor-xy", type=float, default=None,
                        help="floor_sigma_xy [m/sqrt(s)] (default: the dataset's)")
    parser.add_argument("--floor-phi", type=float, default=None,
                        help="floor_sigma_phi [rad/sqrt(s)] (default: the dataset's)")
    parser.add_argument("--join-feature-sigma", type=float, default=0.0,
                        help="per-feature position sigma added in the joins' tests [m]")
    parser.add_argument("--map-sizes", default="30,60,120,240",
                        help="features per local map for the join test, comma-separated")
    args = parser.parse_args()
    defaults = dcslam.datasets.VICTORIA_PARK_DEFAULTS
    odometry = {name: defaults[name] * args.scale for name in
                ("sigma_speed", "sigma_steering", "floor_sigma_xy", "floor_sigma_phi")}
    if args.floor_xy is not None:
        odometry["floor_sigma_xy"] = args.floor_xy
    if args.floor_phi is not None:
        odometry["floor_sigma_phi"] = args.floor_phi
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
    # Bigger maps span longer stretches of the drive: systematic odometry errors (wheel radius,
    # slip, steering bias) grow with the span, white noise only with its square root. Their
    # pairs drift farther apart, so the unambiguity radii grow with the map (1 m / 3 m at 30
    # features).
    for size in (int(s) for s in args.map_sizes.split(",")):
        scale = max(1.0, np.sqrt(size / 30))
        distances, separations, conditional = join_pair_distances(
            vp, size, len(vp.steps), scale, 3 * scale, args.join_feature_sigma)
        print(f"join pairs of consecutive local maps of {size} features: {len(distances)} pairs, "
              f"median distance {np.median(separations):.2f} m, median squared Mahalanobis "
              f"{np.median(distances):.2f} (chi2(2): 1.39), share below 9.21: "
              f"{np.mean(distances < 9.21):.2f}; given the join's other pairs: median "
              f"{np.median(conditional):.2f}, share below 9.21: {np.mean(conditional < 9.21):.2f}")


if __name__ == "__main__":
    main()
