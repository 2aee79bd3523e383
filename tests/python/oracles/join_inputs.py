"""The problem D&C's join and the dense join are compared on: a run's associations replayed as
known ids, the EKF maps of two stretches of it in the state form the dense join takes, and a
split D&C can reproduce with one local-map size.
"""

from typing import Dict, List, Sequence, Tuple

import numpy as np

from dcslam import EkfSlam
from dcslam.datasets import Step


def known_steps(steps: Sequence, measurement_ids: Sequence) -> List[Step]:
    """``steps`` with ``landmark_ids`` = ``measurement_ids`` (per step, (m,) ids), the
    measurements with id < 0 dropped: a run's associations replayed in ``"known"`` mode."""
    out = []
    for step, ids in zip(steps, measurement_ids):
        ids = np.asarray(ids, dtype=np.int64)
        keep = ids >= 0
        out.append(Step(step.u, step.Q, np.asarray(step.z)[keep], np.asarray(step.R)[keep],
                        t=getattr(step, "t", None), landmark_ids=ids[keep]))
    return out


def ekf_map(steps: Sequence, config) -> Tuple[np.ndarray, np.ndarray, List[int], np.ndarray]:
    """EkfSlam over ``steps`` (``config`` in ``"known"`` association), from the origin with
    zero covariance.

    Returns ``(x, P, ids, poses)``: the final state ``[robot; f_0; f_1; ...]`` (3 + 2n,),
    its covariance, the feature ids in state order, and the (N, 3) robot pose after each
    step.
    """
    slam = EkfSlam(config)
    poses = np.empty((len(steps), 3))
    for k, step in enumerate(steps):
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R, step.landmark_ids)
        poses[k] = slam.pose()
    estimate = slam.estimate()
    x = np.concatenate([estimate.robot, np.asarray(estimate.landmarks, dtype=float).ravel()])
    return x, np.array(estimate.covariance, dtype=float), [int(i) for i in estimate.landmark_ids], poses


def first_seen(measurement_ids: Sequence) -> Dict[int, int]:
    """Landmark id -> the first step with a measurement of it."""
    first: Dict[int, int] = {}
    for k, ids in enumerate(measurement_ids):
        for i in np.asarray(ids):
            if int(i) >= 0:
                first.setdefault(int(i), k)
    return first


def reproducible_split(steps: Sequence, k: int) -> int:
    """The latest split at or before ``k`` that D&C can make with ``local_map_features`` =
    the number of landmarks of ``steps[:split]``: a local map closes at the step its size
    reaches the limit, so the split must follow a step that saw a new landmark. (D&C makes no
    other split if ``steps[split:]`` see fewer landmarks.)"""
    return 1 + max(step for step in first_seen([s.landmark_ids for s in steps]).values() if step < k)
