"""dcslam.datasets: Victoria Park and iSAM 2D files against independent oracles."""

import gzip
import math
import shutil
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

import dcslam
from dcslam import geometry as G

ISAM_FILE = Path(__file__).parent.parent / "data" / "isam_victoria_park.txt.gz"
BUNDLED = resources.files("dcslam") / "data" / "victoria_park"


@pytest.fixture(scope="module")
def raw_vp():
    return dcslam.datasets.victoria_park(steering="raw", max_range=1e9)


@pytest.fixture(scope="module")
def isam():
    return dcslam.datasets.read_isam2d(ISAM_FILE)


def read_csv(name):
    with gzip.open(BUNDLED / name, "rt") as f:
        return np.loadtxt(f, delimiter=",", skiprows=1)


def test_bundled_data_is_package_data():
    names = {entry.name for entry in BUNDLED.iterdir()}
    assert set(dcslam.datasets.VICTORIA_PARK_FILES) <= names


def test_victoria_park_shapes_and_counts(raw_vp):
    assert len(raw_vp.steps) == 7249
    assert raw_vp.detections_total == 52974 and raw_vp.detections_beyond_range == 0
    sizes = [len(s.z) for s in raw_vp.steps]
    assert sum(sizes) == 52974 and sizes.count(0) == 19 and max(sizes) == 18
    empty = raw_vp.steps[sizes.index(0)]
    assert empty.z.shape == (0, 2) and empty.R.shape == (0, 2, 2)
    s = raw_vp.steps[100]
    assert s.u.shape == (3,) and s.Q.shape == (3, 3) and s.z.shape[1] == 2
    assert s.R.shape == (len(s.z), 2, 2) and isinstance(s.t, float)
    assert raw_vp.gps.shape == (4466, 3)
    np.testing.assert_allclose(raw_vp.gps[0], [20.967, -67.64927094, -41.71421779])
    assert np.all(np.diff(raw_vp.t) > 0)
    assert np.all(np.linalg.eigvalsh(raw_vp.Q[1:]) > 0)  # the floor keeps Q positive definite


def test_max_range_filter_counts_what_it_drops():
    vp = dcslam.datasets.victoria_park()
    assert vp.options["max_range"] == 30.0
    assert len(vp.z) + vp.detections_beyond_range == vp.detections_total == 52974
    assert vp.z[:, 0].max() <= 30.0


def test_measurements_follow_the_documented_conventions(raw_vp):
    trees = read_csv("vp_trees.csv.gz")
    np.testing.assert_allclose(raw_vp.z[:, 0], trees[:, 2] + trees[:, 4] / 2)
    np.testing.assert_allclose(raw_vp.z[:, 1], trees[:, 3] - math.pi / 2)
    np.testing.assert_allclose(raw_vp.trees_diameter, trees[:, 4])


def test_dead_reckoning_matches_readme_totals_and_numpy_integration(raw_vp):
    assert np.hypot(*raw_vp.u[:, :2].T).sum() == pytest.approx(4026.6, abs=0.1)
    assert raw_vp.u[:, 2].sum() == pytest.approx(-4.4678, abs=1e-3)
    # Oracle: plain Euler integration of the 40 Hz samples (exact zero-order hold in the
    # heading, no splitting), sampled at the scan times, against the composed u chain.
    odometry = read_csv("vp_odometry.csv.gz")
    t, v, a = odometry.T
    L, H = 2.83, 0.76
    vc = v / (1 - H / L * np.tan(a))
    dt = np.diff(t)
    heading = np.concatenate([[0], np.cumsum(vc[:-1] * np.tan(a[:-1]) / L * dt)])
    mid = heading[:-1] + 0.5 * vc[:-1] * np.tan(a[:-1]) / L * dt
    x = np.concatenate([[0], np.cumsum(vc[:-1] * dt * np.cos(mid))])
    y = np.concatenate([[0], np.cumsum(vc[:-1] * dt * np.sin(mid))])
    pose, poses = np.zeros(3), []
    for u in raw_vp.u:
        pose = G.compose(pose, u)
        poses.append(pose)
    poses = np.array(poses)
    # Compare at scans that fall on an odometry sample's time (to 1 ms): no partial interval.
    index = np.searchsorted(t, raw_vp.t)
    index = np.clip(index, 0, len(t) - 1)
    on_sample = np.abs(t[index] - raw_vp.t) < 1e-9
    assert on_sample.sum() > 100
    # Earlier scans split sample intervals; the midpoint rule is not exactly additive under a
    # split, which leaves micrometres after a kilometre.
    np.testing.assert_allclose(poses[on_sample, 0], x[index[on_sample]], atol=1e-4)
    np.testing.assert_allclose(poses[on_sample, 1], y[index[on_sample]], atol=1e-4)
    wrapped = np.angle(np.exp(1j * (poses[on_sample, 2] - heading[index[on_sample]])))
    np.testing.assert_allclose(wrapped, 0, atol=1e-8)


