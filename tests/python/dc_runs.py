"""A D&C run over a simulation without ids, as the revisit tests make it, optionally
interrupted at one step (to checkpoint the filter, or to call estimate() in the middle)."""

import pickle

import dcslam


def run_dc(sim, config, *, split=None, at_split=None):
    """Runs every step; at step `split`, `at_split(slam)` may return a replacement filter.
    Returns the filter, the ids each update returned and the final estimate()."""
    slam = dcslam.DCSlam(config)
    returned = []
    for k, step in enumerate(sim.steps):
        if k == split:
            slam = at_split(slam) or slam
        slam.predict(step.u, step.Q)
        returned.append(slam.update(step.z, step.R))
    estimate = slam.estimate()
    return slam, returned, estimate


def pickled(slam):
    """A copy of the filter through pickle, as a run resumed in another process has it."""
    return pickle.loads(pickle.dumps(slam))
