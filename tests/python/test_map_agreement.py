"""map_agreement on synthetic maps, and map_trajectory on a synthetic run."""

import numpy as np
import pytest

import dcslam
from dcslam.pipeline import SlamPipeline, map_agreement, map_trajectory

from test_pipeline import corridor_steps


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
