"""Where EKF data association loses precision and recall on the simulator (issue 4;
docs/data_association.md, "Where the simulator's errors come from").

`breakdown`: runs EkfSlam step by step on a simulated run with clutter and classifies every
measurement against the simulator's true ids. It re-implements the bench's score_pairings
(features labelled by the majority of their measurements; precision = correct / pairings,
recall = correct / re-observations of mapped landmarks) and checks the counts, then splits the
wrong pairings and the missed re-observations by cause, using each feature's creator (the true
id of the measurement that started it) and the individual gate of the measurement against
its own landmark's feature(s) computed from the estimate before the update. Per scan with a
wrong pairing it compares JCBB's hypothesis with the true one (own features passing the
gate) under the joint test. Slow (copies the full covariance every step): ~1 min.

`oracle`: the perfect-map oracle. Each scan is associated knowing the true robot pose, the
true landmark positions and the exact set of landmarks in view (each takes one measurement),
by the most likely assignment under the simulator's noise and clutter model (Hungarian
algorithm); then its pairings are declined in order of their margin (cost of the best
assignment without the pairing minus the best) to trace precision against recall.

Needs scipy (the "test" extra).

Usage: python studies/association_breakdown.py breakdown|oracle TRAJECTORY [--steps 600]
       [--clutter 0.1] [--seed 0] [--gate 0.99] [--unexplained-density 0]
"""

from __future__ import annotations

import argparse
import collections
import math

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

import dcslam


def wrap(angle):
    return (angle + np.pi) % (2 * np.pi) - np.pi


def predict_range_bearing(robot, features):
    """h(x_R, f) for features (n, 2) seen from the robot (no sensor offset), with Jacobians."""
    dx = features[:, 0] - robot[0]
    dy = features[:, 1] - robot[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z_hat = np.stack([r, np.arctan2(dy, dx) - robot[2]], 1)
    H_robot = np.zeros((len(features), 2, 3))
    H_feature = np.zeros((len(features), 2, 2))
    H_robot[:, 0, 0], H_robot[:, 0, 1] = -dx / r, -dy / r
    H_robot[:, 1, 0], H_robot[:, 1, 1], H_robot[:, 1, 2] = dy / q, -dx / q, -1.0
    H_feature[:, 0, 0], H_feature[:, 0, 1] = dx / r, dy / r
    H_feature[:, 1, 0], H_feature[:, 1, 1] = -dy / q, dx / q
    return z_hat, H_robot, H_feature


def stacked(estimate, z, R, pairs):
    """Innovation and covariance of the pairings (measurement row, feature index), stacked."""
    k = len(pairs)
    features = np.array([j for _, j in pairs])
    z_hat, H_robot, H_feature = predict_range_bearing(estimate.robot, estimate.landmarks[features])
    columns = [0, 1, 2]
    for j in features:
        columns += [3 + 2 * j, 4 + 2 * j]
    columns = sorted(set(columns))
    position = {c: n for n, c in enumerate(columns)}
    H = np.zeros((2 * k, len(columns)))
    nu = np.zeros(2 * k)
    noise = np.zeros((2 * k, 2 * k))
    for a, (i, j) in enumerate(pairs):
        H[2 * a:2 * a + 2, :3] = H_robot[a]
        H[2 * a:2 * a + 2, position[3 + 2 * j]:position[3 + 2 * j] + 2] = H_feature[a]
        v = z[i] - z_hat[a]
        v[1] = wrap(v[1])
        nu[2 * a:2 * a + 2] = v
        noise[2 * a:2 * a + 2, 2 * a:2 * a + 2] = R[i]
    P = estimate.covariance[np.ix_(columns, columns)]
    return nu, H @ P @ H.T + noise


def distance_sq(estimate, z, R, pairs):
    if not pairs:
        return 0.0
    nu, S = stacked(estimate, z, R, pairs)
    return float(nu @ np.linalg.solve(S, nu))


def replay(args):
    """Runs the filter; returns per-measurement records and per-scan hypothesis comparisons."""
    sim = dcslam.simulate(args.trajectory, steps=args.steps, seed=args.seed, clutter=args.clutter)
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="jcbb", gate_confidence=args.gate,
                                            unexplained_density=args.unexplained_density))
    gate = chi2.ppf(args.gate, 2)
    creator, born = {}, {}
    records = []
    scans = collections.Counter()
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        estimate = slam.estimate()
        index_of = {int(f): k for k, f in enumerate(estimate.landmark_ids)}
        own = collections.defaultdict(list)
        for k, f in enumerate(estimate.landmark_ids):
            own[creator[int(f)]].append(k)
        ids = slam.update(step.z, step.R)
        z, R = np.asarray(step.z), np.asarray(step.R)
        measured = {int(t) for t in step.true_ids if t >= 0}
        jcbb_pairs, true_pairs, wrong = [], [], False
        for i, got in enumerate(ids.tolist()):
            true = int(step.true_ids[i])
            record = dict(step=step.index, got=got, true=true)
            if got == -1:
                record["decision"] = "rejected"
            elif got in index_of:
                record["decision"] = "paired"
                record["creator"] = creator[got]
                record["d2"] = distance_sq(estimate, z, R, [(i, index_of[got])])
                record["feature_age"] = step.index - born[got]
                jcbb_pairs.append((i, index_of[got]))
                wrong |= creator[got] != true
            else:
                record["decision"] = "new"
                creator[got] = true
                born[got] = step.index
            if true >= 0 and own.get(true):
                d2 = [distance_sq(estimate, z, R, [(i, k)]) for k in own[true]]
                record["own_in_gate"] = min(d2) <= gate
                if record["own_in_gate"]:
                    record["own_feature"] = own[true][int(np.argmin(d2))]
                    true_pairs.append((i, record["own_feature"]))
            if true < 0 and len(estimate.landmark_ids):
                # Features whose gate holds this clutter, and whether their landmark was measured.
                p = estimate.robot[:2] + z[i, 0] * np.array(
                    [math.cos(estimate.robot[2] + z[i, 1]), math.sin(estimate.robot[2] + z[i, 1])])
                near = np.nonzero(np.sum((estimate.landmarks - p) ** 2, 1) < 36.0)[0]
                in_gate = [int(k) for k in near if distance_sq(estimate, z, R, [(i, int(k))]) <= gate]
                record["in_gate"] = bool(in_gate)
                record["in_free_gate"] = any(
                    creator[int(estimate.landmark_ids[k])] not in measured for k in in_gate)
            records.append(record)
        taken_by = {k: int(step.true_ids[i]) for i, k in jcbb_pairs}
        for record in records[len(records) - len(ids):]:
            if record["decision"] == "rejected" and "own_feature" in record:
                record["own_taken_by"] = taken_by.get(record["own_feature"])
        if wrong:
            scans[compare(estimate, z, R, jcbb_pairs, true_pairs, args.gate)] += 1
    resolved = slam.resolve(np.array([r["got"] for r in records], dtype=np.int64))
    for record, feature in zip(records, resolved.tolist()):
        record["resolved"] = feature
    return sim, records, scans


