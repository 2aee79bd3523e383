"""Scores of a SLAM run against ground truth: data association as a clustering, the robot, the
map and the trajectory.

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
  filter's own covariance (3 dof: consistent at 99 % when below 11.34), and its consistency
  index (NEES / chi2(3, 0.95), Paz et al. 2007 §III.C).
- **Robot NEES over time** (:func:`nees_series`): the NEES and consistency index of the
  robot (or some of its components, e.g. the heading alone) at a series of estimates.
- **Map** (:func:`map_scores`): the landmarks' position RMS against the truth, and the joint
  NEES and consistency index of all landmarks matched to a true one.
- **ATE** (:func:`absolute_trajectory_error`): the RMS position error of a trajectory against
  a truth trajectory with the same poses.

Maps and trajectories are compared with the truth after one of two alignments, named by
``alignment``: ``"first_pose"`` (the default) uses none, because the filters estimate in the
frame of the first pose and the truth (``sim.poses``, ``mrclam().poses_true``) is given in
that frame, so the known first pose is the alignment; ``"rigid"`` first fits a rotation and
translation (no scale) of the estimate onto the truth (:func:`dcslam.metrics.rigid_fit_2d`),
which removes the error of the start, as ``evo_ape --align`` does. For NEES the covariance is
rotated with the estimate; the fit's own uncertainty is ignored.

:func:`score_run` gathers them all for a :class:`~dcslam.PipelineResult` against a dataset
with ground truth (the simulator's or MR.CLAM's).

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
from typing import Any, Optional, Sequence

import numpy as np

from .consistency import chi2_threshold, nees
from .metrics import rigid_fit_2d

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
    "ALIGNMENTS",
    "TrajectoryError",
    "absolute_trajectory_error",
    "NeesSeries",
    "nees_series",
    "MapScores",
    "map_scores",
    "TruthScores",
    "score_run",
]

ALIGNMENTS = ("first_pose", "rigid")


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
        recall_lost_to_rejected: pairs of measurements of one landmark lost because one of
            the two was rejected (or its feature dropped), over the landmarks' pairs.
        recall_lost_to_splits: pairs of measurements of one landmark, both in features, but
            in two different ones (a landmark mapped twice, or a measurement given to another
            landmark's feature), over the landmarks' pairs.
            ``pairwise_recall + recall_lost_to_rejected + recall_lost_to_splits == 1``.
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
    recall_lost_to_rejected: float
    recall_lost_to_splits: float


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
        consistency_index: ``nees / chi2(3, 0.95)`` (the paper's CI: above 1 is optimistic).
    """

    position_error: float
    heading_error: float
    nees: float
    consistent99: bool
    consistency_index: float


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
    _, kept_sizes = np.unique(truth[both], return_counts=True)
    kept_pairs = _pairs(kept_sizes)  # pairs of one landmark's measurements, both in a feature
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
        recall_lost_to_rejected=(true_pairs - kept_pairs) / true_pairs if true_pairs else 0.0,
        recall_lost_to_splits=(kept_pairs - true_positive) / true_pairs if true_pairs else 0.0,
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
        consistency_index=float(value / chi2_threshold(3, alpha=0.05)),
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


def _alignment_name(alignment: str) -> str:
    if alignment not in ALIGNMENTS:
        raise ValueError(f"evaluation: 'alignment' must be one of {', '.join(ALIGNMENTS)}, got {alignment!r}")
    return alignment


