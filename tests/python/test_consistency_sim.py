"""Monte Carlo consistency of the robot heading on the straight trajectory (Paz et al. 2007,
§III.C, Fig. 4): the EKF starts consistent and becomes optimistic; D&C stays consistent.

20 runs of 150 steps with the paper's noise and known association. The mean consistency
index is averaged over the runs and over a few checkpoints: the first 30 steps ("early") and
the last 30 ("late"). Measured with 14 base seeds (0, 1000, ..., 13000): EKF early 0.28-0.72,
EKF late 2.0-4.7, D&C early 0.20-0.52, D&C late 0.27-0.80; the bounds below leave room for
other seeds.
"""

import math

import numpy as np
import pytest

import dcslam
from dcslam.consistency import chi2_threshold

RUNS = 20
STEPS = 150
EARLY = (10, 20, 30)
LATE = (120, 135, 150)


def heading_ci(slam, sim, step):
    est = slam.estimate()
    error = math.remainder(est.robot[2] - sim.poses[step][2], 2 * math.pi)
    return error**2 / est.covariance[2, 2] / chi2_threshold(1, 0.05)


@pytest.fixture(scope="module")
def mean_heading_ci():
    """{"ekf"|"dc": {checkpoint step: CI averaged over the runs}}."""
    per_run = {"ekf": {k: [] for k in EARLY + LATE}, "dc": {k: [] for k in EARLY + LATE}}
    for seed in range(RUNS):
        sim = dcslam.simulate("straight", steps=STEPS, seed=seed)
        cfg = dcslam.SlamConfig(association="known", join_association="known", seed=seed)
        for name, slam in (("ekf", dcslam.EkfSlam(cfg)), ("dc", dcslam.DCSlam(cfg))):
            done = 0
            for step in EARLY + LATE:
                slam.run(sim.steps[done:step])
                done = step
                per_run[name][step].append(heading_ci(slam, sim, step))
    return {name: {k: float(np.mean(v)) for k, v in cis.items()} for name, cis in per_run.items()}


def window_mean(curve, steps):
    return float(np.mean([curve[k] for k in steps]))


def test_ekf_heading_is_consistent_early(mean_heading_ci):
    assert window_mean(mean_heading_ci["ekf"], EARLY) < 1.0


def test_ekf_heading_becomes_optimistic(mean_heading_ci):
    assert window_mean(mean_heading_ci["ekf"], LATE) > 1.5


def test_dc_heading_stays_consistent_and_beats_ekf(mean_heading_ci):
    dc_late = window_mean(mean_heading_ci["dc"], LATE)
    assert window_mean(mean_heading_ci["dc"], EARLY) < 1.0
    assert dc_late < 1.0
    assert dc_late < 0.5 * window_mean(mean_heading_ci["ekf"], LATE)
