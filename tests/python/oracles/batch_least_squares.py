"""The batch least-squares optimum of a SLAM run with given data associations: Gauss-Newton
over every pose and landmark, written from the definition in numpy/scipy, independent of the
filters.

Poses ``x_1..x_N`` and every associated landmark are variables (``x_0`` is the origin, fixed),
with

- odometry residuals ``Q_k^{-1/2} (⊖x_{k-1} ⊕ x_k - u_k)`` (angle wrapped), the same
  model as the filters' ``predict(u_k, Q_k)``: ``x_k = x_{k-1} ⊕ u`` with ``u ~ N(u_k, Q_k)``;
- observation residuals ``R^{-1/2} (z - h(x_k, l_j))`` (bearing wrapped), ``h`` being
  :func:`dcslam.geometry.observe` with the dataset's sensor offset; step ``k``'s ``z`` is
  taken at the pose right after step ``k``'s predict.

It is what a filter would give if its linearisations were exact, so a filter's map far from
the optimum of its own associations is off for the filter's reasons. The Jacobians are the
analytic ones of :mod:`dcslam.geometry`, checked against central differences by
:func:`check_jacobians`. ``studies/vp_batch_reference.py`` and
``studies/vp_join_linearisation.py`` measure Victoria Park's maps against it.
"""

import dataclasses
import sys
import time
from typing import Dict, List, Sequence

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dcslam import geometry

MODEL = "range_bearing"


# ---------------------------------------------------------------------------------------
# Residuals and their Jacobians
# ---------------------------------------------------------------------------------------

def odometry_residual(previous, current, u, jacobians: bool = False):
    """Unwhitened ``⊖previous ⊕ current - u`` with the angle wrapped.

    With ``jacobians=True`` also returns d/d previous (3x3) and d/d current (3x3): the chain
    rule through :func:`dcslam.geometry.invert` and :func:`dcslam.geometry.compose`.
    """
    inverse, J_inverse = geometry.invert(previous, jacobians=True)
    relative, J_a, J_b = geometry.compose(inverse, current, jacobians=True)
    error = np.asarray(relative, dtype=float) - np.asarray(u, dtype=float)
    error[2] = geometry.wrap_angle(error[2])
    if not jacobians:
        return error
    return error, J_a @ J_inverse, J_b


def observation_residual(sensor_offset, robot, landmark, z, jacobians: bool = False):
    """Unwhitened ``z - h(robot, landmark)`` with the bearing wrapped.

    With ``jacobians=True`` also returns d/d robot (2x3) and d/d landmark (2x2) of the
    residual (the negated Jacobians of :func:`dcslam.geometry.observe`).
    """
    z_hat, H_robot, H_landmark = geometry.observe(MODEL, sensor_offset, robot, landmark, jacobians=True)
    error = geometry.innovation(MODEL, z, z_hat)
    if not jacobians:
        return error
    return error, -np.asarray(H_robot), -np.asarray(H_landmark)


def _numeric_jacobian(function, point, index, eps):
    """Central differences of ``function(*point)`` with respect to argument ``index``;
    angle-like outputs are differenced with wrapping so that a wrap does not show up."""
    base = [np.array(p, dtype=float) for p in point]
    columns = []
    for i in range(len(base[index])):
        plus = [p.copy() for p in base]
        minus = [p.copy() for p in base]
        plus[index][i] += eps
        minus[index][i] -= eps
        difference = np.asarray(function(*plus), float) - np.asarray(function(*minus), float)
        difference = np.array([geometry.wrap_angle(d) if abs(d) > np.pi else d for d in difference])
        columns.append(difference / (2 * eps))
    return np.column_stack(columns)


def check_jacobians(sensor_offset=(3.78, 0.5, 0.0), trials: int = 20, seed: int = 0, eps: float = 1e-6) -> float:
    """Largest absolute difference between the analytic residual Jacobians and central
    differences, over ``trials`` random odometry and observation factors."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(trials):
        previous = np.array([*rng.uniform(-50, 50, 2), rng.uniform(-np.pi, np.pi)])
        current = np.array([*rng.uniform(-50, 50, 2), rng.uniform(-np.pi, np.pi)])
        u = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-0.3, 0.3)])
        _, J_previous, J_current = odometry_residual(previous, current, u, jacobians=True)
        for index, analytic in ((0, J_previous), (1, J_current)):
            numeric = _numeric_jacobian(lambda a, b: odometry_residual(a, b, u), (previous, current), index, eps)
            worst = max(worst, float(np.max(np.abs(numeric - analytic))))
        robot = np.array([*rng.uniform(-50, 50, 2), rng.uniform(-np.pi, np.pi)])
        landmark = robot[:2] + rng.uniform(5, 25) * np.array([np.cos(a := rng.uniform(-np.pi, np.pi)), np.sin(a)])
        z = np.array([rng.uniform(3, 30), rng.uniform(-np.pi, np.pi)])
        _, J_robot, J_landmark = observation_residual(sensor_offset, robot, landmark, z, jacobians=True)
        for index, analytic in ((0, J_robot), (1, J_landmark)):
            numeric = _numeric_jacobian(lambda r, l: observation_residual(sensor_offset, r, l, z),
                                        (robot, landmark), index, eps)
            worst = max(worst, float(np.max(np.abs(numeric - analytic))))
    return worst


def _whitener(covariance, what: str) -> np.ndarray:
    """W with W' W = covariance^{-1} (inverse of the lower Cholesky factor)."""
    covariance = np.asarray(covariance, dtype=float)
    try:
        lower = np.linalg.cholesky(0.5 * (covariance + covariance.T))
    except np.linalg.LinAlgError as error:
        raise ValueError(f"batch_optimum: {what} is not positive definite") from error
    return np.linalg.inv(lower)


