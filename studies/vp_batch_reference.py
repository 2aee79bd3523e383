"""Victoria Park: each filter's map against the batch least-squares optimum of its own
data associations.

The EKF and D&C maps of Victoria Park (both with unknown data association) differ by about
1 m at the park's far end. This tool asks which of the two is off. For each filter it takes
the filter's own associations (``PipelineResult.measurement_ids``) and solves the full SLAM
problem they define by Gauss-Newton: every pose ``x_1..x_N`` and every associated landmark
are variables (``x_0`` is the origin, fixed), with

- odometry residuals ``Q_k^{-1/2} (⊖x_{k-1} ⊕ x_k - u_k)`` (angle wrapped), the same
  model as the filters' ``predict(u_k, Q_k)``: ``x_k = x_{k-1} ⊕ u`` with ``u ~ N(u_k, Q_k)``;
- observation residuals ``R^{-1/2} (z - h(x_k, l_j))`` (bearing wrapped), ``h`` being
  :func:`dcslam.geometry.observe` with the dataset's sensor offset; step ``k``'s ``z`` is
  taken at the pose right after step ``k``'s predict (``trajectory[k]`` in the filter's
  own estimate).

The batch optimum is what a filter would give if its linearisations were exact: a filter's
map far from its own optimum is off for the filter's reasons (linearisation, D&C's joins),
while a difference between the two optima is a difference of associations. A third
reference, the *consensus* optimum, uses only the measurements both filters associate with
the same landmark (landmarks paired when each holds the majority of the other's
measurements), to tell which filter's own associations move its optimum away. It is a
weak arbiter: dropping the disputed measurements also drops constraints, so its optimum
depends on where the disputes lie (on Victoria Park it sits near the EKF's optimum for the
whole run but nearer D&C's for the first 6195 steps).

The tool prints (1) for each filter how far its map lies from its own optimum (metres, and
in the filter's own landmark covariance), (2) the shares of landmarks within 1 m and 2 m
between maps and optima (:func:`dcslam.metrics.map_agreement`, no ids), (3) distances
between the same landmark in two sets (paired by shared measurements), each near the start
and beyond (``--near``, 150 m), (4) how far each optimum's trajectory, and each filter's online
one, lies from the GPS, the one reference independent of both filters, with D&C's optimum also
solved without the measurements the EKF associates with another landmark.

Usage:
    .venv/bin/python studies/vp_batch_reference.py [--seed S] [--max-steps N]
        [--local-map-features P] [--tree-relinearisation N] [--json OUT]

This is an analysis tool, not a test of the project's map-agreement target: it reports
numbers and asserts nothing. Only numpy/scipy are used (no GTSAM); the Gauss-Newton solver is
the tests' oracle ``tests/python/oracles/batch_least_squares.py`` (checked by
``tests/python/test_batch_least_squares.py``).
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

# The solver is the tests' oracle, kept beside the tests that check it so that the numbers
# this study reports come from tested code; a study is a script, not a package, so it finds
# tests/python by path.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from oracles.batch_least_squares import BatchResult, batch_optimum  # noqa: E402


# ---------------------------------------------------------------------------------------
# Ids that do not resolve to the final map
# ---------------------------------------------------------------------------------------

def unresolved_count(measurement_ids: Sequence, landmark_ids) -> int:
    """Measurements whose id is >= 0 but not a feature of the final map."""
    known = {int(i) for i in landmark_ids}
    return sum(1 for ids in measurement_ids for i in np.asarray(ids) if int(i) >= 0 and int(i) not in known)


# ---------------------------------------------------------------------------------------
# Comparisons
# ---------------------------------------------------------------------------------------

def distance_summary(distance: np.ndarray) -> Dict[str, float]:
    """count, RMS, max and share <= 1 m of a set of distances [m]."""
    distance = np.asarray(distance, dtype=float)
    if len(distance) == 0:
        return {"count": 0, "rms": float("nan"), "max": float("nan"), "within_1m": float("nan")}
    return {"count": int(len(distance)), "rms": float(np.sqrt(np.mean(distance**2))),
            "max": float(distance.max()), "within_1m": float(np.mean(distance <= 1.0))}


def _by_region(distance: np.ndarray, from_start: np.ndarray, near_radius: float) -> Dict[str, Dict]:
    near = np.asarray(from_start) <= near_radius
    return {"all": distance_summary(distance), "near": distance_summary(distance[near]),
            "far": distance_summary(distance[~near])}


def shared_measurement_pairs(first_ids: Sequence, second_ids: Sequence) -> Dict[int, int]:
    """Landmarks of two runs that are the same landmark by their measurements: first-run
    landmark a -> second-run landmark b when b holds more than half of a's measurements and
    a more than half of b's (so the pairing is one-to-one)."""
    counts: Dict[tuple, int] = {}
    first_total: Dict[int, int] = {}
    second_total: Dict[int, int] = {}
    for a_ids, b_ids in zip(first_ids, second_ids):
        for a, b in zip(np.asarray(a_ids), np.asarray(b_ids)):
            a, b = int(a), int(b)
            if a >= 0:
                first_total[a] = first_total.get(a, 0) + 1
            if b >= 0:
                second_total[b] = second_total.get(b, 0) + 1
            if a >= 0 and b >= 0:
                counts[(a, b)] = counts.get((a, b), 0) + 1
    return {a: b for (a, b), n in counts.items() if 2 * n > first_total[a] and 2 * n > second_total[b]}


