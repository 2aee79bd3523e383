"""GTSAM iSAM2 against dcslam (D&C and EKF) on one iSAM-format 2D file (Victoria Park).

Both sides get the same inputs: the steps of :func:`dcslam.datasets.read_isam2d` (odometry
with the file's covariance read as GTSAM reads it, Cartesian landmark points in the robot
frame with their 2x2 covariance, the file's landmark ids as known association). GTSAM's
landmark factor is the same Cartesian point model as dcslam's ``observation="point"``,
``z = R(theta)^T (l - t)``, written as a ``gtsam.CustomFactor`` with analytic Jacobians;
GTSAM's own ``load2D`` would instead turn these lines into bearing/range factors, a different
model. The reference is the batch optimum (Levenberg-Marquardt started at iSAM2's answer).

Usage:
    python benchmarks/gtsam_compare.py [--file PATH] [--max-steps N] [--json OUT] [--markdown]

The default file is the repository's copy of GTSAM's Victoria Park example,
``tests/data/isam_victoria_park.txt.gz``; ``--file`` takes any other iSAM/GTSAM 2D file.

Needs GTSAM: ``pip install dcslam[gtsam]`` (or ``pip install gtsam``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import json
import math
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
from rich.console import Console
from rich.table import Table

import dcslam
from dcslam.datasets import read_isam2d

try:
    import gtsam
except ImportError:
    gtsam = None

DEFAULT_FILE = Path(__file__).resolve().parent.parent / "tests" / "data" / "isam_victoria_park.txt.gz"

# Pose 0 is the frame everything is reported in; dcslam starts there with zero covariance.
PRIOR_SIGMAS = np.array([1e-6, 1e-6, 1e-8])


def pose_key(pose_id: int) -> int:
    return gtsam.symbol("x", pose_id)


def landmark_key(landmark_id: int) -> int:
    return gtsam.symbol("l", landmark_id)


class PointObservationFactors:
    """Builds GTSAM factors for dcslam's Cartesian point observation and counts their cost.

    The measurement is the landmark in the robot frame, ``h(x, l) = R(theta)^T (l - t)``.
    Jacobians are with respect to GTSAM's Pose2 tangent (body-frame increments): for
    ``d = h(x, l)``, ``dh/dx = [[-1, 0, d_y], [0, -1, -d_x]]`` and ``dh/dl = R(theta)^T``.
    The factors call back into Python, so the time spent there is tracked to tell how much
    of iSAM2's wall time is this wrapper rather than GTSAM itself.
    """

    def __init__(self):
        self.evaluations = 0
        self.seconds = 0.0

    def make(self, pose_id: int, landmark_id: int, z: np.ndarray, R: np.ndarray) -> "gtsam.CustomFactor":
        measured = np.array(z, dtype=float)
        noise = gtsam.noiseModel.Gaussian.Covariance(np.array(R, dtype=float))

        def error(factor, values, jacobians):
            started = time.perf_counter()
            pose = values.atPose2(factor.keys()[0])
            landmark = values.atPoint2(factor.keys()[1])
            c, s = math.cos(pose.theta()), math.sin(pose.theta())
            dx, dy = landmark[0] - pose.x(), landmark[1] - pose.y()
            in_robot = np.array([c * dx + s * dy, -s * dx + c * dy])
            if jacobians is not None:
                jacobians[0] = np.array([[-1.0, 0.0, in_robot[1]], [0.0, -1.0, -in_robot[0]]])
                jacobians[1] = np.array([[c, s], [-s, c]])
            self.evaluations += 1
            self.seconds += time.perf_counter() - started
            return in_robot - measured

        return gtsam.CustomFactor(noise, gtsam.KeyVector([pose_key(pose_id), landmark_key(landmark_id)]), error)


def run_isam2(steps: Sequence) -> Dict:
    """iSAM2, one update per step with that step's new factors and initial guesses.

    A new pose starts at iSAM2's current estimate of the previous pose composed with the
    odometry; a new landmark starts at its first observation seen from that guess.
    """
    observations = PointObservationFactors()
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    graph = gtsam.NonlinearFactorGraph()
    known_landmarks = set()

    started = time.perf_counter()
    first = gtsam.NonlinearFactorGraph()
    first.add(gtsam.PriorFactorPose2(pose_key(0), gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(PRIOR_SIGMAS)))
    first_values = gtsam.Values()
    first_values.insert(pose_key(0), gtsam.Pose2())
    isam.update(first, first_values)
    graph.push_back(first)
    previous_pose_id, previous_pose = 0, gtsam.Pose2()
    for step in steps:
        new_factors = gtsam.NonlinearFactorGraph()
        new_values = gtsam.Values()
        pose_id = step.pose_id
        if pose_id != previous_pose_id:
            odometry = gtsam.Pose2(*step.u)
            new_factors.add(gtsam.BetweenFactorPose2(pose_key(previous_pose_id), pose_key(pose_id), odometry,
                                                     gtsam.noiseModel.Gaussian.Covariance(np.array(step.Q))))
            pose = previous_pose.compose(odometry)
            new_values.insert(pose_key(pose_id), pose)
        else:  # landmarks seen from pose 0 before any motion
            pose = previous_pose
        for landmark_id, z, R in zip(step.landmark_ids, step.z, step.R):
            landmark_id = int(landmark_id)
            new_factors.add(observations.make(pose_id, landmark_id, z, R))
            if landmark_id not in known_landmarks:
                known_landmarks.add(landmark_id)
                new_values.insert(landmark_key(landmark_id), pose.transformFrom(gtsam.Point2(*z)))
        isam.update(new_factors, new_values)
        graph.push_back(new_factors)
        previous_pose_id, previous_pose = pose_id, isam.calculateEstimatePose2(pose_key(pose_id))
    update_seconds = time.perf_counter() - started

    started = time.perf_counter()
    estimate = isam.calculateEstimate()
    estimate_seconds = time.perf_counter() - started
    return dict(graph=graph, estimate=estimate, final_pose_id=previous_pose_id,
                landmark_ids=np.array(sorted(known_landmarks), dtype=np.int64),
                update_seconds=update_seconds, estimate_seconds=estimate_seconds,
                callback_evaluations=observations.evaluations, callback_seconds=observations.seconds)


def batch_optimum(graph, initial) -> Dict:
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    params.setMaxIterations(100)
    started = time.perf_counter()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize()
    return dict(estimate=result, seconds=time.perf_counter() - started, iterations=optimizer.iterations(),
                error_initial=graph.error(initial), error_final=graph.error(result))


def landmark_marginals_seconds(graph, estimate, landmark_ids: np.ndarray) -> float:
    """Time for GTSAM to produce the joint covariance of all landmarks (what dcslam's
    ``estimate()`` returns anyway)."""
    started = time.perf_counter()
    marginals = gtsam.Marginals(graph, estimate)
    marginals.jointMarginalCovariance(gtsam.KeyVector([landmark_key(int(i)) for i in landmark_ids]))
    return time.perf_counter() - started


def run_dcslam(filter_class, steps: Sequence, cfg) -> Dict:
    slam = filter_class(cfg)
    started = time.perf_counter()
    slam.run(steps)
    update_seconds = time.perf_counter() - started
    started = time.perf_counter()
    estimate = slam.estimate()
    estimate_seconds = time.perf_counter() - started
    return dict(estimate=estimate, update_seconds=update_seconds, estimate_seconds=estimate_seconds)


def gtsam_solution(estimate, landmark_ids: np.ndarray, final_pose_id: int) -> Dict:
    pose = estimate.atPose2(pose_key(final_pose_id))
    landmarks = np.array([estimate.atPoint2(landmark_key(int(i))) for i in landmark_ids]).reshape(-1, 2)
    return dict(robot=np.array([pose.x(), pose.y(), pose.theta()]), landmarks=landmarks)


def dcslam_solution(estimate: "dcslam.Estimate", landmark_ids: np.ndarray) -> Dict:
    row_of = {int(i): row for row, i in enumerate(estimate.landmark_ids)}
    missing = [int(i) for i in landmark_ids if int(i) not in row_of]
    if missing:
        raise RuntimeError(f"dcslam's map lacks landmark ids {missing[:10]}")
    rows = [row_of[int(i)] for i in landmark_ids]
    return dict(robot=np.asarray(estimate.robot), landmarks=np.asarray(estimate.landmarks)[rows])


def difference(solution: Dict, reference: Dict) -> Dict:
    landmark_errors = np.linalg.norm(solution["landmarks"] - reference["landmarks"], axis=1)
    heading = solution["robot"][2] - reference["robot"][2]
    return dict(
        landmark_rms_m=float(np.sqrt(np.mean(landmark_errors ** 2))) if len(landmark_errors) else 0.0,
        landmark_max_m=float(landmark_errors.max()) if len(landmark_errors) else 0.0,
        final_position_m=float(np.linalg.norm(solution["robot"][:2] - reference["robot"][:2])),
        final_heading_rad=float(abs(math.atan2(math.sin(heading), math.cos(heading)))),
    )


def compare(path: Path, max_steps: Optional[int] = None, marginals: bool = True,
            tree_passes: Sequence[int] = ()) -> Dict:
    dataset = read_isam2d(path)
    steps = dataset.steps[:max_steps] if max_steps is not None else dataset.steps[:]
    cfg = dataset.slam_config()

    isam2 = run_isam2(steps)
    batch = batch_optimum(isam2["graph"], isam2["estimate"])
    dc = run_dcslam(dcslam.DCSlam, steps, cfg)
    ekf = run_dcslam(dcslam.EkfSlam, steps, cfg)

    landmark_ids, final_pose_id = isam2["landmark_ids"], isam2["final_pose_id"]
    reference = gtsam_solution(batch["estimate"], landmark_ids, final_pose_id)
    solutions = {
        "isam2": gtsam_solution(isam2["estimate"], landmark_ids, final_pose_id),
        "dcslam_dc": dcslam_solution(dc["estimate"], landmark_ids),
        "dcslam_ekf": dcslam_solution(ekf["estimate"], landmark_ids),
    }
    timings = {
        "isam2": (isam2["update_seconds"], isam2["estimate_seconds"]),
        "dcslam_dc": (dc["update_seconds"], dc["estimate_seconds"]),
        "dcslam_ekf": (ekf["update_seconds"], ekf["estimate_seconds"]),
    }
    # D&C with other SlamConfig.tree_relinearisation pass counts (the default's row is dcslam_dc).
    for passes in tree_passes:
        name = f"dcslam_dc_tree{passes}"
        run = run_dcslam(dcslam.DCSlam, steps, dataclasses.replace(cfg, tree_relinearisation=passes))
        solutions[name] = dcslam_solution(run["estimate"], landmark_ids)
        timings[name] = (run["update_seconds"], run["estimate_seconds"])
    methods = {}
    for name, solution in solutions.items():
        update_seconds, estimate_seconds = timings[name]
        methods[name] = dict(update_seconds=update_seconds, estimate_seconds=estimate_seconds,
                             total_seconds=update_seconds + estimate_seconds,
                             vs_batch=difference(solution, reference))
    dc_total, isam2_total = methods["dcslam_dc"]["total_seconds"], methods["isam2"]["total_seconds"]
    return dict(
        file=str(path), steps=len(steps), poses=final_pose_id + 1 if steps else 1,
        landmarks=int(len(landmark_ids)), measurements=int(sum(len(s.z) for s in steps)),
        gtsam_version=importlib.metadata.version("gtsam"), dcslam_version=dcslam.__version__,
        local_map_features=cfg.local_map_features,
        methods=methods,
        dc_over_isam2_time=dc_total / isam2_total,
        dc_vs_isam2=difference(solutions["dcslam_dc"], solutions["isam2"]),
        dc_vs_ekf=difference(solutions["dcslam_dc"], solutions["dcslam_ekf"]),
        isam2_callback=dict(evaluations=isam2["callback_evaluations"], seconds=isam2["callback_seconds"]),
        batch=dict(seconds=batch["seconds"], iterations=batch["iterations"],
                   error_from_isam2=batch["error_initial"], error=batch["error_final"]),
        isam2_landmark_marginals_seconds=(
            landmark_marginals_seconds(isam2["graph"], isam2["estimate"], landmark_ids) if marginals else None),
    )


METHOD_LABELS = {"isam2": "GTSAM iSAM2", "dcslam_dc": "dcslam D&C", "dcslam_ekf": "dcslam EKF"}
TABLE_HEADER = ["method", "updates (s)", "estimate (s)", "total (s)", "lm RMS (m)", "lm max (m)",
                "pose (m)", "heading (rad)"]


def table_rows(report: Dict) -> List[List[str]]:
    rows = []
    for name, method in report["methods"].items():
        d = method["vs_batch"]
        label = METHOD_LABELS.get(name, name.replace("dcslam_dc_tree", "dcslam D&C, tree_relinearisation="))
        rows.append([label, f"{method['update_seconds']:.4f}", f"{method['estimate_seconds']:.4f}",
                     f"{method['total_seconds']:.4f}", f"{d['landmark_rms_m']:.3g}", f"{d['landmark_max_m']:.3g}",
                     f"{d['final_position_m']:.3g}", f"{d['final_heading_rad']:.3g}"])
    return rows


def print_report(report: Dict, markdown: bool = False) -> None:
    title = (f"{Path(report['file']).name}: {report['steps']} steps, {report['poses']} poses, "
             f"{report['landmarks']} landmarks, {report['measurements']} measurements "
             f"(gtsam {report['gtsam_version']}, dcslam {report['dcslam_version']}, "
             f"local maps of {report['local_map_features']} features)")
    caption = "lm RMS/max, pose, heading: difference from the batch optimum (frame of pose 0, final pose)"
    if markdown:
        print(title + "\n")
        print("| " + " | ".join(TABLE_HEADER) + " |")
        print("|" + "|".join("---" for _ in TABLE_HEADER) + "|")
        for row in table_rows(report):
            print("| " + " | ".join(row) + " |")
        print("\n" + caption + "\n")
    else:
        table = Table(title=title, caption=caption)
        for column in TABLE_HEADER:
            table.add_column(column, justify="left" if column == "method" else "right")
        for row in table_rows(report):
            table.add_row(*row)
        Console(width=max(Console().width, 110)).print(table)

    callback = report["isam2_callback"]
    batch = report["batch"]
    dc_isam2, dc_ekf = report["dc_vs_isam2"], report["dc_vs_ekf"]
    notes = [
        f"time ratio dcslam D&C / iSAM2: {report['dc_over_isam2_time']:.3g}",
        f"dcslam D&C vs iSAM2: landmark RMS {dc_isam2['landmark_rms_m']:.3g} m, final position "
        f"{dc_isam2['final_position_m']:.3g} m; D&C vs EKF: landmark RMS {dc_ekf['landmark_rms_m']:.3g} m",
        f"batch reference: Levenberg-Marquardt from iSAM2's estimate, {batch['iterations']} iterations, "
        f"{batch['seconds']:.3f} s, graph error {batch['error_from_isam2']:.6g} -> {batch['error']:.6g}",
        f"iSAM2's time includes {callback['evaluations']} Python evaluations of the point factor "
        f"({callback['seconds']:.3f} s measured inside them, plus call overhead)",
        "dcslam's estimate() includes the full covariance (robot and all landmarks); iSAM2's "
        "calculateEstimate() is the mean only.",
    ]
    if report["isam2_landmark_marginals_seconds"] is not None:
        notes.append(f"GTSAM joint marginal covariance of all landmarks (gtsam.Marginals): "
                     f"{report['isam2_landmark_marginals_seconds']:.3f} s extra")
    for note in notes:
        print(f"- {note}" if markdown else note)


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--file", type=Path, default=DEFAULT_FILE,
                        help="iSAM/GTSAM 2D file, plain or gzip (default: tests/data/isam_victoria_park.txt.gz)")
    parser.add_argument("--max-steps", type=int, default=None, help="use only the first N steps")
    parser.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    parser.add_argument("--no-marginals", action="store_true", help="skip timing GTSAM's landmark marginals")
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    parser.add_argument("--tree-relinearisation", default="",
                        help="also run D&C with these SlamConfig.tree_relinearisation counts, e.g. 0,20")
    args = parser.parse_args(argv)
    if not args.file.is_file():
        print(f"gtsam_compare: no such file: {args.file} (pass an iSAM/GTSAM 2D file with --file)",
              file=sys.stderr)
        return 2
    if gtsam is None:
        print("gtsam_compare: GTSAM is not installed; install it with 'pip install dcslam[gtsam]' "
              "(or 'pip install gtsam').", file=sys.stderr)
        return 2
    if args.max_steps is not None and args.max_steps < 1:
        parser.error("--max-steps must be at least 1")
    tree_passes = [int(p) for p in args.tree_relinearisation.split(",") if p]
    report = compare(args.file, args.max_steps, marginals=not args.no_marginals, tree_passes=tree_passes)
    print_report(report, markdown=args.markdown)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
