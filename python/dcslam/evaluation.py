"""Scores of a SLAM run against ground truth: data association as a clustering, and the robot.

Data association is judged as the user sees it, after the final fold (``estimate()``, then
``resolve()`` on every id the filter returned): the measurements are clustered into the
final map's features, and the clustering is compared with the true one (one cluster per
landmark). A landmark split into two features is an error here, which a per-measurement
score cannot see.

- **Pairwise precision**: of the pairs of measurements that end in one feature, the share
  that come from one landmark. **Pairwise recall**: of the pairs of measurements of one
  landmark, the share that end in one feature. A rejected measurement (id -1) and a clutter
  point (true id -1) are singletons: they form no true pair, and a clutter point in a feature
  makes every pair it is in a false one.
- **Features per landmark**: for each landmark measured at least ``min_measurements`` (3)
  times, the number of distinct final features that hold at least 2 of its measurements,
  averaged. 1.0 is the ideal; a duplicated landmark counts 2.
- **Wrong merges**: features whose measurements come from two or more landmarks.
- **Robot error**: the final pose's position and heading error and its NEES under the
  filter's own covariance (3 dof: consistent at 99 % when below 11.34).

:func:`majority_scores` keeps the older per-measurement score (each feature labelled by the
landmark most of its measurements came from) only for comparison with earlier figures.

::

    ids = [slam.update(s.z, s.R) for s in sim.steps]
    est = slam.estimate()
    scores = dcslam.evaluation.evaluate_run(slam, est, ids, sim)
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from .consistency import chi2_threshold, nees

__all__ = [
    "AssociationScores",
    "RobotScores",
    "RunScores",
    "MajorityScores",
    "association_scores",
    "majority_scores",
    "feature_landmarks",
    "robot_scores",
    "evaluate_run",
]


@dataclasses.dataclass(frozen=True)
class AssociationScores:
    """The clustering of measurements into features against the true landmarks.

    Attributes:
        pairwise_precision: true pairs in one feature / pairs in one feature (1.0 when no
            feature holds two measurements).
        pairwise_recall: true pairs in one feature / pairs of measurements of one landmark.
        features_per_landmark: mean over landmarks measured >= ``min_measurements`` times of
            the number of features holding >= 2 of their measurements.
        duplicated_landmarks: how many of those landmarks have two or more such features.
        wrong_merges: features holding measurements of two or more landmarks.
        landmarks_scored: landmarks measured >= ``min_measurements`` times.
        features: distinct features holding at least one measurement.
        measurements, clutter, rejected: counts (rejected = id -1).
    """

    pairwise_precision: float
    pairwise_recall: float
    features_per_landmark: float
    duplicated_landmarks: int
    wrong_merges: int
    landmarks_scored: int
    features: int
    measurements: int
    clutter: int
    rejected: int


@dataclasses.dataclass(frozen=True)
class MajorityScores:
    """The older per-measurement score (issue 4's): each feature stands for the landmark most
    of its measurements came from. Blind to duplicates: a landmark split into five features
    scores 100 %. Kept only beside :class:`AssociationScores`.

    Attributes:
        precision: correct pairings / pairings with a feature that already had a measurement.
        recall: correct pairings / measurements of a landmark measured before.
    """

    precision: float
    recall: float


@dataclasses.dataclass(frozen=True)
class RobotScores:
    """The final robot pose against the truth.

    Attributes:
        position_error: distance [m]; heading_error: wrapped [rad].
        nees: ``e' P_RR^-1 e`` (3 dof); consistent99: ``nees <= chi2(3, 0.99)`` (11.34).
    """

    position_error: float
    heading_error: float
    nees: float
    consistent99: bool


@dataclasses.dataclass(frozen=True)
class RunScores:
    """:func:`evaluate_run`'s result: ``association``, ``robot``, ``majority`` and the map size."""

    association: AssociationScores
    robot: RobotScores
    majority: MajorityScores
    map_size: int


def _flat_ids(values, name: str) -> np.ndarray:
    if isinstance(values, np.ndarray):
        array = values
    else:
        parts = [np.asarray(v).reshape(-1) for v in values]
        array = np.concatenate(parts) if parts else np.zeros(0, np.int64)
    array = np.asarray(array).reshape(-1)
    if array.size and not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"evaluation: '{name}' must hold integer ids, got dtype {array.dtype}")
    return array.astype(np.int64, copy=False)


