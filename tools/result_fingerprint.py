#!/usr/bin/env python3
"""Everything a change meant to be speed-only must leave bitwise alone, saved to compare.

Runs D&C on Victoria Park (the bench's preset, amortized and one-shot, and without the
per-feature join noise) and on the simulator's revisit scenes and paper trajectories, and
saves per run the feature id of every measurement, the online trajectory, each join's
schedule and counts (``JOIN_FIELDS``), and the final estimate's robot, landmarks, landmark
ids and covariance to an .npz. ``--compare`` then checks two such files array by array, byte
for byte, and exits 1 on any difference.

Usage (from the worktree root, after ``bash tools/setup.sh``):

    .venv/bin/python tools/result_fingerprint.py before.npz     # on the old build
    .venv/bin/python tools/result_fingerprint.py after.npz      # on the new build
    .venv/bin/python tools/result_fingerprint.py --compare before.npz after.npz

``--seeds N`` (default 4) simulator seeds a scene; ``--quick`` one small scene, seed 0, no
Victoria Park (seconds, for a test of the tool itself); ``--set FIELD=VALUE`` (repeatable)
overrides a SlamConfig field in every run, to fingerprint a configuration other than the
default (values read as JSON, else as strings, as ``benchmarks/revisit_association.py``
reads them).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys

import numpy as np

import dcslam

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
from revisit_association import PAPER_TRAJECTORIES, parse_overrides, simulation  # noqa: E402

JOIN_FIELDS = ("step_created", "step_finished", "work_units", "overlap", "pairings", "tries")


def fingerprint(slam: dcslam.DCSlam, source) -> dict:
    batch = slam.run(source)
    estimate = slam.estimate()
    # The joins' schedule: an amortized join finishing at another step moves the online poses.
    joins = np.array([[join[field] for field in JOIN_FIELDS] for join in slam.stats.joins], dtype=np.int64)
    return dict(ids=batch.ids, trajectory=batch.trajectory, robot=estimate.robot,
                landmarks=estimate.landmarks, landmark_ids=estimate.landmark_ids,
                covariance=estimate.covariance, joins=joins.reshape(-1, len(JOIN_FIELDS)))


def runs(seeds: int, quick: bool, overrides: dict):
    """(name, filter, source) of every run, each configured with `overrides` on top."""
    config = dataclasses.replace(dcslam.SlamConfig(association="jcbb", join_association="rjc"), **overrides)
    if quick:
        yield "small_loop_laps/0", dcslam.DCSlam(config), dcslam.revisit_scenario("small_loop_laps", 0)
        return
    vp = dcslam.datasets.victoria_park()
    yield "vp", dcslam.DCSlam(vp.slam_config(**overrides)), vp
    yield "vp_one_shot", dcslam.DCSlam(vp.slam_config(**{**overrides, "amortize": False})), vp
    yield "vp_no_feature_sigma", dcslam.DCSlam(vp.slam_config(**{**overrides, "join_feature_sigma": 0.0})), vp
    for name in (*dcslam.REVISIT_SCENARIOS, *PAPER_TRAJECTORIES):
        for seed in range(seeds):
            yield f"{name}/{seed}", dcslam.DCSlam(dataclasses.replace(config, seed=seed)), simulation(name, seed)


def differences(first: str, second: str) -> list:
    """Names of the arrays that differ (in presence, dtype, shape or any byte)."""
    a, b = np.load(first), np.load(second)
    names = sorted(set(a.files) | set(b.files))
    return [name for name in names
            if name not in a.files or name not in b.files or a[name].dtype != b[name].dtype
            or a[name].shape != b[name].shape or a[name].tobytes() != b[name].tobytes()]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("output", nargs="?", help=".npz to write")
    parser.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a SlamConfig override for every run")
    args = parser.parse_args(argv)
    if args.compare:
        differing = differences(*args.compare)
        total = len(set(np.load(args.compare[0]).files) | set(np.load(args.compare[1]).files))
        print(f"{total} arrays compared, {len(differing)} differ" + (f": {', '.join(differing)}" if differing else ""))
        return 1 if differing else 0
    if not args.output:
        parser.error("give an output .npz, or --compare BEFORE AFTER")
    overrides = parse_overrides(args.set)
    arrays = {}
    for name, slam, source in runs(args.seeds, args.quick, overrides):
        for key, value in fingerprint(slam, source).items():
            arrays[f"{name}/{key}"] = value
        print(f"{name}: {len(arrays[f'{name}/landmark_ids'])} landmarks", flush=True)
    np.savez(args.output, **arrays)
    return 0


if __name__ == "__main__":
    sys.exit(main())
