"""Are D&C's local maps consistent where a join compares them? (issue "Landmarks seen again
are recognised"; SlamConfig.join_feature_sigma)

Builds local maps as D&C does (an EKF with JCBB from the true pose, a few steps each) on a
revisit scene, takes the difference f_a - f_b of every two features of one local map whose
sightings are all of one landmark (seen at least twice), and compares it with the truth in
the map's base frame: its NEES under the map's covariance, plus ``sigma**2 * I`` per feature
as ``join_feature_sigma`` adds it at a join. A consistent map gives a mean of 2 and 1 % beyond
the 99 % gate. The per-pair computation is the one ``tests/python/test_join_feature_sigma.py``
checks the default with.

Usage: python studies/local_map_consistency.py [--scene loop_both_ways] [--seeds 5]
       [--sigmas 0,0.01,0.015,0.02]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from test_join_feature_sigma import relative_errors  # noqa: E402

GATE_99 = 9.21  # chi-square 2 dof at 0.99


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="loop_both_ways")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--sigmas", default="0,0.01,0.015,0.02")
    args = parser.parse_args()
    pairs = [pair for seed in range(args.seeds) for pair in relative_errors(seed, args.scene)]
    print(f"{args.scene}, seeds 0..{args.seeds - 1}: {len(pairs)} feature differences")
    for sigma in (float(s) for s in args.sigmas.split(",")):
        nees = np.array([d @ np.linalg.solve(S + 2 * sigma**2 * np.eye(2), d) for d, S in pairs])
        print(f"  sigma {sigma:.3f} m: mean NEES {nees.mean():.2f}, beyond the 99 % gate {np.mean(nees > GATE_99):.3f}")


if __name__ == "__main__":
    main()
