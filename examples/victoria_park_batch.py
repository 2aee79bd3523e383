"""Victoria Park in one call from Python, checkpointed half-way and resumed.

    python examples/victoria_park_batch.py
"""

import pickle

import numpy as np

import dcslam

vp = dcslam.datasets.victoria_park()
slam = dcslam.DCSlam(vp.slam_config())
half = len(vp.steps) // 2
rows = int(vp.offsets[half])
# The first half from the packed arrays, in one call into C++ with the GIL released.
first = slam.run_batch(vp.u[:half], vp.Q[:half], vp.z[:rows], vp.R[:rows], vp.offsets[: half + 1])
print(f"{len(first)} scans, {len(first.ids)} measurements, {first.step_seconds.sum():.3f} s in the filter")

# A checkpoint: pickle holds the whole filter, pending joins included.
saved = pickle.dumps(slam)
resumed: dcslam.DCSlam = pickle.loads(saved)
second = resumed.run_batch(vp.u[half:], vp.Q[half:], vp.z[rows:], vp.R[rows:], vp.offsets[half:] - rows)
resumed.finish_joins()
estimate = resumed.estimate()
trajectory = np.vstack([first.trajectory, second.trajectory[1:]])
print(f"checkpoint {len(saved) / 1e6:.1f} MB; {len(estimate.landmarks)} landmarks; "
      f"online trajectory {trajectory.shape}")