def _pairs(counts: np.ndarray) -> int:
    counts = counts.astype(np.int64)
    return int(np.sum(counts * (counts - 1) // 2))


def association_scores(true_ids, feature_ids, min_measurements: int = 3) -> AssociationScores:
    """Pairwise precision/recall, features per landmark and wrong merges of a run.

    Args:
        true_ids: every measurement's true landmark (-1: clutter), as one array or one
            array per step, in the order of ``feature_ids``.
        feature_ids: every measurement's FINAL feature (-1: rejected), i.e. the filter's
            returned ids passed through ``resolve()`` after ``estimate()``.
        min_measurements: landmarks measured fewer times are left out of features per
            landmark (at least 2).

    Raises:
        ValueError: the two differ in length, or hold non-integers.
    """
    truth = _flat_ids(true_ids, "true_ids")
    features = _flat_ids(feature_ids, "feature_ids")
    if truth.shape != features.shape:
        raise ValueError(f"evaluation: 'true_ids' has {truth.size} measurements, 'feature_ids' {features.size}")
    if min_measurements < 2:
        raise ValueError(f"evaluation: 'min_measurements' must be at least 2, got {min_measurements}")
    in_feature = features >= 0
    of_landmark = truth >= 0

    _, feature_sizes = np.unique(features[in_feature], return_counts=True)
    predicted_pairs = _pairs(feature_sizes)
    _, landmark_sizes = np.unique(truth[of_landmark], return_counts=True)
    true_pairs = _pairs(landmark_sizes)
    both = in_feature & of_landmark
    cells, cell_sizes = np.unique(np.stack([features[both], truth[both]]), axis=1, return_counts=True)
    true_positive = _pairs(cell_sizes)

    # Wrong merges: features with measurements of two or more landmarks.
    cell_features = cells[0]
    landmarks_per_feature = np.unique(cell_features, return_counts=True)[1]
    wrong_merges = int(np.sum(landmarks_per_feature >= 2))

    # Features per landmark: (feature, landmark) cells with >= 2 measurements, per landmark.
    landmark_ids, landmark_counts = np.unique(truth[of_landmark], return_counts=True)
    scored = landmark_ids[landmark_counts >= min_measurements]
    strong = cells[1][cell_sizes >= 2]
    strong_landmarks, strong_counts = np.unique(strong, return_counts=True)
    per_landmark = np.zeros(len(scored), np.int64)
    found = np.isin(scored, strong_landmarks)
    per_landmark[found] = strong_counts[np.searchsorted(strong_landmarks, scored[found])]

    return AssociationScores(
        pairwise_precision=true_positive / predicted_pairs if predicted_pairs else 1.0,
        pairwise_recall=true_positive / true_pairs if true_pairs else 1.0,
        features_per_landmark=float(per_landmark.mean()) if len(scored) else math.nan,
        duplicated_landmarks=int(np.sum(per_landmark >= 2)),
        wrong_merges=wrong_merges,
        landmarks_scored=int(len(scored)),
        features=int(len(feature_sizes)),
        measurements=int(truth.size),
        clutter=int(np.sum(~of_landmark)),
        rejected=int(np.sum(~in_feature)),
    )


def feature_landmarks(true_ids, feature_ids):
    """The landmark each feature stands for: the true id most of its measurements carry.

    Returns ``(features, landmarks)``, two int64 arrays over the distinct ids ``>= 0`` in
    ``feature_ids`` (as ``update()`` returned them, before ``resolve()``), sorted by feature
    id. Clutter votes too (``-1``), so a feature born of clutter gets ``-1``; a tie goes to a
    landmark before clutter, then to the smaller id.
    """
    truth = _flat_ids(true_ids, "true_ids")
    features = _flat_ids(feature_ids, "feature_ids")
    if truth.shape != features.shape:
        raise ValueError(f"evaluation: 'true_ids' has {truth.size} measurements, 'feature_ids' {features.size}")
    keep = features >= 0
    pairs, counts = np.unique(np.stack([features[keep], truth[keep]]), axis=1, return_counts=True)
    order = np.lexsort((pairs[1], pairs[1] < 0, -counts, pairs[0]))  # per feature: best first
    pairs = pairs[:, order]
    first = np.ones(pairs.shape[1], dtype=bool)
    first[1:] = pairs[0, 1:] != pairs[0, :-1]
    return pairs[0, first].astype(np.int64), pairs[1, first].astype(np.int64)


def majority_scores(true_ids, feature_ids) -> MajorityScores:
    """The older per-measurement score (see :class:`MajorityScores`), in measurement order.

    A measurement "pairs" when its feature already had a measurement before it; it is
    correct when its landmark is its feature's majority landmark. Blind to duplicates.
    """
    truth = _flat_ids(true_ids, "true_ids")
    features = _flat_ids(feature_ids, "feature_ids")
    if truth.shape != features.shape:
        raise ValueError(f"evaluation: 'true_ids' has {truth.size} measurements, 'feature_ids' {features.size}")
    votes: dict = {}
    for f, t in zip(features.tolist(), truth.tolist()):
        if f >= 0 and t >= 0:
            counter = votes.setdefault(f, {})
            counter[t] = counter.get(t, 0) + 1
    label = {f: max(c.items(), key=lambda kv: (kv[1], -kv[0]))[0] for f, c in votes.items()}
    seen_features: set = set()
    seen_landmarks: set = set()
    pairings = correct = reobservations = 0
    for f, t in zip(features.tolist(), truth.tolist()):
        if t >= 0 and t in seen_landmarks:
            reobservations += 1
        if f >= 0 and f in seen_features:
            pairings += 1
            if t >= 0 and label.get(f) == t and t in seen_landmarks:
                correct += 1
        if f >= 0:
            seen_features.add(f)
        if t >= 0:
            seen_landmarks.add(t)
    return MajorityScores(
        precision=correct / pairings if pairings else 1.0,
        recall=correct / reobservations if reobservations else 1.0,
    )


def robot_scores(estimate, true_pose) -> RobotScores:
    """The estimate's robot (``estimate.robot``, ``estimate.covariance[:3, :3]``) against
    the true pose (3,)."""
    true_pose = np.asarray(true_pose, dtype=float).reshape(-1)
    if true_pose.shape != (3,):
        raise ValueError(f"evaluation: 'true_pose' must have shape (3,), got {true_pose.shape}")
    robot = np.asarray(estimate.robot, dtype=float)
    covariance = np.asarray(estimate.covariance, dtype=float)[:3, :3]
    value = nees(robot, covariance, true_pose, angle_indices=(2,))
    return RobotScores(
        position_error=float(np.hypot(*(robot[:2] - true_pose[:2]))),
        heading_error=float(abs(math.remainder(robot[2] - true_pose[2], 2 * math.pi))),
        nees=float(value),
        consistent99=bool(value <= chi2_threshold(3, alpha=0.01)),
    )


def evaluate_run(slam, estimate, returned_ids: Sequence[Any], simulation) -> RunScores:
    """Scores a finished run on a simulation.

    Args:
        slam: the filter (:class:`~dcslam.EkfSlam` or :class:`~dcslam.DCSlam`); its
            ``resolve()`` maps the returned ids to the final features.
        estimate: ``slam.estimate()`` taken after the last step (and before any further step:
            D&C's ``resolve()`` follows the final fold's merges only until then).
        returned_ids: what ``update()`` returned at each step.
        simulation: the :class:`~dcslam.Simulation` the run used (``true_ids``, ``poses``).
    """
    steps_run = len(returned_ids)
    returned = _flat_ids(returned_ids, "returned_ids")
    final = np.asarray(slam.resolve(returned), dtype=np.int64)
    truth = np.asarray(simulation.true_ids, dtype=np.int64)[: len(final)]
    return RunScores(
        association=association_scores(truth, final),
        robot=robot_scores(estimate, simulation.poses[steps_run]),
        majority=majority_scores(truth, final),
        map_size=int(len(estimate.landmark_ids)),
    )
