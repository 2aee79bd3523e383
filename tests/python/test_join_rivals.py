"""The last join of D&C's estimate() commits only to what RJC's rival hypotheses agree on
(SlamConfig.join_rival_margin).

The scene: the paper's loop, 600 steps, 10 % clutter, no ids, the join's draws from
SlamConfig.seed = scene seed + 2000 (the third draw of benchmarks/revisit_association.py
--rjc-seeds 3). The loop closes in the final fold's last join, and there a few closing pairs
compete with shifted alignments that collect as many chance pairs. The oracle is the
simulator: the true final pose, and with it the robot's error and NEES (dcslam.evaluation).
Without the rule these two runs close the loop wrong (robot 15-17 m off, NEES in the
thousands); with it, scene seed 2 closes right and scene seed 5 stays open with a consistent
robot. (Scene seed 9 closed wrong without the rule until the next join's decision between a
weak join's versions counted its own pairs twice, 2026-12-07: it now closes right either way.)
"""

import numpy as np
import pytest

import dcslam
from dc_runs import pickled, run_dc
from dcslam import evaluation

NEES_99 = 11.34  # chi-square, 3 dof, 0.99


def loop_run(scene_seed, split=None, at_split=None, **options):
    sim = dcslam.simulate("loop", steps=600, seed=scene_seed, clutter=0.1)
    # As traced: rejecting what the local maps leave unpaired beside tentative features, and
    # offering tentative features beside confirmed ones (with confirmed_first_confidence, the
    # default since 2026-12-06, seed 9's loop closes right without the rule), with RJC's tries
    # of then (rjc_p_fail 0.01, until 2026-12-06: other tries are another draw of the closure)
    # and without their crossed pairings exchanged (the default since 2026-12-08).
    config = dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=scene_seed + 2000,
                               new_feature_beside_tentative=False, confirmed_first_confidence=None,
                               rjc_p_fail=0.01, rjc_exchange_crossed=False, **options)
    slam, returned, estimate = run_dc(sim, config, split=split, at_split=at_split)
    return slam, returned, estimate, evaluation.evaluate_run(slam, estimate, returned, sim).robot


@pytest.fixture(scope="module", params=[5, 2])
def runs(request):
    return request.param, {margin: loop_run(request.param, join_rival_margin=margin) for margin in (None, 3)}


def test_the_default():
    assert dcslam.SlamConfig().join_rival_margin == 3


def test_without_the_rule_the_loop_closes_wrong(runs):
    _, by_margin = runs
    robot = by_margin[None][3]
    assert robot.position_error > 10.0
    assert robot.nees > 1000.0
    assert len(by_margin[None][0].fold_pairings()[-1]["disputed"]) == 0


def test_with_the_rule_the_robot_is_consistent(runs):
    scene_seed, by_margin = runs
    slam, _, _, robot = by_margin[3]
    assert robot.nees <= NEES_99
    last = slam.fold_pairings()[-1]
    if scene_seed == 2:
        # Closed right: the fold's versions were compared by the last join's agreed pairs, and
        # the version taken leaves that join no rival.
        assert robot.position_error < 2.0
    else:
        # Left open, the robot's uncertainty kept: the closing pairs were disputed.
        assert robot.position_error > 2.0
        assert len(last["disputed"]) > 0
    # The disputed pairs are pairs the last join did not make.
    made = {tuple(pair) for pair in last["pairs"]}
    assert not any(tuple(pair) in made for pair in last["disputed"])


def test_only_the_last_fold_join_has_rivals(runs):
    _, by_margin = runs
    slam = by_margin[3][0]
    assert all(len(record["disputed"]) == 0 for record in slam.join_pairings())
    assert all(len(record["disputed"]) == 0 for record in slam.fold_pairings()[:-1])


@pytest.mark.parametrize("case", ["immediate", "threaded", "resumed from a checkpoint"])
def test_the_rule_does_not_depend_on_the_join_schedule(runs, case):
    scene_seed, by_margin = runs
    if scene_seed != 5:
        pytest.skip("one scene is enough")
    _, returned, estimate, _ = by_margin[3]
    split = 300
    other = {
        "immediate": lambda: loop_run(scene_seed, amortize=False),
        "threaded": lambda: loop_run(scene_seed, threaded_joins=True),
        "resumed from a checkpoint": lambda: loop_run(scene_seed, split=split, at_split=pickled),
    }[case]()
    np.testing.assert_array_equal(np.concatenate(returned), np.concatenate(other[1]))
    for field in ("robot", "landmarks", "landmark_ids", "covariance"):
        np.testing.assert_array_equal(getattr(estimate, field), getattr(other[2], field))


@pytest.mark.parametrize("value", [-1, 2.5, "3"])
def test_join_rival_margin_is_checked_by_name(value):
    with pytest.raises((ValueError, TypeError), match="join_rival_margin"):
        dcslam.DCSlam(dcslam.SlamConfig(join_rival_margin=value))
