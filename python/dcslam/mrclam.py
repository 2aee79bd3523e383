"""UTIAS MR.CLAM dataset 2 as filter steps, with the Vicon ground truth in the first pose's frame.

The Multi-Robot Cooperative Localization and Mapping dataset (Leung, Halpern, Barfoot, Liu,
IJRR 2011) has five robots driving among 15 barcoded landmarks for 1900 s, each with wheel
odometry (v, omega), a camera giving range and bearing to barcodes, and Vicon poses. Dataset 2's
resampled files share one 50 Hz clock. Robot 1's files are bundled with the package
(``dcslam/data/mrclam``); any robot reads from a folder holding the same files.

One step per time at which the robot saw at least one landmark: the odometry between the
previous such time and this one is integrated into ``u`` (the relative motion of the robot
frame) and its covariance ``Q``; every landmark seen at that time is one row of ``z``
(range, bearing) with its landmark subject number in ``landmark_ids``. Sightings of the other
robots (the barcodes that ``Barcodes.dat`` gives subjects 1-5) are left out.

How the noise values were derived from robot 1 against the Vicon truth, the clean-up of the
truth's heading glitches and what the numbers are: ``docs/mrclam.md``.
"""

from __future__ import annotations

import contextlib
import gzip
import math
import os
import re
import zlib
from importlib import resources
from typing import Any, Dict, NoReturn, Optional, Tuple, Union

import numpy as np

from . import _core
from .config import SlamConfig
from .datasets import _read_only
from .packed import PackedSteps, Step, Steps

__all__ = ["MrClam", "mrclam", "MRCLAM_DEFAULTS", "LOCAL_MAP_FEATURES", "ROBOT_COUNT", "BUNDLED_ROBOTS", "robot_files",
           "read_table", "read_robot", "clean_heading_glitches", "integrate_odometry"]

PathLike = Union[str, "os.PathLike[str]"]

ROBOT_COUNT = 5  # dataset 2 has robots 1-5 (subjects 1-5 of Barcodes.dat)
BUNDLED_ROBOTS = (1,)

# Noise and odometry calibration, derived from robot 1 against its Vicon truth
# (studies/mrclam_noise_study.py; the derivation and the checks on robots 2 and 4 are in
# docs/mrclam.md).
MRCLAM_DEFAULTS = dict(
    odometry_delay=0.20,         # the robot moves this long [s] after its logged speeds
    speed_scale=0.953,           # true forward speed / logged speed
    turn_scale=0.907,            # true turn rate / logged turn rate
    sigma_speed=0.0076,          # white noise on the forward speed [m/s/sqrt(Hz)]
    sigma_turn=0.031,             # white noise on the turn rate [rad/s/sqrt(Hz)]
    sigma_lateral=0.0025,        # white noise on the sideways speed (slip) [m/s/sqrt(Hz)]
    range_sigma_fraction=0.04,   # range sigma / range
    sigma_bearing=0.03,          # [rad]
)
_POSITIVE_OPTIONS = ("range_sigma_fraction", "sigma_bearing")
_SIGNED_OPTIONS = ("odometry_delay",)
# D&C's local map size here: the room has only 15 landmarks, so the default 30 would never
# close a local map (D&C would be the EKF); 8 was the best landmark RMS on robot 1 among
# 4, 6, 8, 10, 12 and 30 (docs/mrclam.md).
LOCAL_MAP_FEATURES = 8

# The columns of each file (whitespace-separated, no header; '#' lines are comments).
GROUNDTRUTH_FIELDS = ("t", "x", "y", "theta")
ODOMETRY_FIELDS = ("t", "v", "omega")
MEASUREMENT_FIELDS = ("t", "barcode", "range", "bearing")
BARCODE_FIELDS = ("subject", "barcode")
LANDMARK_FIELDS = ("barcode", "x", "y", "sd_x", "sd_y")

# A heading sample further than this from the circular median of its neighbours is a Vicon
# glitch (the robots turn at most 0.6 rad/s, 0.15 rad over the half second around a sample).
HEADING_GLITCH_RAD = 0.1
HEADING_GLITCH_HALF_WINDOW = 12  # samples on each side (0.24 s at 50 Hz)

# The longest line accepted, as in the C++ text reader, and the most text a file may hold (a
# robot's largest file is 5 MB): a broken file cannot take more memory than that.
MAX_LINE_BYTES = 64 * 1024
MAX_FILE_BYTES = 256 << 20
_NUMBER = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_NUMBER_CHARACTERS = b"0123456789+-.eE "


