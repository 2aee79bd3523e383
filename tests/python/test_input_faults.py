"""Absurd numbers and silent coercions: each input is refused with a ValueError naming it, and
the filter is left as it was (docs/api.md, "Input rules")."""

import numpy as np
import pytest

import dcslam


def known_filter(observation="range_bearing"):
    slam = dcslam.EkfSlam(dcslam.SlamConfig(observation=observation, association="known",
                                            join_association="known"))
    slam.predict(np.zeros(3), np.zeros((3, 3)))
    slam.update([[2.0, 0.1]], np.eye(2) * 0.01, [0])
    return slam


def assert_unchanged(slam, before):
    after = slam.estimate()
    np.testing.assert_array_equal(after.covariance, before.covariance)
    np.testing.assert_array_equal(after.robot, before.robot)
    assert np.all(np.isfinite(after.covariance))


@pytest.mark.parametrize("u, Q, message", [
    ([1e155, 0.0, 0.0], np.eye(3) * 0.01, r"predict: argument 'u'\[0\]: 1e\+155 exceeds 1000000 m in magnitude"),
    ([0.0, 0.0, -1e7], np.eye(3) * 0.01, r"predict: argument 'u'\[2\]: -10000000 exceeds 1000 rad"),
    (np.zeros(3), np.diag([1e155, 1.0, 1.0]), r"predict: argument 'Q'\[0, 0\]: 1e\+155 exceeds 1e\+12"),
    # A large variance on one axis does not excuse a negative one on another.
    (np.zeros(3), np.diag([1e6, 1e-4, -1e-7]), r"not positive semi-definite \(smallest eigenvalue -1e-07\)"),
])
def test_absurd_motions_are_refused_with_the_value(u, Q, message):
    slam = known_filter()
    before = slam.estimate()
    with pytest.raises(dcslam.InvalidArgument, match=message):
        slam.predict(u, Q)
    assert_unchanged(slam, before)


def test_a_zero_variance_from_rounding_is_still_legal():
    slam = known_filter()
    rotation = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
    singular = rotation @ np.diag([0.04, 0.0, 1e-4]) @ rotation.T  # eigenvalue ~ -1e-18
    slam.predict([1.0, 0.0, 0.1], 0.5 * (singular + singular.T))
    assert np.all(np.linalg.eigvalsh(slam.estimate().covariance) > -1e-9)


@pytest.mark.parametrize("observation, z, R, message", [
    ("range_bearing", [[1e155, 0.1]], np.eye(2) * 0.01, r"update: argument 'z'\[0\]: range 1e\+155 exceeds"),
    ("range_bearing", [[2.0, 1e9]], np.eye(2) * 0.01, r"update: argument 'z'\[0\]: bearing 1000000000 exceeds"),
    ("point", [[3.0, -1e300]], np.eye(2) * 0.01, r"update: argument 'z'\[0\]: coordinate -1e\+300 exceeds"),
    ("range_bearing", [[2.0, 0.1]], np.eye(2) * 1e200, r"update: argument 'R'\[0, 0\]: 1e\+200 exceeds 1e\+12"),
])
def test_absurd_measurements_are_refused_with_the_value(observation, z, R, message):
    slam = known_filter(observation)
    before = slam.estimate()
    with pytest.raises(dcslam.InvalidArgument, match=message):
        slam.update(z, R, [1])
    assert_unchanged(slam, before)


def test_a_uint64_id_beyond_int64_is_refused_not_wrapped():
    slam = known_filter()
    ids = np.array([2**64 - 1], dtype=np.uint64)
    with pytest.raises(ValueError, match=r"update: argument 'landmark_ids'\[0\] is 18446744073709551615"):
        slam.update([[2.0, 0.1]], np.eye(2) * 0.01, ids)


class _Step:
    def __init__(self, ids, u=(0.0, 0.0, 0.0)):
        self.u, self.Q = np.asarray(u), np.eye(3) * 1e-4
        self.z, self.R, self.landmark_ids = np.array([[2.0, 0.1]]), np.eye(2) * 0.01, ids


@pytest.mark.parametrize("ids", [[0.7], ["3"], [2**64 - 1], np.array([2**64 - 1], dtype=np.uint64), [True]])
def test_run_and_update_refuse_the_same_ids(ids):
    slam = known_filter()
    with pytest.raises(ValueError, match="update: argument 'landmark_ids'"):
        slam.update([[2.0, 0.1]], np.eye(2) * 0.01, ids)
    with pytest.raises(ValueError, match="run: step 0: argument 'landmark_ids'"):
        slam.run([_Step(ids)])
    assert len(slam.stats.step_seconds) == 1


