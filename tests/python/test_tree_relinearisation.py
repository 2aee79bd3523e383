"""D&C's re-linearised tree (``SlamConfig.tree_relinearisation``) against an independent
oracle: the least-squares optimum of the same local maps as measurements of the global map,
solved by dense Gauss-Newton with central-difference Jacobians
(``oracles/submap_joining.py``). Also: the passes leave the run itself unchanged, the linear
case stays exact (``test_ekf_slam.py``'s batch oracle), and the option is checked."""

import dataclasses

import numpy as np
import pytest

import dcslam
from oracles import submap_joining


def _rotation(phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


def drive(slam, steps, ids):
    """Runs `steps`, then one motion more, so that the open local map is never one that has
    just started (its robot, at its base with zero covariance, would make the oracle's
    measurement singular). Returns the ids update() gave."""
    returned = []
    for s in steps:
        slam.predict(s.u, s.Q)
        returned.append(slam.update(s.z, s.R, s.true_ids if ids else None))
    slam.predict(steps[-1].u, steps[-1].Q)
    return returned


def run_pair(steps, config, ids=True):
    """The same steps through a plain D&C and one with the re-linearised tree."""
    plain = dcslam.DCSlam(dataclasses.replace(config, tree_relinearisation=0))
    relinearised = dcslam.DCSlam(config)
    return plain, relinearised, (drive(plain, steps, ids), drive(relinearised, steps, ids))


def oracle_problem(slam, plain_estimate):
    """The kept local maps, their features labelled with the ids they end as (resolve() after
    estimate(); a dropped tentative feature, -1 there, is a variable of its own), and a start
    point from the plain D&C estimate (boundary poses kept by keep_local_map_poses)."""
    leaves = slam._core.tree_leaves()
    local_maps = []
    for leaf in leaves:
        raw = np.asarray(leaf["feature_ids"], dtype=np.int64)
        final = slam.resolve(raw)
        ids = [int(f) if f >= 0 else int(r) for f, r in zip(final, raw)]
        local_maps.append(submap_joining.LocalMap(np.asarray(leaf["x"]), np.asarray(leaf["P"]), ids))
    pose_of = {int(i): p for i, p in zip(plain_estimate.past_pose_ids, plain_estimate.past_poses)}
    boundaries = np.array([pose_of[int(leaf["robot_id"])] for leaf in leaves[:-1]])
    known = {int(i): p for i, p in zip(plain_estimate.landmark_ids, plain_estimate.landmarks)}
    start = {}
    for k, local_map in enumerate(local_maps):
        base = np.zeros(3) if k == 0 else boundaries[k - 1]
        for j, fid in enumerate(local_map.feature_ids):
            local = local_map.x[3 + 2 * j:5 + 2 * j]
            start.setdefault(fid, known.get(fid, base[:2] + _rotation(base[2]) @ local))
    return local_maps, start, boundaries


SCENES = [
    # known ids: every join's pairs are the landmarks'
    ("loop", 80, dict(association="known", join_association="known"), True),
    # no ids, clutter: pairs found by JCBB/RJC, tentative features dropped at joins, the
    # estimate's fold and duplicate merge: the tree must redo the run's own decisions
    ("small_loop_laps", 160, dict(), False),
]


@pytest.mark.parametrize("scenario, steps, options, ids", SCENES, ids=[s[0] for s in SCENES])
def test_relinearised_estimate_is_the_least_squares_optimum_of_the_local_maps(scenario, steps, options, ids):
    if scenario in dcslam.simulation.REVISIT_SCENARIOS:
        sim = dcslam.simulation.revisit_scenario(scenario, seed=3, steps=steps)
    else:
        sim = dcslam.simulate(scenario, steps=steps, seed=3)
    config = dcslam.SlamConfig(keep_local_map_poses=True, tree_relinearisation=20, **options)
    plain, relinearised, _ = run_pair(sim.steps, config, ids)
    before = plain.estimate()
    after = relinearised.estimate()
    passes = relinearised.stats.counters["relinearisation_passes"]
    assert 1 <= passes < 20 and relinearised.stats.counters["relinearisation_last_step"] <= 1e-9

    local_maps, start, boundaries = oracle_problem(relinearised, before)
    optimum = submap_joining.solve(local_maps, start, boundaries, before.robot)
    assert optimum.iterations < 30  # converged

    by_id = {int(i): k for k, i in enumerate(after.landmark_ids)}
    assert set(by_id) == {int(i) for i in before.landmark_ids}
    error = max(np.max(np.abs(after.landmarks[k] - optimum.features[i])) for i, k in by_id.items())
    assert error < 1e-6
    assert np.max(np.abs(after.robot[:2] - optimum.robot[:2])) < 1e-6
    assert abs(dcslam.geometry.wrap_angle(after.robot[2] - optimum.robot[2])) < 1e-8
    # The plain tree is measurably elsewhere: the check above can tell the two apart.
    plain_error = max(np.max(np.abs(before.landmarks[k] - optimum.features[int(i)]))
                      for k, i in enumerate(before.landmark_ids))
    assert plain_error > 100 * error

    # The covariance is the inverse of the optimum's information, marginalised to the robot
    # and the estimate's features (the dropped features' variables marginalised out).
    order = [optimum.feature_order.index(int(i)) for i in after.landmark_ids]
    rows = np.concatenate([np.arange(3)] + [3 + 2 * k + np.arange(2) for k in order])
    expected = optimum.covariance[np.ix_(rows, rows)]
    covariance = after.covariance[:len(rows), :len(rows)]
    assert np.max(np.abs(covariance - expected)) <= 1e-5 * np.max(np.abs(expected))


def test_the_run_is_unchanged_and_every_join_schedule_gives_the_same_estimate():
    sim = dcslam.simulation.revisit_scenario("small_loop_laps", seed=1, steps=120)
    config = dcslam.SlamConfig(local_map_features=15, tree_relinearisation=5)
    plain, relinearised, (plain_ids, relinearised_ids) = run_pair(sim.steps, config, ids=False)
    for a, b in zip(plain_ids, relinearised_ids):
        np.testing.assert_array_equal(a, b)
    plain_estimate, estimate = plain.estimate(), relinearised.estimate()
    all_ids = np.concatenate(plain_ids)
    np.testing.assert_array_equal(plain.resolve(all_ids), relinearised.resolve(all_ids))
    assert sorted(plain_estimate.landmark_ids) == sorted(estimate.landmark_ids)
    assert estimate.past_poses.shape == (0, 3)  # kept inside the passes, not asked for

    for schedule in (dict(amortize=False), dict(threaded_joins=True)):
        other = dcslam.DCSlam(dataclasses.replace(config, **schedule))
        drive(other, sim.steps, ids=False)
        again = other.estimate()
        np.testing.assert_array_equal(again.landmark_ids, estimate.landmark_ids)
        np.testing.assert_array_equal(again.landmarks, estimate.landmarks)
        np.testing.assert_array_equal(again.covariance, estimate.covariance)


def test_without_the_option_no_local_map_is_kept():
    slam = dcslam.DCSlam(dcslam.SlamConfig(local_map_features=5))
    sim = dcslam.simulate("loop", steps=30, seed=0)
    for s in sim.steps:
        slam.predict(s.u, s.Q)
        slam.update(s.z, s.R)
    assert slam._core.tree_leaves() == []
    assert "relinearisation_passes" not in slam.stats.counters


@pytest.mark.parametrize("value", [-1, 101])
def test_out_of_range_passes_are_refused_by_name(value):
    with pytest.raises(ValueError, match="tree_relinearisation"):
        dcslam.DCSlam(dcslam.SlamConfig(tree_relinearisation=value))


def test_victoria_park_first_2000_scans_reach_the_optimum_of_their_local_maps():
    vp = dcslam.datasets.victoria_park()
    config = vp.slam_config(keep_local_map_poses=True, tree_relinearisation=30)
    plain = dcslam.DCSlam(dataclasses.replace(config, tree_relinearisation=0))
    relinearised = dcslam.DCSlam(config)
    for slam in (plain, relinearised):
        for s in vp.steps[:2000]:
            slam.predict(s.u, s.Q)
            slam.update(s.z, s.R)
    before, after = plain.estimate(), relinearised.estimate()
    local_maps, start, boundaries = oracle_problem(relinearised, before)
    optimum = submap_joining.solve(local_maps, start, boundaries, before.robot, tolerance=1e-7)
    assert optimum.iterations < 30
    error = max(np.max(np.abs(p - optimum.features[int(i)])) for i, p in zip(after.landmark_ids, after.landmarks))
    plain_error = max(np.max(np.abs(p - optimum.features[int(i)])) for i, p in zip(before.landmark_ids, before.landmarks))
    assert error < 1e-6 < 0.1 < plain_error
