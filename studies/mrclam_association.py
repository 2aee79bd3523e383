"""MR.CLAM without ids: how far is each filter's data association from what the data allows,
and what do the gates have to do with it? (issues "Landmarks seen again are recognised" and
"Real data with ground truth")

For each robot, the EKF and D&C run with the barcodes hidden (JCBB in the local maps, RJC at
D&C's joins) and are scored against the barcodes with ``dcslam.evaluation.association_scores``
(pairwise precision and recall of the final clustering, features per landmark, wrong merges),
plus the final robot position error. Each row is one setting of the gates:
``gate_confidence`` (the individual and joint compatibility tests everywhere) and
``join_feature_sigma`` (a position sigma added to every feature in D&C's join tests only).
With ``--oracle``, D&C is run again with each join's decision replaced by the true partner
where it is among the join's candidates (``set_join_oracle(..., "among_candidates")``): the
ceiling of a perfect choice behind those gates.

Usage: python studies/mrclam_association.py [--robots 1 2 4] [--data-dir PATH/resampled_50hz]
       [--settings 0.99:0 0.999:0 0.999:0.2] [--oracle] [--set field=value ...]
       (--set: SlamConfig overrides of every run, e.g. --set final_merge_confidence=0.999
       --set weak_join_pairings=0)
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

import dcslam
from dcslam import evaluation

# The revisit benchmark's override parser, so that every study reads FIELD=VALUE the same way.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "benchmarks"))
from revisit_association import parse_overrides  # noqa: E402


def scores(slam, returned, true_ids, data):
    estimate = slam.estimate()
    association = evaluation.association_scores(true_ids, slam.resolve(returned))
    return association, float(np.linalg.norm(estimate.robot[:2] - data.poses_true[-1][:2]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", type=int, nargs="+", default=[1])
    parser.add_argument("--data-dir", default=None, help="needed for robots other than the bundled robot 1")
    parser.add_argument("--settings", nargs="+", default=["0.99:0", "0.999:0", "0.999:0.1", "0.999:0.2", "0.999:0.3"],
                        help="gate_confidence:join_feature_sigma pairs")
    parser.add_argument("--oracle", action="store_true", help="also the among-candidates join oracle for D&C")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a SlamConfig override of every run (repeatable)")
    args = parser.parse_args()
    overrides = parse_overrides(args.set)
    print(f"{'robot':>5s} {'gate':>6s} {'join sigma':>10s} {'filter':6s} {'P':>6s} {'R':>6s} {'feat/lm':>7s} "
          f"{'wrong':>5s} {'robot err':>9s}")
    for robot in args.robots:
        data = dcslam.datasets.mrclam(robot, data_dir=None if robot == 1 and args.data_dir is None else args.data_dir)
        true_ids = data.true_ids
        ekf_done = set()
        for setting in args.settings:
            gate, sigma = (float(value) for value in setting.split(":"))
            config = data.slam_config(**{"association": "jcbb", "join_association": "rjc", **overrides,
                                         "gate_confidence": gate, "join_feature_sigma": sigma})
            rows = []
            if gate not in ekf_done:  # join_feature_sigma does not touch the EKF
                ekf_done.add(gate)
                rows.append(("EKF", dcslam.EkfSlam(config), None))
            dc = dcslam.DCSlam(config)
            rows.append(("D&C", dc, None))
            for name, slam, _ in rows:
                returned = slam.run(data).ids
                association, error = scores(slam, returned, true_ids, data)
                print(f"{robot:5d} {gate:6.3f} {sigma:10.2f} {name:6s} {association.pairwise_precision:6.3f} "
                      f"{association.pairwise_recall:6.3f} {association.features_per_landmark:7.2f} "
                      f"{association.wrong_merges:5d} {error:8.2f} m", flush=True)
                if name == "D&C" and args.oracle:
                    features, landmarks = evaluation.feature_landmarks(true_ids, returned)
                    oracle = dcslam.DCSlam(config)
                    oracle.set_join_oracle(features, landmarks, "among_candidates")
                    association, error = scores(oracle, oracle.run(data).ids, true_ids, data)
                    print(f"{robot:5d} {gate:6.3f} {sigma:10.2f} {'oracle':6s} {association.pairwise_precision:6.3f} "
                          f"{association.pairwise_recall:6.3f} {association.features_per_landmark:7.2f} "
                          f"{association.wrong_merges:5d} {error:8.2f} m", flush=True)


if __name__ == "__main__":
    main()
