"""dcslam.metrics: the rigid fit, GPS outliers and alignment on synthetic tracks, map_agreement
on synthetic maps, and map_trajectory on a synthetic run."""

import math

import numpy as np
import pytest

import dcslam
from dcslam.metrics import TooFewGpsFixes, gps_alignment, gps_outliers, map_agreement, map_trajectory, rigid_fit_2d
from dcslam.pipeline import SlamPipeline

from test_pipeline import corridor_steps, rotation


def test_rigid_fit_recovers_an_exact_transform():
    rng = np.random.default_rng(0)
    source = rng.uniform(-50, 50, size=(20, 2))
    R, t = rotation(2.5), np.array([-7.0, 13.0])
    fitted_R, fitted_t = rigid_fit_2d(source, source @ R.T + t)
    np.testing.assert_allclose(fitted_R, R, atol=1e-12)
    np.testing.assert_allclose(fitted_t, t, atol=1e-10)
    with pytest.raises(ValueError):
        rigid_fit_2d(source[:1], source[:1])


def test_gps_outliers_flags_jumps_and_recovers_after_a_gap():
    t = np.arange(0, 20, 0.2)
    gps = np.column_stack([t, 5.0 * t, np.zeros_like(t)])  # 5 m/s along x
    gps[30, 1:] = [300.0, -40.0]           # a single wild fix
    gps[60:63, 2] += 50.0                  # a run of three bad fixes
    gap = np.column_stack([t[-1] + 60.0, 5.0 * t[-1] + 250.0, 0.0])  # a real jump across a 60 s gap
    gps = np.concatenate([gps, gap])
    outlier = gps_outliers(gps, max_speed=20.0)
    assert sorted(np.flatnonzero(outlier)) == [30, 60, 61, 62]


def test_gps_alignment_recovers_rotation_translation_and_rms():
    rng = np.random.default_rng(1)
    times = np.linspace(0.0, 300.0, 1201)
    # A wavy drive in the trajectory's own frame.
    trajectory = np.column_stack([3.0 * times, 40.0 * np.sin(times / 30.0), np.zeros_like(times)])
    R, t = rotation(-0.7), np.array([120.0, -45.0])
    gps_times = np.linspace(5.0, 295.0, 400)
    true_positions = np.column_stack([np.interp(gps_times, times, trajectory[:, i]) for i in range(2)])
    gps_xy = true_positions @ R.T + t + rng.normal(0, 0.5, size=true_positions.shape)
    gps = np.column_stack([gps_times, gps_xy])
    gps[100, 1:] += [400.0, 0.0]           # an outlier
    gps = np.concatenate([gps, [[400.0, 0.0, 0.0]]])  # a fix after the trajectory ends
    alignment = gps_alignment(times, trajectory, gps)
    assert alignment.outliers == 1 and len(alignment.times) == 399
    assert alignment.yaw == pytest.approx(-0.7, abs=2e-3)
    np.testing.assert_allclose(alignment.translation, t, atol=0.3)
    assert alignment.rms == pytest.approx(0.5 * math.sqrt(2), rel=0.15)
    np.testing.assert_allclose(alignment.apply(alignment.trajectory_at_gps), alignment.gps_used, atol=3.0)
    pose = alignment.apply_poses(np.array([[1.0, 2.0, 0.5]]))
    np.testing.assert_allclose(pose[0, :2], R @ [1.0, 2.0] + t, atol=0.3)
    assert pose[0, 2] == pytest.approx(0.5 - 0.7, abs=2e-3)
    with pytest.raises(TooFewGpsFixes, match="1 usable GPS fixes"):
        gps_alignment(times, trajectory, gps[:1])
    assert issubclass(TooFewGpsFixes, ValueError)  # callers that caught ValueError still do


def test_identical_and_shifted_maps():
    rng = np.random.default_rng(0)
    points = rng.uniform(-50, 50, size=(200, 2))
    same = map_agreement(points, points + 0.3 * rng.standard_normal((200, 2)) / np.sqrt(2), radius=1.5)
    assert same.first_in_second == 1.0 and same.second_in_first == 1.0
    assert (same.first_size, same.second_size) == (200, 200)
    far = map_agreement(points, points + [10.0, 0.0], radius=1.0)
    assert far.first_in_second < 0.2 and far.second_in_first < 0.2


def test_missing_and_extra_landmarks_count_on_their_own_side():
    xs = np.arange(0.0, 100.0, 5.0)
    full = np.column_stack([xs, np.zeros_like(xs)])  # 20 landmarks, 5 m apart
    half = full[::2]
    extra = np.vstack([full, [[2.5, 50.0], [7.5, 50.0]]])
    agreement = map_agreement(full, half)
    assert agreement.first_in_second == pytest.approx(0.5) and agreement.second_in_first == 1.0
    agreement = map_agreement(extra, full)
    assert agreement.first_in_second == pytest.approx(20 / 22) and agreement.second_in_first == 1.0


