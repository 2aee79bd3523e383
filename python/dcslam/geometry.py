"""2D geometry with analytic Jacobians (docs/design.md §2).

Poses are ``(x, y, phi)``, points ``(x, y)``, angles in radians wrapped to (-pi, pi].
Every function takes ``jacobians=True`` to also return its Jacobians with respect to each
input, in argument order:

- ``compose(a, b)`` = a ⊕ b, Jacobians (3x3, 3x3);
- ``invert(a)`` = ⊖a, Jacobian (3x3);
- ``transform_point(a, p)`` = a ⊕ p, Jacobians (2x3, 2x2);
- ``inverse_transform_point(a, p)`` = (⊖a) ⊕ p, Jacobians (2x3, 2x2);
- ``observe(model, sensor_offset, robot, feature)`` = h(x_R, f), Jacobians (2x3, 2x2);
- ``inverse_observe(model, sensor_offset, robot, z)`` = g(x_R, z), Jacobians (2x3, 2x2);
- ``innovation(model, z, z_hat)`` = z - z_hat with the bearing wrapped.

``model`` is ``"range_bearing"`` or ``"point"``. Wrong shapes or non-finite values raise
``ValueError`` naming the argument.
"""

from ._core.geometry import (  # noqa: F401
    compose,
    innovation,
    inverse_observe,
    inverse_transform_point,
    invert,
    observe,
    transform_point,
    wrap_angle,
)

__all__ = [
    "compose",
    "innovation",
    "inverse_observe",
    "inverse_transform_point",
    "invert",
    "observe",
    "transform_point",
    "wrap_angle",
]
