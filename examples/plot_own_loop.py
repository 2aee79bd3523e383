"""A loop of your own, then its map drawn: landmarks and robot with their 95 % ellipses, the
poses the loop saw, and the simulator's truth. Writes own_loop_map.png."""

import numpy as np

import dcslam
import dcslam.plots

sim = dcslam.simulate("loop", steps=200, seed=1)
slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc"))
poses = [slam.pose()]
for s in sim.steps:
    slam.predict(s.u, s.Q)
    slam.update(s.z, s.R)
    poses.append(slam.pose())
dcslam.plots.plot_map(slam.estimate(), "own_loop_map.png", truth=sim, trajectory=np.array(poses))