def _points(values, name: str, columns: Sequence[int]) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 2 or array.shape[1] not in columns:
        wanted = " or ".join(f"(n, {c})" for c in columns)
        raise ValueError(f"evaluation: '{name}' must have shape {wanted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"evaluation: '{name}' contains a non-finite value")
    return array


def _fit(source: np.ndarray, target: np.ndarray, alignment: str):
    """Rotation and translation taking ``source`` onto ``target`` under ``alignment``."""
    if alignment == "rigid":
        return rigid_fit_2d(source, target)
    return np.eye(2), np.zeros(2)


@dataclasses.dataclass(frozen=True)
class TrajectoryError:
    """Absolute trajectory error: position errors of paired poses after an alignment.

    Attributes:
        alignment: ``"first_pose"`` or ``"rigid"`` (see the module's docstring).
        rmse, mean, median, max: of ``errors`` [m].
        errors: (n,) distance of each aligned pose from its true position.
        rotation, translation: the alignment, ``aligned = rotation @ p + translation``.
    """

    alignment: str
    rmse: float
    mean: float
    median: float
    max: float
    errors: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray


def absolute_trajectory_error(trajectory, truth, alignment: str = "first_pose") -> TrajectoryError:
    """The ATE of ``trajectory`` against ``truth``: the RMS distance of paired positions.

    Args:
        trajectory, truth: (n, 2) or (n, 3) poses in the same order (a heading column is
            ignored), e.g. a run's ``trajectory`` and ``poses_true[1:n + 1]``.
        alignment: ``"first_pose"`` (compare as given: both in the first pose's frame) or
            ``"rigid"`` (rotation and translation fitted first; needs n >= 2).

    Raises:
        ValueError: shapes that differ, no pose, non-finite values, an unknown alignment.
    """
    alignment = _alignment_name(alignment)
    estimated = _points(trajectory, "trajectory", (2, 3))[:, :2]
    reference = _points(truth, "truth", (2, 3))[:, :2]
    if len(estimated) != len(reference) or len(estimated) == 0:
        raise ValueError(f"evaluation: 'trajectory' has {len(estimated)} poses, 'truth' {len(reference)}; "
                         f"need the same number, at least 1")
    rotation, translation = _fit(estimated, reference, alignment)
    errors = np.linalg.norm(estimated @ rotation.T + translation - reference, axis=1)
    return TrajectoryError(
        alignment=alignment, rmse=float(np.sqrt(np.mean(errors**2))), mean=float(errors.mean()),
        median=float(np.median(errors)), max=float(errors.max()), errors=errors,
        rotation=rotation, translation=translation)


@dataclasses.dataclass(frozen=True)
class NeesSeries:
    """NEES of a series of estimates against the truth (see :func:`nees_series`).

    Attributes:
        nees: (k,); consistency_index: (k,) ``nees / chi2(dof, 1 - alpha)``.
        dof: components scored; alpha: the test's level; bound: ``chi2(dof, 1 - alpha)``.
        mean_nees: mean over the series; share_consistent: share with ``nees <= bound``.
    """

    nees: np.ndarray
    consistency_index: np.ndarray
    dof: int
    alpha: float
    bound: float

    @property
    def mean_nees(self) -> float:
        return float(np.mean(self.nees)) if len(self.nees) else math.nan

    @property
    def share_consistent(self) -> float:
        return float(np.mean(self.nees <= self.bound)) if len(self.nees) else math.nan


def nees_series(estimates, covariances, truth, components: Sequence[int] = (0, 1, 2),
                angle_components: Sequence[int] = (2,), alpha: float = 0.05) -> NeesSeries:
    """The NEES and consistency index of each of k estimates of a state against its truth.

    Args:
        estimates: (k, d) e.g. robot poses; covariances: (k, d, d); truth: (k, d).
        components: which components are scored (``(2,)``: the heading alone).
        angle_components: components whose error is wrapped to [-pi, pi].
        alpha: the consistency index divides by ``chi2(len(components), 1 - alpha)``.

    Raises:
        ValueError: shapes that do not agree, a component out of range, a covariance that is
        not positive definite on the scored components.
    """
    estimates = np.asarray(estimates, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if estimates.ndim != 2 or truth.shape != estimates.shape or covariances.shape != estimates.shape + estimates.shape[1:]:
        raise ValueError(f"evaluation: need estimates (k, d), covariances (k, d, d) and truth (k, d); got "
                         f"{estimates.shape}, {covariances.shape} and {truth.shape}")
    picked = list(components)
    if not picked or any(not 0 <= c < estimates.shape[1] for c in picked):
        raise ValueError(f"evaluation: 'components' {picked} out of range for states of {estimates.shape[1]}")
    angles = [picked.index(c) for c in angle_components if c in picked]
    values = np.array([nees(x[picked], P[np.ix_(picked, picked)], t[picked], angle_indices=angles)
                       for x, P, t in zip(estimates, covariances, truth)])
    bound = chi2_threshold(len(picked), alpha)
    return NeesSeries(nees=values, consistency_index=values / bound, dof=len(picked), alpha=float(alpha),
                      bound=float(bound))


@dataclasses.dataclass(frozen=True)
class MapScores:
    """The final map's landmarks against the true ones (see :func:`map_scores`).

    Attributes:
        alignment: ``"first_pose"`` or ``"rigid"``.
        landmarks: features scored (matched to a true landmark); missing: true landmarks no
            feature was matched to.
        rms, max_error: position errors of the scored features [m].
        nees: joint NEES of the scored features' positions (``dof = 2 landmarks``) under their
            joint covariance; consistency_index: ``nees / chi2(dof, 1 - alpha)``.
    """

    alignment: str
    landmarks: int
    missing: int
    rms: float
    max_error: float
    nees: float
    dof: int
    consistency_index: float


def map_scores(estimate, landmarks_true, landmark_ids_true, feature_landmark=None, alignment: str = "first_pose",
               alpha: float = 0.05) -> MapScores:
    """Position RMS and joint NEES of the estimate's landmarks against the truth.

    Args:
        estimate: an :class:`~dcslam.Estimate` (``landmarks``, ``landmark_ids``, ``covariance``).
        landmarks_true: (N, 2) true positions; landmark_ids_true: (N,) their ids.
        feature_landmark: the true id each feature stands for, as ``(features, landmarks)``
            (what :func:`feature_landmarks` returns) when the filter ran without ids; ``None``
            when its ids are the true ones (known association). Features without a true
            landmark are left out; two features of one landmark are both scored.
        alignment: ``"first_pose"`` or ``"rigid"`` (fitted on the scored features).

    With no feature to score (or one, for ``"rigid"``) the errors, NEES and index are NaN.

    Raises:
        ValueError: bad shapes, an unknown alignment, a covariance that is not positive
        definite on the scored features.
    """
    alignment = _alignment_name(alignment)
    truth = _points(landmarks_true, "landmarks_true", (2,))
    truth_ids = np.asarray(landmark_ids_true, dtype=np.int64).reshape(-1)
    if len(truth_ids) != len(truth):
        raise ValueError(f"evaluation: 'landmark_ids_true' has {len(truth_ids)} ids for {len(truth)} landmarks")
    feature_ids = np.asarray(estimate.landmark_ids, dtype=np.int64)
    if feature_landmark is None:
        label = feature_ids
    else:
        features, landmarks = (np.asarray(a, dtype=np.int64) for a in feature_landmark)
        lookup = dict(zip(features.tolist(), landmarks.tolist()))
        label = np.array([lookup.get(f, -1) for f in feature_ids.tolist()], dtype=np.int64)
    row_of_truth = {int(i): r for r, i in enumerate(truth_ids)}
    scored = np.array([r for r, l in enumerate(label.tolist()) if l in row_of_truth], dtype=np.int64)
    missing = len(set(row_of_truth) - set(label[scored].tolist()))
    if len(scored) == 0 or (alignment == "rigid" and len(scored) < 2):
        return MapScores(alignment, int(len(scored)), missing, math.nan, math.nan, math.nan, 0, math.nan)
    positions = np.asarray(estimate.landmarks, dtype=float)[scored]
    targets = truth[[row_of_truth[int(l)] for l in label[scored]]]
    rotation, translation = _fit(positions, targets, alignment)
    aligned = positions @ rotation.T + translation
    errors = np.linalg.norm(aligned - targets, axis=1)
    index = (3 + 2 * scored[:, None] + np.arange(2)).reshape(-1)
    covariance = np.asarray(estimate.covariance, dtype=float)[np.ix_(index, index)]
    # Every 2x2 block C_ab becomes R C_ab R' (the block-diagonal rotation applied in O(n^2),
    # not as two dense (2n)^3 products).
    blocks = covariance.reshape(len(scored), 2, len(scored), 2)
    rotated = np.einsum("ij,ajbk,lk->aibl", rotation, blocks, rotation, optimize=True).reshape(covariance.shape)
    value = nees(aligned.reshape(-1), rotated, targets.reshape(-1))
    dof = 2 * len(scored)
    return MapScores(alignment=alignment, landmarks=int(len(scored)), missing=int(missing),
                     rms=float(np.sqrt(np.mean(errors**2))), max_error=float(errors.max()), nees=float(value),
                     dof=dof, consistency_index=float(value / chi2_threshold(dof, alpha)))


@dataclasses.dataclass(frozen=True)
class TruthScores:
    """:func:`score_run`'s result.

    Attributes:
        ate: the filter's own trajectory (pose after each step, as known then) against the
            truth, ``"first_pose"`` alignment; ate_rigid: the same after a rigid fit (``None``
            for a run of 1 step). For D&C this trajectory is the chain of local maps, which
            later joins never correct.
        ate_checkpoints: the robot of the full estimate at each checkpoint against the truth
            (``"first_pose"``): for D&C every local map joined, the same footing as the EKF;
            ``None`` without checkpoints.
        robot: the final estimate's robot (:class:`RobotScores`).
        robot_nees: the robot's NEES at the run's checkpoints (:class:`NeesSeries`, 3 dof),
            ``None`` when the run recorded none; heading_nees: the heading's alone (1 dof).
        map: the final map against the true landmarks (:class:`MapScores`, first-pose
            alignment); map_rigid: after a rigid fit.
        association: :class:`AssociationScores` of the run's measurement ids against the true
            ones; ``None`` when the run used the true ids (known association).
    """

    ate: TrajectoryError
    ate_rigid: Optional[TrajectoryError]
    ate_checkpoints: Optional[TrajectoryError]
    robot: RobotScores
    robot_nees: Optional[NeesSeries]
    heading_nees: Optional[NeesSeries]
    map: MapScores
    map_rigid: MapScores
    association: Any

    def summary(self) -> dict:
        """Plain numbers (JSON-ready)."""
        out = {"ate_m": self.ate.rmse, "ate_rigid_m": self.ate_rigid.rmse if self.ate_rigid else math.nan,
               "final_position_error_m": self.robot.position_error, "final_heading_error_rad": self.robot.heading_error,
               "final_robot_nees": self.robot.nees, "final_robot_ci": self.robot.consistency_index,
               "landmark_rms_m": self.map.rms, "landmark_rms_rigid_m": self.map_rigid.rms,
               "landmarks_scored": self.map.landmarks, "map_nees": self.map.nees, "map_dof": self.map.dof,
               "map_ci": self.map.consistency_index, "map_ci_rigid": self.map_rigid.consistency_index}
        if self.robot_nees is not None and self.heading_nees is not None and self.ate_checkpoints is not None:
            out.update(ate_checkpoints_m=self.ate_checkpoints.rmse, robot_nees_mean=self.robot_nees.mean_nees,
                       robot_nees_share_consistent=self.robot_nees.share_consistent,
                       robot_ci_mean=float(np.mean(self.robot_nees.consistency_index)),
                       heading_ci_mean=float(np.mean(self.heading_nees.consistency_index)))
        if self.association is not None:
            a = self.association
            out.update(pairwise_precision=a.pairwise_precision, pairwise_recall=a.pairwise_recall,
                       features_per_landmark=a.features_per_landmark, wrong_merges=a.wrong_merges)
        return out


def score_run(result, poses_true, landmarks_true, landmark_ids_true, true_ids=None) -> TruthScores:
    """Every score of a :class:`~dcslam.PipelineResult` against a ground truth.

    Args:
        result: the run (its ``trajectory``, ``estimate``, ``measurement_ids`` and, when the
            pipeline had ``checkpoint_every``, ``checkpoints``).
        poses_true: (steps + 1, 3) true poses, ``poses_true[0]`` the first pose (the frame of
            everything), ``poses_true[k]`` the pose after k steps.
        landmarks_true, landmark_ids_true: (N, 2) and (N,) the true landmarks.
        true_ids: every measurement's true landmark in step order (one array, or one per
            step), to score the association of a run without ids; ``None`` skips it (and maps
            are matched by the estimate's own ids).
    """
    poses_true = _points(poses_true, "poses_true", (3,))
    steps = result.steps
    if len(poses_true) < steps + 1:
        raise ValueError(f"evaluation: 'poses_true' has {len(poses_true)} poses for a run of {steps} steps")
    truth_path = poses_true[1:steps + 1]
    association = None
    feature_landmark = None
    if true_ids is not None:
        counts = [len(ids) for ids in result.measurement_ids]
        truth = _flat_ids(true_ids, "true_ids")[: int(sum(counts))]
        final = _flat_ids(result.measurement_ids, "measurement_ids")
        association = association_scores(truth, final)
        feature_landmark = feature_landmarks(truth, final)
    robot_nees = heading_nees = ate_checkpoints = None
    checkpoints = getattr(result, "checkpoints", None)
    if checkpoints is not None and len(checkpoints.steps):
        at = poses_true[checkpoints.steps]
        ate_checkpoints = absolute_trajectory_error(checkpoints.robot, at, "first_pose")
        robot_nees = nees_series(checkpoints.robot, checkpoints.covariance, at)
        heading_nees = nees_series(checkpoints.robot, checkpoints.covariance, at, components=(2,))
    return TruthScores(
        ate=absolute_trajectory_error(result.trajectory, truth_path, "first_pose"),
        ate_rigid=absolute_trajectory_error(result.trajectory, truth_path, "rigid") if steps >= 2 else None,
        ate_checkpoints=ate_checkpoints,
        robot=robot_scores(result.estimate, poses_true[steps]),
        robot_nees=robot_nees,
        heading_nees=heading_nees,
        map=map_scores(result.estimate, landmarks_true, landmark_ids_true, feature_landmark, "first_pose"),
        map_rigid=map_scores(result.estimate, landmarks_true, landmark_ids_true, feature_landmark, "rigid"),
        association=association,
    )
