"""SLAM filters: the shared :class:`SlamFilter` surface and the sparse-aware :class:`EkfSlam`.

Both wrap a compiled filter (``dcslam._core``); Python crosses into C++ once per call, and
the GIL is released while C++ works (``predict`` and ``update``: when another Python thread
exists; docs/design.md §9). A filter object is not thread-safe: call
it from one thread at a time.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, Dict, List, Optional, Union, overload

import numpy as np

from . import _core
from .config import SlamConfig
from .packed import PackedSteps

__all__ = ["Estimate", "SlamStats", "DCSlamStats", "BatchResult", "SlamFilter", "EkfSlam", "DCSlam"]


def _no_past_poses() -> np.ndarray:
    return np.zeros((0, 3))


def _no_past_pose_ids() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dataclasses.dataclass(frozen=True)
class Estimate:
    """The whole map in the frame of the first pose (docs/api.md).

    Attributes:
        robot: (3,) current robot pose (x, y, phi).
        landmarks: (n, 2) feature positions, in state order.
        landmark_ids: (n,) int64 feature ids (the caller's ids in ``"known"`` mode).
        covariance: (3 + 2n, 3 + 2n) full covariance, ordered [robot, lm 0, lm 1, ...]
            (a view of the leading block of ``joint_covariance``).
        past_poses: (m, 3) past robot poses (x, y, phi), oldest first: with
            ``SlamConfig.keep_local_map_poses``, :class:`DCSlam` keeps the pose at every
            local-map boundary (docs/design.md §4.5); (0, 3) otherwise and for :class:`EkfSlam`.
        past_pose_ids: (m,) int64, the step of each past pose: the number of ``predict``
            calls made before it (so ``sim.poses[past_pose_ids]`` are their true poses).
        joint_covariance: (3 + 2n + 3m, 3 + 2n + 3m) covariance of [robot, lm 0, ...,
            past pose 0, ...]; ``covariance`` itself when m = 0 (the default).
    """

    robot: np.ndarray
    landmarks: np.ndarray
    landmark_ids: np.ndarray
    covariance: np.ndarray
    past_poses: np.ndarray = dataclasses.field(default_factory=_no_past_poses)
    past_pose_ids: np.ndarray = dataclasses.field(default_factory=_no_past_pose_ids)
    joint_covariance: Optional[np.ndarray] = None

    def __post_init__(self):
        if self.joint_covariance is None:
            if len(self.past_poses):
                raise ValueError("Estimate: joint_covariance is required with past poses")
            object.__setattr__(self, "joint_covariance", self.covariance)

    @classmethod
    def _from_core(cls, values: Dict[str, Any]) -> "Estimate":
        """From the compiled filter's dict, whose joint covariance is viewed, not copied."""
        values = dict(values)
        joint = values.pop("joint_covariance")
        d = 3 + 2 * len(values["landmarks"])
        return cls(covariance=joint[:d, :d], joint_covariance=joint, **values)


@dataclasses.dataclass(frozen=True)
class SlamStats:
    """Per-step statistics; one entry per step (a step opens with each ``predict``).

    Attributes:
        step_seconds: wall time of each step (predict and its updates), seconds.
        num_features: map size after each step.
        measurements: measurements received in each step.
        paired: measurements paired with an existing feature.
        new_features: measurements that started a feature.
        rejected: measurements rejected (id -1).
        association_seconds: part of each step's time spent in data association (candidate
            search, gates, NN/JCBB; inside the local map for D&C; 0 in "known" mode).
        counters: named totals, e.g. ``"predicts"``, ``"updates"`` (filters may add more).
    """

    step_seconds: np.ndarray
    num_features: np.ndarray
    measurements: np.ndarray
    paired: np.ndarray
    new_features: np.ndarray
    rejected: np.ndarray
    association_seconds: np.ndarray
    counters: Dict[str, float]

    @property
    def total_seconds(self) -> float:
        return float(self.step_seconds.sum())


@dataclasses.dataclass(frozen=True)
class BatchResult(Sequence):
    """What :meth:`SlamFilter.run_batch` returns; also the sequence of each step's ids
    (``len(result)`` steps, ``result[k]`` a view of ``ids``), as a loop of ``update`` calls
    would have collected them.

    Attributes:
        ids: (M,) int64, the feature id each measurement went to, as :meth:`SlamFilter.update`
            returns them (a new id when it started a feature, -1 when rejected).
        offsets: (N + 1,) int64; step k's measurements are ``ids[offsets[k]:offsets[k + 1]]``.
        trajectory: (N + 1, 3) the online pose (x, y in m, phi in rad) as :meth:`SlamFilter.pose`
            gives it: before the first step, then after each step.
        step_seconds: (N,) wall time of each step's predict and update, in seconds.
    """

    ids: np.ndarray
    offsets: np.ndarray
    trajectory: np.ndarray
    step_seconds: np.ndarray

    def __len__(self) -> int:
        return len(self.step_seconds)

    @overload
    def __getitem__(self, index: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, index: slice) -> List[np.ndarray]: ...

    def __getitem__(self, index: Union[int, slice]):
        if isinstance(index, slice):
            return [self[k] for k in range(*index.indices(len(self)))]
        k = int(index)
        if k < 0:
            k += len(self)
        if not 0 <= k < len(self):
            raise IndexError(f"step {index} out of range for {len(self)} steps")
        return self.ids[self.offsets[k]:self.offsets[k + 1]]


class SlamFilter:
    """The interface of :class:`EkfSlam` and :class:`~dcslam.DCSlam` (docs/api.md).

    Subclasses build the compiled filter and pass it to ``__init__``.

    On an instance, ``predict``, ``update`` and ``pose`` are the compiled filter's own methods
    (same arguments, checks and results as documented here): a Python method in between would
    cost about 0.1 us a call, a sixth of the per-step crossing budget (BENCHMARKS.md, "Python
    at native speed"). ``help(dcslam.DCSlam.update)`` shows the documentation.
    """

    _DIRECT = ("predict", "update", "pose")

    def __init__(self, core: "_core.SlamFilter", config: SlamConfig):
        self._core = core
        self._config = config
        self._bind_direct()

    def _bind_direct(self) -> None:
        # Instance attributes shadow the documented methods below (vars(): mypy would refuse
        # assigning to a method); a method a subclass overrides is left to the subclass.
        vars(self).update({name: getattr(self._core, name) for name in self._DIRECT
                           if getattr(type(self), name) is getattr(SlamFilter, name)})

    def __getstate__(self) -> Dict[str, Any]:
        # Without the bound methods: a copy binds its own (deepcopy would keep the original's).
        return {key: value for key, value in vars(self).items() if key not in self._DIRECT}

    def __setstate__(self, state: Dict[str, Any]) -> None:
        vars(self).update(state)
        self._bind_direct()

    @property
    def config(self) -> SlamConfig:
        return self._config

    def predict(self, u, Q) -> None:
        """Moves the robot by ``u`` (3,), the relative motion x_{R(k-1)R(k)} (x, y [m], phi
        [rad]), with covariance Q (3, 3) [m^2, rad^2]. Raises ``ValueError`` naming the argument
        for a bad shape or value, and leaves the filter unchanged.

        ``x_R <- x_R ⊕ u``, ``P_RR <- F P_RR F' + G Q G'``, ``P_RM <- F P_RM`` (docs/design.md §3.1).
        Q (3, 3) must be symmetric positive semi-definite; a zero variance (e.g. a known
        heading) is legal. Opens a new step in :attr:`stats`.
        """
        self._core.predict(u, Q)

    def update(self, z, R, landmark_ids=None) -> np.ndarray:
        """Processes one scan and returns, per measurement, the id of its feature.

        Args:
            z: (m, 2) measurements in the sensor frame per ``SlamConfig.observation``:
                (r [m], beta [rad]) or (x [m], y [m]); m may be 0 (an empty list is fine).
            R: (2, 2) noise covariance for all measurements, or (m, 2, 2), in the units of z
                squared ([m^2], [rad^2], [m rad]); symmetric positive definite.
            landmark_ids: (m,) int64, required in ``"known"`` association mode and refused in
                the others. -1 marks a measurement that is not a landmark (rejected).

        Returns:
            (m,) int64: the feature id each measurement went to (a new id when it started a
            feature, -1 when rejected).

        Paired measurements are applied jointly (docs/design.md §3.2: ``S = H P H' + R``,
        ``K = P H' S^-1``, covariance downdate as one symmetric rank-2k update); new
        features are then initialised from the updated robot (``f = g(x_R, z)``).

        Raises:
            ValueError: a bad shape, dtype or value (:class:`dcslam.InvalidArgument`: a
                non-finite or absurd number, an R that is not symmetric positive definite, ids
                missing, refused, repeated in one scan or < -1), naming the argument and row;
                or a scan whose innovation covariance is not finite or not positive definite (a
                known-id measurement of a feature at a predicted range of 1e-300, say); the
                filter is left unchanged. For :class:`DCSlam`, also when a join failed
                (this call ran it, or, threaded, the worker did): the message names the join and
                the step whose update queued it, and the filter is back at its state just before
                that update, every call since undone (docs/design.md §5.4).
        """
        return self._core.update(z, R, landmark_ids)

    def estimate(self) -> Estimate:
        """The whole map with its full covariance, in the frame of the first pose (with the
        past poses kept by ``keep_local_map_poses``; see :class:`Estimate`)."""
        return Estimate._from_core(self._core.estimate())

    def pose(self) -> np.ndarray:
        """(3,) current robot pose in the first pose's frame; cheap (no covariance)."""
        return self._core.pose()

    def resolve(self, ids) -> np.ndarray:
        """Maps ids ever returned by :meth:`update` to the feature holding them now.

        -1 stays -1; the id of a feature removed as spurious (a tentative feature, see
        :class:`EkfSlam`) becomes -1. For :class:`DCSlam`, "now" means after the joins the
        run has done; right after :meth:`estimate` (until the next :meth:`predict` or
        :meth:`update`) it also follows the merges of the joins that estimate() made on copies
        of the stack, so that every id resolves to a landmark of that estimate (or -1).
        """
        return self._core.resolve(ids)

    @property
    def stats(self) -> SlamStats:
        """Per-step timings and counts; see :class:`SlamStats`."""
        return SlamStats(**self._core.stats)

    def run_batch(self, u, Q, z, R, offsets, landmark_ids=None) -> BatchResult:
        """Runs ``predict(u[k], Q[k])`` then ``update`` with step k's measurements for every step,
        in one call into C++ with the GIL released: bitwise what the loop of step calls gives.

        Args:
            u: (N, 3) relative motions x_{R(k-1) R(k)}: x, y [m], phi [rad].
            Q: (N, 3, 3) their covariances, or one (3, 3) for every step; symmetric positive
                semi-definite.
            z: (M, 2) every step's measurements in step order: (r [m], beta [rad]) or (x, y) [m]
                in the sensor frame, per ``SlamConfig.observation``.
            R: (M, 2, 2) their covariances, or one (2, 2) for every measurement; symmetric
                positive definite.
            offsets: (N + 1,) integers; step k owns rows ``offsets[k]:offsets[k + 1]`` of z, R
                and landmark_ids (``offsets[0] == 0``, non-decreasing, ``offsets[N] == M``).
            landmark_ids: (M,) integers, required in ``"known"`` association mode and refused in
                the others; -1 marks a measurement that is not a landmark.

        Arrays that are float64 (ids and offsets int64) and C-contiguous are read in place;
        others are converted once.

        Returns:
            :class:`BatchResult`: every measurement's id, the online trajectory (N + 1, 3) and
            each step's wall time.

        Raises:
            ValueError (:class:`dcslam.InvalidArgument` for values): a bad shape or dtype,
            naming the array; a value that ``predict`` or ``update`` would refuse, naming the
            step and its index in the arrays (``"run_batch: step 12 (u[12], Q[12]): predict:
            argument 'Q' is not positive semi-definite ..."``). Every step is checked before
            the first one runs, so a refused batch leaves the filter unchanged. A D&C join
            that fails during the run raises as :meth:`update` would (the steps before stay
            applied).
        """
        ids, trajectory, step_seconds = self._core.run_batch(u, Q, z, R, offsets, landmark_ids)
        return BatchResult(ids=ids, offsets=np.asarray(offsets, dtype=np.int64), trajectory=trajectory,
                           step_seconds=step_seconds)

    def run(self, source: Any) -> BatchResult:
        """Runs every step of ``source`` with :meth:`run_batch`.

        ``source`` is a dataset (:class:`~dcslam.datasets.VictoriaPark`,
        :class:`~dcslam.datasets.Isam2d`, :class:`~dcslam.datasets.MrClam`), a
        :class:`~dcslam.Simulation`, their ``steps``, or a :class:`~dcslam.packed.PackedSteps`:
        their arrays are used in place, with their landmark ids in ``"known"`` association
        mode. Any other iterable of step objects (``s.u, s.Q, s.z, s.R``, and
        ``s.landmark_ids`` in ``"known"`` mode, as a :class:`~dcslam.packed.Step` has them) is
        packed first, each value converted as :meth:`predict` and :meth:`update` convert
        theirs (a bad one raises ``ValueError`` naming the step).
        """
        use_ids = self._config.association == "known"
        if not isinstance(source, PackedSteps) and hasattr(source, "packed_steps"):
            source = source.packed_steps()
        if isinstance(source, PackedSteps):
            return self.run_batch(source.u, source.Q, source.z, source.R, source.offsets,
                                  source.landmark_ids if use_ids else None)
        packed = _core.pack_steps(((s.u, s.Q, s.z, s.R, s.landmark_ids if use_ids else None) for s in source),
                                  use_ids)
        return self.run_batch(*packed)


class EkfSlam(SlamFilter):
    """Sparse-aware EKF SLAM on one map (docs/design.md §3; Paz et al. 2007, §II).

    Cost per step O(n) except the covariance downdate, O(n^2), done in one pass over one
    triangle of P. Data association (``cfg.association``):

    - ``"known"``: landmark ids given to :meth:`update`;
    - ``"nn"``: nearest neighbour among individually compatible features (2-dof chi-square
      gate at ``cfg.gate_confidence``);
    - ``"jcbb"``: Joint Compatibility Branch and Bound over the scan (most pairings, then
      lowest joint Mahalanobis distance; with ``cfg.unexplained_density > 0`` the highest
      likelihood ratio against leaving measurements unexplained), at most
      ``cfg.jcbb_max_nodes`` tree nodes per scan; ``stats.counters`` has ``"jcbb_nodes"``
      and ``"jcbb_bound_hits"``.

    Candidates come from a spatial hash of the feature means queried with a radius that
    provably contains every gate-passing feature, so a step's association is O(m) for a
    bounded sensor range (docs/data_association.md). In ``"nn"``/``"jcbb"`` a measurement
    compatible with no feature starts one; one that is compatible with some feature but left
    unpaired (e.g. two measurements competing for one feature) starts one only when every
    hypothesis pairing it is less likely than the chosen one by more than
    ``cfg.new_feature_margin`` (``"jcbb"`` with the likelihood criterion;
    ``stats.counters["unexplained_started"]`` counts them), and is otherwise rejected (id
    -1) rather than duplicating a landmark.

    Spurious measurements: a new feature is tentative until seen ``cfg.min_sightings``
    times; a tentative feature not seen for more than ``cfg.tentative_window`` steps is
    removed from the map (exact marginalisation), and from then on :meth:`resolve` maps its
    id to -1 (``stats.counters["tentative_removed"]`` counts them). ``"known"`` mode never
    removes features.

    Args:
        cfg: the run's options; default ``SlamConfig()``.
    """

    def __init__(self, cfg: Optional[SlamConfig] = None):
        cfg = SlamConfig() if cfg is None else cfg
        super().__init__(_core.EkfSlam(cfg._to_core()), cfg)


@dataclasses.dataclass(frozen=True)
class DCSlamStats(SlamStats):
    """:class:`SlamStats` plus the D&C join events and the stack's shape.

    Attributes:
        joins: one dict per join in creation order: ``index``, ``leaves`` (local maps in the
            result), ``step_created``, ``step_finished`` (-1 while pending),
            ``features_first``, ``features_second``, ``features_joined``, ``overlap``,
            ``pairings``, ``deferred_pairings`` (a weak join's pairs left to the next join's
            decision, or a large join's doubtful pairs, ``cfg.weak_join_pairings``),
            ``alternatives_taken`` (0-2: inputs of which it joined a version other than the
            one made), ``duplicates_merged`` (duplicated features merged in its result,
            ``cfg.join_merge_max_leaves``), ``tries`` (RJC), ``chunked`` (its pairs are chunked JCBB's, which
            paired more than RJC, ``cfg.chunked_jcbb_min_overlap``), ``widened`` (its pairs are a second
            search's at a wider gate, made where RJC paired less than half its overlap and
            pairing more), ``iterations`` (linearisation points of the
            constraint update, at most ``cfg.join_iterations``; 0 without pairings),
            ``seconds`` (summed over the slices it ran in), ``seconds_association``,
            ``work_units`` (all three include the associations of the version combinations
            not chosen and the joins of the other versions).
        stack: (local maps, features) of each map on the stack, bottom first.
        fold_joins: the joins of the last :meth:`DCSlam.estimate`'s final fold (the stack's
            maps, top first, each joined with everything after it; empty before the first
            ``estimate()``), as dicts with the keys of ``joins``: ``index`` is the position in
            the fold, ``leaves`` the local maps joined so far, ``step_created`` and
            ``step_finished`` the step ``estimate()`` was called at. Its last join closes
            whatever loop the run ended on.
        side_joins: the joins still pending that the last :meth:`DCSlam.estimate` computed on
            the side (or took as an earlier call computed them), in creation order, with the
            keys of ``joins``, each as ``joins`` will report the real join once it has run:
            ``index`` is its index in ``joins``, ``step_finished`` the step of the
            ``estimate()`` that computed it. The fold joins their results with the rest.
    """

    joins: List[Dict[str, Any]] = dataclasses.field(default_factory=list)
    stack: List[tuple] = dataclasses.field(default_factory=list)
    fold_joins: List[Dict[str, Any]] = dataclasses.field(default_factory=list)
    side_joins: List[Dict[str, Any]] = dataclasses.field(default_factory=list)


class DCSlam(SlamFilter):
    """Divide and Conquer SLAM (Paz et al. 2007, Algorithm 2; docs/design.md §4-§5).

    Local maps of ``cfg.local_map_features`` features are built with the sparse-aware EKF
    and joined as a binary tree with map joining 2.0; the result is the EKF's answer (exact
    in the linear-Gaussian case) at O(n) cost per step (amortized) and O(n^2) in total.
    Joins run immediately (``amortize=False``), spread over the following steps
    (``amortize=True``, default) or on a background thread (``threaded_joins=True``), with
    bitwise the same result. :meth:`estimate` joins the whole stack on copies (anytime) and
    never disturbs the run, computing the joins still pending on the side; a join still
    pending at the next call is taken as computed, so watching the map during the run pays
    for each pending join once (``stats.counters["estimate_pending_joins_reused"]``). Its
    cost grows with the map: milliseconds on Victoria Park, about a second on a small scene
    revisited for 1,600 steps. :meth:`pose` is cheap.

    Data association at joins: ``cfg.join_association`` (``"rjc"``, ``"jcbb"`` or
    ``"known"``); :meth:`resolve` maps the id of a feature merged at a join to the feature
    that holds it now, and the id of a tentative feature removed by the spurious-measurement
    policy to -1 (see :class:`EkfSlam`; a closed local map keeps its tentative features, and
    the join with the next map drops those no feature of it matches).

    With ``cfg.keep_local_map_poses`` every join keeps the first map's robot (the pose where
    the second map started) as a past pose, so :meth:`estimate` also returns the robot pose
    at every local-map boundary with its full covariance (``Estimate.past_poses``,
    ``past_pose_ids``, ``joint_covariance``; docs/divide_and_conquer.md).
    """

    def __init__(self, cfg: Optional[SlamConfig] = None):
        cfg = SlamConfig() if cfg is None else cfg
        super().__init__(_core.DCSlam(cfg._to_core()), cfg)

    @property
    def stats(self) -> DCSlamStats:
        """Per-step timings and counts, join events and the stack; see :class:`DCSlamStats`."""
        return DCSlamStats(**self._core.stats, joins=self._core.joins(), stack=self._core.stack_shape(),
                           fold_joins=self._core.fold_joins(), side_joins=self._core.side_joins())

    def join_pairings(self) -> list:
        """What each real join's association saw and decided, by feature id, in the order of
        ``stats.joins``: dicts with ``first_ids`` and ``second_ids`` (int64 arrays, the two
        maps' features) and ``pairs`` ((k, 2) int64 array of (id in the first map, id in the
        second) matched). Empty arrays while a join is pending. A weak join's ``pairs`` (and a
        large join's that kept a version without its doubtful pairs) are those it made until a
        later join decides (``stats.joins``' ``deferred_pairings``),
        then those of the version that join took (its ``alternatives_taken``;
        ``cfg.weak_join_pairings``). Ids are those ``update()`` returned (before
        ``resolve()``), so a simulator's ids label them; see
        ``studies/duplicate_diagnosis.py --joins``. ``merged`` ((d, 2) int64): the duplicates
        merged in the join's result after it, (id merged, id kept) (``cfg.join_merge_max_leaves``;
        empty in :meth:`fold_pairings`). ``disputed`` ((d, 2) int64, as ``pairs``): the pairs
        RJC's best hypothesis made that a rival hypothesis disagrees with, left out
        (``cfg.join_rival_margin``; only the last record of :meth:`fold_pairings` can hold any).

        With a join oracle set (:meth:`set_join_oracle`), each dict also audits the oracle's
        pairing through the join's own model: ``truth_pairs`` ((t, 2) int64, as ``pairs``),
        ``truth_distance_sq`` (t,) the marginal Mahalanobis distance of each true pair,
        ``truth_candidate`` (t,) bool, whether it passed the individual gate that builds the
        candidate lists, and ``truth_consistent`` (t,) bool, whether it passes the decision
        gate given the more certain true pairs (taken in increasing distance): a true pair
        that is not consistent is one the two maps disagree about; and ``own_pairs`` ((o, 2)
        int64), the association's own decision before the oracle corrected it (so that a join
        can be scored in a history the oracle kept right). Empty without an oracle."""
        return [_pairing_record(record) for record in self._core.join_pairings()]

    def fold_pairings(self) -> list:
        """What each join of the last :meth:`estimate`'s final fold saw and decided, as
        :meth:`join_pairings` does for the real joins: the stack's maps, top first, each joined
        with everything after it (the current local map first). Empty before the first
        ``estimate()``."""
        return [_pairing_record(record) for record in self._core.fold_pairings()]

    def side_join_pairings(self) -> list:
        """What each pending join that the last :meth:`estimate` computed on the side saw and
        decided, as :meth:`join_pairings` does for the real joins, in the order of
        ``stats.side_joins``; the real join, once it has run, records the same (a weak join's
        record then changes when a later join takes one of its versions, as in
        :meth:`join_pairings`). Empty before the first ``estimate()`` and when no join was
        pending."""
        return [_pairing_record(record) for record in self._core.side_join_pairings()]

    def set_join_oracle(self, feature_ids, landmark_ids, mode: str = "truth", min_first_features: int = 0,
                        max_first_features: Optional[int] = None) -> None:
        """A research instrument, never for a real run: corrects every join's association with
        the truth, to measure how far it is from what the joined maps allow.

        ``feature_ids`` are ids ``update()`` returned and ``landmark_ids`` the landmark each
        stands for (a simulator's ``true_ids``, e.g. by majority over the measurements a
        previous run gave that id; < 0 for clutter). The local maps do not depend on the
        joins, so a second run with the same seed returns the same ids. ``mode``:
        ``"truth"`` pairs each feature of the second map with the first unused feature of its
        landmark in the first map; ``"among_candidates"`` does so only where that feature is
        among the individually compatible candidates; ``"remove_wrong"`` keeps the
        association's own pairs less the wrong ones; ``"audit"`` changes nothing and records
        the oracle's pairing in :meth:`join_pairings` (why a true pair was not made).
        ``min_first_features`` corrects only the joins whose first map holds at least that
        many features, and ``max_first_features`` (if given) only those whose first map holds
        at most that many (the others are audited and left as they are), to tell which joins'
        mistakes decide the final map. Only before the first ``predict()``.
        See ``studies/join_association_ceiling.py``."""
        features = np.asarray(feature_ids)
        landmarks = np.asarray(landmark_ids)
        if features.ndim != 1 or landmarks.shape != features.shape:
            raise ValueError(f"set_join_oracle: feature_ids and landmark_ids must be 1-D of one length, "
                             f"got shapes {features.shape} and {landmarks.shape}")
        for name, values in (("feature_ids", features), ("landmark_ids", landmarks)):
            if values.size and not np.issubdtype(values.dtype, np.integer):
                raise ValueError(f"set_join_oracle: {name} must be integers, got dtype {values.dtype}")
        if not _is_integer(min_first_features):
            raise ValueError(f"set_join_oracle: min_first_features must be an integer, got {min_first_features!r}")
        if max_first_features is not None and not _is_integer(max_first_features):
            raise ValueError(f"set_join_oracle: max_first_features must be an integer, got {max_first_features!r}")
        self._core.set_join_oracle(features.astype(np.int64).tolist(), landmarks.astype(np.int64).tolist(), mode,
                                   int(min_first_features), None if max_first_features is None else int(max_first_features))

    def finish_joins(self) -> None:
        """Completes every queued join now (waits for the worker in threaded mode).

        Raises ``ValueError`` (:class:`dcslam.InvalidArgument`) when a join fails, after putting
        the filter back at its state before the update that queued it (docs/design.md §5.4)."""
        self._core.finish_joins()


def _is_integer(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _pairing_record(record: dict) -> dict:
    """A join's pairing record from the compiled module, as numpy arrays."""
    return dict(
        first_ids=np.asarray(record["first_ids"], dtype=np.int64),
        second_ids=np.asarray(record["second_ids"], dtype=np.int64),
        pairs=np.asarray(record["pairs"], dtype=np.int64).reshape(-1, 2),
        truth_pairs=np.asarray(record["truth_pairs"], dtype=np.int64).reshape(-1, 2),
        truth_distance_sq=np.asarray(record["truth_distance_sq"], dtype=float),
        truth_candidate=np.asarray(record["truth_candidate"], dtype=bool),
        truth_consistent=np.asarray(record["truth_consistent"], dtype=bool),
        own_pairs=np.asarray(record["own_pairs"], dtype=np.int64).reshape(-1, 2),
        merged=np.asarray(record["merged"], dtype=np.int64).reshape(-1, 2),
        disputed=np.asarray(record["disputed"], dtype=np.int64).reshape(-1, 2))
