#!/usr/bin/env python3
"""MR.CLAM: are the filters inconsistent on the real data because of the data's errors, or would
they be on this trajectory anyway?

The same robot, the same steps, the same true poses and landmarks, but the odometry and the
sightings replaced by what the models say they are: ``u`` the true motion plus a draw of
N(0, Q), each ``z`` the true range and bearing plus a draw of N(0, R), with the steps' own Q
and R. Both filters run with known ids on the real data and on these "white" versions (one per
seed) and are scored against the truth (``dcslam.evaluation.score_run``). If the white
versions are consistent where the real data is not, the errors the models leave out (biases,
docs/mrclam.md) are the cause.

    .venv/bin/python studies/mrclam_white_noise.py --seeds 5
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import dcslam
from dcslam.evaluation import score_run
from dcslam.geometry import compose, invert

KEYS = ("ate_checkpoints_m", "landmark_rms_m", "landmark_rms_rigid_m", "robot_nees_mean", "final_robot_ci",
        "heading_ci_mean", "map_ci", "map_ci_rigid")


def white_copy(data, seed: int):
    """The data with u and z drawn from the models around the truth (same steps, Q, R)."""
    rng = np.random.default_rng(seed)
    truth = data.poses_true
    u = np.array([compose(invert(a), b) for a, b in zip(truth[:-1], truth[1:])])
    values, vectors = np.linalg.eigh(data.Q)
    roots = vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]
    u += np.einsum("kij,kj->ki", roots, rng.standard_normal(u.shape))
    step = np.repeat(np.arange(len(data.steps)), np.diff(data.offsets))
    pose = truth[step + 1]
    where = dict(zip(data.landmark_ids_true.tolist(), data.landmarks_true))
    landmark = np.array([where[i] for i in data.landmark_ids.tolist()])
    d = landmark - pose[:, :2]
    z = np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - pose[:, 2]])
    z += np.sqrt(np.diagonal(data.R, axis1=1, axis2=2)) * rng.standard_normal(z.shape)
    z[:, 1] = np.arctan2(np.sin(z[:, 1]), np.cos(z[:, 1]))
    return data.replaced(u=u, z=z, white_noise_seed=seed)


def scores(data, filter_name: str, every: int) -> dict:
    result = dcslam.SlamPipeline(data.steps, data.slam_config(), filter=filter_name, checkpoint_every=every).run()
    summary = score_run(result, data.poses_true, data.landmarks_true, data.landmark_ids_true).summary()
    return {key: summary[key] for key in KEYS}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", type=int, default=1)
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--json", type=Path, default=Path("results/mrclam_white_noise.json"))
    args = parser.parse_args(argv)

    data = dcslam.datasets.mrclam(args.robot, args.data_dir)
    report = {"robot": args.robot, "seeds": args.seeds, "real": {}, "white": {}}
    for name in ("ekf", "dc"):
        report["real"][name] = scores(data, name, args.every)
        runs = [scores(white_copy(data, seed), name, args.every) for seed in range(args.seeds)]
        report["white"][name] = {key: float(np.mean([r[key] for r in runs])) for key in KEYS}
        report["white"][name]["map_ci_per_seed"] = [r["map_ci"] for r in runs]
        for label in ("real", "white"):
            line = ", ".join(f"{k} {v:.3g}" for k, v in report[label][name].items() if k in KEYS)
            print(f"{name} {label:5s}: {line}", flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