def compare(estimate, z, R, jcbb_pairs, true_pairs, confidence):
    d_jcbb = distance_sq(estimate, z, R, jcbb_pairs)
    d_true = distance_sq(estimate, z, R, true_pairs)
    if true_pairs and d_true > chi2.ppf(confidence, 2 * len(true_pairs)):
        return "true hypothesis not jointly compatible"
    if len(true_pairs) > len(jcbb_pairs):
        return "true hypothesis has more pairings"
    if len(true_pairs) < len(jcbb_pairs):
        return "JCBB's hypothesis has more pairings"
    return "same pairings, JCBB's D^2 lower" if d_jcbb <= d_true else "same pairings, true D^2 lower"


def score(records):
    """dcslam_bench's score_pairings; marks each record scored_paired / correct / revisit."""
    votes = collections.defaultdict(collections.Counter)
    for r in records:
        if r["resolved"] >= 0 and r["true"] >= 0:
            votes[r["resolved"]][r["true"]] += 1
    label = {}
    for feature, counts in votes.items():
        most = max(counts.values())
        label[feature] = min(t for t, n in counts.items() if n == most)
    seen, mapped = set(), set()
    for r in records:
        feature, landmark = r["resolved"], r["true"]
        r["revisit"] = landmark >= 0 and landmark in mapped
        r["scored_paired"] = r["correct"] = False
        if feature < 0:
            continue
        if feature not in seen:
            seen.add(feature)
            if feature in label:
                mapped.add(label[feature])
            continue
        r["scored_paired"] = True
        r["correct"] = landmark >= 0 and label.get(feature) == landmark


