"""Victoria Park without ids: which of D&C's close pairs of landmarks are duplicates, and why
the final duplicate merge left them.

Question (issue "Landmarks seen again are recognised"): D&C's final map holds more pairs of
landmarks closer than 1 m than the EKF's. For each such pair of D&C's map this prints its
distance, the Mahalanobis distance^2 of f_a - f_b in the final map (the merge's test), how many
other features are within the merge radius and compatible (the merge's ambiguity rule), and
whether the EKF's map has a landmark pair at the same place (then it is likely two real trees).
It also prints how far the two maps agree (``dcslam.metrics.map_agreement``, within 1 and 2 m).

    .venv/bin/python studies/vp_close_pairs.py [--radius 1.0] [--seed 0] [--list]
        [--set field=value ...]   (overrides of the preset, both filters, e.g.
                                   --set large_overlap_confidence=0.999)
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
from scipy.stats import chi2

import dcslam
from dcslam.datasets import victoria_park
from dcslam.metrics import map_agreement

# The revisit benchmark's override parser, so that both read FIELD=VALUE the same way.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "benchmarks"))
from revisit_association import parse_overrides  # noqa: E402


def close_pairs(landmarks: np.ndarray, radius: float) -> list[tuple[int, int, float]]:
    """Every pair (a, b), a < b, of rows of ``landmarks`` closer than ``radius``."""
    from scipy.spatial import cKDTree

    tree = cKDTree(landmarks)
    pairs = sorted(tree.query_pairs(radius))
    return [(a, b, float(np.linalg.norm(landmarks[a] - landmarks[b]))) for a, b in pairs]


def difference_distance_sq(estimate, a: int, b: int, feature_sigma: float = 0.0) -> float:
    P = estimate.covariance
    ia, ib = 3 + 2 * a, 3 + 2 * b
    S = (P[ia:ia + 2, ia:ia + 2] + P[ib:ib + 2, ib:ib + 2] - P[ia:ia + 2, ib:ib + 2] - P[ib:ib + 2, ia:ia + 2])
    S = S + 2.0 * feature_sigma**2 * np.eye(2)
    d = estimate.landmarks[a] - estimate.landmarks[b]
    try:
        return float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return float("inf")


def compatible_within(estimate, k: int, radius: float, gate: float, feature_sigma: float = 0.0) -> int:
    """How many other features are within ``radius`` of feature k and pass the merge test."""
    near = np.flatnonzero(np.linalg.norm(estimate.landmarks - estimate.landmarks[k], axis=1) <= radius)
    return sum(1 for j in near if j != k and difference_distance_sq(estimate, k, j, feature_sigma) <= gate)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radius", type=float, default=1.0, help="a close pair is closer than this (m)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--list", action="store_true", help="print every D&C close pair")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a SlamConfig override of the preset, for both runs (repeatable)")
    args = parser.parse_args()

    vp = victoria_park()
    config = vp.slam_config(seed=args.seed, **parse_overrides(args.set))
    merge_confidence = config.final_merge_confidence or config.gate_confidence
    gate = float(chi2.ppf(merge_confidence, 2))
    estimates = {}
    for name, cls in (("EKF", dcslam.EkfSlam), ("D&C", dcslam.DCSlam)):
        slam = cls(config)
        slam.run(vp)
        estimates[name] = slam.estimate()
        pairs = close_pairs(estimates[name].landmarks, args.radius)
        print(f"{name}: {len(estimates[name].landmarks)} landmarks, {len(pairs)} pairs closer than {args.radius} m")

    for radius in (1.0, 2.0):
        agreement = map_agreement(estimates["D&C"], estimates["EKF"], radius=radius)
        print(f"within {radius:g} m: D&C->EKF {agreement.first_in_second:.3f}, EKF->D&C {agreement.second_in_first:.3f}")

    ekf_pairs = close_pairs(estimates["EKF"].landmarks, args.radius)
    ekf_midpoints = np.array([(estimates["EKF"].landmarks[a] + estimates["EKF"].landmarks[b]) / 2
                              for a, b, _ in ekf_pairs]).reshape(-1, 2)
    dc = estimates["D&C"]
    rows = []
    for a, b, distance in close_pairs(dc.landmarks, args.radius):
        d2 = difference_distance_sq(dc, a, b)
        d2_sigma = difference_distance_sq(dc, a, b, config.join_feature_sigma)
        ekf_near = int(np.sum(np.linalg.norm(estimates["EKF"].landmarks - (dc.landmarks[a] + dc.landmarks[b]) / 2, axis=1) < 1.0))
        rivals = max(compatible_within(dc, a, config.merge_radius, gate, config.join_feature_sigma),
                     compatible_within(dc, b, config.merge_radius, gate, config.join_feature_sigma))
        midpoint = (dc.landmarks[a] + dc.landmarks[b]) / 2
        ekf_has = bool(len(ekf_midpoints)) and float(np.min(np.linalg.norm(ekf_midpoints - midpoint, axis=1))) < 1.0
        rows.append((a, b, distance, d2, rivals, ekf_has, d2_sigma, ekf_near))
    compatible = [r for r in rows if r[3] <= gate]
    print(f"D&C close pairs: {len(rows)}; also a close pair in the EKF's map: {sum(r[5] for r in rows)}; "
          f"compatible (D^2 <= {gate:.2f}): {len(compatible)}, of which ambiguous (another compatible "
          f"feature within {config.merge_radius} m): {sum(r[4] > 1 for r in compatible)}")
    if args.list:
        print(" a     b     dist   D^2   D^2(join_feature_sigma)  compatible-within-radius  EKF-pair-there  EKF-landmarks-within-1m")
        for a, b, distance, d2, rivals, ekf_has, d2_sigma, ekf_near in rows:
            print(f"{a:5d} {b:5d} {distance:6.3f} {d2:8.2f} {d2_sigma:8.2f} {rivals:3d} {'yes' if ekf_has else 'no':4s} {ekf_near:3d}")


if __name__ == "__main__":
    main()
