"""Real datasets as sequences of filter steps: Victoria Park and iSAM/GTSAM 2D text files.

Each reader converts a whole file in one C++ call into flat numpy arrays; the step objects of
``.steps`` are light views into those arrays. Malformed files raise
:class:`dcslam.ParseError` (a ``ValueError``) naming the file, the line and the field.

Conventions (docs/design.md §2): ``u`` is the relative motion ``x_{R(k-1) R(k)}`` of the
robot frame, ``Q`` its covariance; measurements ``z`` are (m, 2) with one covariance ``R``
(2, 2) each. See ``docs/victoria_park.md`` for the Victoria Park vehicle model and noise choices.
"""

from __future__ import annotations

import contextlib
import math
import os
from importlib import resources
from typing import Optional, Tuple, Union

import numpy as np

from . import _core
from .config import SlamConfig
from .packed import PackedSteps, Step, Steps

__all__ = ["Step", "VictoriaPark", "Isam2d", "victoria_park", "read_isam2d"]

PathLike = Union[str, "os.PathLike[str]"]

VICTORIA_PARK_FILES = ("vp_odometry.csv.gz", "vp_scans.csv.gz", "vp_trees.csv.gz", "vp_gps.csv.gz")

# Noise choices for Victoria Park, C++'s VictoriaParkOptions (dcslam_bench reads the same); the
# reasons are in docs/victoria_park.md.
VICTORIA_PARK_DEFAULTS = _core.datasets.victoria_park_options()

# Heading that lines dead reckoning up with GPS over the first 120 s, per steering
# (docs/victoria_park.md, "The data").
_INITIAL_HEADING_DEG = {"raw": 33.75, "recalibrated": 34.5}


def _read_only(arrays: dict) -> dict:
    for value in arrays.values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return arrays


class VictoriaPark:
    """Victoria Park (ACFR), one step per laser scan; see :func:`victoria_park`.

    Attributes:
        steps: sequence of :class:`Step` (t, u, Q, z, R, diameters), one per laser scan.
        gps: (k, 3) t, x, y as recorded (outliers and gaps included).
        t, u, Q, z, R, offsets, diameters: the flat arrays behind ``steps``.
        trees_diameter: alias of ``diameters``, (M,) trunk diameter of each measurement.
        sensor_offset: laser pose on the rear-axle frame, (3.78, 0.5, 0.0).
        initial_pose_hint: (x, y, phi) first GPS fix and the heading that aligns dead
            reckoning with GPS, for plotting the map in the GPS frame.
        detections_total: detections in the tree file; detections_beyond_range: dropped ones.
        options: the options the steps were made with.
    """

    def __init__(self, arrays: dict, options: dict):
        self._arrays = _read_only(arrays)
        self.options = dict(options)
        self.t, self.u, self.Q = arrays["t"], arrays["u"], arrays["Q"]
        self.z, self.R, self.offsets = arrays["z"], arrays["R"], arrays["offsets"]
        self.diameters = self.trees_diameter = arrays["diameters"]
        self.gps = arrays["gps"]
        self.sensor_offset: Tuple[float, float, float] = tuple(arrays["laser_offset"])
        self.detections_total = int(arrays["detections_total"])
        self.detections_beyond_range = int(arrays["detections_beyond_range"])
        heading = math.radians(_INITIAL_HEADING_DEG[self.options["steering"]])
        first_fix = self.gps[0, 1:] if len(self.gps) else np.zeros(2)
        self.initial_pose_hint = np.array([first_fix[0], first_fix[1], heading])
        self.steps = Steps(self.offsets, self._step, self.packed_steps)

    def _step(self, k: int, rows: slice) -> Step:
        return Step(self.u[k], self.Q[k], self.z[rows], self.R[rows], t=float(self.t[k]),
                    diameters=self.diameters[rows], index=k)

    def packed_steps(self) -> PackedSteps:
        """The arrays behind ``steps``, as :meth:`~dcslam.SlamFilter.run_batch` takes them."""
        return PackedSteps(self.u, self.Q, self.z, self.R, self.offsets)

    def slam_config(self, **overrides) -> SlamConfig:
        """A :class:`~dcslam.SlamConfig` for this dataset, the preset ``dcslam_bench vp`` runs
        too (C++'s ``victoria_park_slam_config``): range–bearing from the laser's offset, JCBB
        inside local maps, RJC at joins. Keyword arguments override fields."""
        values = SlamConfig._from_core(_core.datasets.victoria_park_slam_config(self.sensor_offset)).to_dict()
        values.update(overrides)
        return SlamConfig(**values)

    def __repr__(self) -> str:
        return (f"VictoriaPark(steps={len(self.steps)}, measurements={len(self.z)}, "
                f"steering={self.options['steering']!r}, max_range={self.options['max_range']})")


