"""Chunked JCBB beside RJC at large joins (SlamConfig.chunked_jcbb_min_overlap).

The scene: the simulator's long_revisits, seed 17, 10 % clutter, no ids. Its whole-lap joins
(overlaps of 200-400 features) are where RJC's tries, seeded on a few pairs drawn from the
whole overlap, pair only part of the overlap, and the rest of each lap is mapped twice: RJC
alone ends at pairwise recall 0.57. Chunked JCBB, deciding the second map's features in map
order and conditioning each chunk on the pairings before it, pairs more at those joins and
is kept there: recall 0.91. The oracle is the simulator's true landmark of every measurement
(dcslam.evaluation). The checkpoint test runs the non-default value through a pickle, which
must keep it: resumed with the default, the run would end as the default run does.
"""

import dataclasses

import numpy as np
import pytest

import dcslam
from dcslam import evaluation
from dc_runs import pickled, run_dc

# The run traced in docs/data_association.md, made with JCBB's pairing count in the local maps
# (unexplained_density 0, the default until 2026-12-05), the gate of then (0.99), rejections
# beside tentative features and tentative features offered beside confirmed ones (until
# 2026-12-06) and RJC's tries of then (rjc_p_fail 0.01, until 2026-12-06): one draw of a
# lottery that any change in a local map's pairings or in RJC's tries redraws.
BASE = dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=17, unexplained_density=0.0,
                         gate_confidence=0.99, new_feature_beside_tentative=False,
                         confirmed_first_confidence=None, rjc_p_fail=0.01)
RJC_ALONE = dataclasses.replace(BASE, chunked_jcbb_min_overlap=0)


@pytest.fixture(scope="module")
def sim():
    return dcslam.revisit_scenario("long_revisits", 17)


@pytest.fixture(scope="module")
def runs(sim):
    return {"default": run_dc(sim, BASE), "rjc alone": run_dc(sim, RJC_ALONE)}


def association(sim, result):
    slam, returned, estimate = result
    return evaluation.evaluate_run(slam, estimate, returned, sim).association


def test_the_default():
    assert dcslam.SlamConfig().chunked_jcbb_min_overlap == 100


def test_whole_lap_joins_pair_their_landmarks(sim, runs):
    default, alone = association(sim, runs["default"]), association(sim, runs["rjc alone"])
    assert default.pairwise_recall > 0.85
    assert alone.pairwise_recall < 0.7
    assert default.pairwise_precision >= alone.pairwise_precision - 0.005
    assert default.features_per_landmark < alone.features_per_landmark


def test_only_large_joins_are_decided_by_chunks(runs):
    chunked = [join for join in runs["default"][0].stats.joins if join["chunked"]]
    assert chunked, "no join kept chunked JCBB's pairs"
    assert all(join["overlap"] >= BASE.chunked_jcbb_min_overlap for join in chunked)
    assert not any(join["chunked"] for join in runs["rjc alone"][0].stats.joins)


def test_a_checkpoint_keeps_the_value(sim, runs):
    slam_a, returned_a, a = runs["rjc alone"]
    slam_b, returned_b, b = run_dc(sim, RJC_ALONE, split=len(sim.steps) // 2, at_split=pickled)
    assert np.array_equal(slam_a.resolve(np.concatenate(returned_a)), slam_b.resolve(np.concatenate(returned_b)))
    assert np.array_equal(a.landmarks, b.landmarks)
    assert np.array_equal(a.covariance, b.covariance)
    assert not np.array_equal(runs["default"][2].landmarks, b.landmarks)


def test_a_negative_overlap_is_refused():
    with pytest.raises(ValueError, match="chunked_jcbb_min_overlap"):
        dcslam.DCSlam(dataclasses.replace(BASE, chunked_jcbb_min_overlap=-1))
