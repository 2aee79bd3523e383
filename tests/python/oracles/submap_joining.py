"""The least-squares optimum of "local maps as measurements of the global map" (the
submap-joining problem of Huang, Wang and Dissanayake's I-SLSJF and of Zhao et al.'s Linear
SLAM), solved by dense Gauss-Newton in numpy, independent of the filters.

Local map ``k`` (0-based, in the order they were closed) has its base at the global pose
``B_k`` (``B_0`` is the origin, fixed) and its robot at ``B_{k+1}``; the open local map, last,
has its robot at the final pose ``R``. Its mean ``z_k`` and covariance ``P_k`` measure

    h_k(X) = [ ⊖B_k ⊕ B_{k+1} ;  ⊖B_k ⊕ F_i  for each of its features i ]

(headings wrapped), and every feature of the same id in different local maps is one global
``F_i``. The optimum minimises ``sum_k (z_k - h_k(X))' P_k^-1 (z_k - h_k(X))``; its
covariance is the inverse of the Gauss-Newton information there. The Jacobians are central
differences of the residual, so nothing here shares code with the library.
"""

import dataclasses
from typing import Dict, List, Sequence

import numpy as np


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def _rotation(phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


def _between(a, b):
    """b seen from a: ⊖a ⊕ b."""
    d = _rotation(a[2]).T @ (b[:2] - a[:2])
    return np.array([d[0], d[1], wrap(b[2] - a[2])])


@dataclasses.dataclass
class LocalMap:
    """One local map: mean ``x`` = [robot (3); features (2 each)] in its base frame, its
    covariance ``P`` and the global id of each feature."""

    x: np.ndarray
    P: np.ndarray
    feature_ids: Sequence[int]


@dataclasses.dataclass
class SubmapSolution:
    boundaries: np.ndarray  # (L, 3): B_1 .. B_L (L = closed local maps)
    robot: np.ndarray       # (3,)
    features: Dict[int, np.ndarray]
    covariance: np.ndarray  # over [robot; features in `feature_order`]
    feature_order: List[int]
    iterations: int


def solve(local_maps: Sequence[LocalMap], initial_features: Dict[int, np.ndarray],
          initial_poses: np.ndarray, initial_robot: np.ndarray, tolerance: float = 1e-9,
          max_iterations: int = 30) -> SubmapSolution:
    """Gauss-Newton from the given start (``initial_poses``: B_1..B_L; the last local map is
    the open one, so there are ``len(local_maps) - 1`` boundaries)."""
    boundaries = len(local_maps) - 1
    feature_order = sorted({int(i) for m in local_maps for i in m.feature_ids})
    column = {fid: 3 * boundaries + 3 + 2 * k for k, fid in enumerate(feature_order)}
    dim = 3 * boundaries + 3 + 2 * len(feature_order)
    state = np.zeros(dim)
    state[:3 * boundaries] = np.asarray(initial_poses, dtype=float).reshape(-1)
    state[3 * boundaries:3 * boundaries + 3] = initial_robot
    for fid in feature_order:
        state[column[fid]:column[fid] + 2] = initial_features[fid]

    def pose_columns(k):  # B_k for k >= 1, and the final robot for k = boundaries + 1
        return list(range(3 * (k - 1), 3 * k))

    whitening = [np.linalg.cholesky(np.linalg.inv(m.P)).T for m in local_maps]

    feature_columns = [np.array([[column[int(fid)], column[int(fid)] + 1] for fid in m.feature_ids], dtype=int).reshape(-1, 2)
                       for m in local_maps]

    def local_error(k, base, robot, features):
        """z_k - h_k (unwhitened, heading wrapped) for given base, robot and (n_k, 2) features."""
        in_base = (features - base[:2]) @ _rotation(base[2])  # rows: Rot(base)' (f - t)
        error = local_maps[k].x - np.concatenate([_between(base, robot), in_base.reshape(-1)])
        error[2] = wrap(error[2])
        return error

    def central_difference(function, point, index, step):
        plus, minus = point.copy(), point.copy()
        plus[..., index] += step
        minus[..., index] -= step
        return -(function(plus) - function(minus)) / (2.0 * step)  # d h / d x = -d error / d x

    for iteration in range(1, max_iterations + 1):
        information = np.zeros((dim, dim))
        gradient = np.zeros(dim)
        for k, local_map in enumerate(local_maps):
            base = np.zeros(3) if k == 0 else state[pose_columns(k)]
            robot = state[pose_columns(k + 1)]
            features = state[feature_columns[k]]
            error = local_error(k, base, robot, features)
            n = len(local_map.feature_ids)
            columns = (pose_columns(k) if k > 0 else []) + pose_columns(k + 1) + list(feature_columns[k].reshape(-1))
            jacobian = np.zeros((error.size, len(columns)))
            c = 0
            if k > 0:
                for i in range(3):
                    jacobian[:, c] = central_difference(lambda b: local_error(k, b, robot, features), base, i, 1e-6)
                    c += 1
            for i in range(3):
                jacobian[:, c] = central_difference(lambda r: local_error(k, base, r, features), robot, i, 1e-6)
                c += 1
            # Feature j enters only its own two rows, so all the features' x (then y) are moved
            # at once and each one's rows read off the difference.
            for axis in range(2):
                difference = central_difference(lambda f: local_error(k, base, robot, f), features, axis, 1e-6)
                for j in range(n):
                    jacobian[3 + 2 * j:5 + 2 * j, c + 2 * j + axis] = difference[3 + 2 * j:5 + 2 * j]
            whitened_jacobian = whitening[k] @ jacobian
            columns = np.array(columns, dtype=int)
            information[np.ix_(columns, columns)] += whitened_jacobian.T @ whitened_jacobian
            gradient[columns] += whitened_jacobian.T @ (whitening[k] @ error)
        delta = np.linalg.solve(information, gradient)
        state += delta
        if np.max(np.abs(delta)) <= tolerance:
            break
    covariance_all = np.linalg.inv(information)
    keep = np.concatenate([np.arange(3 * boundaries, dim)])
    return SubmapSolution(
        boundaries=state[:3 * boundaries].reshape(boundaries, 3),
        robot=state[3 * boundaries:3 * boundaries + 3].copy(),
        features={fid: state[column[fid]:column[fid] + 2].copy() for fid in feature_order},
        covariance=covariance_all[np.ix_(keep, keep)],
        feature_order=feature_order,
        iterations=iteration,
    )
