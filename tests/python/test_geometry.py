"""Geometry bindings: Jacobians against central differences, round trips, bad input."""

import math

import numpy as np
import pytest

import dcslam
from dcslam import geometry as g

RNG = np.random.default_rng(7)
MODELS = ["range_bearing", "point"]


def random_pose(near_pi: bool = False) -> np.ndarray:
    phi = (math.pi - RNG.uniform(0, 1e-3)) * RNG.choice([-1, 1]) if near_pi else RNG.uniform(-math.pi, math.pi)
    return np.array([*RNG.uniform(-20, 20, 2), phi])


def numeric_jacobian(f, x, angle_rows=(), eps=1e-6):
    cols = []
    for i in range(len(x)):
        d = np.zeros(len(x))
        d[i] = eps
        diff = np.asarray(f(x + d)) - np.asarray(f(x - d))
        for r in angle_rows:
            diff[r] = g.wrap_angle(diff[r])
        cols.append(diff / (2 * eps))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("near_pi", [False, True])
def test_compose_and_invert_jacobians(near_pi):
    for _ in range(100):
        a, b = random_pose(near_pi), random_pose(near_pi)
        c, Ja, Jb = g.compose(a, b, jacobians=True)
        assert c.shape == (3,) and -math.pi < c[2] <= math.pi
        np.testing.assert_allclose(Ja, numeric_jacobian(lambda v: g.compose(v, b), a, (2,)), atol=1e-6)
        np.testing.assert_allclose(Jb, numeric_jacobian(lambda v: g.compose(a, v), b, (2,)), atol=1e-6)
        _, J = g.invert(a, jacobians=True)
        np.testing.assert_allclose(J, numeric_jacobian(g.invert, a, (2,)), atol=1e-6)


def test_round_trips():
    for _ in range(100):
        a, b = random_pose(), random_pose(True)
        np.testing.assert_allclose(g.compose(a, g.invert(a)), 0, atol=1e-12)
        back = g.compose(g.invert(a), g.compose(a, b))
        np.testing.assert_allclose(back[:2], b[:2], atol=1e-9)
        assert abs(g.wrap_angle(back[2] - b[2])) < 1e-12
        p = RNG.uniform(-10, 10, 2)
        np.testing.assert_allclose(g.inverse_transform_point(a, g.transform_point(a, p)), p, atol=1e-9)


def test_compose_matches_homogeneous_matrices():
    # Independent oracle: a ⊕ b is the product of the 3x3 homogeneous transforms.
    def T(p):
        c, s = math.cos(p[2]), math.sin(p[2])
        return np.array([[c, -s, p[0]], [s, c, p[1]], [0, 0, 1]])

    for _ in range(50):
        a, b = random_pose(), random_pose()
        Tc = T(a) @ T(b)
        c = g.compose(a, b)
        np.testing.assert_allclose(c[:2], Tc[:2, 2], atol=1e-12)
        assert abs(g.wrap_angle(c[2] - math.atan2(Tc[1, 0], Tc[0, 0]))) < 1e-12


@pytest.mark.parametrize("model", MODELS)
def test_observation_jacobians_and_inverse(model):
    rows = (1,) if model == "range_bearing" else ()
    for _ in range(100):
        robot = random_pose(RNG.random() < 0.3)
        offset = np.array([RNG.uniform(-4, 4), RNG.uniform(-1, 1), RNG.uniform(-math.pi, math.pi)])
        bearing = RNG.uniform(-math.pi, math.pi)
        local = RNG.uniform(1, 15) * np.array([math.cos(bearing), math.sin(bearing)])
        feature = g.transform_point(g.compose(robot, offset), local)
        z, Jr, Jf = g.observe(model, offset, robot, feature, jacobians=True)
        np.testing.assert_allclose(Jr, numeric_jacobian(lambda v: g.observe(model, offset, v, feature), robot, rows), atol=1e-6)
        np.testing.assert_allclose(Jf, numeric_jacobian(lambda v: g.observe(model, offset, robot, v), feature, rows), atol=1e-6)
        f, Gr, Gz = g.inverse_observe(model, offset, robot, z, jacobians=True)
        np.testing.assert_allclose(f, feature, atol=1e-9)
        np.testing.assert_allclose(Gr, numeric_jacobian(lambda v: g.inverse_observe(model, offset, v, z), robot), atol=1e-6)
        np.testing.assert_allclose(Gz, numeric_jacobian(lambda v: g.inverse_observe(model, offset, robot, v), z), atol=1e-6)


def test_range_bearing_by_hand():
    # Sensor 1 m ahead of a robot at (2, 3) facing +y; a feature at (2, 10) is 6 m straight ahead.
    z = g.observe("range_bearing", (1.0, 0.0, 0.0), (2.0, 3.0, math.pi / 2), (2.0, 10.0))
    np.testing.assert_allclose(z, [6.0, 0.0], atol=1e-12)
    z = g.observe("point", (1.0, 0.0, 0.0), (2.0, 3.0, math.pi / 2), (0.0, 4.0))
    np.testing.assert_allclose(z, [0.0, 2.0], atol=1e-12)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: g.compose([1.0, 2.0], [0, 0, 0]), "'a'"),
        (lambda: g.compose([0, 0, 0], np.zeros((3, 1))), "'b'"),
        (lambda: g.invert([0, float("nan"), 0]), "'a'"),
        (lambda: g.transform_point([0, 0, 0], [1.0, float("inf")]), "'p'"),
        (lambda: g.observe("range_bearing", [0, 0, 0], [0, 0, 0], [1, 2, 3]), "'feature'"),
        (lambda: g.observe("laser", [0, 0, 0], [0, 0, 0], [1, 2]), "'model'"),
        (lambda: g.inverse_observe("point", [0, 0], [0, 0, 0], [1, 2]), "'sensor_offset'"),
        (lambda: g.compose("abc", [0, 0, 0]), "'a'"),
        (lambda: g.compose(None, [0, 0, 0]), "'a'"),
    ],
)
def test_bad_input_raises_value_error_naming_argument(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_version_and_config():
    assert dcslam.__version__.count(".") == 2
    cfg = dcslam.SlamConfig()
    assert cfg.validate() is cfg
    with pytest.raises(ValueError, match="association"):
        dcslam.SlamConfig(association="magic").validate()
    with pytest.raises(ValueError, match="gate_confidence"):
        dcslam.SlamConfig(gate_confidence=1.5).validate()
    with pytest.raises(ValueError, match="sensor_offset"):
        dcslam.SlamConfig(sensor_offset=(0.0, 1.0)).validate()
