"""A measurement JCBB leaves unpaired beside a mapped feature starts a feature when the decision
was clear (SlamConfig.new_feature_margin, 5 by default).

On the simulator's lawn_overlap (strips closer than the sensor range, 10 % clutter, no ids)
about 0.04 of the pairwise recall was lost to rejected measurements, most of them first
sightings of landmarks that fall in a mapped neighbour's gate. Started as features when every
hypothesis that pairs them is at least e^5 times less likely than JCBB's, they recover part of
it, in the EKF and in D&C's local maps alike, without a loss of precision. The oracle is the
simulator's true landmark of every measurement (dcslam.evaluation); the margin rule itself is
checked decision by decision against exhaustive enumeration in the C++ tests.
"""

import dataclasses
import math

import pytest

import dcslam
from dcslam import evaluation


def scores(filter_name: str, config: dcslam.SlamConfig):
    sim = dcslam.revisit_scenario("lawn_overlap", 0)
    slam = dcslam.DCSlam(config) if filter_name == "dc" else dcslam.EkfSlam(config)
    returned = slam.run(sim.steps)
    association = evaluation.evaluate_run(slam, slam.estimate(), returned, sim).association
    return association, slam.stats.counters


def test_the_default():
    assert dcslam.SlamConfig().new_feature_margin == 5.0


@pytest.mark.parametrize("filter_name", ["ekf", "dc"])
def test_clear_decisions_start_features_and_recover_recall(filter_name):
    # The margin alone: both reject beside tentative features, as when it was measured.
    default, default_counters = scores(filter_name, dcslam.SlamConfig(seed=0, new_feature_beside_tentative=False))
    rejecting, rejecting_counters = scores(filter_name, dcslam.SlamConfig(seed=0, new_feature_margin=math.inf,
                                                                          new_feature_beside_tentative=False))
    assert default_counters["unexplained_started"] > 50
    assert rejecting_counters.get("unexplained_started", 0) == 0
    assert default.recall_lost_to_rejected < rejecting.recall_lost_to_rejected - 0.005
    assert default.pairwise_recall > rejecting.pairwise_recall + 0.005
    assert default.pairwise_precision > rejecting.pairwise_precision - 0.003


def test_the_pairing_count_always_rejects():
    config = dcslam.SlamConfig(seed=0, unexplained_density=0.0)
    _, counters = scores("ekf", config)
    assert counters.get("unexplained_started", 0) == 0
    _, counters_inf = scores("ekf", dataclasses.replace(config, new_feature_margin=math.inf))
    assert counters_inf.get("jcbb_nodes") == counters.get("jcbb_nodes")


@pytest.mark.parametrize("bad", [-1.0, math.nan])
def test_a_bad_margin_is_refused_by_name(bad):
    with pytest.raises(ValueError, match="new_feature_margin"):
        dcslam.EkfSlam(dcslam.SlamConfig(new_feature_margin=bad))
