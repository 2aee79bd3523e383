"""SLAM configuration: a plain dataclass mirrored by the compiled ``_core.SlamConfig``."""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, Mapping, Optional, Tuple

import numpy as np

from . import _core

__all__ = ["SlamConfig", "Observation", "Association", "JoinAssociation"]

# The option strings, for type checkers and editors; SlamConfig.validate() checks them at run time.
Observation = Literal["range_bearing", "point"]
Association = Literal["known", "nn", "jcbb"]
JoinAssociation = Literal["rjc", "jcbb", "known"]


def _is_boolean(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def to_core_struct(values: Any, core: Any, name: str) -> Any:
    """Copies every field of the dataclass ``values`` onto the compiled struct ``core`` and
    runs its ``validate()``: type and range errors become ``ValueError`` naming the field.

    The compiled struct's default value tells a field's type. Booleans and numbers are kept
    apart, which the compiled setters would not do: they read None, 2 or 0.5 as a boolean
    and True as the number 1."""
    for field in dataclasses.fields(values):
        value = getattr(values, field.name)
        default = getattr(core, field.name)
        if isinstance(default, bool) and not _is_boolean(value):
            raise ValueError(f"{name}.{field.name}: expected True or False, got {value!r}")
        numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
        # An optional number (None by default, as SimulationConfig.side_steps) is told by its annotation.
        numeric = numeric or (default is None and ("int" in str(field.type) or "float" in str(field.type)))
        if numeric and _is_boolean(value):
            raise ValueError(f"{name}.{field.name}: expected a number, got {value!r}")
        try:
            setattr(core, field.name, value)
        except TypeError:  # a wrong Python type, or an integer the compiled field cannot hold
            # pybind11's own message lists every overload over several lines: one short line instead.
            kind = "None or a number" if default is None else type(default).__name__
            shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
            raise ValueError(f"{name}.{field.name}: invalid value {shown} (expected {kind}"
                             f"{' that the field can hold' if kind != 'str' else ''})") from None
    core.validate()
    return core


@dataclasses.dataclass
class SlamConfig:
    """Options of an :class:`~dcslam.EkfSlam` or :class:`~dcslam.DCSlam` run.

    Every field has a default. Option values are checked when a filter is built (or by
    :meth:`validate`): an unknown name or an out-of-range number raises ``ValueError``
    naming the field.

    Attributes:
        observation: ``"range_bearing"`` (r, beta) or ``"point"`` ((x, y) in the sensor frame).
        sensor_offset: sensor pose (x, y, phi) on the robot.
        association: data association inside local maps: ``"known"``, ``"nn"`` or ``"jcbb"``.
        gate_confidence: chi-square confidence of the individual/joint compatibility tests
            (0.999; Victoria Park's preset 0.99).
        unexplained_density: ``"jcbb"``: expected measurements per scan and per m^2 that no
            mapped feature explains (clutter and first sightings). 0: JCBB keeps the
            hypothesis with most pairings; > 0 (default 0.02): the most likely one against
            leaving measurements unexplained at that density (docs/data_association.md,
            "Likelihood criterion").
        new_feature_margin: ``"jcbb"`` with ``unexplained_density > 0``: a measurement left
            unpaired although compatible with mapped features starts a tentative feature
            when every hypothesis pairing it is less likely than the chosen one by more than
            this natural-log likelihood ratio (default 5, about 150 to 1); otherwise it is
            rejected (id -1). ``math.inf``: always rejected (docs/data_association.md,
            "Unexplained measurements beside mapped features").
        new_feature_beside_tentative: ``"nn"``/``"jcbb"`` with ``min_sightings > 1``: a
            measurement left unpaired whose compatible features are all still tentative
            starts a feature on probation instead of being rejected (whatever
            ``new_feature_margin`` says): its first sighting, a close call, does not count, so
            ``min_sightings`` more confirm it. Most tentative features are clutter; a rejection
            beside them loses a landmark's first sighting. ``False`` (default): rejected. On the
            simulated scenes ``True`` raises recall by 0.01-0.02 but maps more landmarks twice
            and leaves D&C's robot further off on the paper's straight trajectory
            (docs/data_association.md, "Unpaired beside tentative features only").
        confirmed_first_confidence: ``"nn"``/``"jcbb"`` with ``min_sightings > 1``: a
            measurement within this confidence region (chi-square, 2 dof) of a confirmed
            feature is not offered to the tentative features, so it cannot confirm one. A
            clutter point beside a landmark starts a tentative feature whose wide covariance
            would otherwise take the landmark's next measurement and become a second feature
            of it. Only close calls are restricted: a measurement far out in its landmark's
            gate may still pair with a tentative feature, which on data with biased sightings
            (MR.CLAM) is often the only way its landmark is recognised. ``None``: every
            compatible feature is a candidate (docs/data_association.md, "Confirmed features
            first").
        jcbb_max_nodes: ``"jcbb"``: interpretation-tree nodes per scan (>= 1) before JCBB
            returns the best hypothesis found so far (counted in ``stats.counters``
            ``"jcbb_bound_hits"``).
        min_sightings: ``"nn"``/``"jcbb"``: a new feature is tentative until it has been
            seen this many times (>= 1; 1 turns the spurious-measurement policy off).
        tentative_window: ``"nn"``/``"jcbb"``: a tentative feature not seen for more than
            this many steps (>= 1) is removed from the map (its id then resolves to -1).
            Never applied in ``"known"`` mode, where the caller's ids are trusted.
        merge_radius: ``"nn"``/``"jcbb"``: two features of one map that were never paired
            in the same scan, lie within this distance (m) and are each other's only
            compatible feature at ``gate_confidence`` are merged into the older one (its
            id is what :meth:`resolve` then returns for both). 2.0 by default; 0 never
            merges (docs/data_association.md, "Duplicated features").
        final_merge_confidence: D&C only: confidence of that merge test in the final merge of
            :meth:`~dcslam.DCSlam.estimate` (on the folded map, after every join), in (0, 1);
            ``None`` (default): ``gate_confidence``. That merge decides last, so a wrong one
            bends no later decision; on the simulator's revisit scenes 0.999 raises D&C's
            pairwise recall by 0.01-0.02 at a precision cost of about 0.001
            (docs/data_association.md, "Duplicates merged in D&C's estimate").
        final_merge_shared_scans: D&C only: in that final merge, two features paired in one
            scan (two measurements of one scan are two landmarks, unless one pairing was
            wrong) may still be merged when they were seen together in at most this many
            scans (>= 0) and each was also seen in a scan without the other. 1 by default;
            0 never merges features seen in one scan, the rule of the merges inside a map.
            The EKF ignores it (docs/data_association.md, "Duplicates merged in D&C's
            estimate").
        join_merge_max_leaves: D&C only: after each join whose result spans at most this many
            local maps (>= 0) and keeps no alternative, the joined map's duplicated features
            are merged with the final merge's test, features seen once left out, so that
            larger joins do not meet a landmark twice. 0 (the default) never; with today's
            other defaults 4 raises long_revisits' recall a little (0.878 -> 0.886 over three
            RJC draws) with fewer runs whose robot is within its 99 % bound (22 of 30 against
            25), and leaves the paper's loop as it is (docs/data_association.md, "Duplicates
            merged after small joins").
        weak_join_pairings: D&C only: a join of 8 local maps or more that makes at most this
            many pairs (>= 0), some of them with a feature seen once, is weak: it also builds
            its result without those pairs and, from 16 local maps, without any pair, and
            the next join (or the final fold of :meth:`~dcslam.DCSlam.estimate`) joins the
            versions that score highest, twice its own pairs plus the weak join's; the
            fold, where the rest of the run is known, counts for a weak fold join of 8 local
            maps or more the pairs of every fold join after it.
            One wrong pair between features seen once at such a join bends both maps, and
            the next join then duplicates a whole lap's landmarks. A join of 16 local maps
            or more that makes more pairs than this keeps its result without its doubtful
            pairs (a rival candidate nearly as close) when they are at least a tenth of
            its pairs, decided the same way. 30 (default) by
            measurement on the simulator's revisit scenes; 0: off, every join's pairs are
            final when made (docs/data_association.md, "Weak joins decided by the next
            join" and "Large joins' doubtful pairs, decided by the next join").
        local_map_features: D&C closes a local map when it holds this many features.
        join_association: association at D&C joins: ``"rjc"``, ``"jcbb"`` or ``"known"``.
        rjc_b, rjc_p_good, rjc_p_fail: RJC (Paz et al. 2007, Alg. 3) parameters. At most
            t = log(rjc_p_fail) / log(1 - rjc_p_good^rjc_b) tries: 14 at the defaults.
            rjc_p_fail 0.001 (0.01 until 2026-12-06) by measurement on the revisit scenes
            (docs/data_association.md, "D&C's map depends on RJC's draws").
        rjc_exchange_crossed: D&C: each RJC try's hypothesis (its conditional pairings taken
            nearest first, each feature once) exchanges the features of two pairings when the
            sum of their distances falls: two close landmarks, each a feature in both maps,
            are otherwise often paired crosswise. True (default) by measurement: D&C's recall
            without ids as high or higher on every simulated scene (lawn_overlap 0.938 ->
            0.940, the snail 0.931 -> 0.937, long_revisits 0.932 -> 0.942 over three RJC
            draws), Victoria Park's map 401 landmarks instead of 402 (docs/data_association.md,
            "Crossed pairings exchanged"). False: each try's greedy hypothesis as it is.
        join_iterations: D&C: linearisation points of each join's constraint update (>= 1).
            The join re-linearises the move of the second map into the first's frame at the
            constrained estimate until it stops moving (an iterated EKF); 1 linearises once,
            at the prior means (docs/divide_and_conquer.md).
        join_feature_sigma: D&C joins' compatibility tests only: a per-feature position
            error in metres (>= 0) that repeated sightings do not average out, added as
            ``join_feature_sigma**2 * I`` to each feature of a tested pair; the update still
            imposes the pairs exactly (and in the test of the duplicate merge that ends
            :meth:`~dcslam.DCSlam.estimate`). 0.01 (default) by measurement: a local EKF's
            linearisation leaves each feature about 1 cm of error, relative to the others of
            its map, that its covariance does not hold (docs/data_association.md, "A feature
            error at the joins"); 0: the maps' covariances alone. Victoria Park's config sets
            0.1 from the data (docs/victoria_park.md).
        large_overlap_confidence: D&C: confidence (in (0, 1)) of RJC's tests at a join whose
            overlap holds at least 50 features; ``gate_confidence`` at every other join.
            There many pairings settle the maps' relative pose, so a tight gate only turns
            true pairs away, and a true pair turned away at a join is a landmark mapped twice
            for good. 0.999 (default) by measurement on the simulator's revisit scenes, when
            the gate was 0.99; with the default gate (0.999 since) it is one gate everywhere
            (docs/data_association.md, "Large overlaps decided at a wider gate").
        chunked_jcbb_min_overlap: D&C: from this overlap on (features of the second map with
            a candidate; >= 0), a join that RJC has paired is decided a second time by
            chunked JCBB, and the hypothesis with more pairings is kept: the second map's
            features in map order, 32 at a time, each chunk by JCBB conditioned on the
            pairings of the chunks before it, as the EKF pairs sighting after sighting. At a
            whole-lap join the two maps have drifted apart along the lap, and RJC's tries,
            seeded on a few pairs drawn from the whole overlap, pair only part of it. 100
            (default) by measurement on the simulator's revisit scenes; 0: RJC alone
            (docs/data_association.md, "The EKF's order at large joins").
        join_rival_margin: D&C: at the last join of :meth:`~dcslam.DCSlam.estimate`'s fold
            (the newest local maps against the rest of the map, which no later join decides),
            when its overlap holds at least 100 features, every RJC try within this many
            pairings of the best one (>= 0) is verified, and a try that agrees with fewer than
            80 % of its own pairings (made by the best try too, or compatible with all of the
            best's) is a rival: another alignment of the two maps that the data support nearly
            as well. The join keeps only the best try's pairings that every rival makes too
            (and chunked JCBB, which decides by count, does not replace them). A loop closed by
            a few pairings at the end of a run then stays open rather than closing wrong: the
            robot keeps its uncertainty instead of ending tens of metres off with a covariance
            of centimetres. 3 (default) by measurement on the paper's loop and the revisit
            scenes; None: the best try as it is (docs/data_association.md, "The fold's last
            join commits only to what its rivals agree on").
        tree_relinearisation: D&C: damped Gauss-Newton passes (>= 0) that
            :meth:`~dcslam.DCSlam.estimate` makes through the whole tree of joins: every kept
            local map is rebuilt from its own odometry and measurements, and every join
            redone, all linearised at the previous pass's map, each pass's step shortened
            until it does not raise the batch objective; until no mean moves by more than
            1e-9 (m or rad). Converged, the estimate is the batch least-squares optimum of
            the run's own associations (every pose and landmark) with its full covariance
            (docs/divide_and_conquer.md, "Re-linearised joins through the tree"). 0
            (default): the paper's D&C, nothing kept; chosen by measurement: on Victoria Park
            one pass brings the map from 1.62 m to 0.019 m RMS of that optimum, but costs
            about as much CPU again as the whole plain run (1.9x its total). The passes may
            stop before this many (``tree_relinearisation_tolerance``).
        tree_relinearisation_tolerance: D&C: the re-linearisation passes stop early once a
            pass, taken whole, predicts that another could lower the batch objective (a sum
            of squared whitened residuals) by at most this much: its result's objective less
            the minimum of the linearised problem it solved (``stats.counters``'
            ``relinearisation_objective`` and ``relinearisation_predicted_objective``). The
            map then lies within ``sqrt(tolerance)`` standard deviations of the optimum in
            every direction. 3.84 (default; chi-square's 95 % point for one degree of
            freedom), by measurement: one pass on Victoria Park, two on the iSAM file
            (docs/divide_and_conquer.md, "When the passes stop"). 0: every pass, or until no
            mean moves by more than 1e-9 (the optimum to rounding).
        seed: every random choice is reproducible from it.
        amortize: D&C spreads each join over the following steps (docs/design.md §5.3).
        threaded_joins: D&C runs joins on a background thread while mapping goes on
            (same result as ``amortize``; uses a second core).
        estimate_threads: D&C: threads ``estimate()`` may use for the parts of its final fold
            that do not depend on each other (the associations of a join's candidate
            versions, the rest of the fold carried through each version of a weak fold
            join, each join's fill a column block per thread) and of the re-linearisation
            passes (``tree_relinearisation``: the leaves' fits and rebuilds, the joins of
            disjoint subtrees); the estimate is bitwise the same for every count. 0 (default): every
            hardware thread; 1: the calling thread only (one core per process, say, when
            runs are spread over processes).
        keep_local_map_poses: D&C keeps the robot pose at every local-map boundary in the
            map, with its covariance: ``Estimate.past_poses``, ``past_pose_ids`` and
            ``joint_covariance`` (docs/design.md §4.5). No effect on :class:`~dcslam.EkfSlam`.
        online_localisation_sigma: D&C: when a local map closes, its features are paired
            with the oldest map's (the join association) and the pose the next local map
            starts from is conditioned on those pairs (5 at least), if the chain of maps
            between the two leaves that pose with a position standard deviation of at most
            this many metres: :meth:`~dcslam.DCSlam.pose` and the online trajectory then know
            of a place seen again before the joins reach it. The maps and
            :meth:`~dcslam.DCSlam.estimate` are unchanged. Larger loops are left to the
            joins. 10 suited the simulated scenes and Victoria Park (whose online trajectory
            it brings from 5.31 to 4.52 m RMS of the GPS, for 6 % more of D&C's work; with
            amortized or threaded joins each localisation is spread over the steps after its
            closure, so the worst step does not grow); ``math.inf``: always. ``None`` (default, the paper's D&C): the pose
            composes the stack's maps (docs/divide_and_conquer.md, "The online pose on places
            seen again", has the measurements). No effect on :class:`~dcslam.EkfSlam`.
    """

    observation: Observation = "range_bearing"
    sensor_offset: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    association: Association = "jcbb"
    gate_confidence: float = 0.999
    unexplained_density: float = 0.02
    new_feature_margin: float = 5.0
    new_feature_beside_tentative: bool = False
    confirmed_first_confidence: Optional[float] = 0.9
    jcbb_max_nodes: int = 20000
    min_sightings: int = 2
    tentative_window: int = 5
    merge_radius: float = 2.0
    final_merge_confidence: Optional[float] = None
    final_merge_shared_scans: int = 1
    join_merge_max_leaves: int = 0
    weak_join_pairings: int = 30
    local_map_features: int = 30
    join_association: JoinAssociation = "rjc"
    rjc_b: int = 4
    rjc_p_good: float = 0.8
    rjc_p_fail: float = 0.001
    rjc_exchange_crossed: bool = True
    join_iterations: int = 10
    join_feature_sigma: float = 0.01
    large_overlap_confidence: float = 0.999
    chunked_jcbb_min_overlap: int = 100
    join_rival_margin: Optional[int] = 3
    tree_relinearisation: int = 0
    tree_relinearisation_tolerance: float = 3.841458820694124
    seed: int = 0
    amortize: bool = True
    threaded_joins: bool = False
    estimate_threads: int = 0
    keep_local_map_poses: bool = False
    online_localisation_sigma: Optional[float] = None

    def _to_core(self) -> "_core.SlamConfig":
        return to_core_struct(self, _core.SlamConfig(), "SlamConfig")

    def validate(self) -> "SlamConfig":
        """Checks every field; raises ``ValueError`` naming the first bad one."""
        self._to_core()
        return self

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def _from_core(cls, core: "_core.SlamConfig") -> "SlamConfig":
        """The options of a compiled ``_core.SlamConfig`` (a C++ preset), as the dataclass."""
        values = {f.name: getattr(core, f.name) for f in dataclasses.fields(cls)}
        values["sensor_offset"] = tuple(float(v) for v in values["sensor_offset"])
        return cls(**values)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "SlamConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"SlamConfig: unknown field(s) {', '.join(unknown)}")
        return cls(**dict(values))
