"""Two maps joined by a dense numpy join written from the definition, independent of the C++
map joining: the oracle D&C's joins are checked against.

Map m1 is in the global frame and ends at robot pose R1; map m2 is expressed in R1's frame.
The join is the constrained MAP of the stacked prior ``x0 = [x1; x2]``,
``P0 = blkdiag(P1, P2)`` under ``f1_i - (R1 ⊕ f2_j) = 0`` for every id the two maps share,
found by the iterated EKF (Gauss-Newton) ``x+ = x0 + P0 H' (H P0 H')^-1 (-c(x) - H (x0 - x))``
until no coordinate moves by more than the tolerance. The joined map holds m1's features and
``R1 ⊕`` m2's unmatched ones. A state is ``[robot; f_0; f_1; ...]`` with the feature ids in
state order beside it.
"""

from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
import scipy.linalg

from dcslam import geometry


def landmarks_of(x: np.ndarray, ids: Sequence[int], offset: int = 0) -> Dict[int, np.ndarray]:
    """Feature positions by id of a state whose features start at ``offset + 3``."""
    return {int(i): x[offset + 3 + 2 * n:offset + 5 + 2 * n].copy() for n, i in enumerate(ids)}


class DenseJoin(NamedTuple):
    """The dense join's answer: the joined map by id, the stacked state ``[x1; x2]`` at the
    solution, the linearisation points used and whether the last step met the tolerance."""

    features: Dict[int, np.ndarray]
    state: np.ndarray
    iterations: int
    converged: bool


def shared_pairs(ids1: Sequence[int], ids2: Sequence[int]) -> List[Tuple[int, int]]:
    """(i, j): m1's i-th and m2's j-th feature carry the same id."""
    where = {int(lid): i for i, lid in enumerate(ids1)}
    return [(where[int(lid)], j) for j, lid in enumerate(ids2) if int(lid) in where]


def join_constraints(state: np.ndarray, size1: int, pairs: Sequence[Tuple[int, int]]):
    """``c(x) = f1_i - (R1 ⊕ f2_j)`` stacked over ``pairs`` and its Jacobian (2r, N) at the
    stacked ``state = [x1; x2]``, ``size1 = len(x1)``."""
    c = np.empty(2 * len(pairs))
    C = np.zeros((2 * len(pairs), len(state)))
    R1 = state[:3]
    for row, (i, j) in enumerate(pairs):
        a, b, r = 3 + 2 * i, size1 + 3 + 2 * j, 2 * row
        moved, J_pose, J_point = geometry.transform_point(R1, state[b:b + 2], jacobians=True)
        c[r:r + 2] = state[a:a + 2] - np.asarray(moved)
        C[r:r + 2, a:a + 2] = np.eye(2)
        C[r:r + 2, :3] = -np.asarray(J_pose)
        C[r:r + 2, b:b + 2] = -np.asarray(J_point)
    return c, C


def stacked_difference(a: np.ndarray, b: np.ndarray, size1: int) -> np.ndarray:
    """``a - b`` for stacked states, the two robots' headings wrapped (a state built from
    another map may hold the same heading on the other side of ±pi)."""
    difference = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    for angle in (2, size1 + 2):
        difference[angle] = geometry.wrap_angle(difference[angle])
    return difference


def dense_join(x1, P1, ids1, x2, P2, ids2, max_iterations: int = 100, tolerance: float = 1e-9,
               initial: Optional[np.ndarray] = None) -> DenseJoin:
    """Constrained MAP of two maps, m2 expressed in m1's robot frame R1 (see the module
    docstring), by Gauss-Newton from ``initial`` (default: the prior means ``[x1; x2]``).

    Stops when no coordinate moves by more than ``tolerance`` or after ``max_iterations``
    linearisation points. The joined map holds m1's features and ``R1 ⊕`` m2's unmatched
    ones.
    """
    x1, x2 = np.asarray(x1, dtype=float), np.asarray(x2, dtype=float)
    size1 = len(x1)
    x0 = np.concatenate([x1, x2])
    P0 = scipy.linalg.block_diag(P1, P2)
    pairs = shared_pairs(ids1, ids2)
    # Without shared features nothing constrains the prior: its means are the answer.
    state, iterations, converged = x0.copy(), 0, not pairs
    if pairs and initial is not None:
        state = np.asarray(initial, dtype=float).copy()
    while not converged and iterations < max_iterations:
        iterations += 1
        c, C = join_constraints(state, size1, pairs)
        PCt = P0 @ C.T
        innovation = -c - C @ stacked_difference(x0, state, size1)
        updated = x0 + PCt @ scipy.linalg.cho_solve(scipy.linalg.cho_factor(C @ PCt), innovation)
        converged = np.max(np.abs(stacked_difference(updated, state, size1))) < tolerance
        state = updated
    features = landmarks_of(state, ids1)
    R1 = state[:3]
    matched = {j for _, j in pairs}
    for j, lid in enumerate(ids2):
        if j not in matched:
            features[int(lid)] = np.asarray(geometry.transform_point(R1, state[size1 + 3 + 2 * j:size1 + 5 + 2 * j]))
    return DenseJoin(features, state, iterations, converged)


def split_costs(state: np.ndarray, x1, P1, x2, P2) -> Dict[str, float]:
    """``|x - x0|^2_{P0^-1}`` at the stacked ``state``, split into m1's part (``m1``) and
    m2's (``m2``), with how far each part's robot moved (``*_robot_move`` metres,
    ``*_heading_move`` radians) and its features at most (``*_feature_move`` metres), from
    the prior means and in the part's own frame."""
    size1 = len(x1)
    difference = stacked_difference(state, np.concatenate([x1, x2]), size1)
    out = {}
    for name, part, P in (("m1", difference[:size1], P1), ("m2", difference[size1:], P2)):
        out[name] = float(part @ scipy.linalg.cho_solve(scipy.linalg.cho_factor(P), part))
        out[f"{name}_robot_move"] = float(np.linalg.norm(part[:2]))
        out[f"{name}_heading_move"] = float(abs(part[2]))
        out[f"{name}_feature_move"] = float(np.max(np.linalg.norm(part[3:].reshape(-1, 2), axis=1), initial=0.0))
    out["total"] = out["m1"] + out["m2"]
    return out


def state_from_map(features: Dict[int, np.ndarray], pose_at_split, robot, ids1, ids2) -> np.ndarray:
    """The stacked state ``[x1; x2]`` a global map implies: m1's robot at ``pose_at_split``
    and its features where the map has them, m2's robot (``robot``, the map's final pose) and
    features moved into that pose's frame."""
    pose_at_split = np.asarray(pose_at_split, dtype=float)
    x1 = [pose_at_split] + [features[i] for i in ids1]
    x2 = [np.asarray(geometry.compose(geometry.invert(pose_at_split), robot))]
    x2 += [np.asarray(geometry.inverse_transform_point(pose_at_split, features[i])) for i in ids2]
    return np.concatenate([np.ravel(v) for v in x1 + x2])