@pytest.mark.parametrize("u", [["1", "2", "3"], np.array([1.0, 0.0, 0.0]) + 1j, [True, False, False],
                               np.array([1, 0, 0], dtype=object)])
def test_strings_complex_and_booleans_are_not_numbers(u):
    slam = known_filter()
    with pytest.raises(ValueError, match="predict: argument 'u': expected an array of real numbers"):
        slam.predict(u, np.eye(3) * 1e-4)
    with pytest.raises(ValueError, match="update: argument 'z': expected an array of real numbers"):
        slam.update(np.array([u[:2]]), np.eye(2) * 0.01, [1])
    with pytest.raises(ValueError, match="run: step 0: argument 'u'"):
        slam.run([_Step([1], u=u)])


@pytest.mark.parametrize("field", ["amortize", "threaded_joins", "keep_local_map_poses"])
@pytest.mark.parametrize("value", [None, 2, 0.5, "yes", 1])
def test_boolean_options_take_only_booleans(field, value):
    with pytest.raises(ValueError, match=f"SlamConfig.{field}: expected True or False"):
        dcslam.SlamConfig(**{field: value}).validate()
    dcslam.SlamConfig(**{field: np.bool_(True)}).validate()


@pytest.mark.parametrize("field, value", [("local_map_features", True), ("merge_radius", True),
                                          ("seed", True), ("steps", True)])
def test_numeric_options_refuse_booleans(field, value):
    if field == "steps":
        with pytest.raises(ValueError, match="SimulationConfig.steps"):
            dcslam.SimulationConfig(steps=value).validate()
        return
    with pytest.raises(ValueError, match=f"SlamConfig.{field}"):
        dcslam.SlamConfig(**{field: value}).validate()


@pytest.mark.parametrize("config, field", [(dcslam.SlamConfig, "local_map_features"), (dcslam.SlamConfig, "seed"),
                                           (dcslam.SimulationConfig, "side_steps")])
def test_an_integer_too_large_for_its_field_is_one_short_line(config, field):
    # pybind11's TypeError listed the setter's signature over several lines (found by CLI fuzzing).
    with pytest.raises(ValueError) as error:
        config(**{field: 10 ** 20}).validate()
    message = str(error.value)
    assert message.startswith(f"{config.__name__}.{field}: invalid value 100000000000000000000 (expected ")
    assert "\n" not in message and len(message) < 150, message


@pytest.mark.parametrize("field", ["side_steps", "num_features", "world_margin"])
def test_optional_numeric_simulation_options_refuse_booleans(field):
    with pytest.raises(ValueError, match=f"SimulationConfig.{field}: expected a number, got True"):
        dcslam.SimulationConfig(**{field: True}).validate()


@pytest.mark.parametrize("association", ["jcbb", "nn"])
def test_joins_by_id_need_ids_inside_local_maps(association):
    config = dcslam.SlamConfig(association=association, join_association="known")
    with pytest.raises(ValueError, match="SlamConfig.join_association: 'known' needs association 'known'"):
        dcslam.DCSlam(config)


@pytest.mark.parametrize("observation, field", [("range_bearing", "range_sigma_fraction"),
                                                ("range_bearing", "bearing_sigma"), ("point", "point_sigma")])
def test_the_simulator_refuses_measurement_noise_the_filters_refuse(observation, field):
    with pytest.raises(ValueError, match=f"SimulationConfig.{field}: must be finite and > 0"):
        dcslam.simulate("straight", steps=5, observation=observation, **{field: 0.0})


def test_the_chi_square_quantile_prints_the_refused_value():
    with pytest.raises(dcslam.InvalidArgument, match=r"alpha must lie in \(0, 1\), got -1e-09"):
        dcslam._core.chi2_upper_quantile(2.0, -1e-9)


def test_estimate_threads_is_a_count_of_zero_or_more():
    with pytest.raises(ValueError, match=r"SlamConfig.*estimate_threads: must be >= 0 \(0: every hardware thread\), got -1"):
        dcslam.SlamConfig(estimate_threads=-1).validate()
    with pytest.raises(ValueError, match="SlamConfig.estimate_threads"):
        dcslam.SlamConfig(estimate_threads=True).validate()
    dcslam.SlamConfig(estimate_threads=0).validate()