def test_recalibrated_steering_differs_and_is_default():
    vp = dcslam.datasets.victoria_park()
    assert vp.options["steering"] == "recalibrated"
    assert vp.u[:, 2].sum() != pytest.approx(-4.4678, abs=0.1)
    assert vp.initial_pose_hint[2] == pytest.approx(math.radians(34.5))


def test_slam_configs():
    vp = dcslam.datasets.victoria_park()
    cfg = vp.slam_config()
    assert isinstance(cfg, dcslam.SlamConfig)
    assert cfg.observation == "range_bearing" and cfg.association == "jcbb"
    assert tuple(cfg.sensor_offset) == (3.78, 0.5, 0.0) and cfg.join_feature_sigma == 0.1
    cfg.validate()
    # The preset is C++'s (dcslam_bench's too), read back field by field: nothing lost on the way.
    assert dcslam.SlamConfig._from_core(cfg._to_core()) == cfg
    assert vp.options == dcslam.datasets.VICTORIA_PARK_DEFAULTS == dcslam._core.datasets.victoria_park_options()
    g = dcslam.datasets.read_isam2d(ISAM_FILE).slam_config()
    assert g.observation == "point" and g.association == "known" and g.join_association == "known"
    assert tuple(g.sensor_offset) == (0.0, 0.0, 0.0)
    assert dcslam.SlamConfig._from_core(dcslam._core.datasets.isam2d_slam_config()) == g
    assert dcslam.datasets.read_isam2d(ISAM_FILE).slam_config(local_map_features=9).local_map_features == 9


def test_every_source_gives_the_one_step_type(raw_vp, isam):
    sim = dcslam.simulate("loop", steps=12)
    robot = dcslam.datasets.mrclam()
    for steps in (raw_vp.steps, isam.steps, robot.steps, sim.steps):
        assert type(steps) is dcslam.packed.Steps and type(steps[-1]) is dcslam.datasets.Step
        assert steps[-1].index == len(steps) - 1 and [s.index for s in steps[2:4]] == [2, 3]
    assert raw_vp.steps[5].landmark_ids is None and raw_vp.steps[5].t == raw_vp.t[5]
    np.testing.assert_array_equal(np.concatenate([s.landmark_ids for s in sim.steps]), sim.true_ids)
    np.testing.assert_array_equal(robot.steps[7].landmark_ids, robot.landmark_ids[robot.offsets[7]:robot.offsets[8]])


def test_isam_file(isam):
    assert isam.odometry_lines == 6968 and isam.landmark_lines == 3640
    assert len(isam.steps) == 6968
    assert len(np.unique(isam.landmark_ids)) == 151
    assert isam.landmark_ids.dtype == np.int64
    assert np.hypot(*isam.u[:, :2].T).sum() == pytest.approx(4026.6, abs=0.1)
    s = next(s for s in isam.steps if len(s.z))
    assert s.landmark_ids.shape == (len(s.z),) and s.R.shape == (len(s.z), 2, 2)
    np.testing.assert_allclose(s.R[0], [[0.4, 0], [0, 0.4]])
    np.testing.assert_allclose(isam.Q[0], np.diag([1e-4, 4e-6, 4e-6]))


def test_measurements_agree_with_isam_landmarks(raw_vp, isam):
    # The iSAM file skipped scans without motion; match its poses to scans by the distance
    # travelled (both integrate the raw steering). Our measurement, turned back into a point
    # of the rear-axle frame with the dataset's sensor offset, must land on the file's
    # LANDMARK point. The file used the range to the trunk's surface: remove our radius.
    travelled = np.cumsum(np.hypot(*raw_vp.u[:, :2].T))
    isam_travelled = np.cumsum(np.hypot(*isam.u[:, :2].T))
    misfits = []
    for k in range(0, len(isam.steps), 3):
        s = isam.steps[k]
        if len(s.z) == 0:
            continue
        scan = raw_vp.steps[int(np.argmin(np.abs(travelled - isam_travelled[k])))]
        if len(scan.z) == 0:
            continue
        surface = scan.z - np.c_[scan.diameters / 2, np.zeros(len(scan.z))]
        points = np.array([G.inverse_observe("range_bearing", raw_vp.sensor_offset, np.zeros(3), z)
                           for z in surface])
        misfits += [np.hypot(*(points - p).T).min() for p in s.z]
    assert len(misfits) > 500
    assert np.median(misfits) < 0.12