def _excerpt(text: bytes, limit: int = 40) -> str:
    """At most ``limit`` bytes of the file for a message, non-printable bytes as \\xNN."""
    shown = "".join(chr(b) if 32 <= b < 127 else f"\\x{b:02x}" for b in text[:limit])
    return shown + ("..." if len(text) > limit else "")


def _file_bytes(path: str) -> bytes:
    """The whole text of a plain or gzip file (gzip told by its magic bytes, not its name)."""
    try:
        with open(path, "rb") as handle:
            gzipped = handle.read(2) == b"\x1f\x8b"
            handle.seek(0)
            # Read one byte past the limit to tell a file at the limit from a larger one, without
            # reading (or inflating) more than that.
            try:
                data = (gzip.GzipFile(fileobj=handle) if gzipped else handle).read(MAX_FILE_BYTES + 1)
            except (EOFError, OSError, zlib.error) as error:
                if not gzipped:
                    raise
                raise _core.ParseError(f"{path}: broken gzip stream ({error})") from None
    except FileNotFoundError:
        raise _core.ParseError(f"{path}: no such file") from None
    except OSError as error:
        raise _core.ParseError(f"{path}: cannot read ({error.strerror or error})") from None
    if len(data) > MAX_FILE_BYTES:
        raise _core.ParseError(f"{path}: more than {MAX_FILE_BYTES} bytes of text")
    return data


def read_table(path: PathLike, fields: Tuple[str, ...], integer_fields: Tuple[str, ...] = ()) -> Tuple[np.ndarray, np.ndarray]:
    """Reads a whitespace-separated table without header into a float array.

    Blank lines and lines starting with ``#`` are skipped. Every other line must hold exactly
    ``len(fields)`` decimal numbers (no inf, nan, hex or digit separators); ``integer_fields``
    must be whole.

    Returns:
        (values (n, len(fields)), line_numbers (n,)) with 1-based line numbers for messages.

    Raises:
        dcslam.ParseError: ``"<file>:<line>: field '<name>': ..."``, a missing or empty file, a
        broken gzip stream, a NUL byte or a line longer than 64 KiB.
    """
    path = os.fspath(path)
    data = _file_bytes(path)
    if b"\0" in data:
        line = data.count(b"\n", 0, data.index(b"\0")) + 1
        raise _core.ParseError(f"{path}:{line}: NUL byte (not a text file)")
    lines = data.split(b"\n")
    if max(map(len, lines)) > MAX_LINE_BYTES:
        number = next(i for i, line in enumerate(lines, 1) if len(line) > MAX_LINE_BYTES)
        raise _core.ParseError(f"{path}:{number}: line longer than {MAX_LINE_BYTES} bytes")
    rows = [(number, line.split()) for number, line in enumerate(lines, 1)]
    rows = [(number, tokens) for number, tokens in rows if tokens and not tokens[0].startswith(b"#")]
    if not rows:
        raise _core.ParseError(f"{path}: no data lines")
    width = len(fields)
    for number, tokens in rows:
        if len(tokens) != width:
            raise _core.ParseError(f"{path}:{number}: {len(tokens)} fields, expected {width} ({' '.join(fields)}): "
                                   f"'{_excerpt(b' '.join(tokens))}'")
    flat = [token for _, tokens in rows for token in tokens]
    numbers = np.array([number for number, _ in rows], dtype=np.int64)
    # Fast path: only the characters of decimal numbers, then numpy's conversion. Python's
    # float() grammar restricted to these characters is exactly the decimal numbers (no inf,
    # nan, hex or '_'); anything else is looked up token by token for its message.
    joined = b" ".join(flat)
    values = None
    if not joined.translate(None, _NUMBER_CHARACTERS):
        try:
            values = np.array(flat, dtype=float).reshape(-1, width)
        except ValueError:
            values = None
    if values is None:
        _raise_first_bad_token(path, fields, rows)
    too_large = ~np.isfinite(values)
    if too_large.any():
        row, column = np.argwhere(too_large)[0]
        raise _core.ParseError(f"{path}:{numbers[row]}: field '{fields[column]}': "
                               f"'{_excerpt(rows[row][1][column])}' is beyond the range of a double")
    for name in integer_fields:
        column = fields.index(name)
        fractional = np.flatnonzero(values[:, column] != np.floor(values[:, column]))
        if len(fractional):
            row = fractional[0]
            raise _core.ParseError(f"{path}:{numbers[row]}: field '{name}': "
                                   f"'{_excerpt(rows[row][1][column])}' is not an integer")
    return values, numbers


