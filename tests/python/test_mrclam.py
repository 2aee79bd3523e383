"""dcslam.datasets.mrclam: the reader against tiny hand-written files with values worked out by
hand, the bundled robot against the dataset's published counts, and every bad input refused
with the file, the line and the field."""

import gzip
import math

import numpy as np
import pytest

import dcslam
from dcslam.mrclam import clean_heading_glitches, integrate_odometry

# Subjects 1-5 are robots (barcodes 5, 14, 41, 32, 23), 6 and 7 landmarks (barcodes 18, 45).
BARCODES = "1 5\n2 14\n3 41\n4 32\n5 23\n6 18\n7 45\n"
LANDMARKS = "18 4.0 1.0 0.001 0.001\n45 1.0 4.0 0.001 0.001\n"
# One sample a second: 1 s straight at 1 m/s, a quarter turn on the spot, 1 s straight.
ODOMETRY = "0 1 0\n1 0 1.5707963267948966\n2 1 0\n3 0 0\n"
# The robot starts at (2, 1) facing +y, ends at (1, 2) facing -x.
GROUNDTRUTH = ("0 2 1 1.5707963267948966\n1 2 2 1.5707963267948966\n2 2 2 3.141592653589793\n"
               "3 1 2 3.141592653589793\n")
# t=1: landmark 18 and robot 2 (barcode 14); t=2: landmark 45; t=3: both landmarks.
MEASUREMENT = "1 18 2.5 0.1\n1 14 3.0 0.0\n2 45 2.0 -0.2\n3 18 3.0 0.3\n3 45 2.0 0.4\n"


def write_robot(folder, robot=1, gzipped=True, **replace):
    files = {f"newRobot{robot}_Groundtruth.txt": GROUNDTRUTH, f"newRobot{robot}_Odometry.txt": ODOMETRY,
             f"newRobot{robot}_Measurement.txt": MEASUREMENT, "Barcodes.dat": BARCODES,
             "Landmark_Groundtruth.dat": LANDMARKS}
    for name, text in files.items():
        # The key of a file in ``replace``: Groundtruth, Odometry, Measurement, Barcodes, Landmark.
        key = name.split("_")[-1] if name.startswith("newRobot") else name.split("_")[0]
        text = replace.get(key.split(".")[0], text)
        data = text.encode() if isinstance(text, str) else text
        if gzipped and name.startswith("newRobot"):
            (folder / (name + ".gz")).write_bytes(gzip.compress(data))
        else:
            (folder / name).write_bytes(data)
    return folder


def load(folder, robot=1, **options):
    noise = dict(odometry_delay=0.0, speed_scale=1.0, turn_scale=1.0, sigma_speed=0.0, sigma_turn=0.0,
                 sigma_lateral=0.0)
    return dcslam.datasets.mrclam(robot, folder, **{**noise, **options})


