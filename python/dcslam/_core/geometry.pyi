"""
2D geometry with analytic Jacobians.
"""
from __future__ import annotations
import numpy
import numpy.typing
import typing
__all__: list[str] = ['compose', 'innovation', 'inverse_observe', 'inverse_transform_point', 'invert', 'observe', 'transform_point', 'wrap_angle']
def compose(a: typing.Any, b: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def innovation(model: str, z: typing.Any, z_hat: typing.Any) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[2, 1]"]:
    ...
def inverse_observe(model: str, sensor_offset: typing.Any, robot: typing.Any, z: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def inverse_transform_point(a: typing.Any, p: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def invert(a: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def observe(model: str, sensor_offset: typing.Any, robot: typing.Any, feature: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def transform_point(a: typing.Any, p: typing.Any, *, jacobians: bool = False) -> typing.Any:
    ...
def wrap_angle(angle: typing.SupportsFloat | typing.SupportsIndex) -> float:
    """
    Wraps an angle to (-pi, pi].
    """