def _raise_first_bad_token(path: str, fields: Tuple[str, ...], rows) -> NoReturn:
    for number, tokens in rows:
        for column, token in enumerate(tokens):
            if not _NUMBER.fullmatch(token):
                raise _core.ParseError(f"{path}:{number}: field '{fields[column]}': "
                                       f"'{_excerpt(token)}' is not a number")
    raise _core.ParseError(f"{path}: not a table of decimal numbers")


def _require(condition_failed: np.ndarray, path: str, lines: np.ndarray, field: str, what: str) -> None:
    """Raises a ParseError naming the first row where ``condition_failed`` holds."""
    bad = np.flatnonzero(condition_failed)
    if len(bad):
        raise _core.ParseError(f"{path}:{lines[bad[0]]}: field '{field}': {what}")


def _require_increasing(times: np.ndarray, path: str, lines: np.ndarray, strictly: bool) -> None:
    steps = np.diff(times)
    _require(np.concatenate([[False], steps <= 0 if strictly else steps < 0]), path, lines, "t",
             "time not after the previous line's" if strictly else "time goes backwards")


def robot_files(robot: int) -> Dict[str, str]:
    """File names of one robot's data (each may also be read with ``.gz`` appended)."""
    return {
        "groundtruth": f"newRobot{robot}_Groundtruth.txt",
        "odometry": f"newRobot{robot}_Odometry.txt",
        "measurement": f"newRobot{robot}_Measurement.txt",
        "barcodes": "Barcodes.dat",
        "landmarks": "Landmark_Groundtruth.dat",
    }


def _find(folder: str, name: str) -> str:
    for candidate in (name + ".gz", name):
        path = os.path.join(folder, candidate)
        if os.path.isfile(path):
            return path
    raise _core.ParseError(f"{os.path.join(folder, name)}[.gz]: no such file")


def _check_robot(robot) -> int:
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)):
        raise _core.InvalidArgument(f"mrclam: argument 'robot' must be an integer 1-{ROBOT_COUNT}, got {robot!r}")
    if not 1 <= robot <= ROBOT_COUNT:
        raise _core.InvalidArgument(f"mrclam: argument 'robot' must be 1-{ROBOT_COUNT} "
                                    f"(MR.CLAM has {ROBOT_COUNT} robots), got {robot}")
    return int(robot)