# ---------------------------------------------------------------------------------------
# The full SLAM problem
# ---------------------------------------------------------------------------------------

@dataclasses.dataclass
class SlamProblem:
    """Factors of the full SLAM problem defined by one set of associations.

    Poses are numbered 0..N (pose k+1 is the pose of step k's measurements; pose 0 is the
    origin). ``pose_column[k]`` is the first column of pose k in the state vector, -1 for a
    fixed pose (pose 0, and poses reached from a fixed pose by an exactly known motion,
    ``Q = 0``, such as Victoria Park's first step). Landmarks follow the poses.
    """

    sensor_offset: np.ndarray
    fixed_poses: Dict[int, np.ndarray]
    pose_column: np.ndarray                # (N+1,)
    landmark_ids: np.ndarray               # (L,) in column order
    landmark_column: np.ndarray            # (L,)
    odometry_pose: np.ndarray              # (F_o,) pose k of factor (previous is k-1)
    odometry_u: np.ndarray                 # (F_o, 3)
    odometry_whitener: np.ndarray          # (F_o, 3, 3)
    observation_pose: np.ndarray           # (F_z,)
    observation_landmark: np.ndarray       # (F_z,) index into landmark_ids
    observation_z: np.ndarray              # (F_z, 2)
    observation_whitener: np.ndarray       # (F_z, 2, 2)
    dimension: int
    dropped_measurements: int              # id >= 0 but not among the given landmarks

    @property
    def residual_count(self) -> int:
        return 3 * len(self.odometry_pose) + 2 * len(self.observation_pose)

    @property
    def degrees_of_freedom(self) -> int:
        return self.residual_count - self.dimension


def build_problem(steps: Sequence, measurement_ids: Sequence, sensor_offset, landmark_ids) -> SlamProblem:
    """The factors of ``steps`` with the associations ``measurement_ids`` (per step, (m,)
    ids; < 0 or not in ``landmark_ids``: the measurement is left out)."""
    if len(measurement_ids) != len(steps):
        raise ValueError(f"build_problem: {len(measurement_ids)} id arrays for {len(steps)} steps")
    known = {int(i) for i in landmark_ids}
    count = len(steps)
    pose_column = np.full(count + 1, -1, dtype=np.int64)
    fixed_poses = {0: np.zeros(3)}
    column = 0
    odometry_pose, odometry_u, odometry_whitener = [], [], []
    for k, step in enumerate(steps):
        pose = k + 1
        Q = np.asarray(step.Q, dtype=float)
        if (k in fixed_poses) and not np.any(Q):
            fixed_poses[pose] = geometry.compose(fixed_poses[k], step.u)
            continue
        pose_column[pose] = column
        column += 3
        odometry_pose.append(pose)
        odometry_u.append(np.asarray(step.u, dtype=float))
        odometry_whitener.append(_whitener(Q, f"Q of step {k}"))
    used = sorted({int(i) for ids in measurement_ids for i in np.asarray(ids) if int(i) >= 0 and int(i) in known})
    slot = {landmark: n for n, landmark in enumerate(used)}
    landmark_column = column + 2 * np.arange(len(used), dtype=np.int64)
    column += 2 * len(used)
    observation_pose, observation_landmark, observation_z, observation_whitener = [], [], [], []
    dropped = 0
    for k, (step, ids) in enumerate(zip(steps, measurement_ids)):
        ids = np.asarray(ids)
        if len(ids) != len(step.z):
            raise ValueError(f"build_problem: step {k} has {len(step.z)} measurements and {len(ids)} ids")
        for z, R, landmark in zip(np.asarray(step.z), np.asarray(step.R), ids):
            landmark = int(landmark)
            if landmark < 0:
                continue
            if landmark not in slot:
                dropped += 1
                continue
            observation_pose.append(k + 1)
            observation_landmark.append(slot[landmark])
            observation_z.append(np.asarray(z, dtype=float))
            observation_whitener.append(_whitener(R, f"R of a measurement of step {k}"))
    return SlamProblem(
        sensor_offset=np.asarray(sensor_offset, dtype=float),
        fixed_poses=fixed_poses,
        pose_column=pose_column,
        landmark_ids=np.array(used, dtype=np.int64),
        landmark_column=landmark_column,
        odometry_pose=np.array(odometry_pose, dtype=np.int64),
        odometry_u=np.array(odometry_u).reshape(-1, 3),
        odometry_whitener=np.array(odometry_whitener).reshape(-1, 3, 3),
        observation_pose=np.array(observation_pose, dtype=np.int64),
        observation_landmark=np.array(observation_landmark, dtype=np.int64),
        observation_z=np.array(observation_z).reshape(-1, 2),
        observation_whitener=np.array(observation_whitener).reshape(-1, 2, 2),
        dimension=column,
        dropped_measurements=dropped,
    )


