"""Both filters on Victoria Park: the first 1500 scans (about 5 min of driving, the first
loop) and the whole run, and the paper's "essentially the same map" as an open target.
Numbers measured with the defaults of docs/victoria_park.md are in that file ("D&C against
the EKF")."""

import numpy as np
import pytest

import dcslam
from dcslam.metrics import gps_alignment, map_agreement, map_trajectory
from dcslam.pipeline import SlamPipeline

SCANS = 1500


@pytest.fixture(scope="module")
def victoria_park():
    return dcslam.datasets.victoria_park()


@pytest.fixture(scope="module")
def runs(victoria_park):
    cfg = victoria_park.slam_config()
    return {name: SlamPipeline(victoria_park.steps, cfg, filter=name, max_steps=SCANS).run() for name in ("ekf", "dc")}


def test_both_trajectories_follow_gps(victoria_park, runs):
    for result in runs.values():
        own = gps_alignment(result.timestamps, result.trajectory, victoria_park.gps)
        from_map = gps_alignment(*map_trajectory(result, victoria_park.steps), victoria_park.gps)
        assert own.rms < 8.0 and from_map.rms < 8.0, result.filter_name


def test_map_sizes_are_close_enough(runs):
    ekf, dc = runs["ekf"].map_size, runs["dc"].map_size
    assert 150 < ekf < 350
    # With join_feature_sigma the joins merge the trees the EKF merges (without it D&C kept
    # 1.2-1.7 times as many: duplicates 0.3 m apart; docs/victoria_park.md).
    assert 0.85 * ekf <= dc <= 1.15 * ekf


@pytest.fixture(scope="module")
def whole_runs(victoria_park):
    cfg = victoria_park.slam_config()
    return {name: SlamPipeline(victoria_park.steps, cfg, filter=name).run() for name in ("ekf", "dc")}


def test_dc_closes_the_parks_loops_like_the_ekf(victoria_park, whole_runs):
    # Before the long-span odometry floor, D&C's large joins paired almost nothing: 1,500
    # landmarks, 40 m from GPS, 7 % / 15 % agreement.
    for result in whole_runs.values():
        from_map = gps_alignment(*map_trajectory(result, victoria_park.steps), victoria_park.gps)
        assert from_map.rms < 6.0, result.filter_name
    biggest = max(whole_runs["dc"].joins, key=lambda join: join["leaves"])
    assert biggest["pairings"] > biggest["overlap"] / 2
    ekf, dc = whole_runs["ekf"].map_size, whole_runs["dc"].map_size
    assert 0.85 * ekf <= dc <= 1.2 * ekf
    # Within 2 m the agreement stays at 90-99 % over RJC seeds 0-7; within 1 m it is limited
    # by the far landmarks, 150-250 m from the start, where the two maps differ by about their
    # own standard deviation (~1 m).
    agreement = map_agreement(whole_runs["dc"].estimate, whole_runs["ekf"].estimate, radius=2.0)
    assert min(agreement.first_in_second, agreement.second_in_first) > 0.9


def test_maps_are_essentially_the_same(victoria_park, whole_runs):
    # The paper's claim, within 1 m, over RJC seeds 0-7: one seed is one draw of D&C's joins.
    # With rjc_p_fail 0.001 (the default since 2026-12-06) the eight give 0.90-0.96, mean
    # 0.93 (at 0.01: 0.92-0.97, mean 0.94), and every one of them is as close to GPS as the
    # EKF's map (4.33-4.35 m against 4.32 m). Without confirmed_first_confidence they gave
    # 0.81-0.92, limited by the far landmarks, 150-250 m from the start, where the two maps
    # differ by about their own standard deviation (docs/victoria_park.md).
    maps = [whole_runs["dc"].estimate]  # seed 0, the default
    for seed in range(1, 8):
        slam = dcslam.DCSlam(victoria_park.slam_config(seed=seed))
        slam.run(victoria_park)
        maps.append(slam.estimate())
    lower = []
    for dc_map in maps:
        agreement = map_agreement(dc_map, whole_runs["ekf"].estimate, radius=1.0)
        lower.append(min(agreement.first_in_second, agreement.second_in_first))
    assert np.mean(lower) >= 0.92
    assert min(lower) >= 0.88


def test_map_agreement_is_measured_in_one_frame(runs):
    agreement = map_agreement(runs["dc"].estimate, runs["ekf"].estimate, radius=5.0)
    # Within 5 m most landmarks have a counterpart: both maps are in the first pose's frame.
    assert agreement.first_in_second > 0.6 and agreement.second_in_first > 0.6


# (80, 1) is a known failure, kept in view: at 80 the park's loop closes on RJC seed 0 and on
# two of seeds 1-7 only. On seed 1 the fold's first join makes one pair more than at
# rjc_p_fail 0.01, and the fold's last join then pairs 28 of its overlap of 104 (472
# landmarks, EKF 410; docs/data_association.md, "A second search at a wider gate"). Strict: once
# a change lets this case pass, it fails, so that the docs' sweep is measured again.
@pytest.mark.parametrize("local_map_features, seed", [
    (45, 0),
    (80, 0),
    pytest.param(80, 1, marks=pytest.mark.xfail(
        strict=True, reason="Victoria Park at 80 features a local map, RJC seed 1: the loop stays open")),
])
def test_dc_map_does_not_depend_on_where_local_maps_end(victoria_park, whole_runs, local_map_features, seed):
    # At these sizes a large join meets the park's loop after a drift that puts every true
    # pair beyond the first search's gate (marginal D^2 13-22): before the second search at a
    # wider gate, 45 closed it with 9 pairs of a 112-landmark overlap and mapped 520 landmarks
    # (GPS 5.10 m), 80 mapped 475 (5.45 m); with it 405 and 404 (4.41 and 4.46 m) on RJC
    # seed 0, the default.
    cfg = victoria_park.slam_config(local_map_features=local_map_features, seed=seed)
    result = SlamPipeline(victoria_park.steps, cfg, filter="dc").run()
    ekf = whole_runs["ekf"]
    assert abs(result.map_size - ekf.map_size) <= 0.03 * ekf.map_size
    from_map = gps_alignment(*map_trajectory(result, victoria_park.steps), victoria_park.gps)
    ekf_from_map = gps_alignment(*map_trajectory(ekf, victoria_park.steps), victoria_park.gps)
    assert from_map.rms < ekf_from_map.rms + 0.3
    # Where the two maps place the park's far end varies with the local-map size (80: 83 %
    # within 2 m; the default 30: 96 % within 1 m).
    agreement = map_agreement(result.estimate, ekf.estimate, radius=2.0)
    assert min(agreement.first_in_second, agreement.second_in_first) > 0.8
    # The repair is the second search's, and a user sees where it was made: a real join at 45,
    # the final fold's second join at 80.
    assert any(join["widened"] for join in result.stats.joins + result.stats.fold_joins)

