"""
Dataset readers (use dcslam.datasets).
"""
from __future__ import annotations
import dcslam._core
import numpy
import numpy.typing
import typing
__all__: list[str] = ['integrate_odometry', 'isam2d_slam_config', 'load_victoria_park', 'read_isam2d', 'victoria_park_options', 'victoria_park_slam_config']
def integrate_odometry(samples: typing.Annotated[numpy.typing.ArrayLike, numpy.float64], t_begin: typing.SupportsFloat | typing.SupportsIndex, t_end: typing.SupportsFloat | typing.SupportsIndex, *, sigma_speed: typing.SupportsFloat | typing.SupportsIndex, sigma_steering: typing.SupportsFloat | typing.SupportsIndex, floor_sigma_xy: typing.SupportsFloat | typing.SupportsIndex, floor_sigma_phi: typing.SupportsFloat | typing.SupportsIndex) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64]]:
    """
    Victoria Park's vehicle model: (t, encoder speed, steering) samples -> (u, Q).
    """
def isam2d_slam_config() -> dcslam._core.SlamConfig:
    """
    The filter options for replaying an iSAM 2D file (isam2d_slam_config in C++).
    """
def load_victoria_park(odometry: str, scans: str, trees: str, gps: str, *, steering: str, max_range: typing.SupportsFloat | typing.SupportsIndex, sigma_range: typing.SupportsFloat | typing.SupportsIndex, sigma_bearing: typing.SupportsFloat | typing.SupportsIndex, sigma_speed: typing.SupportsFloat | typing.SupportsIndex, sigma_steering: typing.SupportsFloat | typing.SupportsIndex, floor_sigma_xy: typing.SupportsFloat | typing.SupportsIndex, floor_sigma_phi: typing.SupportsFloat | typing.SupportsIndex) -> dict:
    """
    Reads the four Victoria Park CSVs into flat arrays (one step per laser scan).
    """
def read_isam2d(path: str) -> dict:
    """
    Reads an iSAM/GTSAM 2D text file (ODOMETRY/LANDMARK lines).
    """
def victoria_park_options() -> dict:
    """
    VictoriaParkOptions' defaults, by load_victoria_park's keyword names.
    """
def victoria_park_slam_config(laser_offset: typing.Any) -> dcslam._core.SlamConfig:
    """
    The filter options for Victoria Park (victoria_park_slam_config in C++).
    """
