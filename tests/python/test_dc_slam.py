"""DCSlam's Python surface: bad input is refused naming the argument and changes nothing;
anytime estimates; stats with joins; resolve()."""

import numpy as np
import pytest

import dcslam


def known_run(steps=120, seed=3):
    sim = dcslam.simulate("loop", steps=steps, seed=seed)
    cfg = dcslam.SlamConfig(association="known", join_association="known", local_map_features=12)
    return sim, cfg


def snapshot(slam):
    est = slam.estimate()
    return est.robot.copy(), est.landmarks.copy(), est.covariance.copy(), len(slam.stats.step_seconds)


@pytest.mark.parametrize(
    "call, needle",
    [
        (lambda s: s.predict([1.0, 0.0], np.eye(3)), "'u'"),
        (lambda s: s.predict([1.0, 0.0, 0.0], np.diag([1.0, 1.0, -1.0])), "'Q'"),
        (lambda s: s.predict([1.0, 0.0, 0.0], [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), "'Q'"),
        (lambda s: s.predict([np.nan, 0.0, 0.0], np.eye(3)), "'u'"),
        (lambda s: s.update(np.zeros((2, 3)), np.eye(2), [1, 2]), "'z'"),
        (lambda s: s.update(np.ones((2, 2)), np.diag([1.0, -1.0]), [1, 2]), "'R'"),
        (lambda s: s.update(np.ones((2, 2)), np.eye(2), None), "landmark_ids"),
        (lambda s: s.update(np.ones((2, 2)), np.eye(2), [1]), "landmark_ids"),
    ],
)
def test_bad_input_names_the_argument_and_changes_nothing(call, needle):
    sim, cfg = known_run(60)
    slam = dcslam.DCSlam(cfg)
    slam.run(sim.steps)
    before = snapshot(slam)
    with pytest.raises(ValueError, match=needle):
        call(slam)
    after = snapshot(slam)
    for a, b in zip(before[:3], after[:3]):
        np.testing.assert_array_equal(a, b)
    assert before[3] == after[3]


def test_unknown_options_are_refused_naming_the_field():
    with pytest.raises(ValueError, match="join_association"):
        dcslam.DCSlam(dcslam.SlamConfig(join_association="icp"))
    with pytest.raises(ValueError, match="local_map_features"):
        dcslam.DCSlam(dcslam.SlamConfig(local_map_features=0))
    with pytest.raises(ValueError, match="join_iterations"):
        dcslam.DCSlam(dcslam.SlamConfig(join_iterations=0))
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="join_feature_sigma"):
            dcslam.DCSlam(dcslam.SlamConfig(join_feature_sigma=bad))


@pytest.mark.parametrize("join_iterations", [1, 3, 10])
def test_join_events_report_the_linearisation_points_used(join_iterations):
    sim, cfg = known_run(120)
    cfg.join_iterations = join_iterations
    slam = dcslam.DCSlam(cfg)
    slam.run(sim.steps)
    slam.finish_joins()
    joins = slam.stats.joins
    assert joins and any(j["pairings"] > 0 for j in joins)
    for j in joins:
        if j["pairings"] == 0:
            assert j["iterations"] == 0
        elif join_iterations == 1:
            assert j["iterations"] == 1
        else:  # the simulator's joins are non-linear: at least one re-linearisation
            assert 2 <= j["iterations"] <= join_iterations


def test_anytime_estimate_does_not_disturb_the_run_and_stats_report_joins():
    sim, cfg = known_run(120)
    probed, plain = dcslam.DCSlam(cfg), dcslam.DCSlam(cfg)
    for k, s in enumerate(sim.steps):
        for slam in (probed, plain):
            slam.predict(s.u, s.Q)
            slam.update(s.z, s.R, s.true_ids)
        if k % 10 == 0:
            est = probed.estimate()
            n = len(est.landmark_ids)
            assert est.covariance.shape == (3 + 2 * n, 3 + 2 * n)
            assert len(set(est.landmark_ids.tolist())) == n  # known ids: every landmark once
    a, b = probed.estimate(), plain.estimate()
    np.testing.assert_array_equal(a.covariance, b.covariance)
    stats = plain.stats
    assert len(stats.step_seconds) == len(sim.steps)
    assert stats.joins and all(j["leaves"] >= 2 for j in stats.joins)
    assert sum(leaves for leaves, _ in stats.stack) == stats.counters["local_maps_closed"]
    # Known ids: every landmark seen is in the map, at its true place within 5 sigma.
    truth = sim.landmarks[b.landmark_ids]
    sigma = np.sqrt(np.diag(b.covariance)[3:].reshape(-1, 2))
    assert np.all(np.abs(b.landmarks - truth) < 5 * sigma + 1e-9)


def test_resolve_maps_merged_ids_and_keeps_minus_one():
    sim = dcslam.simulate("loop", steps=120, seed=5)
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc", local_map_features=12))
    returned = []
    for s in sim.steps:
        slam.predict(s.u, s.Q)
        returned.append(slam.update(s.z, s.R))
    slam.finish_joins()
    ids = np.concatenate(returned)
    resolved = slam.resolve(ids)
    assert resolved.dtype == np.int64 and resolved.shape == ids.shape
    assert np.all(resolved[ids == -1] == -1)
    assert (resolved != ids).any()  # joins did merge features
    assert slam.stats.counters["stack_depth"] > 1  # estimate() has a stack to join
    est = slam.estimate()
    # Right after estimate(), ids resolve to that estimate's landmarks: the joins it made on
    # copies of the stack merged features too.
    after_estimate = slam.resolve(ids)
    assert set(after_estimate[after_estimate >= 0].tolist()) == set(est.landmark_ids.tolist())
    np.testing.assert_array_equal(slam.resolve(est.landmark_ids), est.landmark_ids)
    assert (after_estimate != resolved).any()  # the stack's joins merged some
    # The next step leaves that estimate behind: the run's own joins are what counts again.
    slam.predict(sim.steps[0].u, sim.steps[0].Q)
    np.testing.assert_array_equal(slam.resolve(ids), resolved)


@pytest.mark.parametrize("extra", [dict(amortize=False), dict(), dict(threaded_joins=True)])
def test_covariance_is_exactly_symmetric_at_every_estimate(extra):
    # Joins fill P block by block; the diagonal blocks were once computed whole and left
    # asymmetric in the last bits (some 200 of 1,913 states on Victoria Park).
    sim = dcslam.revisit_scenario("loop_both_ways", 1)
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc", **extra))
    for k, step in enumerate(sim.steps):
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R)
        if k % 60 == 59:
            P = slam.estimate().covariance
            assert P.shape[0] > 100
            assert np.array_equal(P, P.T), f"step {k}: {np.count_nonzero(P != P.T)} entries differ from P'"