def association_difference(first_ids, second_ids, pairs: Dict[int, int]) -> Dict[str, int]:
    """Counts of measurements by how the two runs associated them (``pairs`` maps the
    first run's landmarks onto the second's): both_same (paired landmarks), both_different,
    first_only / second_only (the other run has none), neither."""
    counts = {"both_same": 0, "both_different": 0, "first_only": 0, "second_only": 0, "neither": 0}
    for a_ids, b_ids in zip(first_ids, second_ids):
        for a, b in zip(np.asarray(a_ids), np.asarray(b_ids)):
            a, b = int(a), int(b)
            if a >= 0 and b >= 0:
                counts["both_same" if pairs.get(a) == b else "both_different"] += 1
            elif a >= 0:
                counts["first_only"] += 1
            elif b >= 0:
                counts["second_only"] += 1
            else:
                counts["neither"] += 1
    return counts


def _per_step(first_ids: Sequence, second_ids: Sequence):
    """The two runs' ids of each step as int64 arrays, step by step."""
    for a_ids, b_ids in zip(first_ids, second_ids):
        yield np.asarray(a_ids, dtype=np.int64), np.asarray(b_ids, dtype=np.int64)


def _same_landmark(a_ids: np.ndarray, b_ids: np.ndarray, pairs: Dict[int, int]) -> np.ndarray:
    """Per measurement: the first run's landmark is the second run's, by ``pairs``."""
    return np.array([a >= 0 and pairs.get(int(a)) == int(b) for a, b in zip(a_ids, b_ids)], dtype=bool)


def undisputed_ids(first_ids: Sequence, second_ids: Sequence, pairs: Dict[int, int]) -> List[np.ndarray]:
    """The second run's ids less the measurements both runs associate, with landmarks that are
    not the same by ``pairs`` (-1 there): what the second run's associations are without the
    measurements the two runs dispute."""
    out = []
    for a_ids, b_ids in _per_step(first_ids, second_ids):
        disputed = (a_ids >= 0) & (b_ids >= 0) & ~_same_landmark(a_ids, b_ids, pairs)
        out.append(np.where(disputed, -1, b_ids))
    return out


def gps_rms(steps: Sequence, poses: np.ndarray, gps) -> Optional[float]:
    """RMS (m) of a trajectory (pose k: step k's) from the GPS after rigid alignment, or None
    when too few GPS fixes fall within the steps' time span (a short prefix)."""
    from dcslam.metrics import TooFewGpsFixes, gps_alignment

    times = np.array([step.t for step in steps])
    try:
        return float(gps_alignment(times, poses, gps).rms)
    except TooFewGpsFixes:
        return None


