"""Weak joins decided by the next join (SlamConfig.weak_join_pairings).

The scene: the simulator's small_loop_laps, seed 0, 10 % clutter, no ids. Without the option
D&C's recall there collapses (one wrong pair between two features seen once, at the join of
two 4-leaf maps, bends the map and the next join, a lap against a lap, duplicates its
landmarks). The oracle is the simulator's true landmark of every measurement; the other
tests compare the option's runs with themselves run another way (immediate, amortized,
threaded; checkpointed; with an estimate() in the middle), which must not change a bit.
"""

import dataclasses

import numpy as np
import pytest

import dcslam
from dcslam import evaluation
from dc_runs import pickled, run_dc

# The runs traced in docs/data_association.md, made with JCBB's pairing count in the local maps
# (unexplained_density 0, the default until 2026-12-05), the gate of then (0.99), rejections
# beside tentative features and tentative features offered beside confirmed ones (until
# 2026-12-06) and RJC's tries of then (rjc_p_fail 0.01, until 2026-12-06): draws of a
# lottery that any change in a local map's pairings or in RJC's tries redraws.
BASE = dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=0, unexplained_density=0.0,
                         gate_confidence=0.99, new_feature_beside_tentative=False,
                         confirmed_first_confidence=None, rjc_p_fail=0.01)


@pytest.fixture(scope="module")
def sim():
    return dcslam.revisit_scenario("small_loop_laps", 0)


def outcome(slam, returned, estimate):
    ids = slam.resolve(np.concatenate(returned))
    return ids, estimate.robot, estimate.landmarks, estimate.landmark_ids, estimate.covariance


def assert_same(a, b):
    for x, y in zip(outcome(*a), outcome(*b)):
        assert np.array_equal(x, y)


@pytest.fixture(scope="module")
def default_run(sim):
    return run_dc(sim, BASE)


def test_the_option_is_on_by_default():
    assert dcslam.SlamConfig().weak_join_pairings == 30


def test_a_wrong_pair_at_a_weak_join_is_taken_back(sim, default_run):
    slam_off, returned_off, estimate_off = run_dc(sim, dataclasses.replace(BASE, weak_join_pairings=0))
    scores_off = evaluation.evaluate_run(slam_off, estimate_off, returned_off, sim).association
    slam_on, returned_on, estimate_on = default_run
    scores_on = evaluation.evaluate_run(slam_on, estimate_on, returned_on, sim).association
    # The catastrophe is there without the option ...
    assert scores_off.pairwise_recall < 0.7
    assert slam_off.stats.counters["weak_joins"] == 0
    # ... and a later join took a weak join's alternative, which removes it.
    assert slam_on.stats.counters["alternatives_taken"] >= 1
    assert scores_on.pairwise_recall > 0.88
    assert scores_on.pairwise_precision >= scores_off.pairwise_precision
    assert scores_on.features_per_landmark < 1.1 < scores_off.features_per_landmark
    joins = slam_on.stats.joins
    deferring = [join for join in joins if join["deferred_pairings"] > 0]
    weak = [join for join in deferring if join["pairings"] <= 30]
    assert weak and all(join["leaves"] >= 8 and join["pairings"] > 0 for join in weak)
    # The others are large joins that left their doubtful pairs to the next join.
    assert all(join["leaves"] >= 16 and join["deferred_pairings"] < join["pairings"] for join in deferring if join not in weak)
    assert len(weak) == slam_on.stats.counters["weak_joins"]
    assert len(deferring) - len(weak) == slam_on.stats.counters["doubtful_joins"]
    assert sum(join["alternatives_taken"] for join in joins) == slam_on.stats.counters["alternatives_taken"]


@pytest.mark.parametrize("mode", [dict(amortize=False), dict(threaded_joins=True)])
def test_immediate_amortized_and_threaded_joins_decide_alike(sim, default_run, mode):
    assert_same(default_run, run_dc(sim, dataclasses.replace(BASE, **mode)))


def weak_join_waiting(slam):
    """A step at which a weak join is finished and the join that decides it not yet made."""
    joins = slam.stats.joins
    for weak in (join for join in joins if join["deferred_pairings"] > 0):
        deciding = next(join for join in joins if join["index"] > weak["index"] and join["leaves"] > weak["leaves"])
        if deciding["step_created"] > weak["step_finished"] + 1:
            return weak["step_finished"] + 1
    raise AssertionError("no weak join waits for its decision in this run")


def test_a_checkpoint_keeps_a_weak_joins_alternative(sim, default_run):
    split = weak_join_waiting(default_run[0])
    resumed = run_dc(sim, BASE, split=split, at_split=pickled)
    assert_same(default_run, resumed)


def test_an_estimate_that_decides_on_copies_changes_nothing_after_it(sim, default_run):
    split = weak_join_waiting(default_run[0])
    assert_same(default_run, run_dc(sim, BASE, split=split, at_split=lambda slam: slam.estimate() and None))


def test_joins_by_the_callers_ids_are_never_weak(sim):
    config = dataclasses.replace(BASE, association="known", join_association="known")
    slam = dcslam.DCSlam(config)
    for step in sim.steps:
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R, step.landmark_ids)
    slam.estimate()
    assert slam.stats.counters["weak_joins"] == 0


