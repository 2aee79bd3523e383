"""The trimmed per-step path (predict, update, pose straight into the compiled filter, arrays
that are already C-contiguous native float64 read in place) gives what the converting path
gives, keeps every check, and survives copies: a byte-swapped, Fortran-ordered, strided,
float32 or list input moves the filter exactly as the plain array does."""

import copy
import pickle

import numpy as np
import pytest

import dcslam

U = np.array([0.7, -0.1, 0.05])
Q = np.array([[1e-3, 2e-4, 0.0], [2e-4, 5e-4, 1e-5], [0.0, 1e-5, 1e-4]])
Z = np.array([[2.0, 0.3], [3.5, -0.6], [1.2, 1.1]])
R = np.diag([0.01, 0.001])


def run(u, q, z, r):
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="nn"))
    slam.predict(u, q)
    ids = slam.update(z, r)
    return slam.pose(), ids, slam.estimate().covariance


def variants(array):
    yield array.astype(array.dtype.newbyteorder())  # same values, non-native byte order
    yield np.asfortranarray(array)
    yield np.repeat(array, 2, axis=-1)[..., ::2]  # strided view
    yield array.tolist()


@pytest.mark.parametrize("which", range(4))
def test_every_layout_of_the_inputs_moves_the_filter_as_the_plain_arrays_do(which):
    plain = run(U, Q, Z, R)
    for index, argument in enumerate((U, Q, Z, R)):
        arguments = [U, Q, Z, R]
        arguments[index] = list(variants(argument))[which]
        for got, expected in zip(run(*arguments), plain):
            np.testing.assert_array_equal(got, expected)


def test_float32_is_converted_once_and_the_result_matches_its_values():
    single = U.astype(np.float32)
    slam = dcslam.EkfSlam(dcslam.SlamConfig())
    slam.predict(single, Q)
    np.testing.assert_array_equal(slam.pose(), single.astype(np.float64))


@pytest.mark.parametrize("call, message", [
    (lambda s: s.predict(np.array([0.0, np.nan, 0.0]), Q), "predict: argument 'u': contains a non-finite value"),
    (lambda s: s.predict(np.zeros(4), Q), r"predict: argument 'u': expected shape \(3,\), got \(4,\)"),
    (lambda s: s.predict(U, np.eye(2)), r"predict: argument 'Q': expected shape \(3, 3\), got \(2, 2\)"),
    (lambda s: s.predict(U, np.full((3, 3), np.inf)), "predict: argument 'Q': contains a non-finite value"),
    (lambda s: s.update(np.zeros((2, 3)), R), r"update: argument 'z': expected shape \(m, 2\), got \(2, 3\)"),
    (lambda s: s.update(Z, np.eye(3)), r"update: argument 'R': expected shape \(2, 2\) or \(3, 2, 2\)"),
    (lambda s: s.predict(np.array(["1", "2", "3"]), Q), "predict: argument 'u': expected an array of real numbers"),
    (lambda s: s.predict(np.array([True, False, True]), Q), "predict: argument 'u': expected an array of real"),
])
def test_the_direct_path_keeps_every_check(call, message):
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="nn"))
    with pytest.raises(ValueError, match=message):
        call(slam)
    np.testing.assert_array_equal(slam.pose(), np.zeros(3))


def test_an_empty_scan_of_any_empty_shape_is_accepted():
    slam = dcslam.EkfSlam(dcslam.SlamConfig())
    slam.predict(U, Q)
    for empty in (np.zeros((0, 2)), [], np.zeros(0), np.zeros((0, 3))):
        assert slam.update(empty, R).shape == (0,)


def test_copies_drive_their_own_filter():
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="nn"))
    slam.predict(U, Q)
    for other in (copy.deepcopy(slam), pickle.loads(pickle.dumps(slam)), copy.copy(slam)):
        before = slam.pose()
        other.predict(U, Q)
        other.update(Z, R)
        if other._core is not slam._core:  # copy.copy shares the compiled filter, as it shares any attribute
            np.testing.assert_array_equal(slam.pose(), before)
            assert not np.array_equal(other.pose(), before)
        assert other.predict.__self__ is other._core and other.pose.__self__ is other._core


def test_a_long_update_lets_another_python_thread_run():
    """The GIL is released while C++ works when another Python thread exists (only then: alone,
    nothing could use it). A spinning thread must record times inside a long update."""
    import threading
    import time

    sim = dcslam.simulate("straight", steps=120, seed=0, features_per_step=40)
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="known", join_association="known"))
    slam.run(sim)
    step = sim.steps[-1]
    stamps, stop = [], threading.Event()

    def spin():
        while not stop.is_set():
            stamps.append(time.perf_counter())
            time.sleep(0)

    thread = threading.Thread(target=spin)
    thread.start()
    try:
        while not stamps:  # the thread is running
            time.sleep(0.001)
        slam.predict(step.u, step.Q)
        begin = time.perf_counter()
        slam.update(step.z, step.R, step.true_ids)
        end = time.perf_counter()
    finally:
        stop.set()
        thread.join()
    assert end - begin > 2e-3, "the update is too short to tell"
    assert sum(begin < t < end for t in stamps) >= 3


def test_a_subclass_that_overrides_a_step_method_keeps_its_override():
    class Counting(dcslam.EkfSlam):
        calls = 0

        def predict(self, u, Q):
            Counting.calls += 1
            super().predict(u, Q)

    slam = Counting(dcslam.SlamConfig())
    slam.predict(U, Q)
    copy.deepcopy(slam).predict(U, Q)
    assert Counting.calls == 2
    np.testing.assert_array_equal(slam.pose(), U)  # update and pose still go straight to C++
    assert slam.pose.__self__ is slam._core
