"""Revisits: do D&C's large joins fail for lack of re-linearisation, or because earlier joins
paired wrongly? (issue "Landmarks seen again are recognised")

D&C runs one revisit scenario (JCBB in the local maps, RJC at the joins, 10 % clutter, no
ids) with every join's decision replaced by the truth (``DCSlam.set_join_oracle``, mode
``"truth"``), so every join sees a history without association errors, and keeps its local
maps (``tree_relinearisation=1``). At each join whose first map holds ``--min-features`` to
``--max-features`` features, the oracle's audit gives the true pairs' marginal Mahalanobis
distances in D&C's own join (maps linearised where their subtrees were built). The same
pairs are then measured at the least-squares optimum of the two subtrees' local maps, linked
by odometry only (``tests/python/oracles/submap_joining.py``, dense Gauss-Newton: each side's
features identified by landmark, the two sides kept apart), which is where a join
re-linearised through the tree would put them. If the two sets of distances agree, the maps
of a history kept right agree without re-linearisation, and what breaks the joins of the
run as it is lies in its association history.

Usage: python studies/revisit_join_linearisation.py [--scenario long_revisits] [--seed 3]
       [--min-features 100] [--max-features 450]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import dcslam
from dcslam import evaluation

# The oracle is kept beside the test that checks it (tests/python/test_submap_joining.py).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from oracles import submap_joining  # noqa: E402

PRUNING_GATE = 13.82  # chi-square 2 dof at 0.999: the candidate lists' gate at the default 0.99


def compose(a, b):
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], submap_joining.wrap(a[2] + b[2])])


def subtree_problem(leaves, first_leaves, second_leaves, landmark_of):
    """The two subtrees' local maps with one variable per landmark on each side (a feature
    of no landmark, or a landmark's second feature in one leaf, is a variable of its own),
    and a start point chained from the leaves' robots."""
    local = []
    for side, indices in (("first", first_leaves), ("second", second_leaves)):
        for k in indices:
            in_leaf, keys = set(), []
            for feature in leaves[k]["feature_ids"]:
                landmark = landmark_of.get(int(feature), -1)
                own = landmark < 0 or landmark in in_leaf
                keys.append((side, "feature", int(feature)) if own else (side, "landmark", landmark))
                in_leaf.add(landmark)
            local.append((np.asarray(leaves[k]["x"]), np.asarray(leaves[k]["P"]), keys))
    variable = {key: n for n, key in enumerate(sorted({key for _, _, keys in local for key in keys}, key=str))}
    maps = [submap_joining.LocalMap(x, P, [variable[key] for key in keys]) for x, P, keys in local]
    poses = [np.zeros(3)]
    for x, _, _ in local:
        poses.append(compose(poses[-1], x[:3]))
    start = {}
    for k, (x, _, keys) in enumerate(local):
        rotation = np.array([[np.cos(poses[k][2]), -np.sin(poses[k][2])], [np.sin(poses[k][2]), np.cos(poses[k][2])]])
        for i, key in enumerate(keys):
            start.setdefault(variable[key], poses[k][:2] + rotation @ x[3 + 2 * i:5 + 2 * i])
    return maps, start, np.array(poses[1:-1]), poses[-1], variable


def optimum_distances(solution, variable, truth_pairs, landmark_of):
    column = {v: 3 + 2 * n for n, v in enumerate(solution.feature_order)}
    distances = []
    for first, second in truth_pairs:
        a = variable.get(("first", "landmark", landmark_of.get(int(first), -1)))
        b = variable.get(("second", "landmark", landmark_of.get(int(second), -1)))
        if a is None or b is None:
            distances.append(np.nan)
            continue
        ia, ib = column[a], column[b]
        c = solution.covariance
        covariance = c[ia:ia + 2, ia:ia + 2] + c[ib:ib + 2, ib:ib + 2] - c[ia:ia + 2, ib:ib + 2] - c[ib:ib + 2, ia:ia + 2]
        innovation = solution.features[a] - solution.features[b]
        distances.append(float(innovation @ np.linalg.solve(covariance, innovation)))
    return np.array(distances)


def leaf_ranges(joins):
    """Per join event, the local maps (indices in closing order) of its first and second map:
    D&C's stack is a binary counter (a closed local map is pushed; the top two are joined while
    they hold as many local maps), so the events' leaf counts replay it."""
    stack, closed, ranges = [], 0, []
    for event in joins:
        half = event["leaves"] // 2
        while not (len(stack) >= 2 and stack[-1][1] == stack[-2][1] == half):
            stack.append((closed, 1))
            closed += 1
        (start, _), (middle, _) = stack[-2], stack[-1]
        del stack[-2:]
        stack.append((start, event["leaves"]))
        ranges.append((list(range(start, middle)), list(range(middle, start + event["leaves"]))))
    return ranges


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="long_revisits")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--min-features", type=int, default=100)
    parser.add_argument("--max-features", type=int, default=450)
    parser.add_argument("--local", choices=("jcbb", "known"), default="jcbb",
                        help="association in the local maps (known: the simulator's ids, clutter refused)")
    args = parser.parse_args()
    sim = dcslam.revisit_scenario(args.scenario, args.seed)
    config = dcslam.SlamConfig(association=args.local, join_association="rjc", seed=args.seed,
                               tree_relinearisation=1)
    as_is = dcslam.DCSlam(config)
    returned = as_is.run(sim.steps)
    scores = evaluation.evaluate_run(as_is, as_is.estimate(), returned, sim).association
    if args.local == "known":
        features = landmarks = np.unique(sim.true_ids[sim.true_ids >= 0])
    else:
        features, landmarks = evaluation.feature_landmarks(sim.true_ids, np.concatenate(returned))
    landmark_of = dict(zip(features.tolist(), landmarks.tolist()))
    slam = dcslam.DCSlam(config)
    slam.set_join_oracle(features, landmarks, "truth")
    slam.run(sim.steps)
    leaves = slam._core.tree_leaves()
    events = sorted(slam.stats.joins, key=lambda event: event["index"])
    print(f"{args.scenario} seed {args.seed}, {args.local} local maps: recall as is {scores.pairwise_recall:.3f}; below, joins of a history "
          f"kept right by the truth. D^2 of the true pairs: median / 90 % / share above the pruning gate")
    print(f"{'join':>5s} {'leaves':>8s} {'n1':>4s} {'true':>5s} | {'D&C join':>22s} | {'subtree optimum':>22s} "
          f"{'GN steps':>8s}")
    for event, record, (first_leaves, second_leaves) in zip(events, slam.join_pairings(), leaf_ranges(events)):
        size = len(record["first_ids"])
        if not args.min_features <= size <= args.max_features or len(record["truth_pairs"]) == 0:
            continue
        maps, initial, boundaries, robot, variable = subtree_problem(leaves, first_leaves, second_leaves, landmark_of)
        solution = submap_joining.solve(maps, initial, boundaries, robot, tolerance=1e-7, max_iterations=40)
        at_optimum = optimum_distances(solution, variable, record["truth_pairs"], landmark_of)
        in_join = record["truth_distance_sq"]
        known = ~np.isnan(at_optimum)

        def summary(values):
            return (f"{np.median(values):6.1f} {np.quantile(values, 0.9):6.1f} "
                    f"{np.mean(values > PRUNING_GATE):8.1%}")

        print(f"{event['index']:5d} {len(first_leaves):3d}+{len(second_leaves):<4d} {size:4d} {known.sum():5d} | "
              f"{summary(in_join[known])} | {summary(at_optimum[known])} {solution.iterations:8d}", flush=True)


if __name__ == "__main__":
    main()