def test_radius_is_inclusive_and_empty_maps():
    agreement = map_agreement([[0.0, 0.0]], [[1.0, 0.0]], radius=1.0)
    assert agreement.first_in_second == 1.0
    assert map_agreement(np.empty((0, 2)), [[0.0, 0.0]]).first_in_second == 1.0
    assert map_agreement(np.empty((0, 2)), [[0.0, 0.0]]).second_in_first == 0.0
    with pytest.raises(ValueError, match="radius"):
        map_agreement([[0.0, 0.0]], [[0.0, 0.0]], radius=0.0)
    with pytest.raises(ValueError, match="first"):
        map_agreement(np.zeros((3, 3)), [[0.0, 0.0]])


def test_filters_on_one_run_agree_and_map_trajectory_follows_the_run():
    steps = corridor_steps()
    config = dcslam.SlamConfig(observation="point", association="known", join_association="known",
                               local_map_features=8)
    runs = {name: SlamPipeline(steps, config, filter=name).run() for name in ("ekf", "dc")}
    agreement = map_agreement(runs["ekf"].estimate, runs["dc"].estimate, radius=0.2)
    assert agreement.first_in_second == 1.0 and agreement.second_in_first == 1.0
    for result in runs.values():
        times, poses = map_trajectory(result, steps)
        assert len(poses) > 0.7 * len(steps)  # the last steps see fewer than 3 landmarks
        filtered = result.trajectory[np.searchsorted(result.timestamps, times)]
        assert np.max(np.hypot(*(poses[:, :2] - filtered[:, :2]).T)) < 0.3


def test_the_metrics_are_still_importable_where_they_were():
    # They lived in dcslam.pipeline before dcslam.metrics; user code imports them from there.
    for name in dcslam.metrics.__all__:
        assert getattr(dcslam.pipeline, name) is getattr(dcslam.metrics, name)
    assert dcslam.gps_alignment is dcslam.metrics.gps_alignment


def test_the_map_refit_of_an_exact_map_is_the_true_path_and_its_files_round_trip(tmp_path):
    """Noise-free range-bearing scans from known poses, with an offset sensor, and a final map
    equal to the true landmarks: the refit must give back the true poses; a step that sees
    fewer than 3 mapped landmarks gets none. Written as TUM and KITTI, they read back."""
    from types import SimpleNamespace

    from dcslam import geometry, io

    rng = np.random.default_rng(7)
    landmarks = rng.uniform(-15, 15, size=(40, 2))
    ids = np.arange(100, 140)
    offset = (0.4, -0.1, 0.2)
    k = np.arange(30)
    true_poses = np.column_stack([10 * np.cos(0.1 * k), 10 * np.sin(0.1 * k), np.unwrap(0.1 * k + np.pi / 2)])
    true_poses[:, 2] = np.arctan2(np.sin(true_poses[:, 2]), np.cos(true_poses[:, 2]))
    steps, measurement_ids = [], []
    for j, pose in enumerate(true_poses):
        seen = [i for i in range(len(landmarks)) if np.hypot(*(landmarks[i] - pose[:2])) < (2.0 if j == 5 else 9.0)]
        steps.append(SimpleNamespace(z=np.array([geometry.observe("range_bearing", offset, pose, landmarks[i])
                                                 for i in seen]).reshape(-1, 2)))
        measurement_ids.append(ids[seen])
    assert len(measurement_ids[5]) < 3 and min(len(m) for j, m in enumerate(measurement_ids) if j != 5) >= 3
    result = SimpleNamespace(config=dcslam.SlamConfig(observation="range_bearing", sensor_offset=offset),
                             estimate=SimpleNamespace(landmarks=landmarks, landmark_ids=ids),
                             measurement_ids=measurement_ids, timestamps=100.0 + 0.5 * k)
    times, poses = map_trajectory(result, steps)
    kept = k != 5
    np.testing.assert_array_equal(times, 100.0 + 0.5 * k[kept])
    np.testing.assert_allclose(poses[:, :2], true_poses[kept, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (poses[:, 2] - true_poses[kept, 2]))), 0.0, atol=1e-9)
    io.write_tum(tmp_path / "map.tum", times, poses)
    io.write_kitti(tmp_path / "map.kitti", poses)
    read_times, read_poses = io.read_tum(tmp_path / "map.tum")
    np.testing.assert_allclose(read_times, times, atol=1e-9)
    np.testing.assert_allclose(read_poses, poses, atol=1e-8)
    np.testing.assert_allclose(io.read_kitti(tmp_path / "map.kitti"), poses, atol=1e-8)