def breakdown(args):
    sim, records, scans = replay(args)
    score(records)
    paired = sum(r["scored_paired"] for r in records)
    correct = sum(r["correct"] for r in records)
    revisits = sum(r["revisit"] for r in records)
    print(f"precision {correct / paired:.4f} ({correct}/{paired}), recall {correct / revisits:.4f} "
          f"({correct}/{revisits})")
    wrong = collections.Counter()
    for r in (r for r in records if r["scored_paired"] and not r["correct"]):
        if r["true"] >= 0:
            wrong["true measurement -> clutter-born feature" if r.get("creator", 0) < 0
                  else "true measurement -> another landmark's feature"] += 1
        elif r.get("creator", 0) < 0:
            wrong["clutter -> clutter-born feature"] += 1
        else:
            wrong["clutter -> landmark feature"
                  + (" (not measured in the scan)" if r["in_free_gate"] else " (its landmark measured too)")] += 1
    missed = collections.Counter()
    for r in (r for r in records if r["revisit"] and not r["correct"]):
        gate = ("no feature started by this landmark" if "own_in_gate" not in r
                else "own feature in the gate" if r["own_in_gate"] else "own feature outside the gate")
        decision = "paired wrong" if r["decision"] == "paired" else r["decision"]
        missed[f"{decision}; {gate}"] += 1
    left_out = collections.Counter()
    for r in records:
        if r["revisit"] and not r["correct"] and r["decision"] == "rejected" and r.get("own_in_gate"):
            taker = r.get("own_taken_by")
            left_out["left unpaired by the joint test" if taker is None
                     else "taken by clutter" if taker < 0 else "taken by another landmark"] += 1
    swapped = [r for r in records if r["scored_paired"] and not r["correct"] and r["true"] >= 0
               and r.get("creator", -1) >= 0]
    apart = [np.linalg.norm(sim.landmarks[r["creator"]] - sim.landmarks[r["true"]]) for r in swapped]
    young = sum(r["feature_age"] <= 5 for r in swapped)
    paired = [r for r in records if r["scored_paired"]]
    d2_right = np.array([r["d2"] for r in paired if r["correct"]])
    d2_wrong = np.array([r["d2"] for r in paired if not r["correct"]])
    true_with_feature = [r for r in records if "own_in_gate" in r]
    clutter = [r for r in records if r["true"] < 0]
    for title, counts in (("wrong pairings", wrong), ("missed re-observations", missed),
                          ("rejected with their own feature in the gate", left_out),
                          ("scans with a wrong pairing", scans)):
        print(title)
        for key, n in counts.most_common():
            print(f"  {n:5d}  {key}")
    print(f"true measurement -> another landmark's feature: the two landmarks {np.median(apart):.2f} m apart "
          f"(median; 90 % within {np.percentile(apart, 90):.2f} m), {young} of {len(swapped)} to a feature "
          f"started at most 5 steps before")
    print(f"individual d^2 of the pairings: median {np.median(d2_right):.2f} right, {np.median(d2_wrong):.2f} wrong")
    for threshold in (7.0, 5.0):
        print(f"  declining d^2 > {threshold}: {np.sum(d2_wrong > threshold)} wrong and "
              f"{np.sum(d2_right > threshold)} right pairings")
    failing = sum(not r["own_in_gate"] for r in true_with_feature)
    print(f"true measurements of a landmark with a feature: {len(true_with_feature)}, "
          f"{failing} ({failing / len(true_with_feature):.2%}) outside the gate of their own feature")
    print(f"clutter: {len(clutter)}, {sum(r.get('in_gate', False) for r in clutter)} inside some feature's gate, "
          f"{sum(r.get('in_free_gate', False) for r in clutter)} inside the gate of a feature not measured in the scan")


def oracle(args):
    sim = dcslam.simulate(args.trajectory, steps=args.steps, seed=args.seed, clutter=args.clutter)
    cfg = sim.config
    area = 0.5 * cfg.fov * (cfg.max_range ** 2 - cfg.min_range ** 2)
    clutter_mean = args.clutter / (1 - args.clutter) * np.sum(sim.true_ids >= 0) / args.steps
    forced = 1e6  # every landmark in view takes a measurement
    margins, true_measurements = [], 0
    for step in sim.steps:
        pose = sim.poses[step.index + 1]
        z, ids = np.asarray(step.z), np.asarray(step.true_ids)
        view = sorted({int(t) for t in ids if t >= 0})
        m, n = len(z), len(view)
        true_measurements += n
        if m == 0:
            continue
        cost = np.full((m, n + m), np.inf)
        for j, landmark in enumerate(view):
            d = sim.landmarks[landmark] - pose[:2]
            r = math.hypot(*d)
            R = np.diag([(cfg.range_sigma_fraction * r) ** 2, cfg.bearing_sigma ** 2])
            nu = z - np.array([r, math.atan2(d[1], d[0]) - pose[2]])
            nu[:, 1] = wrap(nu[:, 1])
            cost[:, j] = (0.5 * np.einsum("ij,jk,ik->i", nu, np.linalg.inv(R), nu)
                          + 0.5 * math.log(np.linalg.det(2 * np.pi * R)) - forced)
        for i in range(m):
            cost[i, n + i] = -math.log(clutter_mean * z[i, 0] / area)  # clutter density at z_i
        rows, cols = linear_sum_assignment(cost)
        best = cost[rows, cols].sum()
        for i, c in zip(rows, cols):
            if c >= n:
                continue
            without = cost.copy()
            without[i, c] = np.inf
            r2, c2 = linear_sum_assignment(without)
            margin = without[r2, c2].sum() - best
            margins.append((np.inf if margin > forced / 2 else margin, view[c] == int(ids[i])))
    margin = np.array([a for a, _ in margins])
    right = np.array([b for _, b in margins])
    print("margin  precision  recall")
    for threshold in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 2.0):
        kept = margin >= threshold
        print(f"{threshold:6.1f}  {right[kept].mean():.5f}    {right[kept].sum() / true_measurements:.5f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=["breakdown", "oracle"])
    parser.add_argument("trajectory", choices=["straight", "loop", "lawn_mowing", "snail"])
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--clutter", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gate", type=float, default=0.99)
    parser.add_argument("--unexplained-density", type=float, default=0.0)
    args = parser.parse_args()
    breakdown(args) if args.command == "breakdown" else oracle(args)


if __name__ == "__main__":
    main()