def read_robot(folder: PathLike, robot: int) -> Dict[str, Any]:
    """One robot's files, checked, as arrays (no steps built).

    Returns a dict: ``groundtruth`` (n, 4) t x y theta with the heading glitches repaired
    (:func:`clean_heading_glitches`) and ``heading_glitches`` (n,) bool; ``odometry`` (k, 3)
    t v omega; ``measurement`` (m, 4) t barcode range bearing (every sighting, robots
    included); ``subject_of_barcode`` {barcode: subject}; ``robot_barcodes`` (sorted barcodes
    of subjects 1-5); ``landmark_barcodes`` (15,), ``landmark_subjects`` (15,),
    ``landmark_positions`` (15, 2) in the Vicon frame; ``paths`` {kind: path read}.

    Raises:
        dcslam.ParseError: a missing or malformed file (file, line and field named).
        dcslam.InvalidArgument: ``robot`` not 1-5.
    """
    robot = _check_robot(robot)
    folder = os.fspath(folder)
    names = robot_files(robot)
    paths = {kind: _find(folder, name) for kind, name in names.items()}

    barcodes, barcode_lines = read_table(paths["barcodes"], BARCODE_FIELDS, BARCODE_FIELDS)
    for column, field in enumerate(BARCODE_FIELDS):
        _require(barcodes[:, column] < 0, paths["barcodes"], barcode_lines, field, "negative")
        _, first = np.unique(barcodes[:, column], return_index=True)
        repeated = np.ones(len(barcodes), bool)
        repeated[first] = False
        _require(repeated, paths["barcodes"], barcode_lines, field, "appears twice")
    subject_of_barcode = {int(b): int(s) for s, b in barcodes}
    robot_barcodes = np.sort(barcodes[barcodes[:, 0] <= ROBOT_COUNT, 1]).astype(np.int64)

    landmarks, landmark_lines = read_table(paths["landmarks"], LANDMARK_FIELDS, ("barcode",))
    known = np.array([int(b) in subject_of_barcode for b in landmarks[:, 0]])
    _require(~known, paths["landmarks"], landmark_lines, "barcode", f"not a barcode of {paths['barcodes']}")
    landmark_subjects = np.array([subject_of_barcode[int(b)] for b in landmarks[:, 0]], dtype=np.int64)
    _require(landmark_subjects <= ROBOT_COUNT, paths["landmarks"], landmark_lines, "barcode",
             "a robot's barcode, not a landmark's")
    _, first = np.unique(landmark_subjects, return_index=True)
    repeated = np.ones(len(landmarks), bool)
    repeated[first] = False
    _require(repeated, paths["landmarks"], landmark_lines, "barcode", "landmark listed twice")

    groundtruth, truth_lines = read_table(paths["groundtruth"], GROUNDTRUTH_FIELDS)
    _require_increasing(groundtruth[:, 0], paths["groundtruth"], truth_lines, strictly=True)
    odometry, odometry_lines = read_table(paths["odometry"], ODOMETRY_FIELDS)
    _require_increasing(odometry[:, 0], paths["odometry"], odometry_lines, strictly=True)
    # The robots' speeds are below 0.1 m/s and 0.6 rad/s; these bounds only catch broken values.
    _require(np.abs(odometry[:, 1]) > 10.0, paths["odometry"], odometry_lines, "v", "beyond 10 m/s")
    _require(np.abs(odometry[:, 2]) > 100.0, paths["odometry"], odometry_lines, "omega", "beyond 100 rad/s")
    measurement, measurement_lines = read_table(paths["measurement"], MEASUREMENT_FIELDS, ("barcode",))
    _require_increasing(measurement[:, 0], paths["measurement"], measurement_lines, strictly=False)
    unknown = np.array([int(b) not in subject_of_barcode for b in measurement[:, 1]])
    _require(unknown, paths["measurement"], measurement_lines, "barcode", f"not a barcode of {paths['barcodes']}")
    _require(~(measurement[:, 2] > 0), paths["measurement"], measurement_lines, "range", "not positive")
    _require(np.abs(measurement[:, 3]) > math.pi, paths["measurement"], measurement_lines, "bearing",
             "beyond pi in magnitude")
    # Steps integrate the odometry up to each sighting and take the truth there: both must cover it.
    begin = max(odometry[0, 0], groundtruth[0, 0])
    end = min(odometry[-1, 0], groundtruth[-1, 0])
    outside = (measurement[:, 0] < begin) | (measurement[:, 0] > end)
    _require(outside, paths["measurement"], measurement_lines, "t",
             f"outside the span of the odometry and the ground truth ({begin:g} to {end:g} s)")

    heading, glitches = clean_heading_glitches(groundtruth[:, 3])
    groundtruth = groundtruth.copy()
    groundtruth[:, 3] = heading
    return dict(
        groundtruth=groundtruth, heading_glitches=glitches, odometry=odometry, measurement=measurement,
        subject_of_barcode=subject_of_barcode, robot_barcodes=robot_barcodes,
        landmark_barcodes=landmarks[:, 0].astype(np.int64), landmark_subjects=landmark_subjects,
        landmark_positions=landmarks[:, 1:3].copy(), paths=paths,
    )


def _wrap(angle):
    return np.arctan2(np.sin(angle), np.cos(angle))


def clean_heading_glitches(heading, half_window: int = HEADING_GLITCH_HALF_WINDOW,
                           threshold: float = HEADING_GLITCH_RAD) -> Tuple[np.ndarray, np.ndarray]:
    """Repairs the Vicon heading's glitches: samples far from their neighbours.

    The resampled truth holds isolated wrong headings (up to pi off, e.g. where the resampling
    interpolated across the +-pi wrap through 0). A sample further than ``threshold`` from the
    circular median of the ``2 half_window + 1`` samples around it is a glitch; glitches are
    replaced by linear interpolation of the unwrapped heading of the good samples.

    Returns:
        (heading (n,) in [-pi, pi], glitch (n,) bool).
    """
    heading = np.asarray(heading, dtype=float)
    padded = np.pad(heading, (half_window, half_window), mode="edge")
    window = np.lib.stride_tricks.sliding_window_view(padded, 2 * half_window + 1)
    # The median of the angles measured from the window's circular mean does not care where
    # the window crosses +-pi.
    centre = np.arctan2(np.sin(window).mean(axis=1), np.cos(window).mean(axis=1))
    median = centre + np.median(_wrap(window - centre[:, None]), axis=1)
    glitch = np.abs(_wrap(heading - median)) > threshold
    good = np.flatnonzero(~glitch)
    if len(good) < 2:
        return heading.copy(), glitch
    repaired = np.interp(np.arange(len(heading)), good, np.unwrap(heading[good]))
    return _wrap(repaired), glitch