def test_a_negative_value_is_refused_by_name():
    with pytest.raises(ValueError, match="weak_join_pairings"):
        dcslam.DCSlam(dcslam.SlamConfig(weak_join_pairings=-1))


def test_a_wrong_pair_without_a_feature_seen_once_is_taken_back_too():
    """long_revisits seed 6: a join of 32 local maps makes 18 pairs, 4 of them wrong and only
    8 with a feature seen once. Only its version without any pair lets the next join make its
    true pairs (255 instead of 124); before that version existed the run ended at recall 0.23."""
    sim = dcslam.revisit_scenario("long_revisits", 6)
    config = dataclasses.replace(BASE, seed=6)
    slam, returned, estimate = run_dc(sim, config)
    scores = evaluation.evaluate_run(slam, estimate, returned, sim).association
    assert scores.pairwise_recall > 0.65
    joins = slam.stats.joins
    # A weak join of 16 local maps or more deferred all its pairs (it kept the version without
    # any), and a later join took one of its inputs' other versions.
    assert any(join["leaves"] >= 16 and 0 < join["deferred_pairings"] == join["pairings"] for join in joins)
    assert sum(join["alternatives_taken"] for join in joins) >= 1


def test_a_large_joins_doubtful_pairs_are_taken_back():
    """long_revisits seed 1: a large join's doubtful pairs (a rival candidate nearly as close)
    bend its map; without them the next join makes more pairs in all and takes that version.
    Before large joins kept it the run ended at recall 0.55 with 2.6 features per landmark.
    With the maps' covariances alone in the join tests (join_feature_sigma 0): with the default
    1 cm per feature that join's pairs are right and no version is needed there. And with RJC
    alone at the large joins (chunked_jcbb_min_overlap 0): chunked JCBB pairs that join without
    the doubtful pairs' damage (recall 0.895, no version taken back). With RJC's crossed
    pairings exchanged (rjc_exchange_crossed, the default since 2026-12-08) the run ends at
    0.895; without them at 0.68 since the deciding join counts its own pairs twice (2026-12-07;
    0.74 without any version), a counter-example not traced."""
    sim = dcslam.revisit_scenario("long_revisits", 1)
    config = dataclasses.replace(BASE, seed=1, join_feature_sigma=0.0, chunked_jcbb_min_overlap=0)
    slam, returned, estimate = run_dc(sim, config)
    scores = evaluation.evaluate_run(slam, estimate, returned, sim).association
    assert scores.pairwise_recall > 0.78
    joins = slam.stats.joins
    assert slam.stats.counters["doubtful_joins"] >= 1
    # A large join whose record lists fewer pairs than it made: a later join took its version.
    taken = [join for join, record in zip(joins, slam.join_pairings())
             if join["pairings"] > BASE.weak_join_pairings and len(record["pairs"]) < join["pairings"]]
    assert taken and all(join["leaves"] >= 16 for join in taken)
    for join, record in zip(joins, slam.join_pairings()):
        if join in taken:
            assert len(record["pairs"]) == join["pairings"] - join["deferred_pairings"]


def assert_every_listed_pair_is_one_feature(slam, records):
    for record in records:
        pairs = np.array(record["pairs"], dtype=np.int64).reshape(-1, 2)
        assert np.array_equal(slam.resolve(pairs[:, 0]), slam.resolve(pairs[:, 1]))


def test_every_pair_a_join_record_lists_ends_in_one_feature(default_run):
    """A weak join's record lists the pairs of the version a later join took, not those it
    made: after estimate() (which decides the weak joins still waiting), every pair listed by
    join_pairings() and fold_pairings() resolves to one feature."""
    slam, _, _ = default_run
    assert slam.stats.counters["alternatives_taken"] >= 1
    assert_every_listed_pair_is_one_feature(slam, slam.join_pairings() + slam.fold_pairings())


@pytest.fixture(scope="module")
def fold_scene():
    return dcslam.revisit_scenario("loop_both_ways", 2)


def test_a_weak_fold_join_is_decided_by_the_rest_of_the_fold(fold_scene):
    """loop_both_ways scene 2, SlamConfig seed 0: the third join of estimate()'s fold (15 local
    maps, 250 features) is weak. Over it and the next fold join its versions make 181 pairs as
    made, 174 without the pairs of features seen once and 176 without any pair, so the next
    join alone keeps it as made and the run ends at recall 0.70; over the whole rest of the
    fold they make 289, 283 and 370, and the version without any pair ends the run at 0.94
    (both measured with a temporary switch, 2026-12-04). With the scene's seed as SlamConfig's
    (seed 2) the two rules end alike today, so that run no longer tells them apart."""
    config = BASE
    slam, returned, estimate = run_dc(fold_scene, config)
    scores = evaluation.evaluate_run(slam, estimate, returned, fold_scene).association
    assert scores.pairwise_recall > 0.85
    assert scores.features_per_landmark < 1.1
    # Its record lists the pairs of the version taken: each resolves to one feature.
    folds = slam.fold_pairings()
    assert len(folds) >= 3
    assert_every_listed_pair_is_one_feature(slam, folds)
    # The fold runs on copies: every join schedule gives the same estimate.
    assert_same((slam, returned, estimate), run_dc(fold_scene, dataclasses.replace(config, threaded_joins=True)))