def test_steps_group_one_time_and_leave_the_other_robots_out(tmp_path):
    data = load(write_robot(tmp_path))
    assert len(data.steps) == 3 and data.robot_sightings == 1
    np.testing.assert_array_equal(data.t, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(data.offsets, [0, 1, 2, 4])
    np.testing.assert_array_equal(data.landmark_ids, [6, 7, 6, 7])
    np.testing.assert_array_equal(data.steps[2].z, [[3.0, 0.3], [2.0, 0.4]])
    np.testing.assert_array_equal(data.steps[2].landmark_ids, [6, 7])
    assert data.steps[0].t == 1.0


def test_odometry_is_integrated_between_sightings_as_worked_by_hand(tmp_path):
    data = load(write_robot(tmp_path))
    np.testing.assert_allclose(data.u, [[1, 0, 0], [0, 0, math.pi / 2], [1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(data.Q, 0.0)


def test_the_truth_is_in_the_first_pose_frame_as_worked_by_hand(tmp_path):
    data = load(write_robot(tmp_path))
    np.testing.assert_allclose(data.poses_true, [[0, 0, 0], [1, 0, 0], [1, 0, math.pi / 2], [1, 1, math.pi / 2]],
                               atol=1e-12)
    np.testing.assert_array_equal(data.landmark_ids_true, [6, 7])
    # (4, 1) and (1, 4) seen from (2, 1) facing +y.
    np.testing.assert_allclose(data.landmarks_true, [[0, -2], [3, 1]], atol=1e-12)
    np.testing.assert_allclose(data.origin, [2, 1, math.pi / 2])


def test_the_noise_model_of_one_straight_piece_as_worked_by_hand(tmp_path):
    data = load(write_robot(tmp_path), sigma_speed=0.2, sigma_turn=0.1, range_sigma_fraction=0.1, sigma_bearing=0.02)
    # 1 s at 1 m/s in one piece: var(x) = 0.2^2 * 1; a heading error phi turns the 1 m chord by
    # phi/2, so y = 0.5 phi: var(y) = 0.25 * 0.01, cov(y, phi) = 0.5 * 0.01, var(phi) = 0.01.
    np.testing.assert_allclose(data.Q[0], [[0.04, 0, 0], [0, 0.0025, 0.005], [0, 0.005, 0.01]], atol=1e-15)
    # The quarter turn on the spot: no lever, so the heading's noise alone, and the speed noise
    # along the (zero-length) chord, at half the turn: 45 degrees, 0.04 / 2 in each cell.
    np.testing.assert_allclose(data.Q[1], [[0.02, 0.02, 0], [0.02, 0.02, 0], [0, 0, 0.01]], atol=1e-15)
    # A sideways slip of 0.3 m/s/sqrt(Hz) for 1 s: var(y) = 0.09 across the straight chord;
    # on the spot turn it is across the chord's direction (45 degrees off the start frame).
    slip = load(write_robot(tmp_path), sigma_lateral=0.3)
    np.testing.assert_allclose(slip.Q[0], np.diag([0.0, 0.09, 0.0]), atol=1e-15)
    np.testing.assert_allclose(slip.Q[1], [[0.045, -0.045, 0], [-0.045, 0.045, 0], [0, 0, 0]], atol=1e-15)
    # The first sighting is 2.5 m away: range sigma 0.25 m.
    np.testing.assert_allclose(data.R[0], np.diag([0.0625, 0.0004]))
    np.testing.assert_allclose(data.R[1], np.diag([0.04, 0.0004]))


def test_many_small_pieces_reach_the_continuous_white_noise_variance():
    # Straight at 1 m/s for T = 2 s in 1000 pieces: var(y) = sigma^2 * sum (T - t_mid)^2 dt,
    # which is T^3/3 - T dt^2/12 for white noise on the turn rate.
    pieces, T, sigma = 1000, 2.0, 0.3
    times = np.linspace(0.0, T, pieces + 1)[:-1]
    odometry = np.column_stack([times, np.ones(pieces), np.zeros(pieces)])
    _, Q = integrate_odometry(odometry, [T], 0.0, 1.0, 1.0, 0.0, sigma)
    dt = T / pieces
    assert Q[0, 1, 1] == pytest.approx(sigma**2 * (T**3 / 3 - T * dt**2 / 12), rel=1e-9)
    assert Q[0, 1, 2] == pytest.approx(sigma**2 * T**2 / 2, rel=1e-9)
    assert Q[0, 2, 2] == pytest.approx(sigma**2 * T, rel=1e-9)


def test_a_circle_integrates_exactly():
    # v = 1, omega = 1 for pi/2 s: a quarter of the unit circle, in any number of pieces.
    for pieces in (1, 7):
        times = np.linspace(0, math.pi / 2, pieces + 1)[:-1]
        odometry = np.column_stack([times, np.ones(pieces), np.ones(pieces)])
        u, _ = integrate_odometry(odometry, [math.pi / 2], 0.0, 1.0, 1.0, 0.0, 0.0)
        np.testing.assert_allclose(u[0], [1.0, 1.0, math.pi / 2], atol=1e-12)


def test_scales_multiply_the_logged_speeds(tmp_path):
    data = load(write_robot(tmp_path), speed_scale=0.5, turn_scale=2.0)
    np.testing.assert_allclose(data.u, [[0.5, 0, 0], [0, 0, math.pi], [0.5, 0, 0]], atol=1e-12)


def test_a_sighting_between_samples_splits_the_sample(tmp_path):
    data = load(write_robot(tmp_path, Measurement="0.25 18 2.5 0.1\n1 45 2.0 0.0\n"))
    np.testing.assert_allclose(data.u, [[0.25, 0, 0], [0.75, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(data.poses_true[1], [0.25, 0, 0], atol=1e-12)


def test_the_odometry_delay_shifts_the_logged_speeds(tmp_path):
    # With a 0.5 s delay the first second's 1 m/s acts over [0.5, 1.5]: the first step (from
    # 0.5 s, where the odometry now starts, to the sighting at 1 s) moves 0.5 m; the second
    # (1 s to 2 s) half a second straight, then half of the quarter turn on the spot.
    data = load(write_robot(tmp_path, Groundtruth=GROUNDTRUTH.replace("0 2 1", "0.5 2 1", 1)), odometry_delay=0.5)
    assert data.t_begin == 0.5
    np.testing.assert_allclose(data.u[0], [0.5, 0, 0], atol=1e-12)
    np.testing.assert_allclose(data.u[1], [0.5, 0, math.pi / 4], atol=1e-12)
    with pytest.raises(dcslam.ParseError, match="sighting at t=1 s comes before the odometry starts"):
        load(write_robot(tmp_path), odometry_delay=2.0)


def test_plain_text_files_read_like_gzip(tmp_path):
    (tmp_path / "plain").mkdir()
    (tmp_path / "gzip").mkdir()
    plain = load(write_robot(tmp_path / "plain", gzipped=False))
    np.testing.assert_array_equal(plain.u, load(write_robot(tmp_path / "gzip")).u)
    np.testing.assert_array_equal(plain.poses_true, load(write_robot(tmp_path / "gzip")).poses_true)


def test_heading_glitches_are_repaired():
    heading = np.linspace(3.0, 3.3, 60)
    heading = np.arctan2(np.sin(heading), np.cos(heading))  # crosses +-pi
    broken = heading.copy()
    broken[10] = heading[10] + 2.0        # a spike
    broken[41] = 0.0                      # the resampling's artefact across the wrap
    repaired, glitch = clean_heading_glitches(broken)
    assert set(np.flatnonzero(glitch)) == {10, 41}
    np.testing.assert_allclose(np.cos(repaired - heading), 1.0, atol=1e-12)


def test_the_bundled_robot_matches_the_dataset_s_counts():
    data = dcslam.datasets.mrclam()
    # Robot 1 of dataset 2: 8753 sightings, 6852 of landmarks (the dataset's documentation).
    assert len(data.z) == 6852 and data.robot_sightings == 8753 - 6852
    assert len(data.steps) == len(np.unique(data.t)) and np.all(np.diff(data.t) > 0)
    assert data.poses_true.shape == (len(data.steps) + 1, 3) and np.all(data.poses_true[0] == 0)
    assert data.landmarks_true.shape == (15, 2)
    np.testing.assert_array_equal(data.landmark_ids_true, np.arange(6, 21))
    assert set(np.unique(data.landmark_ids)) <= set(range(6, 21))
    cfg = data.slam_config()
    assert cfg.observation == "range_bearing" and cfg.association == "known"


def test_the_bundled_sightings_land_near_the_true_landmarks():
    # The dataset's documentation: |true pose (+) (r, b) - landmark| has a median of 0.085-0.13 m.
    data = dcslam.datasets.mrclam()
    step = np.repeat(np.arange(len(data.steps)), np.diff(data.offsets))
    pose = data.poses_true[step + 1]
    angle = pose[:, 2] + data.z[:, 1]
    seen = pose[:, :2] + data.z[:, :1] * np.column_stack([np.cos(angle), np.sin(angle)])
    where = dict(zip(data.landmark_ids_true.tolist(), data.landmarks_true))
    truth = np.array([where[i] for i in data.landmark_ids.tolist()])
    assert 0.05 < np.median(np.linalg.norm(seen - truth, axis=1)) < 0.15


def test_bundled_dead_reckoning_stays_near_the_truth_for_a_minute():
    # The dataset's documentation: dead reckoning from the true pose stays within 0.3-0.9 m over 60 s.
    data = dcslam.datasets.mrclam()
    pose = np.zeros(3)
    for k in np.flatnonzero(data.t <= data.t_begin + 60):
        pose = dcslam.geometry.compose(pose, data.u[k])
        last = k
    assert np.hypot(*(pose[:2] - data.poses_true[last + 1, :2])) < 0.9


def test_perturbed_copies_are_reproducible_and_widen_the_covariances():
    data = dcslam.datasets.mrclam()
    first, again, other = data.perturbed(3), data.perturbed(3), data.perturbed(4)
    np.testing.assert_array_equal(first.u, again.u)
    np.testing.assert_array_equal(first.z, again.z)
    assert not np.array_equal(first.z, other.z)
    np.testing.assert_allclose(first.Q, 2 * data.Q)
    np.testing.assert_allclose(first.R, 2 * data.R)
    np.testing.assert_array_equal(first.poses_true, data.poses_true)
    unchanged = data.perturbed(3, extra_noise=0.0)
    np.testing.assert_allclose(unchanged.z, data.z, rtol=0, atol=1e-12)
    # The bearing noise drawn has the model's size.
    spread = np.std(first.z[:, 1] - data.z[:, 1])
    assert spread == pytest.approx(data.options["sigma_bearing"], rel=0.05)


@pytest.mark.parametrize("robot", [0, 6, -1, 1.0, "1", True])
def test_robot_numbers_outside_1_to_5_are_refused(robot):
    with pytest.raises(dcslam.InvalidArgument, match="robot"):
        dcslam.datasets.mrclam(robot)


def test_a_robot_that_is_not_bundled_needs_a_folder():
    with pytest.raises(dcslam.InvalidArgument, match="robot 3 is not bundled.*data_dir"):
        dcslam.datasets.mrclam(3)


def test_a_missing_file_is_named(tmp_path):
    write_robot(tmp_path)
    with pytest.raises(dcslam.ParseError, match="newRobot2_Groundtruth.txt.*no such file"):
        dcslam.datasets.mrclam(2, tmp_path)
    (tmp_path / "Barcodes.dat").unlink()
    with pytest.raises(dcslam.ParseError, match="Barcodes.dat.*no such file"):
        dcslam.datasets.mrclam(1, tmp_path)


@pytest.mark.parametrize("kind, text, expected", [
    ("Odometry", "0 1 0\n1 0 x1.5\n", r"newRobot1_Odometry.txt.gz:2: field 'omega': 'x1.5' is not a number"),
    ("Odometry", "0 1 0\n1 0 nan\n", r"Odometry.txt.gz:2: field 'omega': 'nan' is not a number"),
    ("Odometry", "0 1 0\n1 0\n", r"Odometry.txt.gz:2: 2 fields, expected 3 \(t v omega\)"),
    ("Odometry", "0 1 0\n2 0 0\n1 0 0\n", r"Odometry.txt.gz:3: field 't': time not after"),
    ("Odometry", "0 1e400 0\n", r"Odometry.txt.gz:1: field 'v': '1e400' is beyond the range"),
    ("Odometry", "0 50 0\n", r"Odometry.txt.gz:1: field 'v': beyond 10 m/s"),
    ("Odometry", "# only a comment\n\n", r"Odometry.txt.gz: no data lines"),
    ("Measurement", "1 18 2.5 0.1\n1 99 3.0 0.0\n", r"Measurement.txt.gz:2: field 'barcode': not a barcode"),
    ("Measurement", "1 18.5 2.5 0.1\n", r"Measurement.txt.gz:1: field 'barcode': '18.5' is not an integer"),
    ("Measurement", "1 18 -2.5 0.1\n", r"Measurement.txt.gz:1: field 'range': not positive"),
    ("Measurement", "2 18 2.5 0.1\n1 18 2.5 0.1\n", r"Measurement.txt.gz:2: field 't': time goes backwards"),
    ("Measurement", "1 18 2.5 0.1\n7 18 2.5 0.1\n", r"Measurement.txt.gz:2: field 't': outside the span"),
    ("Groundtruth", "0 2 1 0\n0 2 1 0\n", r"Groundtruth.txt.gz:2: field 't': time not after"),
    ("Landmark", "18 4.0 1.0 0.001 0.001\n14 1.0 4.0 0.001 0.001\n",
     r"Landmark_Groundtruth.dat:2: field 'barcode': a robot's barcode"),
    ("Landmark", "18 4.0 1.0 0.001 0.001\n18 1.0 4.0 0.001 0.001\n",
     r"Landmark_Groundtruth.dat:2: field 'barcode': landmark listed twice"),
    ("Barcodes", "1 5\n2 5\n", r"Barcodes.dat:2: field 'barcode': appears twice"),
    ("Odometry", b"0 1 0\n1 0\x00 0\n", r"Odometry.txt.gz:2: NUL byte"),
    ("Odometry", b"0 1 0\n1 \xff 0\n", r"Odometry.txt.gz:2: field 'v': '\\xff' is not a number"),
])
def test_malformed_files_name_file_line_and_field(tmp_path, kind, text, expected):
    write_robot(tmp_path, **{kind: text})
    with pytest.raises(dcslam.ParseError, match=expected) as error:
        dcslam.datasets.mrclam(1, tmp_path)
    assert isinstance(error.value, ValueError) and len(str(error.value)) < 400


def test_a_line_longer_than_the_limit_is_refused(tmp_path):
    write_robot(tmp_path, Odometry="0 1 0\n" + "1" * 70000 + "\n")
    with pytest.raises(dcslam.ParseError, match=r"Odometry.txt.gz:2: line longer than 65536 bytes"):
        dcslam.datasets.mrclam(1, tmp_path)


def test_a_truncated_gzip_file_is_refused(tmp_path):
    write_robot(tmp_path)
    path = tmp_path / "newRobot1_Odometry.txt.gz"
    path.write_bytes(path.read_bytes()[:-6])
    with pytest.raises(dcslam.ParseError, match="Odometry.txt.gz: broken gzip stream"):
        dcslam.datasets.mrclam(1, tmp_path)


@pytest.mark.parametrize("options, expected", [
    ({"range_sigma_fraction": 0.0}, "range_sigma_fraction' must be positive"),
    ({"sigma_turn": -1.0}, "sigma_turn' must be >= 0"),
    ({"speed_scale": float("nan")}, "speed_scale' must be a finite number"),
    ({"sigma_rnage": 0.1}, "unknown option"),
])
def test_bad_options_are_refused(tmp_path, options, expected):
    with pytest.raises(dcslam.InvalidArgument, match=expected):
        dcslam.datasets.mrclam(1, write_robot(tmp_path), **options)


def test_replaced_swaps_step_arrays_and_keeps_the_truth(tmp_path):
    data = load(write_robot(tmp_path))
    copy = data.replaced(z=np.ones((4, 2)), note="test")
    np.testing.assert_array_equal(copy.steps[2].z, [[1, 1], [1, 1]])
    np.testing.assert_array_equal(copy.u, data.u)
    np.testing.assert_array_equal(copy.poses_true, data.poses_true)
    assert copy.options["note"] == "test"
    with pytest.raises(dcslam.InvalidArgument, match=r"'u' must have shape \(3, 3\), got \(2, 3\)"):
        data.replaced(u=np.zeros((2, 3)))


def test_a_file_with_more_text_than_the_limit_is_refused_without_inflating_it(tmp_path, monkeypatch):
    monkeypatch.setattr(dcslam.mrclam, "MAX_FILE_BYTES", 1000)
    write_robot(tmp_path, Odometry="0 1 0\n" * 400)
    with pytest.raises(dcslam.ParseError, match=r"Odometry.txt.gz: more than 1000 bytes of text"):
        dcslam.datasets.mrclam(1, tmp_path)
