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

For D&C the run is repeated with a join oracle in ``"audit"`` mode (``DCSlam.set_join_oracle``:
each feature labelled with the landmark most of its measurements came from; the decisions are
not changed, so the second run is the first one again, which the tool checks). Every true pair
of every join is then seen through that join's own model, and a true pair the join did not
make gets its reason:

- ``failed IC``: its marginal Mahalanobis distance is beyond the individual gate that builds
  the candidate lists, so it was never tested;
- ``maps disagree``: it is a candidate, but it fails the decision gate given the more certain
  true pairs, so no association search could accept it (the two maps are mutually
  inconsistent about it);
- ``lost in search``: it is consistent with the other true pairs, and RJC/JCBB chose
  otherwise (another pair for one of its features, or none).

Each duplicated landmark gets the reason at the join where its features should have met.

With ``--joins``, every real join's scores are listed instead: each feature of the two maps
is labelled with its landmark, and the tool counts the true pairs ("pairable"), the pairs
made, the correct and the wrong ones (and of the wrong, those whose true partner was there),
and the true pairs left unmade by reason; the totals are split by join size.

With ``--wrong-pairs N``, the wrong pairs of the D&C joins of at most N local maps are
classified instead (summed over ``--seeds``): with a clutter-born feature; a swap (the true
partner of one of the two is in the other map); or with the true partner absent; each split by
how many of the two features hold a single measurement (seen once).