def consensus_ids(first_ids: Sequence, second_ids: Sequence, pairs: Dict[int, int]) -> List[np.ndarray]:
    """The first run's ids where both runs associate the measurement with the same landmark
    (by ``pairs``), -1 elsewhere."""
    return [np.where(_same_landmark(a_ids, b_ids, pairs), a_ids, -1)
            for a_ids, b_ids in _per_step(first_ids, second_ids)]


def mahalanobis_summary(difference: Dict[int, np.ndarray], covariance: Dict[int, np.ndarray]) -> Dict[str, float]:
    """d' P^-1 d per landmark with P the filter's own 2x2 marginal: median and share below
    5.99 (95 % of chi-square(2)). A scale for the differences, not a test: the batch
    optimum is not a random draw around the filter's estimate."""
    values = np.array([float(d @ np.linalg.solve(covariance[k], d)) for k, d in difference.items()])
    if len(values) == 0:
        return {"median": float("nan"), "below_5.99": float("nan")}
    return {"median": float(np.median(values)), "below_5.99": float(np.mean(values < 5.99))}


def compare(runs: Dict[str, dict], near_radius: float, consensus: Optional["BatchResult"] = None) -> Dict:
    """All numbers of the report.

    Args:
        runs: ``runs[name]`` = dict(map={id: (2,)}, covariance={id: (2, 2)}, batch=BatchResult,
            trajectory=(N, 3), measurement_ids=[...]), for name in
            ("ekf", "dc"), EKF first.
        near_radius: landmarks this close to the start [m] are "near", the others "far".
        consensus: batch optimum of the measurements both filters associate alike (ids of
            the first run).
    """
    report: Dict = {"near_radius": near_radius, "filters": {}, "shares": [], "same_landmark": []}
    for name, run in runs.items():
        batch: BatchResult = run["batch"]
        ids = sorted(batch.landmarks)
        difference = {i: run["map"][i] - batch.landmarks[i] for i in ids}
        distance = np.array([np.linalg.norm(difference[i]) for i in ids])
        from_start = np.array([np.linalg.norm(batch.landmarks[i]) for i in ids])
        report["filters"][name] = {
            "map_landmarks": len(run["map"]), "batch_landmarks": len(batch.landmarks),
            "iterations": batch.iterations, "converged": batch.converged, "halvings": batch.halvings,
            "chi2_initial": batch.chi2_initial, "chi2": batch.chi2, "dof": batch.degrees_of_freedom,
            "chi2_per_dof": batch.chi2_per_dof, "gradient_max": batch.gradient_norm,
            "last_step": batch.last_step, "dropped_measurements": batch.dropped_measurements,
            "solve_seconds": batch.seconds, "history": batch.history,
            "map_vs_batch": _by_region(distance, from_start, near_radius),
            "map_vs_batch_mahalanobis": mahalanobis_summary(difference, run["covariance"]) if run.get("covariance") else None,
            "final_pose_vs_batch_m": float(np.linalg.norm(run["trajectory"][-1, :2] - batch.poses[-1, :2])),
        }
    names = list(runs)
    if len(names) != 2:
        return report
    a, b = names
    sets = {f"{a} map": runs[a]["map"], f"{b} map": runs[b]["map"],
            f"{a} batch": runs[a]["batch"].landmarks, f"{b} batch": runs[b]["batch"].landmarks}
    if consensus is not None:
        sets["consensus batch"] = consensus.landmarks
    from dcslam.metrics import map_agreement

    couples = [(f"{a} map", f"{b} map"), (f"{a} batch", f"{b} batch"), (f"{a} map", f"{b} batch"),
               (f"{b} map", f"{a} batch"), (f"{a} map", f"{a} batch"), (f"{b} map", f"{b} batch")]
    if consensus is not None:
        couples += [(name, "consensus batch") for name in (f"{a} map", f"{a} batch", f"{b} map", f"{b} batch")]
    for first, second in couples:
        first_points = np.array(list(sets[first].values()), dtype=float).reshape(-1, 2)
        second_points = np.array(list(sets[second].values()), dtype=float).reshape(-1, 2)
        row = {"first": first, "second": second}
        for radius in (1.0, 2.0):
            agreement = map_agreement(first_points, second_points, radius)
            row[f"{radius:g}m"] = (agreement.first_in_second, agreement.second_in_first)
            for region, inside in (("near", lambda p: np.linalg.norm(p, axis=1) <= near_radius),
                                   ("far", lambda p: np.linalg.norm(p, axis=1) > near_radius)):
                forward = map_agreement(first_points[inside(first_points)], second_points, radius).first_in_second
                backward = map_agreement(second_points[inside(second_points)], first_points, radius).first_in_second
                row[f"{radius:g}m_{region}"] = (forward, backward)
        report["shares"].append(row)

    # The same landmark, by shared measurements: every set in the first run's ids.
    pairs = shared_measurement_pairs(runs[a]["measurement_ids"], runs[b]["measurement_ids"])
    in_first_ids = {f"{a} map": runs[a]["map"], f"{a} batch": runs[a]["batch"].landmarks}
    for name in (f"{b} map", f"{b} batch"):
        in_first_ids[name] = {k: sets[name][v] for k, v in pairs.items() if v in sets[name]}
    if consensus is not None:
        in_first_ids["consensus batch"] = consensus.landmarks
    reference = runs[a]["batch"].landmarks
    for first, second in couples:
        keys = [k for k in pairs if k in in_first_ids[first] and k in in_first_ids[second] and k in reference]
        distance = np.array([np.linalg.norm(in_first_ids[first][k] - in_first_ids[second][k]) for k in keys])
        from_start = np.array([np.linalg.norm(reference[k]) for k in keys])
        report["same_landmark"].append({"first": first, "second": second,
                                        **_by_region(distance, from_start, near_radius)})
    report["pairs"] = len(pairs)
    report["association_difference"] = association_difference(
        runs[a]["measurement_ids"], runs[b]["measurement_ids"], pairs)
    if consensus is not None:
        report["consensus"] = {"iterations": consensus.iterations, "converged": consensus.converged,
                               "chi2": consensus.chi2, "dof": consensus.degrees_of_freedom,
                               "chi2_per_dof": consensus.chi2_per_dof, "gradient_max": consensus.gradient_norm,
                               "landmarks": len(consensus.landmarks)}
    return report


