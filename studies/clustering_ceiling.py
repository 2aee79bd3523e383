"""The ceiling of the clustering scores on the revisit scenes: what an association that knows
the true robot pose and the true landmarks reaches (issue "Landmarks seen again are
recognised"; BENCHMARKS.md, "The clustering scores' ceiling").

Each measurement is compared with every true landmark through the simulator's own noise (the
measurement covariance R alone: pose and landmarks are exact), and its feature is the landmark
it is paired with; a measurement left unpaired is a singleton, as a rejected one is for a
filter. Scored with ``dcslam.evaluation.association_scores``, the scores the benchmark reports
for the filters (pairwise precision and recall, features per landmark, wrong merges):

- ``nearest``: the nearest landmark by Mahalanobis distance, if within the gate (the oracle
  the issue names: "true pose, true landmarks, nearest neighbour in the gate");
- ``assignment``: per scan, the pairing of measurements to landmarks (each at most once) that
  minimises the summed distance within the gate (Hungarian algorithm), as a filter's joint
  association does.

No filter can do better than these on what its measurements say, except by luck: they see
the truth the filters estimate. Where a target of the issue is above them, it is out of reach
under the simulator's clutter and noise.

Needs scipy (the "test" extra).

Usage: python studies/clustering_ceiling.py [--seeds 10] [--scenarios a,b] [--gate 0.999]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

import dcslam
from dcslam import evaluation

# The revisit benchmark's scenes and targets, so that the ceiling is of its runs.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
from revisit_association import PAPER_TRAJECTORIES, TARGETS, simulation  # noqa: E402

METHODS = ("nearest", "assignment")
UNPAIRED_COST = 1e9  # above any gated distance: the assignment leaves such a measurement unpaired


def squared_distances(pose, landmarks, z, R):
    """(m, N) Mahalanobis distances of the scan's m measurements to the N true landmarks, seen
    from the true pose through R (range, bearing; no sensor offset in these scenes)."""
    d = landmarks[:, :2] - pose[:2]
    predicted_range = np.hypot(d[:, 0], d[:, 1])
    predicted_bearing = np.arctan2(d[:, 1], d[:, 0]) - pose[2]
    innovation = np.empty((len(z), len(landmarks), 2))
    innovation[..., 0] = z[:, None, 0] - predicted_range[None, :]
    innovation[..., 1] = (z[:, None, 1] - predicted_bearing[None, :] + np.pi) % (2 * np.pi) - np.pi
    information = np.linalg.inv(R)  # (m, 2, 2)
    return np.einsum("mni,mij,mnj->mn", innovation, information, innovation)


def oracle_ids(sim, method: str, gate: float) -> np.ndarray:
    """Every measurement's feature (its landmark's index, -1 unpaired) by the oracle."""
    threshold = chi2.ppf(gate, 2)
    ids = np.full(len(sim.measurements), -1, np.int64)
    for k in range(len(sim.step_offsets) - 1):
        rows = slice(sim.step_offsets[k], sim.step_offsets[k + 1])
        z = sim.measurements[rows]
        if len(z) == 0:
            continue
        distances = squared_distances(sim.poses[k + 1], sim.landmarks, z, sim.measurement_covariances[rows])
        if method == "nearest":
            best = np.argmin(distances, axis=1)
            inside = distances[np.arange(len(z)), best] <= threshold
            ids[rows] = np.where(inside, best, -1)
        else:
            cost = np.where(distances <= threshold, distances, UNPAIRED_COST)
            measurement, landmark = linear_sum_assignment(cost)
            paired = cost[measurement, landmark] < UNPAIRED_COST
            scan = np.full(len(z), -1, np.int64)
            scan[measurement[paired]] = landmark[paired]
            ids[rows] = scan
    return ids


def met_counts(scores) -> list[str]:
    """Seeds meeting the precision, recall and features-per-landmark targets, and all three."""
    precision = [s.pairwise_precision >= TARGETS["precision"] for s in scores]
    recall = [s.pairwise_recall >= TARGETS["recall"] for s in scores]
    per_landmark = [s.features_per_landmark <= TARGETS["features_per_landmark"] for s in scores]
    every = [p and r and f for p, r, f in zip(precision, recall, per_landmark)]
    return [f"{sum(flags)}/{len(scores)}" for flags in (precision, recall, per_landmark, every)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--scenarios", default=",".join([*dcslam.REVISIT_SCENARIOS, *PAPER_TRAJECTORIES]))
    parser.add_argument("--gate", type=float, default=0.999, help="chi-square confidence of the gate (2 dof)")
    args = parser.parse_args()
    if args.seeds < 1 or not 0 < args.gate < 1:
        parser.error("--seeds must be at least 1 and --gate in (0, 1)")
    scenes = [s for s in args.scenarios.split(",") if s]
    unknown = [s for s in scenes if s not in dcslam.REVISIT_SCENARIOS and s not in PAPER_TRAJECTORIES]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}")

    print(f"gate {args.gate}, scene seeds 0-{args.seeds - 1}, 10 % clutter; means over the seeds "
          "(lowest recall / largest features per landmark in brackets)\n")
    print("| scenario | oracle | P | R (lowest) | feat/lm (largest) | dup | wrong | seeds P ok | R ok | feat/lm ok | all three |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        rows = {method: [] for method in METHODS}
        for seed in range(args.seeds):
            sim = simulation(scene, seed)
            for method in METHODS:
                rows[method].append(evaluation.association_scores(sim.true_ids, oracle_ids(sim, method, args.gate)))
        for method in METHODS:
            scores = rows[method]
            recall = [s.pairwise_recall for s in scores]
            per_landmark = [s.features_per_landmark for s in scores]
            print(f"| {scene} | {method} | {np.mean([s.pairwise_precision for s in scores]):.3f} "
                  f"| {np.mean(recall):.3f} ({min(recall):.3f}) | {np.mean(per_landmark):.3f} ({max(per_landmark):.3f}) "
                  f"| {np.mean([s.duplicated_landmarks for s in scores]):.1f} "
                  f"| {np.mean([s.wrong_merges for s in scores]):.1f} | {' | '.join(met_counts(scores))} |", flush=True)


if __name__ == "__main__":
    main()