class Isam2d:
    """An iSAM/GTSAM 2D graph replayed as filter steps; see :func:`read_isam2d`.

    Attributes:
        steps: sequence of :class:`Step` (u, Q, z, R, landmark_ids, pose_id), one per
            ODOMETRY line (plus an initial one when the first pose sees landmarks).
        u, Q, z, R, offsets, landmark_ids, pose_ids: the flat arrays behind ``steps``.
        odometry_lines, landmark_lines: line counts of the file.
    """

    def __init__(self, arrays: dict, path: str):
        self._arrays = _read_only(arrays)
        self.path = path
        self.u, self.Q = arrays["u"], arrays["Q"]
        self.z, self.R, self.offsets = arrays["z"], arrays["R"], arrays["offsets"]
        self.landmark_ids, self.pose_ids = arrays["landmark_ids"], arrays["pose_ids"]
        self.odometry_lines = int(arrays["odometry_lines"])
        self.landmark_lines = int(arrays["landmark_lines"])
        self.steps = Steps(self.offsets, self._step, self.packed_steps)

    def _step(self, k: int, rows: slice) -> Step:
        return Step(self.u[k], self.Q[k], self.z[rows], self.R[rows],
                    landmark_ids=self.landmark_ids[rows], pose_id=int(self.pose_ids[k]), index=k)

    def packed_steps(self) -> PackedSteps:
        """The arrays behind ``steps`` with the file's landmark ids, as
        :meth:`~dcslam.SlamFilter.run_batch` takes them."""
        return PackedSteps(self.u, self.Q, self.z, self.R, self.offsets, self.landmark_ids)

    def slam_config(self, **overrides) -> SlamConfig:
        """A :class:`~dcslam.SlamConfig` for replaying the file, the preset ``dcslam_bench isam``
        runs too (C++'s ``isam2d_slam_config``): Cartesian point observations from the robot
        frame, the file's landmark ids as known association. Keyword arguments override
        fields."""
        values = SlamConfig._from_core(_core.datasets.isam2d_slam_config()).to_dict()
        values.update(overrides)
        return SlamConfig(**values)

    def __repr__(self) -> str:
        return f"Isam2d({self.path!r}, steps={len(self.steps)}, measurements={len(self.z)})"


@contextlib.contextmanager
def _victoria_park_folder(data_dir: Optional[PathLike]):
    if data_dir is not None:
        yield os.fspath(data_dir)
        return
    # as_file gives a real folder even when the package is installed zipped.
    with resources.as_file(resources.files("dcslam") / "data" / "victoria_park") as folder:
        yield os.fspath(folder)


def victoria_park(data_dir: Optional[PathLike] = None, **options) -> VictoriaPark:
    """Loads Victoria Park, one step per laser scan (7249 steps).

    Args:
        data_dir: folder holding ``vp_odometry.csv.gz``, ``vp_scans.csv.gz``,
            ``vp_trees.csv.gz`` and ``vp_gps.csv.gz``; ``None`` uses the copy bundled with
            the package.
        steering: ``"recalibrated"`` (default: ACFR's fit 1.059·α + 0.0026, much closer to
            GPS) or ``"raw"`` (as logged; what the iSAM/GTSAM file integrated).
        max_range: trees whose trunk centre is farther than this [m] are dropped (30).
        sigma_range, sigma_bearing: measurement noise [m], [rad] (0.2, 0.016).
        sigma_speed, sigma_steering: odometry noise per 40 Hz sample [m/s], [rad] (0.6, 0.1).
        floor_sigma_xy, floor_sigma_phi: additive motion noise per sqrt(second) [m], [rad]
            (0.14, 0.002).

    Raises:
        ValueError: unknown option or bad value; :class:`dcslam.ParseError` for a malformed
        or missing file.
    """
    unknown = sorted(set(options) - set(VICTORIA_PARK_DEFAULTS))
    if unknown:
        raise _core.InvalidArgument(
            f"victoria_park: unknown option(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(VICTORIA_PARK_DEFAULTS))})")
    values = {**VICTORIA_PARK_DEFAULTS, **options}
    for name, value in values.items():
        if name == "steering":
            if not isinstance(value, str):
                raise _core.InvalidArgument(f"victoria_park: option 'steering' must be a string, got {value!r}")
        elif isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise _core.InvalidArgument(f"victoria_park: option '{name}' must be a finite number, got {value!r}")
    with _victoria_park_folder(data_dir) as folder:
        paths = [os.path.join(folder, name) for name in VICTORIA_PARK_FILES]
        arrays = _core.datasets.load_victoria_park(*paths, **values)
    return VictoriaPark(arrays, values)


def read_isam2d(path: PathLike) -> Isam2d:
    """Reads an iSAM/GTSAM 2D text file (plain or gzip) of ODOMETRY and LANDMARK lines.

    ``ODOMETRY i j dx dy dtheta c11 c12 c13 c22 c23 c33``: one step, motion of pose j in
    pose i's frame, noise columns read as a covariance (as GTSAM's load2D does).
    ``LANDMARK i l x y c11 c12 c22``: the point (x, y) of landmark l in pose i's frame with
    its 2x2 covariance, attached to the step that ends at pose i. (GTSAM converts this
    noise to bearing/range; we keep the Cartesian point and its noise.)

    Raises:
        dcslam.ParseError: malformed file, naming the file, line and field.
    """
    path = os.fspath(path)
    return Isam2d(_core.datasets.read_isam2d(path), path)


# UTIAS MR.CLAM lives in its own module (it reads its files in Python); it builds its steps with
# _read_only above, so it is imported last.
from .mrclam import MrClam, mrclam  # noqa: E402

__all__ += ["MrClam", "mrclam"]
