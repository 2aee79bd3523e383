"""Victoria Park: where D&C SLAM loses accuracy against the EKF, and why.

On Victoria Park, D&C's final map lies about 0.6-1.5 m RMS from the batch least-squares
optimum of its own data associations, the EKF's about 0.07-0.15 m
(``studies/vp_batch_reference.py``). This tool separates the possible causes.

(A) Same associations. D&C is run with unknown association; its resolved
``measurement_ids`` become known ids (rejected measurements dropped), and both filters are
run on those steps with ``association="known", join_association="known"``. Both then solve
the same problem, with one batch optimum (Gauss-Newton, initialised from the EKF), so any
difference between the two maps' distances to it is the filters', not the associations'.
The distances are also broken down by the step at which each landmark was first seen (bins
of ``--bin`` steps), with, for each bin's worst D&C landmark, the D&C local map whose steps
saw it first, and D&C's largest joins (where the tree's big subtrees end).

(B) One join at step k (``--split``). The known-id steps are cut at k; the EKF maps
``m1 = EKF(steps[:k])`` and ``m2 = EKF(steps[k:])`` (m2 in its own base frame, the robot
pose after step k-1) are joined by a dense numpy join written from the definition: the
constrained MAP of the stacked prior ``x0 = [x1; x2]``, ``P0 = blkdiag(P1, P2)`` under
``f1_i - (R1 ⊕ f2_j) = 0`` for every id the two maps share, by the iterated EKF
(Gauss-Newton) ``x+ = x0 + P0 H' (H P0 H')^-1 (-c(x) - H (x0 - x))`` until no coordinate
moves by more than the tolerance; the joined map is m1's features and ``R1 ⊕`` m2's
unmatched ones. It prints

- the joined map against the batch optimum of all the steps (and, for scale, the EKF over
  all the steps against it);
- DCSlam run with one split at k (``local_map_features`` = the size of m1, checked through
  ``keep_local_map_poses``: its only past pose must be step k, otherwise it says so): its
  distance to the dense join is an independent check of the C++ join, and its distance to
  the batch optimum is the join's own loss;
- the cost ``|x - x0|^2_{P0^-1}`` split into m1's and m2's parts, with the largest move of
  each part's elements, at the join's solution and at the point built from the EKF over all
  the steps (m1's robot = the EKF's pose after step k-1, m2's elements that map moved into
  that pose's frame; it meets the constraints too), and the join re-run from that point (if
  it lands on the same solution at a lower cost, the join's answer is the optimum of the two
  Gaussians, not a local artefact);
- m2 against the batch optimum of steps[k:] alone, in m2's base frame (and the EKF over
  all the steps moved into that frame, against the same optimum).

How to read it: if (A) shows D&C far from the optimum where the EKF is close, the loss is
D&C's. If in (B) the dense join reproduces D&C, and the join is the optimum of its two
Gaussians while m2 itself lies far from its own batch optimum, the loss comes from m2's
linearisation: a long stretch mapped without the old map as an anchor drifts, its Gaussian
is a poor approximation of it, and the join can only correct it linearly. The EKF, anchored
to the old map at every scan, does not accumulate that drift.

Usage:
    .venv/bin/python studies/vp_join_linearisation.py [--seed S] [--max-steps N]
        [--split K] [--bin B] [--json OUT]

An analysis tool: it reports numbers and asserts nothing. numpy/scipy only; the batch optimum,
the dense join and the known-id replay are the tests' oracles (``tests/python/oracles/``:
``batch_least_squares.py``, ``dense_join.py``, ``join_inputs.py``).
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from dcslam.pipeline import SlamPipeline

# vp_batch_reference.py lies beside this script, which puts its folder first on sys.path.
import vp_batch_reference as batch_reference

# The oracles are kept beside the tests that check them so that the numbers this study
# reports come from tested code; a study is a script, not a package, so it finds tests/python
# by path.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from oracles.batch_least_squares import batch_optimum  # noqa: E402
from oracles.dense_join import (dense_join, join_constraints, landmarks_of, shared_pairs,  # noqa: E402
                                split_costs, stacked_difference, state_from_map)
from oracles.join_inputs import ekf_map, first_seen, known_steps, reproducible_split  # noqa: E402


# ---------------------------------------------------------------------------------------
# Distances between maps
# ---------------------------------------------------------------------------------------

def distances(first: Dict[int, np.ndarray], second: Dict[int, np.ndarray], ids=None) -> Dict[int, float]:
    """Distance between the same landmark in two maps, by id (``ids`` or those they share)."""
    ids = sorted(set(first) & set(second)) if ids is None else ids
    return {int(i): float(np.linalg.norm(first[i] - second[i])) for i in ids}


def summary(distance: Dict[int, float]) -> Dict[str, float]:
    """count, RMS, max and share within 1 m of distances by id."""
    return batch_reference.distance_summary(np.array(list(distance.values())))


# ---------------------------------------------------------------------------------------
# The two parts of the report
# ---------------------------------------------------------------------------------------

def local_map_span(step: int, boundaries: Sequence[int], total: int) -> Tuple[int, int]:
    """The steps [start, end) of the local map holding ``step``, the local maps ending at
    ``boundaries`` (D&C's ``past_pose_ids``)."""
    edges = [0] + [int(b) for b in boundaries] + [total]
    n = int(np.searchsorted(edges, step, side="right")) - 1
    return edges[n], edges[n + 1]


def same_associations(steps: Sequence, config, everything, batch, bin_steps: int = 1000) -> Dict:
    """Part (A): the EKF (``everything`` = :func:`ekf_map` of ``steps``) and D&C on the same
    known ids against their common ``batch`` optimum, overall and by first-seen bin."""
    dc = SlamPipeline(steps, config, filter="dc").run()
    # A second run for the boundaries only: past poses in the state change the map's rounding,
    # and the map reported is that of the configuration as given.
    boundaries = SlamPipeline(steps, dataclasses.replace(config, keep_local_map_poses=True),
                              filter="dc").run().estimate.past_pose_ids
    maps = {"ekf": landmarks_of(everything[0], everything[2]),
            "dc": batch_reference.landmarks_by_id(dc.estimate)}
    ids = sorted(batch.landmarks)
    error = {name: distances(landmarks, batch.landmarks, ids) for name, landmarks in maps.items()}
    first = first_seen([s.landmark_ids for s in steps])
    bins = []
    for start in range(0, len(steps), bin_steps):
        selected = [i for i in ids if start <= first[i] < start + bin_steps]
        if not selected:
            continue
        worst = max(selected, key=lambda i: error["dc"][i])
        bins.append({"start": start, "end": min(start + bin_steps, len(steps)),
                     **{name: summary({i: error[name][i] for i in selected}) for name in maps},
                     "dc_worst": {"id": worst, "error": error["dc"][worst], "first_seen": first[worst],
                                  "local_map": local_map_span(first[worst], boundaries, len(steps))}})
    return {
        "landmarks": len(ids), "measurements": sum(len(s.z) for s in steps),
        "batch": {"iterations": batch.iterations, "converged": batch.converged,
                  "chi2_per_dof": batch.chi2_per_dof, "gradient_max": batch.gradient_norm},
        **{name: summary(error[name]) for name in maps},
        "bins": bins, "local_maps": len(boundaries) + 1,
        "large_joins": [{key: join[key] for key in ("leaves", "step_created", "step_finished",
                                                    "features_first", "features_second", "pairings")}
                        for join in dc.joins if join["leaves"] >= 16],
    }


def one_join(steps: Sequence, config, sensor_offset, split: int, everything, batch,
             max_iterations: int = 100, tolerance: float = 1e-9) -> Dict:
    """Part (B): the dense join of ``EKF(steps[:split])`` and ``EKF(steps[split:])``, D&C
    with that one split, the cost split and m2 against its own batch optimum (see the
    module docstring). ``everything`` is :func:`ekf_map` of all the steps, ``batch`` their
    batch optimum."""
    x1, P1, ids1, _ = ekf_map(steps[:split], config)
    x2, P2, ids2, poses2 = ekf_map(steps[split:], config)
    x_all, _, ids_all, poses_all = everything
    joined = dense_join(x1, P1, ids1, x2, P2, ids2, max_iterations, tolerance)
    pairs = shared_pairs(ids1, ids2)
    ekf_all = landmarks_of(x_all, ids_all)
    out = {"split": split, "m1_features": len(ids1), "m2_features": len(ids2), "pairs": len(pairs),
           "iterations": joined.iterations, "converged": joined.converged,
           "join_vs_batch": summary(distances(joined.features, batch.landmarks)),
           "ekf_all_vs_batch": summary(distances(ekf_all, batch.landmarks))}

    dc = SlamPipeline(steps, dataclasses.replace(config, local_map_features=len(ids1), keep_local_map_poses=True),
                      filter="dc").run()
    dc_map = batch_reference.landmarks_by_id(dc.estimate)
    past = [int(i) for i in dc.estimate.past_pose_ids]
    out["dc"] = {"local_map_features": len(ids1), "past_pose_ids": past, "reproduced": past == [split],
                 "reproducible_split": reproducible_split(steps, split),
                 "vs_batch": summary(distances(dc_map, batch.landmarks)),
                 "vs_dense_join": summary(distances(dc_map, joined.features)) if past == [split] else None}

    at_ekf = state_from_map(ekf_all, poses_all[split - 1], x_all[:3], ids1, ids2)
    from_ekf = dense_join(x1, P1, ids1, x2, P2, ids2, max_iterations, tolerance, initial=at_ekf)
    out["costs"] = {
        "dimension": {"m1": len(x1), "m2": len(x2)},
        "join": split_costs(joined.state, x1, P1, x2, P2),
        "ekf_all": split_costs(at_ekf, x1, P1, x2, P2),
        "ekf_all_constraint_max": float(np.max(np.abs(join_constraints(at_ekf, len(x1), pairs)[0]), initial=0.0)),
        "join_from_ekf_all": {**split_costs(from_ekf.state, x1, P1, x2, P2), "iterations": from_ekf.iterations,
                              "converged": from_ekf.converged,
                              "max_from_join": float(np.max(np.abs(stacked_difference(from_ekf.state, joined.state,
                                                                                      len(x1)))))},
    }

    tail = steps[split:]
    local = batch_optimum(tail, [s.landmark_ids for s in tail], sensor_offset, poses2, landmarks_of(x2, ids2))
    out["m2_local"] = {
        "batch": {"iterations": local.iterations, "converged": local.converged, "chi2_per_dof": local.chi2_per_dof},
        "ekf_vs_batch": summary(distances(landmarks_of(x2, ids2), local.landmarks)),
        "ekf_all_vs_batch": summary(distances(landmarks_of(at_ekf, ids2, offset=len(x1)), local.landmarks)),
    }
    return out


# ---------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------

def _rms_max(s: Dict) -> str:
    return f"{s['rms']:.3f} / {s['max']:.3f}"


def _costs(c: Dict) -> str:
    return ", ".join(f"{name} {c[name]:.1f} (robot {c[name + '_robot_move']:.2f} m / {c[name + '_heading_move']:.3f} "
                     f"rad, features up to {c[name + '_feature_move']:.2f} m)" for name in ("m1", "m2")) \
        + f", total {c['total']:.1f}"


def format_report(report: Dict) -> str:
    table = batch_reference._table
    a, b = report["same_associations"], report["one_join"]
    lines = [f"Victoria Park, {report['steps']} steps, seed {report['seed']}; distances in metres, "
             "RMS / max", "",
             "(A) Same associations: both filters on D&C's resolved ids (known association), against their "
             "common batch optimum",
             f"{a['landmarks']} landmarks, {a['measurements']} measurements; batch: {a['batch']['iterations']} GN "
             f"iterations, converged {a['batch']['converged']}, chi2/dof {a['batch']['chi2_per_dof']:.4f}, "
             f"max abs(J'r) {a['batch']['gradient_max']:.1e}"]
    lines += table(["filter", "map vs batch RMS / max", "within 1 m"],
                   [[name, _rms_max(a[name]), f"{a[name]['within_1m']:.3f}"] for name in ("ekf", "dc")])
    lines += ["", f"By the step a landmark was first seen (D&C: {a['local_maps']} local maps; the local map "
              "whose steps first saw the bin's worst D&C landmark)"]
    rows = [[f"{row['start']}-{row['end'] - 1}", str(row["dc"]["count"]), _rms_max(row["ekf"]), _rms_max(row["dc"]),
             f"{row['dc']['within_1m']:.3f}",
             f"{row['dc_worst']['error']:.3f} @ {row['dc_worst']['first_seen']} "
             f"(steps {row['dc_worst']['local_map'][0]}-{row['dc_worst']['local_map'][1] - 1})"]
            for row in a["bins"]]
    lines += table(["first seen", "n", "EKF RMS / max", "D&C RMS / max", "D&C within 1 m",
                    "D&C worst @ first seen (local map)"], rows)
    if a["large_joins"]:
        lines.append("D&C joins of >= 16 local maps: " + "; ".join(
            f"{j['leaves']} maps, created at step {j['step_created']} ({j['features_first']} + "
            f"{j['features_second']} features, {j['pairings']} pairs)" for j in a["large_joins"]))

    dc = b["dc"]
    lines += ["", f"(B) One join at step {b['split']}: dense numpy join of EKF(steps[:{b['split']}]) "
              f"({b['m1_features']} features) and EKF(steps[{b['split']}:]) ({b['m2_features']} features), "
              f"{b['pairs']} shared; {b['iterations']} linearisation points, converged {b['converged']}"]
    lines += table(["map", "vs batch optimum RMS / max", "within 1 m"],
                   [["dense join", _rms_max(b["join_vs_batch"]), f"{b['join_vs_batch']['within_1m']:.3f}"],
                    [f"D&C, local_map_features {dc['local_map_features']}", _rms_max(dc["vs_batch"]),
                     f"{dc['vs_batch']['within_1m']:.3f}"],
                    ["EKF over all the steps", _rms_max(b["ekf_all_vs_batch"]),
                     f"{b['ekf_all_vs_batch']['within_1m']:.3f}"]])
    if dc["reproduced"]:
        lines.append(f"D&C split at step {b['split']} only; D&C vs the dense join: "
                     f"RMS {dc['vs_dense_join']['rms']:.2e}, max {dc['vs_dense_join']['max']:.2e}")
    else:
        lines.append(f"D&C did NOT reproduce the split: its local maps end at steps {dc['past_pose_ids']} "
                     f"(wanted [{b['split']}]); no comparison with the dense join (the latest split at or "
                     f"before it that D&C can make: --split {dc['reproducible_split']})")
    c = b["costs"]
    lines += ["", f"Cost |x - x0|^2 of the stacked prior (dimension m1 {c['dimension']['m1']}, "
              f"m2 {c['dimension']['m2']}; moves from the prior means, m2's in its own base frame):",
              f"- at the join's solution: {_costs(c['join'])}",
              f"- at the EKF-over-everything point (constraint residual max {c['ekf_all_constraint_max']:.1e}): "
              f"{_costs(c['ekf_all'])}",
              f"- the join started from that point: {_costs(c['join_from_ekf_all'])}; "
              f"{c['join_from_ekf_all']['iterations']} points, converged {c['join_from_ekf_all']['converged']}, "
              f"max abs difference to the join's solution {c['join_from_ekf_all']['max_from_join']:.1e}"]
    m2 = b["m2_local"]
    lines += ["", f"m2 = EKF(steps[{b['split']}:]) against the batch optimum of those steps alone, in m2's base "
              f"frame (batch: {m2['batch']['iterations']} GN iterations, converged {m2['batch']['converged']}, "
              f"chi2/dof {m2['batch']['chi2_per_dof']:.4f})",
              f"- m2: RMS / max {_rms_max(m2['ekf_vs_batch'])}, within 1 m {m2['ekf_vs_batch']['within_1m']:.3f}",
              f"- the EKF over all the steps, moved into m2's frame: RMS / max {_rms_max(m2['ekf_all_vs_batch'])}, "
              f"within 1 m {m2['ekf_all_vs_batch']['within_1m']:.3f}"]
    lines.append(f"total {report['seconds']:.1f} s")
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> Dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="slam_config(seed=...)")
    parser.add_argument("--max-steps", type=int, default=None, help="run only the first N steps")
    parser.add_argument("--split", type=int, default=6250, help="(B): the step k the run is cut at (6250)")
    parser.add_argument("--bin", type=int, default=1000, help="(A): steps per first-seen bin (1000)")
    parser.add_argument("--json", dest="json_out", default=None, help="write the numbers here")
    args = parser.parse_args(argv)

    from dcslam.datasets import victoria_park

    started = time.perf_counter()
    vp = victoria_park()
    steps = vp.steps if args.max_steps is None else vp.steps[:args.max_steps]
    if not 0 < args.split < len(steps):
        parser.error(f"--split must lie in 1..{len(steps) - 1}, got {args.split}")
    config = vp.slam_config(seed=args.seed)
    unknown = SlamPipeline(steps, config, filter="dc").run()
    known = known_steps(steps, unknown.measurement_ids)
    known_config = dataclasses.replace(config, association="known", join_association="known")
    everything = ekf_map(known, known_config)
    batch = batch_optimum(known, [s.landmark_ids for s in known], vp.sensor_offset,
                          everything[3], landmarks_of(everything[0], everything[2]))
    report = {"seed": args.seed, "steps": len(steps),
              "same_associations": same_associations(known, known_config, everything, batch, args.bin),
              "one_join": one_join(known, known_config, vp.sensor_offset, args.split, everything, batch)}
    report["seconds"] = time.perf_counter() - started
    print(format_report(report))
    if args.json_out:
        with open(args.json_out, "w") as out:
            json.dump(batch_reference._jsonable(report), out, indent=1)
    return report


if __name__ == "__main__":
    main()
