"""The README's first example: D&C SLAM closes a simulated 400 m loop without landmark ids."""

import numpy as np

import dcslam

sim = dcslam.simulate("loop", steps=400, seed=1)          # the paper's simulator: a 400 m loop
cfg = dcslam.SlamConfig(association="jcbb", join_association="rjc")   # no landmark ids
slam = dcslam.DCSlam(cfg)                                  # or dcslam.EkfSlam(cfg)
for s in sim.steps:
    slam.predict(s.u, s.Q)
    slam.update(s.z, s.R)        # with association="known": slam.update(s.z, s.R, s.landmark_ids)
est = slam.estimate()            # robot (3,), landmarks (n, 2), landmark_ids, covariance
print(np.linalg.norm(est.robot[:2] - sim.poses[-1][:2]))  # 0.02 m: the loop is closed
print(est.landmarks.shape, est.covariance.shape, slam.stats.joins[-1])
