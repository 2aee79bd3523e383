"""The simulated experiments of Paz et al. 2007 (§III.B and Fig. 3), run in C++.

A uniform random field of point features; the robot moves 1 m a step; odometry noise
sigma = 0.10 m along, 0.05 m across and 0.5 deg in heading; a range–bearing sensor of 3 m
range seeing about 16 features a step, with sigma 5 % of the range and 1 deg in bearing;
four trajectories: ``"straight"`` (forward exploration), ``"loop"`` (a square that closes
on its start), ``"lawn_mowing"`` (parallel back-and-forth lanes) and ``"snail"`` (an
inward square spiral). Ground truth for poses, features and every measurement's feature.

::

    sim = dcslam.simulate("snail", steps=500, seed=0)
    for s in sim.steps:          # step i goes from sim.poses[i] to sim.poses[i + 1]
        slam.predict(s.u, s.Q)   # u: the noisy relative motion, Q its covariance
        slam.update(s.z, s.R)    # taken at sim.poses[i + 1]; s.landmark_ids: ground truth

Noise model: the true poses follow the commanded motions exactly; ``u = u_true + n`` with
``n ~ N(0, Q)``, ``Q = diag(odometry_sigma**2)``. Measurements are
``observe(true pose, true feature) + v``, ``v ~ N(0, R)``, with the range sigma computed
from the TRUE range (so ``R`` does not depend on the noise drawn). Every array is
read-only and shares memory with the single C++ run.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal, Optional, Tuple, get_args

import numpy as np

from . import _core
from .config import Observation, to_core_struct
from .packed import PackedSteps, Step, Steps

__all__ = ["SimulationConfig", "Simulation", "Step", "Steps", "simulate", "REVISIT_SCENARIOS", "revisit_scenario"]

Trajectory = Literal["straight", "loop", "loop_both_ways", "lawn_mowing", "snail"]
TRAJECTORIES = get_args(Trajectory)


@dataclasses.dataclass
class SimulationConfig:
    """Every parameter of a simulation; the defaults are the paper's (§III.B).

    Angles are in radians, lengths in metres. Values are checked in C++ when the simulation
    runs (or by :meth:`validate`); a bad one raises ``ValueError`` naming it.

    Attributes:
        trajectory: ``"straight"``, ``"loop"``, ``"loop_both_ways"``, ``"lawn_mowing"`` or
            ``"snail"``. ``"loop_both_ways"`` drives the square once turning left, turns
            round at the start and drives it back turning right, and again.
        steps: number of motions; the run has ``steps + 1`` poses.
        seed: seeds the one ``mt19937_64`` all draws come from (same seed, same arrays).
        step_length: distance moved each step.
        side_steps: loop side, lawn lane length or snail outer side, in steps. ``None``
            chooses it from ``steps``: loop side ``steps // 4`` (the loop closes on its
            start, further steps run more laps); ``loop_both_ways`` side ``steps // 8``; lane length ``round(sqrt(steps *
            lane_spacing_steps))`` (a roughly square swept region); the smallest snail whose
            spiral holds ``steps``.
        lane_spacing_steps: distance between lawn lanes and between snail rings, in steps
            (3 = the sensor range, so neighbouring passes share features).
        odometry_sigma: standard deviations along, across and in heading.
        zero_heading_noise: force the heading sigma to zero (known heading: with
            ``observation="point"`` the problem is linear).
        observation: ``"range_bearing"`` or ``"point"`` ((x, y) in the sensor frame).
        sensor_offset: sensor pose (x, y, phi) on the robot.
        max_range, min_range: detection range; the blind zone below ``min_range`` keeps
            ``R`` positive definite (range sigma is proportional to range).
        fov: full field of view, centred on the sensor's x axis (``2 pi``: all around).
        range_sigma_fraction, bearing_sigma: range-bearing noise (sigma_r = fraction * r);
            > 0 with ``"range_bearing"``, as the filters need a positive definite ``R``.
        point_sigma: isotropic sigma of the ``"point"`` model; > 0 with ``"point"``.
        features_per_step: expected features in the sensor footprint; sets the density to
            ``features_per_step / (fov / 2 * (max_range**2 - min_range**2))``.
        num_features: if set, this many features instead (density follows): 100 to 20,000+.
        world_margin: features fill the corridor of points within this distance of the
            trajectory's positions (not its bounding box: a loop's unseen interior stays
            empty); ``None`` = ``max_range + |sensor offset|``, so every footprint is full.
        clutter: expected fraction of all measurements that are spurious, in [0, 1);
            spurious ones are uniform over the footprint and have ``true_ids == -1``.
    """

    trajectory: Trajectory = "straight"
    steps: int = 500
    seed: int = 0
    step_length: float = 1.0
    side_steps: Optional[int] = None
    lane_spacing_steps: int = 3
    odometry_sigma: Tuple[float, float, float] = (0.10, 0.05, math.radians(0.5))
    zero_heading_noise: bool = False
    observation: Observation = "range_bearing"
    sensor_offset: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_range: float = 3.0
    min_range: float = 0.1
    fov: float = 2 * math.pi
    range_sigma_fraction: float = 0.05
    bearing_sigma: float = math.radians(1.0)
    point_sigma: float = 0.05
    features_per_step: float = 16.0
    num_features: Optional[int] = None
    world_margin: Optional[float] = None
    clutter: float = 0.0

    def _to_core(self) -> "_core.SimulationConfig":
        return to_core_struct(self, _core.SimulationConfig(), "SimulationConfig")

    def validate(self) -> "SimulationConfig":
        """Checks every field; raises ``ValueError`` naming the first bad one."""
        self._to_core()
        return self

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Simulation:
    """A simulated run (see :func:`simulate`).

    Attributes:
        config: the :class:`SimulationConfig` that produced it.
        landmarks: (N, 2) true feature positions; ``true_ids`` index its rows.
        poses: (steps + 1, 3) true robot poses, ``poses[0] = (0, 0, 0)``.
        steps: :class:`~dcslam.packed.Steps`, one :class:`~dcslam.packed.Step` per motion,
            its ``landmark_ids`` the features measured (-1: clutter).
        odometry: (steps, 3) all ``u``; ``Q``: (3, 3) their covariance.
        measurements, measurement_covariances, true_ids: every step's ``z``, ``R`` and
            ids concatenated; step i owns rows ``step_offsets[i]:step_offsets[i + 1]``.
    """

    def __init__(self, config: SimulationConfig, arrays: dict):
        self.config = config
        self.landmarks: np.ndarray = arrays["landmarks"]
        self.poses: np.ndarray = arrays["poses"]
        self.odometry: np.ndarray = arrays["odometry"]
        self.Q: np.ndarray = arrays["odometry_covariance"]
        self.Q.flags.writeable = False
        self.measurements: np.ndarray = arrays["measurements"]
        self.measurement_covariances: np.ndarray = arrays["measurement_covariances"]
        self.true_ids: np.ndarray = arrays["true_ids"]
        self.step_offsets: np.ndarray = arrays["step_offsets"]
        self.steps = Steps(self.step_offsets, self._step, self.packed_steps)

    def _step(self, k: int, rows: slice) -> Step:
        return Step(self.odometry[k], self.Q, self.measurements[rows], self.measurement_covariances[rows],
                    landmark_ids=self.true_ids[rows], index=k)

    def packed_steps(self) -> PackedSteps:
        """The arrays behind ``steps`` (one ``Q`` for all), with ``true_ids`` as the landmark
        ids, as :meth:`~dcslam.SlamFilter.run_batch` takes them."""
        return PackedSteps(self.odometry, self.Q, self.measurements, self.measurement_covariances,
                           self.step_offsets, self.true_ids)

    def __repr__(self) -> str:
        return (
            f"Simulation({self.config.trajectory!r}, steps={len(self.steps)}, "
            f"features={len(self.landmarks)}, measurements={len(self.measurements)})"
        )


def simulate(trajectory: Trajectory, steps: int = 500, seed: int = 0, **overrides: Any) -> Simulation:
    """Runs the simulator of Paz et al. 2007 (§III.B, Fig. 3) in one C++ call.

    Args:
        trajectory: ``"straight"``, ``"loop"``, ``"loop_both_ways"``, ``"lawn_mowing"`` or
            ``"snail"``.
        steps: number of motions (the run has ``steps + 1`` poses).
        seed: same seed, bitwise the same arrays.
        **overrides: any other :class:`SimulationConfig` field.

    Raises:
        ValueError: an unknown trajectory or parameter, or a bad value; the message names it.
    """
    known = {f.name for f in dataclasses.fields(SimulationConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"simulate: unknown parameter(s) {', '.join(unknown)}")
    config = SimulationConfig(trajectory=trajectory, steps=steps, seed=seed, **overrides)
    return Simulation(config, _core.simulate(config._to_core()))


# Scenes where the robot comes back to places it has mapped: the test that data association
# without ids must pass (no landmark mapped twice). Each has 10 % clutter and the paper's
# noise; the seed varies the field, the noise and the clutter.
REVISIT_SCENARIOS = {
    # A 10 m square driven four times.
    "small_loop_laps": dict(trajectory="loop", steps=160, side_steps=10, clutter=0.1),
    # A 15 m square driven left, then back turning right, twice.
    "loop_both_ways": dict(trajectory="loop_both_ways", steps=240, side_steps=15, clutter=0.1),
    # Lawn mowing with lanes 2 m apart, inside the 3 m sensor range: every lane overlaps two.
    "lawn_overlap": dict(trajectory="lawn_mowing", steps=600, lane_spacing_steps=2, clutter=0.1),
    # 1,600 steps around a 25 m square both ways: sixteen laps, every place seen again and again.
    "long_revisits": dict(trajectory="loop_both_ways", steps=1600, side_steps=25, clutter=0.1),
}


def revisit_scenario(name: str, seed: int = 0, **overrides: Any) -> Simulation:
    """One of :data:`REVISIT_SCENARIOS`, simulated with ``seed`` (``overrides`` change any
    :class:`SimulationConfig` field).

    Raises:
        ValueError: an unknown scenario name.
    """
    if name not in REVISIT_SCENARIOS:
        raise ValueError(f"revisit_scenario: unknown scenario {name!r} (expected one of {', '.join(REVISIT_SCENARIOS)})")
    parameters = {**REVISIT_SCENARIOS[name], **overrides}
    trajectory = parameters.pop("trajectory")
    steps = parameters.pop("steps")
    return simulate(trajectory, steps=steps, seed=seed, **parameters)
