"""A quick self-check of the compiled core: analytic Jacobians against central differences."""

from __future__ import annotations

from typing import Callable, List, Tuple

import numpy as np

from . import geometry

Check = Tuple[str, float]


def _numeric_jacobian(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, eps: float = 1e-6,
                      angle_rows: Tuple[int, ...] = ()) -> np.ndarray:
    columns = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        diff = f(x + dx) - f(x - dx)
        for r in angle_rows:  # angles wrap: difference on the circle
            diff[r] = geometry.wrap_angle(diff[r])
        columns.append(diff / (2 * eps))
    return np.stack(columns, axis=1)


def geometry_errors(samples: int = 200, seed: int = 0) -> List[Check]:
    """Largest |analytic - numeric| Jacobian entry of each geometry function."""
    rng = np.random.default_rng(seed)
    worst = {}

    def record(name: str, analytic: np.ndarray, numeric: np.ndarray) -> None:
        worst[name] = max(worst.get(name, 0.0), float(np.max(np.abs(analytic - numeric))))

    for _ in range(samples):
        a = np.array([*rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi)])
        b = np.array([*rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi)])
        p = rng.uniform(-10, 10, 2)
        offset = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi)])
        _, Ja, Jb = geometry.compose(a, b, jacobians=True)
        record("compose", Ja, _numeric_jacobian(lambda v: geometry.compose(v, b), a, angle_rows=(2,)))
        record("compose", Jb, _numeric_jacobian(lambda v: geometry.compose(a, v), b, angle_rows=(2,)))
        _, J = geometry.invert(a, jacobians=True)
        record("invert", J, _numeric_jacobian(geometry.invert, a, angle_rows=(2,)))
        for model, rows in (("range_bearing", (1,)), ("point", ())):
            feature = geometry.transform_point(geometry.compose(a, offset), p)
            _, Jr, Jf = geometry.observe(model, offset, a, feature, jacobians=True)
            record(f"observe[{model}]", Jr, _numeric_jacobian(
                lambda v: geometry.observe(model, offset, v, feature), a, angle_rows=rows))
            record(f"observe[{model}]", Jf, _numeric_jacobian(
                lambda v: geometry.observe(model, offset, a, v), feature, angle_rows=rows))
            z = geometry.observe(model, offset, a, feature)
            _, Jr, Jz = geometry.inverse_observe(model, offset, a, z, jacobians=True)
            record(f"inverse_observe[{model}]", Jr, _numeric_jacobian(
                lambda v: geometry.inverse_observe(model, offset, v, z), a))
            record(f"inverse_observe[{model}]", Jz, _numeric_jacobian(
                lambda v: geometry.inverse_observe(model, offset, a, v), z))
    return sorted(worst.items())
