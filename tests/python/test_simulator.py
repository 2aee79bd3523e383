"""dcslam.simulate against independent numpy oracles (Paz et al. 2007, §III.B)."""

import dataclasses
import math

import numpy as np
import pytest

import dcslam
from dcslam.simulation import TRAJECTORIES

# Measurement noise must be > 0 (the filters need a positive definite R): 1e-15 is far below
# the tolerances of the comparisons.
NOISE_FREE = dict(
    odometry_sigma=(0.0, 0.0, 0.0), range_sigma_fraction=1e-15, bearing_sigma=1e-15, point_sigma=1e-15
)


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2])])


def relative(a, b):
    """(⊖a) ⊕ b, written out."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap(b[2] - a[2])])


def sensor_frame_points(pose, offset, landmarks):
    sensor = compose(pose, offset)
    c, s = math.cos(sensor[2]), math.sin(sensor[2])
    d = landmarks - sensor[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def expected_measurements(model, pose, offset, landmarks):
    q = sensor_frame_points(pose, offset, landmarks)
    if model == "point":
        return q
    return np.stack([np.hypot(q[:, 0], q[:, 1]), np.arctan2(q[:, 1], q[:, 0])], axis=1)


def test_api_shapes_and_types():
    sim = dcslam.simulate("snail", steps=500, seed=0)
    assert sim.landmarks.ndim == 2 and sim.landmarks.shape[1] == 2
    assert sim.poses.shape == (501, 3)
    np.testing.assert_array_equal(sim.poses[0], 0.0)
    assert len(sim.steps) == 500
    count = 0
    for s in sim.steps:
        m = len(s.z)
        assert s.u.shape == (3,) and s.Q.shape == (3, 3)
        assert s.z.shape == (m, 2) and s.R.shape == (m, 2, 2)
        assert s.landmark_ids.shape == (m,) and s.landmark_ids.dtype == np.int64
        assert s.true_ids is s.landmark_ids  # docs/api.md's name for a simulated step's ids
        count += 1
    assert count == 500
    assert sim.steps[-1].index == 499 and sim.steps[499].index == 499
    assert [s.index for s in sim.steps[10:13]] == [10, 11, 12]
    with pytest.raises(IndexError):
        sim.steps[500]
    assert sim.config.trajectory == "snail" and sim.config.steps == 500
    assert not sim.landmarks.flags.writeable and not sim.steps[0].z.flags.writeable


def test_python_defaults_mirror_the_core():
    core = dcslam._core.SimulationConfig()
    config = dcslam.SimulationConfig()
    for field in dataclasses.fields(config):
        actual, expected = getattr(config, field.name), getattr(core, field.name)
        if isinstance(actual, tuple):
            np.testing.assert_array_equal(actual, expected, err_msg=field.name)
        else:
            assert actual == expected, field.name


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
@pytest.mark.parametrize("model", ["range_bearing", "point"])
def test_noise_free_measurements_reconstruct_from_ground_truth(trajectory, model):
    offset = (0.2, 0.1, -0.3)
    sim = dcslam.simulate(trajectory, steps=80, seed=3, observation=model, sensor_offset=offset,
                          fov=math.radians(200), **NOISE_FREE)
    assert len(sim.measurements) > 0
    for i, s in enumerate(sim.steps):
        difference = s.u - relative(sim.poses[i], sim.poses[i + 1])
        difference[2] = wrap(difference[2])  # a U-turn is +pi or -pi, the same motion
        np.testing.assert_allclose(difference, 0.0, atol=1e-12)
        expected = expected_measurements(model, sim.poses[i + 1], offset, sim.landmarks[s.true_ids])
        np.testing.assert_allclose(s.z, expected, atol=1e-12)


def test_noise_statistics_match_the_configured_sigmas():
    sim = dcslam.simulate("lawn_mowing", steps=20000, seed=5)
    cfg = sim.config
    true_u = np.array([relative(a, b) for a, b in zip(sim.poses[:-1], sim.poses[1:])])
    error = sim.odometry - true_u
    error[:, 2] = wrap(error[:, 2])
    normalized = error / np.asarray(cfg.odometry_sigma)
    assert np.all(np.abs(normalized.mean(axis=0)) < 0.05)
    cov = np.cov(normalized.T)
    assert np.all((np.diag(cov) > 0.95) & (np.diag(cov) < 1.05))
    assert np.all(np.abs(cov[~np.eye(3, dtype=bool)]) < 0.05)
    np.testing.assert_allclose(sim.Q, np.diag(np.square(cfg.odometry_sigma)), rtol=1e-15)

    step_of = np.repeat(np.arange(len(sim.steps)), np.diff(sim.step_offsets))
    poses = sim.poses[step_of + 1]
    expected = np.concatenate([
        expected_measurements("range_bearing", sim.poses[i + 1], cfg.sensor_offset,
                              sim.landmarks[s.true_ids])
        for i, s in enumerate(sim.steps)
    ])
    assert len(poses) == len(expected) > 100000
    range_sigma = cfg.range_sigma_fraction * expected[:, 0]
    np.testing.assert_allclose(sim.measurement_covariances[:, 0, 0], range_sigma**2, rtol=1e-12)
    np.testing.assert_allclose(sim.measurement_covariances[:, 1, 1], cfg.bearing_sigma**2)
    assert np.all(sim.measurement_covariances[:, 0, 1] == 0)
    range_error = (sim.measurements[:, 0] - expected[:, 0]) / range_sigma
    bearing_error = wrap(sim.measurements[:, 1] - expected[:, 1]) / cfg.bearing_sigma
    for e in (range_error, bearing_error):
        assert abs(e.mean()) < 0.02
        assert 0.97 < e.var() < 1.03
    assert abs(np.corrcoef(range_error, bearing_error)[0, 1]) < 0.02


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
@pytest.mark.parametrize("fov", [2 * math.pi, math.pi])
def test_about_sixteen_features_per_step(trajectory, fov):
    sim = dcslam.simulate(trajectory, steps=400, seed=1, fov=fov)
    per_step = len(sim.measurements) / len(sim.steps)
    assert 16 * 0.8 < per_step < 16 * 1.2


def test_loop_closes_and_revisits_early_features():
    sim = dcslam.simulate("loop", steps=400, seed=2)
    np.testing.assert_allclose(sim.poses[-1], 0.0, atol=1e-9)
    extent = sim.poses[:, :2].max(axis=0) - sim.poses[:, :2].min(axis=0)
    np.testing.assert_allclose(extent, [100, 100], atol=1e-9)
    early = set(np.concatenate([s.true_ids for s in sim.steps[:5]]).tolist())
    late = np.concatenate([s.true_ids for s in sim.steps[-5:]])
    assert sum(i in early for i in late.tolist()) > 10


def test_lawn_and_snail_shapes():
    lawn = dcslam.simulate("lawn_mowing", steps=500)
    assert np.all(np.diff(lawn.poses[:, 1]) > -1e-9)  # sweeps advance across the lanes
    assert np.ptp(lawn.poses[:, 0]) == pytest.approx(round(math.sqrt(1500)))
    snail = dcslam.simulate("snail", steps=500)
    cells = {tuple(p) for p in np.round(snail.poses[:, :2]).astype(int).tolist()}
    assert len(cells) == len(snail.poses)  # an inward spiral never crosses itself
    centre = (snail.poses[:, :2].max(axis=0) + snail.poses[:, :2].min(axis=0)) / 2
    assert np.linalg.norm(snail.poses[-1, :2] - centre) < 0.25 * np.ptp(snail.poses[:, 0])


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
def test_features_fill_the_corridor_around_the_trajectory(trajectory):
    sim = dcslam.simulate(trajectory, steps=300, seed=6)
    margin = sim.config.max_range
    distance = np.linalg.norm(sim.landmarks[:, None, :] - sim.poses[None, :, :2], axis=2).min(axis=1)
    assert distance.max() <= margin
    # Uniform over the corridor: each distance band holds features in proportion to its
    # area, estimated by Monte Carlo over the bounding box.
    rng = np.random.default_rng(0)
    low, high = sim.poses[:, :2].min(axis=0) - margin, sim.poses[:, :2].max(axis=0) + margin
    probe = rng.uniform(low, high, size=(20000, 2))
    probe_distance = np.linalg.norm(probe[:, None, :] - sim.poses[None, :, :2], axis=2).min(axis=1)
    box_area = np.prod(high - low)
    density = 16 / (math.pi * (margin**2 - sim.config.min_range**2))
    for band in [(0, margin / 2), (margin / 2, margin)]:
        area = box_area * np.mean((probe_distance > band[0]) & (probe_distance <= band[1]))
        count = np.sum((distance > band[0]) & (distance <= band[1]))
        assert count == pytest.approx(density * area, rel=0.1), band


@pytest.mark.parametrize("rate", [0.1, 0.4])
def test_clutter_fraction_and_footprint(rate):
    sim = dcslam.simulate("straight", steps=2000, seed=4, clutter=rate, fov=math.pi / 2)
    spurious = sim.true_ids == -1
    assert abs(spurious.mean() - rate) < 0.02
    z = sim.measurements[spurious]
    assert np.all((z[:, 0] >= 0.1) & (z[:, 0] <= 3.0) & (np.abs(z[:, 1]) <= math.pi / 4))


def test_same_seed_same_arrays_other_seed_other_arrays():
    a = dcslam.simulate("lawn_mowing", steps=300, seed=11, clutter=0.2)
    b = dcslam.simulate("lawn_mowing", steps=300, seed=11, clutter=0.2)
    c = dcslam.simulate("lawn_mowing", steps=300, seed=12, clutter=0.2)
    for name in ("landmarks", "poses", "odometry", "measurements", "measurement_covariances",
                 "true_ids", "step_offsets"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    assert not np.array_equal(a.landmarks, c.landmarks)
    assert not np.array_equal(a.odometry, c.odometry)


def test_scans_are_shuffled():
    sim = dcslam.simulate("straight", steps=50)
    sorted_scans = sum(bool(np.all(np.diff(s.true_ids) > 0)) for s in sim.steps)
    assert sorted_scans < 3


@pytest.mark.parametrize("n", [100, 20000])
def test_num_features_override(n):
    sim = dcslam.simulate("snail", steps=300, num_features=n)
    assert sim.landmarks.shape == (n, 2)
    assert sim.true_ids.max() < n


def test_zero_heading_noise_and_point_model_covariance():
    sim = dcslam.simulate("loop", steps=40, zero_heading_noise=True, observation="point",
                          point_sigma=0.2)
    assert sim.Q[2, 2] == 0.0
    np.testing.assert_array_equal(sim.odometry[:, 2], [relative(a, b)[2] for a, b in
                                                       zip(sim.poses[:-1], sim.poses[1:])])
    np.testing.assert_allclose(sim.measurement_covariances, np.broadcast_to(0.04 * np.eye(2),
                               sim.measurement_covariances.shape))


@pytest.mark.parametrize("kwargs, name", [
    (dict(trajectory="circle"), "trajectory"),
    (dict(steps=0), "steps"),
    (dict(fov=7.0), "fov"),
    (dict(clutter=1.0), "clutter"),
    (dict(max_range=-1.0), "max_range"),
    (dict(observation="bearing_only"), "observation"),
    (dict(sensor_offset=(0.0, 0.0)), "sensor_offset"),
    (dict(num_features=-1), "num_features"),
    (dict(num_features=2.5), "num_features"),
    (dict(odometry_sigma=(0.1, float("nan"), 0.0)), "odometry_sigma"),
    (dict(seed=-1), "seed"),
    (dict(trajectory="snail", side_steps=2), "steps"),
    (dict(warp_speed=9), "warp_speed"),
])
def test_bad_parameters_raise_value_error_naming_them(kwargs, name):
    args = dict(trajectory="straight", steps=10)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        dcslam.simulate(**args)


def test_loop_both_ways_drives_the_square_back():
    side = 6
    sim = dcslam.simulate("loop_both_ways", steps=16 * side, side_steps=side, seed=0)
    positions = sim.poses[:, :2]
    lap = 4 * side
    # Back at the start after each lap; the second lap visits the first lap's places in reverse.
    for k in (lap, 2 * lap, 3 * lap, 4 * lap):
        np.testing.assert_allclose(positions[k], 0.0, atol=1e-9)
    np.testing.assert_allclose(positions[lap:2 * lap + 1], positions[lap::-1], atol=1e-9)
    np.testing.assert_allclose(positions[2 * lap:], positions[:2 * lap + 1], atol=1e-9)


@pytest.mark.parametrize("name", sorted(dcslam.REVISIT_SCENARIOS))
def test_revisit_scenarios_come_back_to_mapped_landmarks(name):
    sim = dcslam.revisit_scenario(name, seed=1)
    assert sim.config.clutter == 0.1
    step_of = np.repeat(np.arange(len(sim.steps)), np.diff(sim.step_offsets))
    truth = np.asarray(sim.true_ids)
    # A landmark is seen again when two of its sightings are more than 8 steps apart (a
    # revisit, not the same pass): most mapped landmarks are.
    revisited = seen = 0
    for landmark in np.unique(truth[truth >= 0]):
        steps = np.sort(step_of[truth == landmark])
        seen += 1
        revisited += bool(np.any(np.diff(steps) > 8))
    assert revisited / seen > 0.5


def test_unknown_revisit_scenario_is_named():
    with pytest.raises(ValueError, match="unknown scenario 'figure_nine'"):
        dcslam.revisit_scenario("figure_nine")