Usage: python studies/duplicate_diagnosis.py SCENARIO [--seed 0] [--filter dc|ekf] [--list] [--joins]
       python studies/duplicate_diagnosis.py SCENARIO --seeds N [--filter dc|ekf]   (tables summed over seeds)
       python studies/duplicate_diagnosis.py SCENARIO --wrong-pairs 8 [--seeds N]
       [--set FIELD=VALUE ...]   (SlamConfig overrides, e.g. local_map_features=20, or seed=S for
        another RJC draw than the scene's seed)
       (SCENARIO: a dcslam.REVISIT_SCENARIOS name or one of the paper's trajectories, e.g. lawn_mowing:
        600 steps, 10 % clutter, as benchmarks/revisit_association.py runs them)
"""

from __future__ import annotations

import argparse
import collections
import pathlib
import sys

import numpy as np

import dcslam
from dcslam import evaluation
from dcslam.consistency import chi2_threshold

# The revisit benchmark's scenes, so that a diagnosed run is one of its runs.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
from revisit_association import parse_overrides, simulation  # noqa: E402


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


REASONS = ("failed IC", "maps disagree", "lost in search")


def missed_reason(candidate: bool, consistent: bool) -> str:
    return REASONS[0] if not candidate else REASONS[1] if not consistent else REASONS[2]


def join_scores(slam, label):
    """Per real join: sizes, pairable, paired, correct, wrong (true partner present), and the
    true pairs not made, by reason (the audit of the join oracle's pairing)."""
    rows = []
    for event, record in zip(sorted(slam.stats.joins, key=lambda j: j["index"]), slam.join_pairings()):
        first = {label.get(i, -1) for i in record["first_ids"].tolist()}
        paired = {int(j): int(i) for i, j in record["pairs"]}
        correct = sum(1 for j, i in paired.items() if label.get(j, -1) >= 0 and label.get(j, -1) == label.get(i, -2))
        wrong_partner_there = sum(1 for j, i in paired.items()
                                  if label.get(j, -1) >= 0 and label.get(j, -1) != label.get(i, -2)
                                  and label.get(j, -1) in first)
        missed = collections.Counter()
        for (i, j), candidate, consistent in zip(record["truth_pairs"].tolist(), record["truth_candidate"],
                                                 record["truth_consistent"]):
            if paired.get(j) != i:
                missed[missed_reason(bool(candidate), bool(consistent))] += 1
        rows.append(dict(index=event["index"], leaves=event["leaves"], first=len(record["first_ids"]),
                         second=len(record["second_ids"]), overlap=event["overlap"],
                         pairable=len(record["truth_pairs"]), paired=len(paired), correct=correct,
                         wrong=len(paired) - correct, wrong_partner_there=wrong_partner_there,
                         missed=sum(missed.values()), failed_ic=missed[REASONS[0]],
                         maps_disagree=missed[REASONS[1]], lost_in_search=missed[REASONS[2]]))
    return rows


def run(filter_name: str, sim, config, oracle=None):
    """One run, per step: the local maps closed before its scan (D&C) and the ids returned."""
    slam = dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)
    if oracle is not None:
        slam.set_join_oracle(*oracle, mode="audit")
    returned, closed_before = [], []
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        if filter_name == "dc":
            closed_before.append(int(slam._core.stats["counters"].get("local_maps_closed", 0)))
        returned.append(slam.update(step.z, step.R))
    return slam, returned, closed_before


def run_config(seed: int, overrides=None) -> dcslam.SlamConfig:
    """JCBB + RJC with immediate joins (each at the step it is created), RJC's draws from the
    scene's seed, then the caller's overrides."""
    return dcslam.SlamConfig(**{**dict(association="jcbb", join_association="rjc", amortize=False, seed=seed),
                                **(overrides or {})})


def majority_labels(sim, returned):
    """Each returned feature id's landmark (the majority of its measurements' true ids), as
    ``(features, landmarks)`` and as a dict."""
    truth = np.asarray(sim.true_ids)
    features, landmarks = evaluation.feature_landmarks(truth, np.concatenate(returned))
    return features, landmarks, dict(zip(features.tolist(), landmarks.tolist()))


def diagnose(name: str, seed: int, filter_name: str, overrides=None):
    sim = simulation(name, seed)
    config = run_config(seed, overrides)
    slam, returned, closed_before = run(filter_name, sim, config)
    truth = np.asarray(sim.true_ids)
    features, landmarks, label = majority_labels(sim, returned)
    if filter_name == "dc":
        slam, audited, closed_before = run(filter_name, sim, config, (features, landmarks))
        if not all(np.array_equal(a, b) for a, b in zip(returned, audited)):
            raise RuntimeError("the audited run returned other ids: the audit changed a decision")
    estimate = slam.estimate()
    scores = evaluation.evaluate_run(slam, estimate, returned, sim)

    raw = np.concatenate(returned)
    final = slam.resolve(raw)
    step_of = np.repeat(np.arange(len(returned)), [len(r) for r in returned])
    born = {}
    for final_id, step in zip(final, step_of):
        born.setdefault(int(final_id), int(step))
    leaf = np.asarray(closed_before) if filter_name == "dc" else np.zeros(len(returned), int)
    spans = join_tree(slam, leaf) if filter_name == "dc" else []
    records = {event["index"]: record for event, record in
               zip(sorted(slam.stats.joins, key=lambda j: j["index"]), slam.join_pairings())} if spans else {}
    fold = slam.fold_pairings() if filter_name == "dc" else []
    stack_leaves = [leaves for leaves, _ in slam._core.stack_shape()] if filter_name == "dc" else []
    fold_first_leaves = list(np.cumsum([0] + stack_leaves[:-1])[::-1])  # top of the stack first
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
        reason = ""
        if leaf_a == leaf_b:
            where = "same local map" if filter_name == "dc" else "EKF map"
        else:
            met = next((s for s in spans if s[0] <= leaf_a and leaf_b <= s[1]), None)
            where = (f"join of {met[2]['leaves']} leaves ({met[2]['features_first']}+{met[2]['features_second']} "
                     f"features, overlap {met[2]['overlap']}, {met[2]['pairings']} pairs)") if met else "final fold"
            if met:
                reason = join_reason(records[met[2]["index"]], landmark, label)
            elif fold:
                # Fold k joins the k-th stack map from the top with everything after it.
                k = next(k for k, first_leaf in enumerate(fold_first_leaves) if first_leaf <= min(leaf_a, leaf_b))
                reason = join_reason(fold[k], landmark, label)
        distance = np.inf
        if a in index and b in index:
            ia, ib = 3 + 2 * index[a], 3 + 2 * index[b]
            P = estimate.covariance
            S = P[ia:ia + 2, ia:ia + 2] + P[ib:ib + 2, ib:ib + 2] - P[ia:ia + 2, ib:ib + 2] - P[ib:ib + 2, ia:ia + 2]
            d = estimate.landmarks[index[a]] - estimate.landmarks[index[b]]
            distance = float(d @ np.linalg.solve(S, d))
        reports.append(dict(landmark=landmark, steps=(born[a], born[b]), leaves=(leaf_a, leaf_b), where=where,
                            reason=reason, distance_sq=distance, compatible=distance <= gate))
    joins = join_scores(slam, label) if filter_name == "dc" else []
    return scores, reports, joins


def join_reason(record, landmark: int, label) -> str:
    """Why the join `record` did not make the true pair of `landmark`, with its marginal D^2."""
    paired = {int(j): int(i) for i, j in record["pairs"]}
    for (i, j), distance_sq, candidate, consistent in zip(record["truth_pairs"].tolist(), record["truth_distance_sq"],
                                                          record["truth_candidate"], record["truth_consistent"]):
        if label.get(j) != landmark:
            continue
        if paired.get(j) == i:
            return "made there"  # another feature of the landmark split off elsewhere
        return f"{missed_reason(bool(candidate), bool(consistent))} (D^2 {distance_sq:.1f})"
    return "no true pair there (a feature of the landmark was dropped or merged elsewhere)"


def summary(name: str, seeds, filter_name: str, overrides=None) -> None:
    """The join-size and duplicate-reason tables summed over `seeds` (docs/data_association.md)."""
    joins, reports = [], []
    for seed in seeds:
        _, seed_reports, seed_joins = diagnose(name, seed, filter_name, overrides)
        joins += seed_joins
        reports += seed_reports
    print(f"{name}, seeds {seeds[0]}..{seeds[-1]}, {filter_name}: {len(reports)} duplicated landmarks")
    print_join_sizes(joins)
    where = collections.Counter(where_kind(r["where"]) for r in reports)
    print("where they should have met: " + ", ".join(f"{k} {v}" for k, v in sorted(where.items())))
    print_reasons(reports)


def where_kind(where: str) -> str:
    """"same local map", "join" (any real join) or "final fold"."""
    return "join" if where.startswith("join") else where


WRONG_KINDS = ("with a clutter-born feature", "a swap (a true partner in the other map)", "the true partners absent")
ONCE = ("both features once", "one once", "neither")


def wrong_pair_kinds(name: str, seeds, max_leaves: int, overrides=None):
    """Counts the right pairs and the wrong ones by kind (WRONG_KINDS x ONCE) of the D&C joins of
    at most `max_leaves` local maps; each feature labelled by the majority of its measurements."""
    counts = collections.Counter()
    for seed in seeds:
        sim = simulation(name, seed)
        slam, returned, _ = run("dc", sim, run_config(seed, overrides))
        _, _, label = majority_labels(sim, returned)
        measurements = collections.Counter(np.concatenate(returned).tolist())
        for event, record in zip(sorted(slam.stats.joins, key=lambda j: j["index"]), slam.join_pairings()):
            if event["leaves"] > max_leaves:
                continue
            first = {label.get(i, -1) for i in record["first_ids"].tolist()}
            second = {label.get(j, -1) for j in record["second_ids"].tolist()}
            for i, j in record["pairs"].tolist():
                li, lj = label.get(i, -1), label.get(j, -1)
                if li == lj and li >= 0:
                    counts["right"] += 1
                    continue
                kind = 0 if li < 0 or lj < 0 else 1 if (lj in first or li in second) else 2
                once = 2 - (measurements[i] == 1) - (measurements[j] == 1)
                counts[(WRONG_KINDS[kind], ONCE[once])] += 1
    return counts


def print_wrong_pair_kinds(counts, max_leaves: int) -> None:
    wrong = sum(v for k, v in counts.items() if k != "right")
    print(f"joins of at most {max_leaves} local maps: {counts['right']} right pairs, {wrong} wrong")
    print(f"{'wrong pairs':44s} " + " ".join(f"{o:>18s}" for o in ONCE))
    for kind in WRONG_KINDS:
        print(f"{kind:44s} " + " ".join(f"{counts[(kind, o)]:18d}" for o in ONCE))


def print_join_sizes(joins) -> None:
    """The join scores summed over the joins of at most 4 leaves and over the larger ones."""
    if not joins:
        return
    counted = ("pairable", "paired", "correct", "wrong", "missed", "failed_ic", "maps_disagree", "lost_in_search")
    print(f"{'joins':>12s} " + " ".join(f"{k:>14s}" for k in counted))
    for title, rows in (("<= 4 leaves", [r for r in joins if r["leaves"] <= 4]),
                        ("> 4 leaves", [r for r in joins if r["leaves"] > 4])):
        print(f"{title:>12s} " + " ".join(f"{sum(r[k] for r in rows):14d}" for k in counted))


def print_reasons(reports) -> None:
    for title, kind in (("a real join", "join"), ("the final fold", "final fold")):
        reasons = collections.Counter(r["reason"].split(" (")[0] for r in reports
                                      if where_kind(r["where"]) == kind and r["reason"])
        if reasons:
            print(f"why, where they should have met in {title}: "
                  + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--filter", choices=("dc", "ekf"), default="dc")
    parser.add_argument("--list", action="store_true", help="one line per duplicated landmark")
    parser.add_argument("--joins", action="store_true", help="score every D&C join's pairs against the truth")
    parser.add_argument("--seeds", type=int, default=None,
                        help="sum the summary tables over seeds 0..N-1 (instead of one seed's details)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="SlamConfig overrides (e.g. local_map_features=20; seed=S for another RJC draw)")
    parser.add_argument("--wrong-pairs", type=int, default=None, metavar="N",
                        help="D&C: classify the wrong pairs of the joins of at most N local maps")
    args = parser.parse_args()
    overrides = parse_overrides(args.set)
    if args.wrong_pairs is not None:
        if args.filter != "dc":
            parser.error("--wrong-pairs scores D&C's joins; the EKF has none")
        seeds = list(range(args.seeds)) if args.seeds is not None else [args.seed]
        print_wrong_pair_kinds(wrong_pair_kinds(args.scenario, seeds, args.wrong_pairs, overrides), args.wrong_pairs)
        return
    if args.seeds is not None:
        if args.seeds < 1:
            parser.error(f"--seeds must be at least 1, got {args.seeds}")
        summary(args.scenario, list(range(args.seeds)), args.filter, overrides)
        return
    scores, reports, joins = diagnose(args.scenario, args.seed, args.filter, overrides)
    if args.joins:
        keys = ("index", "leaves", "first", "second", "overlap", "pairable", "paired", "correct", "wrong",
                "wrong_partner_there", "missed", "failed_ic", "maps_disagree", "lost_in_search")
        print(" ".join(f"{k:>8s}" if len(k) <= 8 else k for k in keys))
        for row in joins:
            print(" ".join(f"{row[k]:8d}" if len(k) <= 8 else f"{row[k]:{len(k)}d}" for k in keys))
    print_join_sizes(joins)
    a = scores.association
    print(f"{args.scenario} seed {args.seed} {args.filter}: P {a.pairwise_precision:.3f} R {a.pairwise_recall:.3f} "
          f"features/landmark {a.features_per_landmark:.3f}, {len(reports)} duplicated landmarks")
    if args.list:
        for r in reports:
            reason = f" {r['reason']};" if r["reason"] else ""
            print(f"  landmark {r['landmark']:5d} steps {r['steps']} leaves {r['leaves']} {r['where']}:{reason} "
                  f"final D^2 {r['distance_sq']:.1f} ({'compatible' if r['compatible'] else 'incompatible'})")
    table = collections.Counter(
        (where_kind(r["where"]), "compatible" if r["compatible"] else "incompatible") for r in reports)
    print(f"{'where they should have met':28s} {'compatible':>10s} {'incompatible':>12s}")
    for where in sorted({w for w, _ in table}):
        print(f"{where:28s} {table[(where, 'compatible')]:10d} {table[(where, 'incompatible')]:12d}")
    print_reasons(reports)


if __name__ == "__main__":
    main()