def integrate_odometry(odometry, step_times, t_begin: float, speed_scale: float, turn_scale: float,
                       sigma_speed: float, sigma_turn: float, sigma_lateral: float = 0.0) -> Tuple[np.ndarray, np.ndarray]:
    """Integrates (v, omega) samples into one relative motion and covariance per step.

    Each sample holds its (v, omega) from its time to the next sample's (the last one to
    ``step_times[-1]``). Step k covers ``(step_times[k-1], step_times[k]]`` (step 0 starts at
    ``t_begin``). Over each piece of length dt inside a step the robot moves along an arc:
    heading change ``phi = turn_scale omega dt``, chord ``s sinc(phi / 2)`` with ``s =
    speed_scale v dt`` at half the heading change. The pieces' errors are independent: ``s``
    has variance ``sigma_speed^2 dt`` and ``phi`` ``sigma_turn^2 dt`` (white noise on the
    speeds), carried to the step's end through the motion that follows them (a heading error
    swings the rest of the path around the point where it happened); a sideways slip across
    the chord has variance ``sigma_lateral^2 dt``.

    Args:
        odometry: (k, 3) t, v, omega with increasing t, ``t[0] <= t_begin``.
        step_times: (n,) non-decreasing, ``>= t_begin``.

    Returns:
        (u (n, 3), Q (n, 3, 3)): motion of the robot frame from the step's start to its end,
        expressed in the start frame, and its covariance.
    """
    odometry = np.asarray(odometry, dtype=float)
    step_times = np.asarray(step_times, dtype=float)
    count = len(step_times)
    if count == 0:
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    # Piece boundaries: every sample time inside the span and every step time.
    inside = odometry[(odometry[:, 0] > t_begin) & (odometry[:, 0] < step_times[-1]), 0]
    bounds = np.unique(np.concatenate([[t_begin], inside, step_times]))
    starts, dt = bounds[:-1], np.diff(bounds)
    sample = np.searchsorted(odometry[:, 0], starts, side="right") - 1
    step = np.searchsorted(step_times, starts, side="right")  # the step each piece belongs to
    s = speed_scale * odometry[sample, 1] * dt
    phi = turn_scale * odometry[sample, 2] * dt

    # Dead reckoning of all pieces in one frame; each step is then a difference of two poses.
    heading_after = np.cumsum(phi)
    heading_before = heading_after - phi
    chord = s * np.sinc(phi / (2 * np.pi))  # np.sinc(x) = sin(pi x) / (pi x)
    direction = heading_before + phi / 2
    moves = chord[:, None] * np.column_stack([np.cos(direction), np.sin(direction)])
    position_after = np.cumsum(moves, axis=0)
    position_before = position_after - moves

    # Pose at each step time: after the last piece of the step (or the start pose when empty).
    last_piece = np.searchsorted(step, np.arange(count), side="right") - 1
    end_xy = np.where(last_piece[:, None] >= 0, position_after[np.maximum(last_piece, 0)], 0.0)
    end_heading = np.where(last_piece >= 0, heading_after[np.maximum(last_piece, 0)], 0.0)
    start_xy = np.vstack([[0.0, 0.0], end_xy[:-1]])
    start_heading = np.concatenate([[0.0], end_heading[:-1]])

    cos0, sin0 = np.cos(start_heading), np.sin(start_heading)
    delta = end_xy - start_xy
    u = np.column_stack([cos0 * delta[:, 0] + sin0 * delta[:, 1],
                         -sin0 * delta[:, 0] + cos0 * delta[:, 1],
                         end_heading - start_heading])

    # Sensitivity of the step's end (x, y, heading), in the global dead-reckoning frame, to
    # each piece's s and phi: s moves the end along the chord; phi turns the chord by half of
    # it about the piece's start and the rest of the path about the piece's end, i.e. the end
    # point about the chord's midpoint, to first order.
    midpoint = (position_before + position_after) / 2
    lever = end_xy[step] - midpoint
    by_speed = np.column_stack([np.cos(direction), np.sin(direction), np.zeros_like(s)])
    by_turn = np.column_stack([-lever[:, 1], lever[:, 0], np.ones_like(s)])
    by_slip = np.column_stack([-np.sin(direction), np.cos(direction), np.zeros_like(s)])
    pieces = sum((sigma**2 * dt)[:, None, None] * by[:, :, None] * by[:, None, :]
                 for sigma, by in ((sigma_speed, by_speed), (sigma_turn, by_turn), (sigma_lateral, by_slip)))
    Q_global = np.zeros((count, 3, 3))
    np.add.at(Q_global, step, pieces)
    # Into each step's start frame.
    rotation = np.zeros((count, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1] = cos0, sin0
    rotation[:, 1, 0], rotation[:, 1, 1] = -sin0, cos0
    rotation[:, 2, 2] = 1.0
    Q = rotation @ Q_global @ rotation.transpose(0, 2, 1)
    return u, (Q + Q.transpose(0, 2, 1)) / 2


def _truth_at(groundtruth: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Vicon poses at ``times``, linear between samples (the heading unwrapped)."""
    heading = np.unwrap(groundtruth[:, 3])
    return np.column_stack([np.interp(times, groundtruth[:, 0], groundtruth[:, 1]),
                            np.interp(times, groundtruth[:, 0], groundtruth[:, 2]),
                            _wrap(np.interp(times, groundtruth[:, 0], heading))])


def _in_frame(origin: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Poses (n, 3) or points (n, 2) expressed in the frame of the pose ``origin``."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    d = poses[:, :2] - origin[:2]
    local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    if poses.shape[1] == 2:
        return local
    return np.column_stack([local, _wrap(poses[:, 2] - origin[2])])


class MrClam:
    """One robot of MR.CLAM dataset 2 as filter steps; see :func:`mrclam`.

    Attributes:
        robot: the robot number (1-5).
        steps: sequence of :class:`~dcslam.packed.Step` (t, u, Q, z, R, landmark_ids), one
            per time the robot saw at least one landmark.
        t, u, Q, z, R, offsets, landmark_ids: the flat arrays behind ``steps``
            (``landmark_ids`` are landmark subject numbers, 6-20).
        t_begin: time of the start pose (the first time both odometry and truth exist).
        poses_true: (len(steps) + 1, 3) Vicon pose at ``t_begin`` and after each step, in the
            frame of the first pose (``poses_true[0] = 0``).
        landmarks_true, landmark_ids_true: (15, 2) and (15,) Vicon landmark positions and
            subject numbers, in the same frame.
        origin: the first pose in the Vicon frame (x, y, theta).
        heading_glitches: truth samples whose heading was repaired (see docs/mrclam.md).
        robot_sightings: sightings of other robots left out.
        options: the noise options the steps were made with.
    """

    def __init__(self, arrays: dict, robot: int, options: dict):
        self._arrays = _read_only(arrays)
        self.robot = robot
        self.options = dict(options)
        self.t, self.u, self.Q = arrays["t"], arrays["u"], arrays["Q"]
        self.z, self.R, self.offsets = arrays["z"], arrays["R"], arrays["offsets"]
        self.landmark_ids = arrays["landmark_ids"]
        self.t_begin = float(arrays["t_begin"])
        self.poses_true = arrays["poses_true"]
        self.landmarks_true, self.landmark_ids_true = arrays["landmarks_true"], arrays["landmark_ids_true"]
        self.origin = arrays["origin"]
        self.heading_glitches = int(arrays["heading_glitches"])
        self.robot_sightings = int(arrays["robot_sightings"])
        self.steps = Steps(self.offsets, self._step, self.packed_steps)

    def _step(self, k: int, rows: slice) -> Step:
        return Step(self.u[k], self.Q[k], self.z[rows], self.R[rows], t=float(self.t[k]),
                    landmark_ids=self.landmark_ids[rows], index=k)

    def packed_steps(self) -> PackedSteps:
        """The arrays behind ``steps`` with the landmark ids, as
        :meth:`~dcslam.SlamFilter.run_batch` takes them."""
        return PackedSteps(self.u, self.Q, self.z, self.R, self.offsets, self.landmark_ids)

    @property
    def true_ids(self) -> np.ndarray:
        """Every measurement's landmark (subject number), in step order: the labels the
        association scores compare with when the filter ran without ids."""
        return self.landmark_ids

    def perturbed(self, seed: int, extra_noise: float = 1.0) -> "MrClam":
        """A copy with simulated noise added, for Monte Carlo runs on the real data.

        Every ``u`` gets a draw of N(0, extra_noise Q) and every measurement one of
        N(0, extra_noise R) (the bearing wrapped), and the covariances the filter is given
        grow to ``(1 + extra_noise) Q`` and ``(1 + extra_noise) R``, so the model stays as
        right (or wrong) as it is on the data itself. The truth is unchanged. The same seed
        gives the same copy.
        """
        if isinstance(extra_noise, bool) or not (isinstance(extra_noise, (int, float)) and
                                                 math.isfinite(extra_noise) and extra_noise >= 0):
            raise _core.InvalidArgument(f"MrClam.perturbed: 'extra_noise' must be a finite number >= 0, got {extra_noise!r}")
        rng = np.random.default_rng(seed)
        # Q may be singular (a step without motion); an eigen-decomposition gives its square root anyway.
        values, vectors = np.linalg.eigh(self.Q)
        roots = vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]
        u = self.u + extra_noise**0.5 * np.einsum("kij,kj->ki", roots, rng.standard_normal(self.u.shape))
        u[:, 2] = _wrap(u[:, 2])
        sigmas = np.sqrt(np.diagonal(self.R, axis1=1, axis2=2))  # R is diagonal here
        z = self.z + extra_noise**0.5 * sigmas * rng.standard_normal(self.z.shape)
        z[:, 1] = _wrap(z[:, 1])
        return self.replaced(u=u, Q=(1 + extra_noise) * self.Q, z=z, R=(1 + extra_noise) * self.R,
                             perturbed_seed=seed, extra_noise=float(extra_noise))

    def replaced(self, u=None, Q=None, z=None, R=None, **note) -> "MrClam":
        """A copy with some of the step arrays replaced (same shapes), the steps' times, ids
        and the truth unchanged; ``note`` is added to ``options`` (what was done)."""
        arrays = dict(self._arrays)
        for name, value in (("u", u), ("Q", Q), ("z", z), ("R", R)):
            if value is not None:
                value = np.array(value, dtype=float)
                if value.shape != arrays[name].shape:
                    raise _core.InvalidArgument(f"MrClam.replaced: '{name}' must have shape "
                                                f"{arrays[name].shape}, got {value.shape}")
                arrays[name] = value
        return MrClam(arrays, self.robot, {**self.options, **note})

    def slam_config(self, **overrides) -> SlamConfig:
        """A :class:`~dcslam.SlamConfig` for this robot: range–bearing from the robot's centre,
        known association (the barcodes) inside local maps and at joins, D&C local maps of
        :data:`LOCAL_MAP_FEATURES` features. Keyword arguments
        override fields (e.g. ``association="jcbb", join_association="rjc"`` to hide the ids)."""
        values: Dict[str, Any] = dict(observation="range_bearing", sensor_offset=(0.0, 0.0, 0.0), association="known",
                      join_association="known", local_map_features=LOCAL_MAP_FEATURES)
        values.update(overrides)
        return SlamConfig(**values)

    def __repr__(self) -> str:
        return f"MrClam(robot={self.robot}, steps={len(self.steps)}, measurements={len(self.z)})"


@contextlib.contextmanager
def _mrclam_folder(robot: int, data_dir: Optional[PathLike]):
    if data_dir is not None:
        yield os.fspath(data_dir)
        return
    if robot not in BUNDLED_ROBOTS:
        raise _core.InvalidArgument(
            f"mrclam: robot {robot} is not bundled with the package (bundled: "
            f"{', '.join(map(str, BUNDLED_ROBOTS))}); pass data_dir, a folder with its files")
    with resources.as_file(resources.files("dcslam") / "data" / "mrclam") as folder:
        yield os.fspath(folder)


def _check_options(options: dict) -> dict:
    unknown = sorted(set(options) - set(MRCLAM_DEFAULTS))
    if unknown:
        raise _core.InvalidArgument(f"mrclam: unknown option(s) {', '.join(unknown)} "
                                    f"(known: {', '.join(sorted(MRCLAM_DEFAULTS))})")
    values = {**MRCLAM_DEFAULTS, **options}
    for name, value in values.items():
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise _core.InvalidArgument(f"mrclam: option '{name}' must be a finite number, got {value!r}")
        if (value < 0 and name not in _SIGNED_OPTIONS) or (value == 0 and name in _POSITIVE_OPTIONS):
            raise _core.InvalidArgument(f"mrclam: option '{name}' must be "
                                        f"{'positive' if name in _POSITIVE_OPTIONS else '>= 0'}, got {value!r}")
    return {name: float(value) for name, value in values.items()}


def mrclam(robot: int = 1, data_dir: Optional[PathLike] = None, **options) -> MrClam:
    """Loads one robot of UTIAS MR.CLAM dataset 2 (Leung et al., IJRR 2011).

    Args:
        robot: 1-5. Only robot 1 is bundled; the others need ``data_dir``.
        data_dir: folder with ``newRobot<N>_Groundtruth.txt``, ``newRobot<N>_Odometry.txt``,
            ``newRobot<N>_Measurement.txt`` (each plain or ``.gz``), ``Barcodes.dat`` and
            ``Landmark_Groundtruth.dat`` (the dataset's resampled 50 Hz files; the landmark file's
            first column is the barcode); ``None`` uses the bundled copy.
        odometry_delay: the logged (v, omega) act this many seconds after their time stamp.
        speed_scale, turn_scale: calibration of the logged v and omega.
        sigma_speed, sigma_turn, sigma_lateral: white noise on v [m/s/sqrt(Hz)], omega
            [rad/s/sqrt(Hz)] and the sideways speed [m/s/sqrt(Hz)].
        range_sigma_fraction: range noise sigma as a share of the measured range.
        sigma_bearing: bearing noise [rad].
        (Defaults in :data:`MRCLAM_DEFAULTS`, derived in docs/mrclam.md.)

    Raises:
        dcslam.InvalidArgument: a robot number outside 1-5, a robot that is not bundled without
        ``data_dir``, an unknown option or a bad value.
        dcslam.ParseError: a missing or malformed file, naming the file, line and field.
    """
    robot = _check_robot(robot)
    values = _check_options(options)
    with _mrclam_folder(robot, data_dir) as folder:
        data = read_robot(folder, robot)
    return _build(data, robot, values)


def _build(data: dict, robot: int, options: dict) -> MrClam:
    groundtruth, odometry, measurement = data["groundtruth"], data["odometry"].copy(), data["measurement"]
    odometry[:, 0] += options["odometry_delay"]
    of_robot = np.isin(measurement[:, 1].astype(np.int64), data["robot_barcodes"])
    sightings = measurement[~of_robot]
    t_begin = max(odometry[0, 0], groundtruth[0, 0])
    early = sightings[:, 0] < t_begin
    if early.any():
        raise _core.ParseError(f"{data['paths']['measurement']}: a landmark sighting at t={sightings[early, 0][0]:g} s "
                               f"comes before the odometry starts (t={t_begin:g} s with odometry_delay)")

    times, first = np.unique(sightings[:, 0], return_index=True)
    offsets = np.append(first, len(sightings)).astype(np.int64)
    u, Q = integrate_odometry(odometry, times, t_begin, options["speed_scale"], options["turn_scale"],
                              options["sigma_speed"], options["sigma_turn"], options["sigma_lateral"])
    subject = data["subject_of_barcode"]
    landmark_ids = np.array([subject[int(b)] for b in sightings[:, 1]], dtype=np.int64)
    R = np.zeros((len(sightings), 2, 2))
    R[:, 0, 0] = (options["range_sigma_fraction"] * sightings[:, 2]) ** 2
    R[:, 1, 1] = options["sigma_bearing"] ** 2

    poses = _truth_at(groundtruth, np.concatenate([[t_begin], times]))
    origin = poses[0].copy()
    order = np.argsort(data["landmark_subjects"])
    arrays = dict(
        t=times, u=u, Q=Q, offsets=offsets, z=np.ascontiguousarray(sightings[:, 2:4]), R=R,
        landmark_ids=landmark_ids, t_begin=t_begin, origin=origin,
        poses_true=_in_frame(origin, poses),
        landmarks_true=_in_frame(origin, data["landmark_positions"][order]),
        landmark_ids_true=data["landmark_subjects"][order],
        heading_glitches=int(data["heading_glitches"].sum()), robot_sightings=int(of_robot.sum()),
    )
    return MrClam(arrays, robot, options)