def copy_bundled(tmp_path):
    for name in dcslam.datasets.VICTORIA_PARK_FILES:
        shutil.copy(BUNDLED / name, tmp_path / name)


def rewrite(path, edit):
    with gzip.open(path, "rt") as f:
        lines = f.read().splitlines()
    edit(lines)
    with gzip.open(path, "wt") as f:
        f.write("\n".join(lines) + "\n")


def test_data_dir_reads_the_same_files(tmp_path):
    copy_bundled(tmp_path)
    vp = dcslam.datasets.victoria_park(tmp_path)
    assert len(vp.steps) == 7249


@pytest.mark.parametrize(
    "name, edit, parts",
    [
        ("vp_trees.csv.gz", lambda lines: lines.__setitem__(0, lines[0].replace("range_m", "rng")),
         ["vp_trees.csv.gz:1", "'range_m'", "missing column"]),
        ("vp_trees.csv.gz", lambda lines: lines.__setitem__(1234, lines[1234].replace(",", ",abc", 2).replace(",abc", ",", 1)),
         ["vp_trees.csv.gz:1235", "field 'range_m'", "'abc", "not a number"]),
        ("vp_trees.csv.gz", lambda lines: lines.__setitem__(1234, "110,45.319,19.25,1e300,0.17"),
         ["vp_trees.csv.gz:1235", "field 'bearing_rad'"]),
        ("vp_odometry.csv.gz", lambda lines: lines.__setitem__(500, "1.0,0,0"),
         ["vp_odometry.csv.gz:501", "field 't_s'", "backwards"]),
        ("vp_scans.csv.gz", lambda lines: lines.__setitem__(7, lines[7] + ",9"),
         ["vp_scans.csv.gz:8", "expected 3 fields"]),
    ],
)
def test_malformed_victoria_park_files(tmp_path, name, edit, parts):
    copy_bundled(tmp_path)
    rewrite(tmp_path / name, edit)
    with pytest.raises(dcslam.ParseError) as error:
        dcslam.datasets.victoria_park(tmp_path)
    assert isinstance(error.value, ValueError)
    for part in parts:
        assert part in str(error.value)


def test_truncated_gzip(tmp_path):
    copy_bundled(tmp_path)
    data = (tmp_path / "vp_gps.csv.gz").read_bytes()
    (tmp_path / "vp_gps.csv.gz").write_bytes(data[: len(data) // 2])
    with pytest.raises(dcslam.ParseError, match="vp_gps.csv.gz: truncated gzip stream"):
        dcslam.datasets.victoria_park(tmp_path)


def test_missing_folder_and_bad_options(tmp_path):
    with pytest.raises(dcslam.ParseError, match="cannot open"):
        dcslam.datasets.victoria_park(tmp_path)
    with pytest.raises(ValueError, match="steering"):
        dcslam.datasets.victoria_park(steering="calibrated")
    with pytest.raises(ValueError, match="unknown option"):
        dcslam.datasets.victoria_park(sigma_rnage=1.0)
    with pytest.raises(ValueError, match="max_range"):
        dcslam.datasets.victoria_park(max_range=-1)


@pytest.mark.parametrize(
    "text, parts",
    [
        ("ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\nEDGE2 1 2\n", [":2", "'tag'", "EDGE2"]),
        ("ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0\n", [":1", "12 tokens"]),
        ("ODOMETRY 0 1 1 0 zero 1e-4 0 0 4e-6 0 4e-6\n", [":1", "field 'dtheta'", "'zero'"]),
        ("ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\nODOMETRY 2 3 1 0 0 1e-4 0 0 4e-6 0 4e-6\n",
         [":2", "field 'i'", "chain"]),
        ("ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\nLANDMARK 1 5 1 2 0.4 0\n", [":2", "8 tokens"]),
    ],
)
def test_malformed_isam_files(tmp_path, text, parts):
    path = tmp_path / "graph.txt"
    path.write_text(text)
    with pytest.raises(dcslam.ParseError) as error:
        dcslam.datasets.read_isam2d(path)
    for part in ["graph.txt", *parts]:
        assert part in str(error.value)
