"""Where and why a landmark ends up mapped twice (issue "Landmarks seen again are recognised").

Runs EKF+JCBB or D&C (JCBB + RJC, immediate joins so that every join happens at the step it is
created) on a simulated scene with clutter, scores the final map against the simulator's ids
(dcslam.evaluation) and, for every duplicated landmark (two or more final features holding at
least two of its measurements), reports:

- the step each of its features was started, and for D&C the local map (leaf) it was born in;
- where the two should have met: the same local map (the local EKF started a second feature
  instead of pairing the measurement), or the D&C join whose leaves first include both (its
  size in leaves, its two maps' feature counts, overlap and pairings), or the final fold of
  ``estimate()`` when no real join has met them yet;
- the pair's Mahalanobis distance f_a - f_b in the final map and whether it passes the 2-dof
  gate there: "compatible" means the association left a pair unpaired that the final map
  says is one landmark; "incompatible" means the maps disagree about it by more than their
  covariances allow.

With ``--joins`` (D&C), every real join's association is scored instead: each feature of the
two maps is labelled with the landmark most of its own measurements came from, and the tool
counts the second map's features that had a partner in the first ("pairable"), the pairs
made, the correct and the wrong ones (and of the wrong, those whose true partner was there),
and the pairable ones left unpaired.

Usage: python tools/duplicate_diagnosis.py SCENARIO [--seed 0] [--filter dc|ekf] [--list] [--joins]
       (SCENARIO: a dcslam.REVISIT_SCENARIOS name or a trajectory, e.g. lawn_mowing)
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

import dcslam
from dcslam import evaluation
from dcslam.consistency import chi2_threshold




def join_tree(slam, leaf_of_step: np.ndarray):
    """(first leaf, last leaf, join event) of every real join, by replaying the stack."""
    joins = sorted(slam.stats.joins, key=lambda j: j["index"])
    closes = np.flatnonzero(np.diff(leaf_of_step) > 0)  # step at which each leaf closed
    stack, spans, next_join = [], [], 0
    for leaf, step in enumerate(closes):
        stack.append((leaf, leaf))
        while next_join < len(joins) and joins[next_join]["step_created"] <= step + 1 and len(stack) >= 2:
            second, first = stack.pop(), stack.pop()
            event = joins[next_join]
            if second[1] - first[0] + 1 != event["leaves"]:
                return spans  # not the shape replayed here: stop rather than misreport
            spans.append((first[0], second[1], event))
            stack.append((first[0], second[1]))
            next_join += 1
    return spans


def join_scores(slam, returned, truth):
    """Per real join: sizes, pairable, paired, correct, wrong (true partner present), missed."""
    features, landmarks = evaluation.feature_landmarks(truth, np.concatenate(returned))
    label = dict(zip(features.tolist(), landmarks.tolist()))
    rows = []
    for event, record in zip(sorted(slam.stats.joins, key=lambda j: j["index"]), slam.join_pairings()):
        first = collections.Counter(label.get(i, -1) for i in record["first_ids"].tolist())
        paired = {int(j): int(i) for i, j in record["pairs"]}
        pairable = [j for j in record["second_ids"].tolist() if label.get(j, -1) >= 0 and label.get(j, -1) in first]
        correct = sum(1 for j, i in paired.items() if label.get(j, -1) >= 0 and label.get(j, -1) == label.get(i, -2))
        wrong = len(paired) - correct
        wrong_partner_there = sum(1 for j, i in paired.items()
                                  if label.get(j, -1) >= 0 and label.get(j, -1) != label.get(i, -2)
                                  and label.get(j, -1) in first)
        rows.append(dict(index=event["index"], leaves=event["leaves"], first=len(record["first_ids"]),
                         second=len(record["second_ids"]), overlap=event["overlap"], pairable=len(pairable),
                         paired=len(paired), correct=correct, wrong=wrong, wrong_partner_there=wrong_partner_there,
                         missed=sum(1 for j in pairable if j not in paired)))
    return rows


def diagnose(name: str, seed: int, filter_name: str):
    sim = (dcslam.revisit_scenario(name, seed) if name in dcslam.REVISIT_SCENARIOS
           else dcslam.simulate(name, steps=600, seed=seed, clutter=0.1))
    config = dcslam.SlamConfig(association="jcbb", join_association="rjc", amortize=False, seed=seed)
    slam = dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)
    returned, closed_before = [], []  # closed_before: local maps closed before each step's scan
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        if filter_name == "dc":
            closed_before.append(int(slam._core.stats["counters"].get("local_maps_closed", 0)))
        returned.append(slam.update(step.z, step.R))
    estimate = slam.estimate()
    scores = evaluation.evaluate_run(slam, estimate, returned, sim)

    raw = np.concatenate(returned)
    final = slam.resolve(raw)
    truth = np.asarray(sim.true_ids)
    step_of = np.repeat(np.arange(len(returned)), [len(r) for r in returned])
    born = {}
    for final_id, step in zip(final, step_of):
        born.setdefault(int(final_id), int(step))
    leaf = np.asarray(closed_before) if filter_name == "dc" else np.zeros(len(returned), int)
    spans = join_tree(slam, leaf) if filter_name == "dc" else []
    index = {int(i): k for k, i in enumerate(estimate.landmark_ids)}
    gate = chi2_threshold(2, alpha=1 - config.gate_confidence)

    cells = collections.Counter(zip(truth.tolist(), final.tolist()))
    features_of = collections.defaultdict(list)
    for (landmark, feature), count in cells.items():
        if landmark >= 0 and feature >= 0 and count >= 2:
            features_of[landmark].append(feature)
    reports = []
    for landmark, features in features_of.items():
        if len(features) < 2:
            continue
        a, b = sorted(features, key=lambda f: born[f])[:2]
        leaf_a, leaf_b = int(leaf[born[a]]), int(leaf[born[b]])
        if leaf_a == leaf_b:
            where = "same local map" if filter_name == "dc" else "EKF map"
        else:
            met = next((s for s in spans if s[0] <= leaf_a and leaf_b <= s[1]), None)
            where = (f"join of {met[2]['leaves']} leaves ({met[2]['features_first']}+{met[2]['features_second']} "
                     f"features, overlap {met[2]['overlap']}, {met[2]['pairings']} pairs)") if met else "final fold"
        distance = np.inf
        if a in index and b in index:
            ia, ib = 3 + 2 * index[a], 3 + 2 * index[b]
            P = estimate.covariance
            S = P[ia:ia + 2, ia:ia + 2] + P[ib:ib + 2, ib:ib + 2] - P[ia:ia + 2, ib:ib + 2] - P[ib:ib + 2, ia:ia + 2]
            d = estimate.landmarks[index[a]] - estimate.landmarks[index[b]]
            distance = float(d @ np.linalg.solve(S, d))
        reports.append(dict(landmark=landmark, steps=(born[a], born[b]), leaves=(leaf_a, leaf_b), where=where,
                            distance_sq=distance, compatible=distance <= gate))
    joins = join_scores(slam, returned, truth) if filter_name == "dc" else []
    return scores, reports, joins


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--filter", choices=("dc", "ekf"), default="dc")
    parser.add_argument("--list", action="store_true", help="one line per duplicated landmark")
    parser.add_argument("--joins", action="store_true", help="score every D&C join's pairs against the truth")
    args = parser.parse_args()
    scores, reports, joins = diagnose(args.scenario, args.seed, args.filter)
    if args.joins:
        keys = ("index", "leaves", "first", "second", "overlap", "pairable", "paired", "correct", "wrong",
                "wrong_partner_there", "missed")
        print(" ".join(f"{k:>8s}" if len(k) <= 8 else k for k in keys))
        for row in joins:
            print(" ".join(f"{row[k]:8d}" if len(k) <= 8 else f"{row[k]:{len(k)}d}" for k in keys))
        totals = {k: sum(r[k] for r in joins) for k in ("pairable", "paired", "correct", "wrong", "missed")}
        print("all joins: " + ", ".join(f"{k} {v}" for k, v in totals.items()))
    a = scores.association
    print(f"{args.scenario} seed {args.seed} {args.filter}: P {a.pairwise_precision:.3f} R {a.pairwise_recall:.3f} "
          f"features/landmark {a.features_per_landmark:.3f}, {len(reports)} duplicated landmarks")
    if args.list:
        for r in reports:
            print(f"  landmark {r['landmark']:5d} steps {r['steps']} leaves {r['leaves']} {r['where']}: "
                  f"final D^2 {r['distance_sq']:.1f} ({'compatible' if r['compatible'] else 'incompatible'})")
    table = collections.Counter(
        ("final fold" if r["where"] == "final fold" else "join" if r["where"].startswith("join") else r["where"],
         "compatible" if r["compatible"] else "incompatible") for r in reports)
    print(f"{'where they should have met':28s} {'compatible':>10s} {'incompatible':>12s}")
    for where in sorted({w for w, _ in table}):
        print(f"{where:28s} {table[(where, 'compatible')]:10d} {table[(where, 'incompatible')]:12d}")


if __name__ == "__main__":
    main()
