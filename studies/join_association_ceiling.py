"""How far D&C's join association is from what its maps allow (issue "Landmarks seen again are
recognised").

For each scenario and seed, D&C (JCBB in the local maps, RJC at the joins, 10 % clutter, no
ids) runs once as it is. Each feature id it returned is then labelled with its landmark
(``dcslam.evaluation.feature_landmarks``: the majority of its measurements' true ids), and the
same run is repeated with every join's decision corrected by that truth
(``DCSlam.set_join_oracle``; the local maps do not depend on the joins, so the ids are the same):

- ``truth``: every feature of the second map paired with its landmark's feature in the first,
  whatever the gates say: the ceiling of D&C with these local maps;
- ``among_candidates``: the true partner where it is among the individually compatible
  candidates: what a perfect choice among the candidates would give;
- ``remove_wrong``: the association's own pairs less the wrong ones: what perfect rejection of
  wrong pairs, with nothing added, would give.

With ``--min-first-features N`` only the joins whose first map holds at least N features are
corrected (the smaller ones decide as they are), with ``--max-first-features M`` only those
holding at most M: which joins' decisions make the difference.

Scores after ``estimate()``/``resolve()`` with ``dcslam.evaluation``; means over seeds.

Usage: python studies/join_association_ceiling.py [--seeds 5 | --seed-list 0,12] [--scenarios a,b]
       [--min-first-features N] [--max-first-features M]
"""

from __future__ import annotations

import argparse

import numpy as np

import dcslam
from dcslam import evaluation

MODES = ("as is", "truth", "among_candidates", "remove_wrong")


def run(sim, seed: int, oracle=None, min_first_features: int = 0, max_first_features=None):
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=seed))
    if oracle is not None:
        slam.set_join_oracle(*oracle, min_first_features=min_first_features, max_first_features=max_first_features)
    returned = slam.run(sim.steps)
    estimate = slam.estimate()
    return evaluation.evaluate_run(slam, estimate, returned, sim), returned


def scenario_rows(name: str, seeds, min_first_features: int = 0, max_first_features=None):
    rows = {mode: [] for mode in MODES}
    for seed in seeds:
        sim = dcslam.revisit_scenario(name, seed)
        scores, returned = run(sim, seed)
        rows["as is"].append(scores)
        features, landmarks = evaluation.feature_landmarks(sim.true_ids, np.concatenate(returned))
        for mode in MODES[1:]:
            rows[mode].append(run(sim, seed, (features, landmarks, mode), min_first_features, max_first_features)[0])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. N-1")
    parser.add_argument("--seed-list", default=None, help="comma-separated seeds instead of --seeds")
    parser.add_argument("--scenarios", default="small_loop_laps,loop_both_ways,lawn_overlap")
    parser.add_argument("--min-first-features", type=int, default=0,
                        help="correct only joins whose first map holds at least this many features")
    parser.add_argument("--max-first-features", type=int, default=None,
                        help="correct only joins whose first map holds at most this many features")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seed_list.split(",")] if args.seed_list else list(range(args.seeds))
    most = "" if args.max_first_features is None else f" and <= {args.max_first_features}"
    print(f"seeds {seeds}; means over seeds; NEES ok counts seeds with NEES <= 11.34; "
          f"oracle at joins whose first map holds >= {args.min_first_features}{most} features")
    print(f"{'scenario':16s} {'joins':17s} {'P':>6s} {'R':>6s} {'feat/lm':>7s} {'dup':>6s} {'wrong':>6s} "
          f"{'NEES ok':>8s}")
    for name in args.scenarios.split(","):
        for mode, scores in scenario_rows(name, seeds, args.min_first_features,
                                                args.max_first_features).items():
            a = [s.association for s in scores]
            mean = lambda values: float(np.mean(values))  # noqa: E731
            ok = sum(s.robot.consistent99 for s in scores)
            print(f"{name:16s} {mode:17s} {mean([x.pairwise_precision for x in a]):6.3f} "
                  f"{mean([x.pairwise_recall for x in a]):6.3f} {mean([x.features_per_landmark for x in a]):7.3f} "
                  f"{mean([x.duplicated_landmarks for x in a]):6.1f} {mean([x.wrong_merges for x in a]):6.1f} "
                  f"{ok:5d}/{len(scores)}")


if __name__ == "__main__":
    main()