def _pose(problem: SlamProblem, state: np.ndarray, k: int) -> np.ndarray:
    column = problem.pose_column[k]
    return problem.fixed_poses[k] if column < 0 else state[column:column + 3]


def linearize(problem: SlamProblem, state: np.ndarray, jacobian: bool = True):
    """Whitened residuals (and their sparse Jacobian, CSR) at ``state``."""
    residuals = np.empty(problem.residual_count)
    rows: List[np.ndarray] = []
    cols: List[np.ndarray] = []
    vals: List[np.ndarray] = []
    row = 0
    for pose, u, W in zip(problem.odometry_pose, problem.odometry_u, problem.odometry_whitener):
        previous, current = _pose(problem, state, pose - 1), _pose(problem, state, pose)
        if jacobian:
            error, J_previous, J_current = odometry_residual(previous, current, u, jacobians=True)
            for k, J in ((pose - 1, J_previous), (pose, J_current)):
                column = problem.pose_column[k]
                if column >= 0:
                    rows.append(np.repeat(np.arange(row, row + 3), 3))
                    cols.append(np.tile(np.arange(column, column + 3), 3))
                    vals.append((W @ J).ravel())
        else:
            error = odometry_residual(previous, current, u)
        residuals[row:row + 3] = W @ error
        row += 3
    for pose, landmark, z, W in zip(problem.observation_pose, problem.observation_landmark,
                                    problem.observation_z, problem.observation_whitener):
        robot = _pose(problem, state, pose)
        landmark_column = problem.landmark_column[landmark]
        position = state[landmark_column:landmark_column + 2]
        if jacobian:
            error, J_robot, J_landmark = observation_residual(problem.sensor_offset, robot, position, z,
                                                              jacobians=True)
            column = problem.pose_column[pose]
            if column >= 0:
                rows.append(np.repeat(np.arange(row, row + 2), 3))
                cols.append(np.tile(np.arange(column, column + 3), 2))
                vals.append((W @ J_robot).ravel())
            rows.append(np.repeat(np.arange(row, row + 2), 2))
            cols.append(np.tile(np.arange(landmark_column, landmark_column + 2), 2))
            vals.append((W @ J_landmark).ravel())
        else:
            error = observation_residual(problem.sensor_offset, robot, position, z)
        residuals[row:row + 2] = W @ error
        row += 2
    if not jacobian:
        return residuals
    J = scipy.sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(problem.residual_count, problem.dimension))
    return residuals, J


def initial_state(problem: SlamProblem, initial_poses, initial_landmarks: Dict[int, np.ndarray]) -> np.ndarray:
    """State vector from (N, 3) poses (``initial_poses[k]`` = pose k+1) and landmark
    positions by id."""
    initial_poses = np.asarray(initial_poses, dtype=float).reshape(-1, 3)
    if len(initial_poses) != len(problem.pose_column) - 1:
        raise ValueError(f"batch_optimum: {len(initial_poses)} initial poses for "
                         f"{len(problem.pose_column) - 1} steps")
    state = np.empty(problem.dimension)
    for k in range(1, len(problem.pose_column)):
        column = problem.pose_column[k]
        if column >= 0:
            state[column:column + 3] = initial_poses[k - 1]
    for landmark, column in zip(problem.landmark_ids, problem.landmark_column):
        state[column:column + 2] = np.asarray(initial_landmarks[int(landmark)], dtype=float)
    return state


def _retract(problem: SlamProblem, state: np.ndarray, step: np.ndarray) -> np.ndarray:
    updated = state + step
    angles = problem.pose_column[problem.pose_column >= 0] + 2
    updated[angles] = np.arctan2(np.sin(updated[angles]), np.cos(updated[angles]))
    return updated


