"""The batch call (SlamFilter.run_batch / run) against its oracle, the loop of step calls:
bitwise the same ids, online trajectory and final estimate; bad packed input is refused naming
the array and index, and leaves the filter as it was."""

import dataclasses

import numpy as np
import pytest

import dcslam
from dcslam.packed import PackedSteps

JOIN_MODES = {
    "immediate": dict(amortize=False),
    "amortized": dict(amortize=True),
    "threaded": dict(threaded_joins=True),
}


def make_filter(name, config):
    return dcslam.EkfSlam(config) if name == "ekf" else dcslam.DCSlam(config)


def step_loop(slam, steps, known=False):
    """The oracle: the README's loop of step calls."""
    ids, poses = [], [slam.pose().copy()]
    for s in steps:
        slam.predict(s.u, s.Q)
        ids.append(slam.update(s.z, s.R, s.landmark_ids if known else None))
        poses.append(slam.pose().copy())
    return np.concatenate(ids), np.array(poses)


def final_estimate(slam):
    if isinstance(slam, dcslam.DCSlam):
        slam.finish_joins()
    return slam.estimate()


def assert_same_estimate(a, b):
    for field in ("robot", "landmarks", "landmark_ids", "covariance"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.fixture(scope="module")
def cluttered():
    # Revisits with 10 % clutter: association without ids, tentative features, merges, joins.
    return dcslam.revisit_scenario("small_loop_laps", seed=2)


@pytest.mark.parametrize("name, joins", [("ekf", "immediate"), ("dc", "immediate"), ("dc", "amortized"),
                                         ("dc", "threaded")])
def test_the_batch_call_is_bitwise_the_loop_of_step_calls(cluttered, name, joins):
    config = dcslam.SlamConfig(local_map_features=15, **JOIN_MODES[joins])
    looped = make_filter(name, config)
    loop_ids, loop_poses = step_loop(looped, cluttered.steps)
    batched = make_filter(name, config)
    result = batched.run(cluttered)
    np.testing.assert_array_equal(result.ids, loop_ids)
    assert len(result) == len(cluttered.steps) and result.trajectory.shape == (len(cluttered.steps) + 1, 3)
    np.testing.assert_array_equal(np.concatenate(list(result)), loop_ids)
    # Threaded: a pending join's robot is its inputs' composed, a finished one's is re-linearised,
    # so the online poses depend on when the worker finishes; before the first join they do not.
    same_until = batched.stats.joins[0]["step_created"] if joins == "threaded" else None
    np.testing.assert_array_equal(result.trajectory[:same_until], loop_poses[:same_until])
    assert result.step_seconds.shape == (len(cluttered.steps),) and np.all(result.step_seconds > 0)
    assert_same_estimate(final_estimate(batched), final_estimate(looped))
    np.testing.assert_array_equal(batched.resolve(result.ids), looped.resolve(loop_ids))


@pytest.mark.parametrize("name", ["ekf", "dc"])
def test_known_ids_and_a_dataset_run_in_two_batches(name):
    isam = dcslam.datasets.read_isam2d("tests/data/isam_victoria_park.txt.gz")
    config = isam.slam_config(local_map_features=20)
    steps = isam.steps[:400]
    looped = make_filter(name, config)
    loop_ids, loop_poses = step_loop(looped, steps, known=True)
    batched = make_filter(name, config)
    # Two batches on slices of the packed arrays; the second's offsets start from 0 again.
    ends = isam.offsets[[0, 150, 400]]
    first = batched.run_batch(isam.u[:150], isam.Q[:150], isam.z[:ends[1]], isam.R[:ends[1]],
                              isam.offsets[:151], isam.landmark_ids[:ends[1]])
    second = batched.run_batch(isam.u[150:400], isam.Q[150:400], isam.z[ends[1]:ends[2]], isam.R[ends[1]:ends[2]],
                               isam.offsets[150:401] - ends[1], isam.landmark_ids[ends[1]:ends[2]])
    np.testing.assert_array_equal(np.concatenate([first.ids, second.ids]), loop_ids)
    np.testing.assert_array_equal(np.vstack([first.trajectory, second.trajectory[1:]]), loop_poses)
    assert_same_estimate(final_estimate(batched), final_estimate(looped))


def test_step_objects_are_packed_as_the_step_calls_convert_them(cluttered):
    config = dcslam.SlamConfig(local_map_features=15)
    steps = cluttered.steps[:60]
    from_arrays = dcslam.DCSlam(config).run(cluttered.steps).ids[: cluttered.step_offsets[60]]
    # Lists for u: converted exactly as predict() converts them.
    converted = [dataclasses.make_dataclass("S", ["u", "Q", "z", "R"])(
        list(s.u), s.Q, s.z, s.R) for s in steps]
    looped = dcslam.DCSlam(config)
    loop_ids, _ = step_loop(looped, converted)
    np.testing.assert_array_equal(dcslam.DCSlam(config).run(converted).ids, loop_ids)
    np.testing.assert_array_equal(loop_ids, from_arrays)


def test_a_shared_q_and_r_are_taken_as_one_matrix_for_all():
    sim = dcslam.simulate("straight", steps=40, seed=1, observation="point")
    config = dcslam.SlamConfig(observation="point", association="nn")
    R = np.eye(2) * sim.config.point_sigma ** 2
    np.testing.assert_array_equal(sim.measurement_covariances, np.broadcast_to(R, sim.measurement_covariances.shape))
    shared = dcslam.EkfSlam(config).run_batch(sim.odometry, sim.Q, sim.measurements, R, sim.step_offsets)
    per_step = dcslam.EkfSlam(config).run_batch(sim.odometry, np.broadcast_to(sim.Q, (40, 3, 3)),
                                                sim.measurements, sim.measurement_covariances, sim.step_offsets)
    np.testing.assert_array_equal(shared.ids, per_step.ids)
    np.testing.assert_array_equal(shared.trajectory, per_step.trajectory)


def packed(steps=10, seed=0):
    sim = dcslam.simulate("straight", steps=steps, seed=seed)
    return dict(u=sim.odometry.copy(), Q=np.broadcast_to(sim.Q, (steps, 3, 3)).copy(), z=sim.measurements.copy(),
                R=sim.measurement_covariances.copy(), offsets=sim.step_offsets.copy())


def with_change(name, change):
    arrays = packed()
    value = arrays[name]
    arrays[name] = change(value) if callable(change) else change
    return arrays


def set_at(index, value):
    def change(array):
        array = array.copy()
        array[index] = value
        return array
    return change


@pytest.mark.parametrize("name, change, message", [
    ("u", lambda u: u[:, :2], r"run_batch: argument 'u': expected shape \(N, 3\), got \(10, 2\)"),
    ("Q", lambda Q: Q[:4], r"argument 'Q': expected shape \(3, 3\) or \(10, 3, 3\), got \(4, 3, 3\)"),
    ("z", lambda z: z[:, :1], r"argument 'z': expected shape \(m, 2\)"),
    ("R", lambda R: R[:-1], r"argument 'R': expected shape \(2, 2\) or \(\d+, 2, 2\)"),
    ("offsets", lambda o: o[:-1], r"argument 'offsets': expected shape \(11,\)"),
    ("offsets", lambda o: o.astype(float), r"argument 'offsets': expected integers, got dtype float64"),
    ("u", lambda u: u.astype(str), r"argument 'u': expected an array of real numbers"),
    ("offsets", set_at(0, 1), r"run_batch: offsets\[0\] is 1, expected 0"),
    ("offsets", set_at(4, 10 ** 6), r"offsets\[5\] = \d+ is below offsets\[4\] = 1000000"),
    ("offsets", set_at(10, 3), r"offsets\[10\] = 3 is below offsets\[9\]"),
    ("u", set_at((7, 0), np.nan), r"run_batch: step 7 \(u\[7\], Q\[7\]\): predict: argument 'u' contains a non-finite"),
    ("Q", set_at((3, 2, 2), -1.0), r"step 3 \(u\[3\], Q\[3\]\): predict: argument 'Q' is not positive semi-definite"),
    ("R", set_at((5, 0, 1), 7.0), r"step \d \(rows \d+\.\.\d+ of z, R\): update: argument 'R'\[\d+\] is not symmetric"),
    ("z", set_at((5, 0), -1.0), r"step \d \(rows \d+\.\.\d+ of z, R\): update: argument 'z'\[\d+\] has a range that"),
])
def test_bad_packed_input_names_the_array_and_index_and_changes_nothing(name, change, message):
    slam = dcslam.DCSlam(dcslam.SlamConfig())
    before = slam.estimate()
    with pytest.raises(ValueError, match=message):
        slam.run_batch(**with_change(name, change))
    assert len(slam.stats.step_seconds) == 0
    assert_same_estimate(slam.estimate(), before)


def test_a_refused_measurement_is_placed_at_its_step_and_row():
    arrays = packed()
    step = 6
    row = int(arrays["offsets"][step]) + 1
    arrays["z"][row, 0] = -1.0
    with pytest.raises(ValueError, match=rf"step {step} \(rows {row - 1}\.\.\d+ of z, R\): update: argument 'z'\[1\]"):
        dcslam.EkfSlam(dcslam.SlamConfig()).run_batch(**arrays)


def test_landmark_ids_follow_the_association_mode():
    arrays = packed()
    ids = np.arange(len(arrays["z"]))
    with pytest.raises(ValueError, match="update: argument 'landmark_ids' is only accepted in association mode 'known'"):
        dcslam.EkfSlam(dcslam.SlamConfig()).run_batch(**arrays, landmark_ids=ids)
    known = dcslam.EkfSlam(dcslam.SlamConfig(association="known", join_association="known"))
    with pytest.raises(ValueError, match="step 0 .*landmark_ids' is required in association mode 'known'"):
        known.run_batch(**arrays)
    with pytest.raises(ValueError, match=r"argument 'landmark_ids': expected shape \(\d+,\) \(one per row of z\)"):
        known.run_batch(**arrays, landmark_ids=ids[1:])
    repeated = ids.copy()
    repeated[1] = repeated[0]
    with pytest.raises(ValueError, match=r"step 0 \(rows 0\.\.\d+ of z, R, landmark_ids\): .*\[1\]: id 0 appears twice"):
        known.run_batch(**arrays, landmark_ids=repeated)
    assert len(known.stats.step_seconds) == 0


def test_an_empty_batch_and_empty_scans():
    slam = dcslam.EkfSlam(dcslam.SlamConfig())
    result = slam.run_batch(np.zeros((0, 3)), np.eye(3), np.zeros((0, 2)), np.eye(2), [0])
    assert len(result) == 0 and result.trajectory.shape == (1, 3) and result.ids.shape == (0,)
    result = slam.run(PackedSteps(np.ones((3, 3)) * 0.1, np.eye(3) * 1e-4, np.zeros((0, 2)), np.zeros((0, 2, 2)),
                                  np.zeros(4, dtype=np.int64)))
    assert [len(ids) for ids in result] == [0, 0, 0]
    np.testing.assert_allclose(result.trajectory[-1], slam.pose())
