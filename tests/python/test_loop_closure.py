"""The README's loop (400 steps, the paper's simulator, seed 1) closed without ids by D&C:
JCBB inside local maps, RJC at joins. The final fold joins a 64-leaf map with the last local
maps at a robot uncertainty of about 7 m, where only 23 of 126 overlap features have their
true partner; RJC's constellation tries find them (docs/data_association.md)."""

import numpy as np

import dcslam
from dcslam import evaluation


def test_readme_loop_closes_without_ids():
    sim = dcslam.simulate("loop", steps=400, seed=1)
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc"))
    returned = slam.run(sim.steps)
    estimate = slam.estimate()
    robot = evaluation.robot_scores(estimate, sim.poses[-1])
    # Ground truth from the simulator: the loop is closed (before: 10.5 m off) and the final
    # pose lies inside its own 99 % covariance ellipsoid.
    assert robot.position_error < 0.5
    assert robot.consistent99
    scores = evaluation.association_scores(sim.true_ids, slam.resolve(np.concatenate(returned)))
    assert scores.pairwise_precision > 0.95
    assert scores.features_per_landmark < 1.1