# ---------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------

def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> List[str]:
    return (["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(row) + " |" for row in rows])


def _rms_max(s: Dict) -> str:
    return f"{s['rms']:.3f} / {s['max']:.3f} ({s['count']})"


def format_report(report: Dict) -> str:
    near = report["near_radius"]
    lines = [f"Victoria Park, {report.get('steps', '?')} steps, seed {report.get('seed', '?')}; "
             f"near = landmarks <= {near:g} m from the start, far = beyond", ""]
    lines.append("1. Each filter's map against the batch optimum (Gauss-Newton) of its own associations")
    rows = []
    for name, f in report["filters"].items():
        m = f["map_vs_batch"]
        mahalanobis = f["map_vs_batch_mahalanobis"]
        rows.append([
            name, f"{f['map_landmarks']} / {f['batch_landmarks']}", str(f["iterations"]), str(f["converged"]),
            f"{f['chi2_initial']:.4g} -> {f['chi2']:.6g}", str(f["dof"]), f"{f['chi2_per_dof']:.4f}",
            f"{f['gradient_max']:.1e}", _rms_max(m["all"]), f"{m['all']['within_1m']:.3f}",
            _rms_max(m["near"]), _rms_max(m["far"]), f"{m['far']['within_1m']:.3f}",
            "-" if mahalanobis is None else f"{mahalanobis['median']:.2f} / {mahalanobis['below_5.99']:.3f}"])
    lines += _table(["filter", "landmarks map / batch", "GN iter.", "converged", "chi2 start -> end", "dof",
                     "chi2/dof", "max abs(J'r)", "map-batch RMS / max [m] (n)", "within 1 m", "near RMS / max (n)",
                     "far RMS / max (n)", "far within 1 m", "d'P^-1 d median / share < 5.99"], rows)
    for name, f in report["filters"].items():
        lines.append(f"- {name}: filter's final pose vs batch {f['final_pose_vs_batch_m']:.3f} m; GN step halvings "
                     f"{f['halvings']}; last max abs(dx) {f['last_step']:.1e}; ids not in the map (left out) "
                     f"{f['dropped_measurements']}; solve {f['solve_seconds']:.1f} s; chi2 by iteration "
                     + ", ".join(f"{c:.6g}" for c in f["history"]))
    if "consensus" in report:
        c = report["consensus"]
        lines += ["", f"Consensus batch (only the measurements both filters associate with the same landmark; "
                  "a weak arbiter, see the module docstring): "
                  f"{c['landmarks']} landmarks, {c['iterations']} GN iterations, converged {c['converged']}, "
                  f"chi2/dof {c['chi2']:.6g} / {c['dof']} = {c['chi2_per_dof']:.4f}, max abs(J'r) {c['gradient_max']:.1e}"]
    lines += ["", "2. Share of A's landmarks within r of a landmark of B / of B's within r of A "
              "(dcslam.metrics.map_agreement); near/far: the counted map's own landmarks"]
    rows = [[row["first"], row["second"]] + [f"{row[key][0]:.3f} / {row[key][1]:.3f}"
                                              for key in ("1m", "2m", "1m_near", "1m_far", "2m_near", "2m_far")]
            for row in report["shares"]]
    lines += _table(["A", "B", "1 m", "2 m", "1 m near", "1 m far", "2 m near", "2 m far"], rows)
    if report.get("same_landmark"):
        lines += ["", f"3. Distance between the same landmark in A and B ({report['pairs']} EKF/D&C landmark pairs "
                  "holding the majority of each other's measurements; near/far by the EKF batch position)"]
        rows = [[row["first"], row["second"], _rms_max(row["all"]), f"{row['all']['within_1m']:.3f}",
                 _rms_max(row["near"]), _rms_max(row["far"]), f"{row['far']['within_1m']:.3f}"]
                for row in report["same_landmark"]]
        lines += _table(["A", "B", "RMS / max [m] (n)", "within 1 m", "near RMS / max (n)", "far RMS / max (n)",
                         "far within 1 m"], rows)
        lines += ["", "Measurements by association (EKF, D&C): "
                  + ", ".join(f"{k} {v}" for k, v in report["association_difference"].items())]
    if report.get("gps_rms"):
        lines += ["", "4. Trajectories against the GPS (RMS after rigid alignment; the batch ones are each "
                  "optimum's poses; 'without the disputed measurements': D&C's associations less those the "
                  "EKF gives another landmark)"]
        lines += _table(["trajectory", "RMS [m]"], [[name, "n/a (too few GPS fixes)" if value is None else f"{value:.3f}"]
                                                   for name, value in report["gps_rms"].items()])
    if "seconds" in report:
        lines.append(f"total {report['seconds']:.1f} s")
    return "\n".join(lines)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def landmarks_by_id(estimate) -> Dict[int, np.ndarray]:
    """An :class:`~dcslam.Estimate`'s landmark positions by id (copies)."""
    return {int(i): np.array(p, dtype=float) for i, p in zip(estimate.landmark_ids, estimate.landmarks)}


def run_filter(steps: Sequence, config, name: str, sensor_offset,
               max_iterations: int = 50, tolerance: float = 1e-6, verbose: bool = False) -> Dict:
    """One filter's run and the batch optimum of its associations (initialised from the
    filter's trajectory and final map)."""
    from dcslam.pipeline import SlamPipeline

    result = SlamPipeline(steps, config, filter=name).run()
    estimate = result.estimate
    landmarks = landmarks_by_id(estimate)
    covariance = {int(i): np.array(estimate.covariance[3 + 2 * k:5 + 2 * k, 3 + 2 * k:5 + 2 * k])
                  for k, i in enumerate(estimate.landmark_ids)}
    measurement_ids = [np.asarray(ids, dtype=np.int64) for ids in result.measurement_ids]
    unresolved = unresolved_count(measurement_ids, landmarks)
    if unresolved:
        # resolve() right after estimate() maps every id to the final map (or -1).
        raise RuntimeError(f"{name}: {unresolved} measurement ids are not landmarks of the final map")
    if verbose:
        print(f"{name}: {len(landmarks)} landmarks; batch solve:", file=sys.stderr)
    batch = batch_optimum(steps, measurement_ids, sensor_offset, result.trajectory, landmarks,
                          max_iterations=max_iterations, tolerance=tolerance, verbose=verbose)
    return {"map": landmarks, "covariance": covariance, "batch": batch, "trajectory": result.trajectory,
            "measurement_ids": measurement_ids}


def main(argv: Optional[Sequence[str]] = None) -> Dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="slam_config(seed=...)")
    parser.add_argument("--max-steps", type=int, default=None, help="run only the first N steps")
    parser.add_argument("--local-map-features", type=int, default=None,
                        help="D&C's local map size (default: slam_config()'s)")
    parser.add_argument("--tree-relinearisation", type=int, default=None,
                        help="D&C's SlamConfig.tree_relinearisation (default: slam_config()'s)")
    parser.add_argument("--max-iterations", type=int, default=50)
    parser.add_argument("--tolerance", type=float, default=1e-6, help="stop at max |dx| below this")
    parser.add_argument("--near", type=float, default=150.0, help="'near the start' radius [m] (150)")
    parser.add_argument("--json", dest="json_out", default=None, help="write the numbers here")
    parser.add_argument("--verbose", action="store_true", help="print each Gauss-Newton iteration")
    args = parser.parse_args(argv)

    from dcslam.datasets import victoria_park

    started = time.perf_counter()
    vp = victoria_park()
    steps = vp.steps if args.max_steps is None else vp.steps[:args.max_steps]
    config = vp.slam_config(seed=args.seed)
    if args.local_map_features is not None:
        config = dataclasses.replace(config, local_map_features=args.local_map_features)
    if args.tree_relinearisation is not None:
        config = dataclasses.replace(config, tree_relinearisation=args.tree_relinearisation)
    runs = {name: run_filter(steps, config, name, vp.sensor_offset,
                             max_iterations=args.max_iterations, tolerance=args.tolerance, verbose=args.verbose)
            for name in ("ekf", "dc")}
    pairs = shared_measurement_pairs(runs["ekf"]["measurement_ids"], runs["dc"]["measurement_ids"])
    if args.verbose:
        print("consensus: batch solve:", file=sys.stderr)
    consensus = batch_optimum(steps, consensus_ids(runs["ekf"]["measurement_ids"], runs["dc"]["measurement_ids"], pairs),
                              vp.sensor_offset, runs["ekf"]["trajectory"], runs["ekf"]["map"],
                              max_iterations=args.max_iterations, tolerance=args.tolerance, verbose=args.verbose)
    report = compare(runs, args.near, consensus)
    # The one reference independent of both filters: which associations' optimum lies nearer
    # the GPS, and D&C's without the measurements the two filters dispute.
    undisputed = batch_optimum(steps, undisputed_ids(runs["ekf"]["measurement_ids"], runs["dc"]["measurement_ids"], pairs),
                               vp.sensor_offset, runs["ekf"]["trajectory"], runs["dc"]["map"],
                               max_iterations=args.max_iterations, tolerance=args.tolerance, verbose=args.verbose)
    report["gps_rms"] = {
        "ekf batch": gps_rms(steps, runs["ekf"]["batch"].poses, vp.gps),
        "dc batch": gps_rms(steps, runs["dc"]["batch"].poses, vp.gps),
        "consensus batch": gps_rms(steps, consensus.poses, vp.gps),
        "dc batch without the disputed measurements": gps_rms(steps, undisputed.poses, vp.gps),
        "ekf online trajectory": gps_rms(steps, runs["ekf"]["trajectory"], vp.gps),
        "dc online trajectory": gps_rms(steps, runs["dc"]["trajectory"], vp.gps),
    }
    report.update(seed=args.seed, steps=len(steps), seconds=time.perf_counter() - started)
    print(format_report(report))
    if args.json_out:
        with open(args.json_out, "w") as out:
            json.dump(_jsonable(report), out, indent=1)
    return report


if __name__ == "__main__":
    main()
