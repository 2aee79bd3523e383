#!/usr/bin/env python3
"""MR.CLAM: which odometry calibration and noise, and which range/bearing noise, the data supports.

Everything is measured against the Vicon truth on the filter's own steps (one per time a
landmark is seen), so the numbers are those the filters see:

1. Odometry delay: the shift of the logged turn rate that best explains the true heading
   over 1 s windows. Odometry scale: least-squares ratio of the true distance (heading change) of each step to
   the logged one (``speed_scale``, ``turn_scale``).
2. Odometry noise: with the scales applied, the residual ``e = u_true - u`` of every step
   against the covariance the noise model gives it. ``Q`` is linear in ``sigma_speed^2``,
   ``sigma_turn^2`` and ``sigma_lateral^2``; the three maximise the Gaussian likelihood of
   the residuals. Then the mean NEES of the steps under the fitted Q, and the share below
   chi2(3, 0.95).
3. Measurement noise: range and bearing of every landmark sighting against the ones the truth
   predicts (true pose at the sighting's time, true landmark); bias, standard deviation, a
   robust sigma (1.4826 MAD), by range bin.

Fit on the bundled robot (1) only; the other robots (``--data-dir`` with their files) are the
check. Writes a JSON report with ``--json``.

    .venv/bin/python studies/mrclam_noise_study.py --data-dir PATH --robots 1 2 4
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import dcslam
from dcslam.consistency import chi2_threshold
from dcslam.geometry import compose, invert

FIT_ROBOT = 1


def wrap(angle):
    return np.arctan2(np.sin(angle), np.cos(angle))


def true_motions(poses: np.ndarray) -> np.ndarray:
    return np.array([compose(invert(a), b) for a, b in zip(poses[:-1], poses[1:])])


def load(robot: int, data_dir, **options):
    return dcslam.datasets.mrclam(robot, data_dir if robot not in dcslam.mrclam.BUNDLED_ROBOTS else None, **options)


def odometry_delay(robot: int, data_dir) -> dict:
    """The delay of the logged speeds that best explains the true heading: the RMS over 1 s
    windows of (true heading change - logged omega integrated), for delays of 0 to 0.6 s."""
    raw = dcslam.mrclam.read_robot(data_dir if robot not in dcslam.mrclam.BUNDLED_ROBOTS else
                                   str(Path(dcslam.__file__).parent / "data" / "mrclam"), robot)
    truth, odometry = raw["groundtruth"], raw["odometry"]
    turned = wrap(np.diff(truth[:, 3]))
    logged = odometry[:-1, 2] * np.diff(odometry[:, 0])
    window = 50
    rms = {}
    for shift in range(0, 31):  # samples of 0.02 s
        a, b = logged[: len(logged) - shift], turned[shift:]
        n = (len(a) // window) * window
        e = b[:n].reshape(-1, window).sum(1) - a[:n].reshape(-1, window).sum(1)
        rms[round(shift * 0.02, 2)] = float(np.sqrt(np.mean(e**2)))
    best = min(rms, key=rms.get)
    return {"odometry_delay": best, "heading_rms_by_delay": rms}


def odometry_scales(robot: int, data_dir, delay: float) -> dict:
    raw = load(robot, data_dir, speed_scale=1.0, turn_scale=1.0, odometry_delay=delay)
    truth = true_motions(raw.poses_true)
    moving = np.abs(raw.u[:, 0]) > 1e-6
    turning = np.abs(raw.u[:, 2]) > 1e-6
    speed = float(np.sum(truth[moving, 0] * raw.u[moving, 0]) / np.sum(raw.u[moving, 0] ** 2))
    turn = float(np.sum(truth[turning, 2] * raw.u[turning, 2]) / np.sum(raw.u[turning, 2] ** 2))
    return {"speed_scale": speed, "turn_scale": turn}


NOISE_TERMS = ("sigma_speed", "sigma_turn", "sigma_lateral")


def odometry_noise(robot: int, data_dir, scales: dict) -> dict:
    """The maximum-likelihood sigma_speed, sigma_turn, sigma_lateral on this robot's steps.

    ``Q_k = sum_j s_j^2 Q_jk`` with ``Q_jk`` the covariance of step k for term j at unit
    sigma; the step residuals are taken as independent zero-mean Gaussians. (A moment fit of
    the summed squares would let the few long steps decide alone.)
    """
    from scipy.optimize import minimize

    unit = [load(robot, data_dir, **scales, **{name: float(name == term) for name in NOISE_TERMS})
            for term in NOISE_TERMS]
    error = true_motions(unit[0].poses_true) - unit[0].u
    error[:, 2] = wrap(error[:, 2])
    basis = np.stack([d.Q for d in unit])  # (terms, steps, 3, 3)

    def negative_log_likelihood(log_variances):
        Q = np.einsum("j,jkab->kab", np.exp(log_variances), basis) + 1e-12 * np.eye(3)
        sign, log_det = np.linalg.slogdet(Q)
        whitened = np.linalg.solve(Q, error[:, :, None])[:, :, 0]
        return 0.5 * float(np.sum(log_det + np.sum(error * whitened, axis=1)))

    start = np.log([0.01**2, 0.04**2, 0.01**2])
    best = minimize(negative_log_likelihood, start, method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-3, "maxiter": 2000})
    sigmas = np.sqrt(np.exp(best.x))
    return {**{name: float(v) for name, v in zip(NOISE_TERMS, sigmas)}, "converged": bool(best.success),
            "rms_error_xy_heading": np.sqrt(np.mean(error**2, axis=0)).tolist()}


def step_nees(robot: int, data_dir, options: dict) -> dict:
    """NEES of each step's odometry residual under the model's Q (steps with a definite Q)."""
    data = load(robot, data_dir, **options)
    error = true_motions(data.poses_true) - data.u
    error[:, 2] = wrap(error[:, 2])
    values = []
    for e, Q in zip(error, data.Q):
        if np.linalg.eigvalsh(Q)[0] > 1e-12 * max(np.trace(Q), 1e-300):
            values.append(float(e @ np.linalg.solve(Q, e)))
    values = np.array(values)
    bound = chi2_threshold(3, 0.05)
    return {"steps": len(data.u), "scored": len(values), "mean_nees": float(values.mean()),
            "median_nees": float(np.median(values)), "share_below_chi2_95": float(np.mean(values <= bound)),
            "dead_reckoning_final_error_m": dead_reckoning_error(data)}


def dead_reckoning_error(data) -> float:
    pose = np.zeros(3)
    for u in data.u:
        pose = compose(pose, u)
    return float(np.hypot(*(pose[:2] - data.poses_true[-1, :2])))


def measurement_residuals(robot: int, data_dir) -> dict:
    data = load(robot, data_dir)
    position = dict(zip(data.landmark_ids_true.tolist(), data.landmarks_true))
    step_of = np.repeat(np.arange(len(data.steps)), np.diff(data.offsets))
    poses = data.poses_true[step_of + 1]
    landmarks = np.array([position[i] for i in data.landmark_ids.tolist()])
    d = landmarks - poses[:, :2]
    predicted_range = np.hypot(d[:, 0], d[:, 1])
    predicted_bearing = wrap(np.arctan2(d[:, 1], d[:, 0]) - poses[:, 2])
    range_error = data.z[:, 0] - predicted_range
    bearing_error = wrap(data.z[:, 1] - predicted_bearing)

    def summary(values):
        median = np.median(values)
        return {"mean": float(values.mean()), "std": float(values.std()), "median": float(median),
                "robust_sigma": float(1.4826 * np.median(np.abs(values - median))),
                "p95_abs": float(np.percentile(np.abs(values), 95)), "max_abs": float(np.abs(values).max())}

    bins = []
    for low, high in ((0, 2), (2, 3), (3, 4), (4, 6), (6, 10)):
        inside = (predicted_range >= low) & (predicted_range < high)
        if inside.sum() >= 20:
            bins.append({"range_m": [low, high], "count": int(inside.sum()),
                         "range": summary(range_error[inside]), "bearing": summary(bearing_error[inside])})
    return {"sightings": int(len(range_error)), "range": summary(range_error), "bearing": summary(bearing_error),
            "range_over_range": summary(range_error / predicted_range),
            "bearing_beyond_0.2_rad": int(np.sum(np.abs(bearing_error) > 0.2)), "by_range": bins}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", type=Path, default=None, help="folder with the other robots' files")
    parser.add_argument("--robots", type=int, nargs="+", default=[FIT_ROBOT])
    parser.add_argument("--json", type=Path, default=Path("results/mrclam_noise_study.json"))
    args = parser.parse_args(argv)

    delay = odometry_delay(FIT_ROBOT, args.data_dir)
    scales = {"odometry_delay": delay["odometry_delay"],
              **odometry_scales(FIT_ROBOT, args.data_dir, delay["odometry_delay"])}
    noise = odometry_noise(FIT_ROBOT, args.data_dir, scales)
    fitted = {**scales, **{name: noise[name] for name in NOISE_TERMS}}
    report = {"fit_robot": FIT_ROBOT, "fitted": fitted, "odometry_fit": noise, "delay_scan": delay, "defaults": dcslam.mrclam.MRCLAM_DEFAULTS,
              "robots": {}}
    print(f"fitted on robot {FIT_ROBOT}: " + ", ".join(f"{k} {v:.4g}" for k, v in fitted.items()))
    for robot in args.robots:
        own_delay = odometry_delay(robot, args.data_dir)["odometry_delay"]
        entry = {"own_delay": own_delay, "scales": odometry_scales(robot, args.data_dir, own_delay),
                 "odometry_with_defaults": step_nees(robot, args.data_dir, {}),
                 "measurements": measurement_residuals(robot, args.data_dir)}
        report["robots"][robot] = entry
        o, m = entry["odometry_with_defaults"], entry["measurements"]
        print(f"robot {robot}: own delay {own_delay:.2f} s, own scales v {entry['scales']['speed_scale']:.3f} omega {entry['scales']['turn_scale']:.3f}; "
              f"step NEES with the defaults: mean {o['mean_nees']:.2f}, median {o['median_nees']:.2f}, "
              f"{100 * o['share_below_chi2_95']:.1f} % below chi2(3, .95); dead reckoning ends "
              f"{o['dead_reckoning_final_error_m']:.1f} m off")
        print(f"   bearing errors beyond 0.2 rad: {m['bearing_beyond_0.2_rad']}")
        for name in ("range", "bearing", "range_over_range"):
            s = m[name]
            print(f"   {name}: mean {s['mean']:+.4f} std {s['std']:.4f} robust sigma {s['robust_sigma']:.4f} "
                  f"p95 |e| {s['p95_abs']:.4f} max {s['max_abs']:.3f}")
        for b in m["by_range"]:
            print(f"   range {b['range_m']}: n {b['count']}, range std {b['range']['std']:.3f} robust "
                  f"{b['range']['robust_sigma']:.3f}, bearing std {b['bearing']['std']:.4f} robust "
                  f"{b['bearing']['robust_sigma']:.4f}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