@dataclasses.dataclass
class BatchResult:
    """Gauss-Newton's answer.

    Attributes:
        poses: (N, 3) pose k+1 (the pose of step k's measurements) for k = 0..N-1.
        landmarks: positions by id (the landmarks the associations use).
        iterations: Gauss-Newton steps taken; converged: the last step's max |dx| fell
            below the tolerance.
        chi2_initial, chi2: sum of squared whitened residuals at the start and the end.
        degrees_of_freedom: residuals - variables.
        gradient_norm: max |J' r| at the end (0 at an exact optimum).
        halvings: step halvings the safeguard needed (0: plain Gauss-Newton throughout).
        history: chi2 after each iteration.
        seconds: wall time of the solve.
    """

    poses: np.ndarray
    landmarks: Dict[int, np.ndarray]
    iterations: int
    converged: bool
    chi2_initial: float
    chi2: float
    degrees_of_freedom: int
    residual_count: int
    dimension: int
    gradient_norm: float
    last_step: float
    halvings: int
    history: List[float]
    dropped_measurements: int
    seconds: float

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / self.degrees_of_freedom if self.degrees_of_freedom > 0 else float("nan")


def _solve_normal_equations(J, residuals):
    H = (J.T @ J).tocsc()
    gradient = J.T @ residuals
    factor = scipy.sparse.linalg.splu(H, permc_spec="MMD_AT_PLUS_A")
    return factor.solve(-gradient), gradient


def batch_optimum(steps: Sequence, measurement_ids: Sequence, sensor_offset, initial_poses,
                  initial_landmarks: Dict[int, np.ndarray], max_iterations: int = 50,
                  tolerance: float = 1e-6, verbose: bool = False) -> BatchResult:
    """Gauss-Newton on the full SLAM problem of ``steps`` with the associations
    ``measurement_ids`` (see the module docstring for the model).

    Args:
        steps: the dataset's steps (``u, Q, z, R``).
        measurement_ids: per step, (m,) landmark ids (< 0: not used).
        sensor_offset: the laser's pose on the robot.
        initial_poses: (N, 3), ``initial_poses[k]`` the pose of step k's measurements (a
            filter's ``trajectory``).
        initial_landmarks: id -> (2,) starting positions; measurements whose id is missing
            here are left out (counted in ``dropped_measurements``).
        max_iterations: Gauss-Newton steps at most.
        tolerance: converged when the step's largest component is below this.

    Each step solves the sparse normal equations ``J'J dx = -J'r`` (SuperLU, minimum
    degree ordering on J'J). A step that raises chi2 is halved until it does not (at most
    20 times); plain Gauss-Newton never needs that near the optimum.
    """
    started = time.perf_counter()
    problem = build_problem(steps, measurement_ids, sensor_offset, list(initial_landmarks))
    state = initial_state(problem, initial_poses, initial_landmarks)
    residuals, J = linearize(problem, state)
    chi2 = chi2_initial = float(residuals @ residuals)
    history: List[float] = []
    converged = False
    halvings = 0
    last_step = float("inf")
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        step, _ = _solve_normal_equations(J, residuals)
        scale = 1.0
        for _ in range(21):
            candidate = _retract(problem, state, scale * step)
            candidate_residuals = linearize(problem, candidate, jacobian=False)
            candidate_chi2 = float(candidate_residuals @ candidate_residuals)
            if candidate_chi2 <= chi2 * (1 + 1e-12) or scale < 1e-5:
                break
            scale *= 0.5
            halvings += 1
        state, chi2 = candidate, candidate_chi2
        last_step = float(np.max(np.abs(scale * step))) if len(step) else 0.0
        history.append(chi2)
        if verbose:
            print(f"  iteration {iterations}: chi2 {chi2:.6g}, max |dx| {last_step:.3g}, scale {scale:g}",
                  file=sys.stderr)
        residuals, J = linearize(problem, state)
        if last_step < tolerance:
            converged = True
            break
    gradient = J.T @ residuals
    poses = np.array([_pose(problem, state, k) for k in range(1, len(problem.pose_column))]).reshape(-1, 3)
    landmarks = {int(i): state[c:c + 2].copy() for i, c in zip(problem.landmark_ids, problem.landmark_column)}
    return BatchResult(
        poses=poses, landmarks=landmarks, iterations=iterations, converged=converged,
        chi2_initial=chi2_initial, chi2=float(residuals @ residuals),
        degrees_of_freedom=problem.degrees_of_freedom, residual_count=problem.residual_count,
        dimension=problem.dimension, gradient_norm=float(np.max(np.abs(gradient))) if len(gradient) else 0.0,
        last_step=last_step, halvings=halvings, history=history,
        dropped_measurements=problem.dropped_measurements, seconds=time.perf_counter() - started)
