"""Broken files: the readers refuse bad bytes, huge lines, empty or truncated input and every
value the filter would refuse, with the file, the line and the field (docs/api.md, "Reader
limits"), on small files generated here."""

import gzip

import pytest

import dcslam

VP_FILES = {
    "vp_odometry.csv.gz": [b"t_s,speed_mps,steering_rad", b"0.0,1.0,0.01", b"0.5,1.0,0.01", b"1.0,1.0,0.0"],
    "vp_scans.csv.gz": [b"scan,t_s,n_trees", b"0,0.0,1", b"1,1.0,1"],
    "vp_trees.csv.gz": [b"scan,t_s,range_m,bearing_rad,diameter_m", b"0,0.0,10.0,1.5,0.3", b"1,1.0,9.5,1.5,0.3"],
    "vp_gps.csv.gz": [b"t_s,x_m,y_m", b"0.0,1.0,2.0", b"1.0,2.0,2.0"],
}

ISAM_HEAD = b"ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\n"


def write_vp(folder, name=None, lines=None, raw=None):
    """The small dataset, with `name` holding `lines` (gzip) or the bytes `raw` instead."""
    for file_name, content in VP_FILES.items():
        data = gzip.compress(b"\n".join(content) + b"\n")
        if file_name == name:
            data = raw if raw is not None else gzip.compress(b"\n".join(lines) + b"\n")
        (folder / file_name).write_bytes(data)
    return folder


def vp_error(folder):
    with pytest.raises(dcslam.ParseError) as error:
        dcslam.datasets.victoria_park(folder)
    message = str(error.value)
    assert len(message) < 400, message
    return message


def isam_error(tmp_path, data, name="graph.txt"):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(dcslam.ParseError) as error:
        dcslam.datasets.read_isam2d(path)
    message = str(error.value)
    assert name in message and len(message) < 400, message
    return message


def test_the_small_files_are_valid(tmp_path):
    vp = dcslam.datasets.victoria_park(write_vp(tmp_path))
    assert len(vp.steps) == 2 and len(vp.z) == 2
    (tmp_path / "graph.txt").write_bytes(ISAM_HEAD)
    assert len(dcslam.datasets.read_isam2d(tmp_path / "graph.txt").steps) == 1


@pytest.mark.parametrize("name, row, field", [
    ("vp_odometry.csv.gz", 2, "speed_mps"), ("vp_scans.csv.gz", 1, "t_s"),
    ("vp_trees.csv.gz", 1, "bearing_rad"), ("vp_gps.csv.gz", 2, "y_m"),
])
def test_a_byte_that_is_not_utf8_names_file_line_and_field(tmp_path, name, row, field):
    lines = list(VP_FILES[name])
    header = lines[0].split(b",")
    values = lines[row].split(b",")
    values[header.index(field.encode())] += b"\xff"
    lines[row] = b",".join(values)
    message = vp_error(write_vp(tmp_path, name, lines))
    assert f"{name}:{row + 1}: field '{field}'" in message and "\\xff" in message


def test_a_byte_that_is_not_utf8_in_the_header_is_named(tmp_path):
    lines = list(VP_FILES["vp_gps.csv.gz"])
    lines[0] = b"t_s,x_m,y_m\xe9"
    message = vp_error(write_vp(tmp_path, "vp_gps.csv.gz", lines))
    assert "vp_gps.csv.gz:1: field 'y_m'" in message and "\\xe9" in message


def test_a_line_longer_than_the_limit_is_refused_without_reading_it_whole(tmp_path):
    huge = gzip.compress(b"t_s,x_m,y_m\n" + b"1" * (8 << 20) + b"\n", compresslevel=1)
    message = vp_error(write_vp(tmp_path, "vp_gps.csv.gz", raw=huge))
    assert "vp_gps.csv.gz:2: line longer than 65536 bytes" in message


def test_a_long_token_is_quoted_as_a_short_excerpt(tmp_path):
    lines = list(VP_FILES["vp_gps.csv.gz"])
    lines[1] = b"0.0,1.0," + b"7" * 60000 + b"x"
    message = vp_error(write_vp(tmp_path, "vp_gps.csv.gz", lines))
    assert "vp_gps.csv.gz:2: field 'y_m': '" + "7" * 40 + "...'" in message


@pytest.mark.parametrize("raw, part", [
    (gzip.compress(b"t_s,x_m,y_m\n"), "vp_gps.csv.gz:2: no data rows after the header"),
    (gzip.compress(b""), "vp_gps.csv.gz:1: empty file"),
    (b"\0" * 64, "vp_gps.csv.gz:1: NUL byte"),
    (gzip.compress(b"t_s,x_m,y_m\n0.0,1.0,2.0\n") + b"garbage", "vp_gps.csv.gz: trailing data after the gzip"),
], ids=["header only", "empty", "NUL bytes", "trailing garbage"])
def test_empty_binary_and_padded_files_are_refused(tmp_path, raw, part):
    assert part in vp_error(write_vp(tmp_path, "vp_gps.csv.gz", raw=raw))


def test_a_truncated_gzip_names_the_line_it_ends_in(tmp_path):
    rows = [b"t_s,x_m,y_m"] + [b"%d.0,1.0,2.0" % k for k in range(2000)]
    data = gzip.compress(b"\n".join(rows) + b"\n")
    message = vp_error(write_vp(tmp_path, "vp_gps.csv.gz", raw=data[: len(data) // 2]))
    assert "vp_gps.csv.gz: truncated gzip stream (it ends in line " in message


@pytest.mark.parametrize("row, field, value", [
    (2, "speed_mps", b"1e300"), (2, "steering_rad", b"1.5"), (2, "t_s", b"0x1p-2"),
])
def test_odometry_the_filter_would_refuse_is_refused_with_its_line(tmp_path, row, field, value):
    lines = list(VP_FILES["vp_odometry.csv.gz"])
    header = lines[0].split(b",")
    values = lines[row].split(b",")
    values[header.index(field.encode())] = value
    lines[row] = b",".join(values)
    message = vp_error(write_vp(tmp_path, "vp_odometry.csv.gz", lines))
    assert f"vp_odometry.csv.gz:{row + 1}: field '{field}'" in message


def test_scan_times_far_apart_give_a_motion_refused_at_the_scan(tmp_path):
    write_vp(tmp_path)
    scans = [b"scan,t_s,n_trees", b"0,0.0,1", b"1,1e9,1"]
    trees = [b"scan,t_s,range_m,bearing_rad,diameter_m", b"0,0.0,10.0,1.5,0.3", b"1,1e9,9.5,1.5,0.3"]
    (tmp_path / "vp_scans.csv.gz").write_bytes(gzip.compress(b"\n".join(scans) + b"\n"))
    (tmp_path / "vp_trees.csv.gz").write_bytes(gzip.compress(b"\n".join(trees) + b"\n"))
    assert "vp_scans.csv.gz:3: the odometry since the previous scan" in vp_error(tmp_path)


@pytest.mark.parametrize("data, parts", [
    (ISAM_HEAD + b"LANDMARK 1 5 1 2 0 0 0\n", [":2", "fields 'c11'..'c22'", "not positive definite"]),
    (ISAM_HEAD + b"LANDMARK 1 5 1 2 1 1 1\n", [":2", "fields 'c11'..'c22'", "not positive definite"]),
    (ISAM_HEAD + b"LANDMARK 1 5 1 2 1e300 0 -1e300\n", [":2", "field 'c11'", "1e+300"]),
    (ISAM_HEAD + b"LANDMARK 1 -5 1 2 0.1 0 0.1\n", [":2", "field 'l'", "-5"]),
    (b"ODOMETRY -1 1 1 0 0 1e-4 0 0 4e-6 0 4e-6\n", [":1", "field 'i'", "-1"]),
    (ISAM_HEAD + b"LANDMARK 1 5 1 2 0.1 0 0.1\nLANDMARK 1 5 3 2 0.1 0 0.1\n", [":3", "field 'l'", "twice"]),
    (b"ODOMETRY 0 1 1e155 0 0 1e-4 0 0 4e-6 0 4e-6\n", [":1", "field 'dx'", "1e+155"]),
    (b"ODOMETRY 0 1 1 0 0 1e6 0 0 1e-4 0 -1e-7\n", [":1", "fields 'c11'..'c33'", "-1e-07"]),
    (b"ODOMETRY 0 1 0x1p0 0 0 1e-4 0 0 4e-6 0 4e-6\n", [":1", "field 'dx'", "'0x1p0' is not a number"]),
    (ISAM_HEAD + b"LANDMARK 1 5 1\xff 2 0.1 0 0.1\n", [":2", "field 'x'", "'1\\xff' is not a number"]),
    (b"ODOM\xc3\x28 0 1\n", [":1", "field 'tag'", "'ODOM\\xc3('"]),
    (b"", ["no ODOMETRY or LANDMARK line"]),
    (b"# only a comment\n\n", ["no ODOMETRY or LANDMARK line"]),
    (b"\0\0\0\0", [":1", "NUL byte"]),
], ids=["zero landmark covariance", "singular landmark covariance", "overflowing landmark covariance",
        "negative landmark id", "negative pose id", "landmark twice at a pose", "absurd motion",
        "negative eigenvalue", "hex float", "bad byte in a value", "bad byte in the tag", "empty",
        "comments only", "NUL bytes"])
def test_isam_files_the_filter_would_refuse(tmp_path, data, parts):
    message = isam_error(tmp_path, data)
    for part in parts:
        assert part in message, message


def test_isam_gzip_with_trailing_garbage_or_truncated(tmp_path):
    data = gzip.compress(b"".join(b"ODOMETRY %d %d 1 0 0 1e-4 0 0 4e-6 0 4e-6\n" % (k, k + 1) for k in range(3000)))
    assert "trailing data after the gzip stream" in isam_error(tmp_path, data + b"\x00junk", "g.txt.gz")
    assert "truncated gzip stream (it ends in line" in isam_error(tmp_path, data[:-20], "g.txt.gz")


def test_concatenated_gzip_members_are_one_file(tmp_path):
    path = tmp_path / "g.txt.gz"
    path.write_bytes(gzip.compress(ISAM_HEAD) + gzip.compress(b"ODOMETRY 1 2 1 0 0 1e-4 0 0 4e-6 0 4e-6\n"))
    assert len(dcslam.datasets.read_isam2d(path).steps) == 2


@pytest.mark.parametrize("option, value", [("max_range", True), ("sigma_range", 1e7), ("steering", 1)])
def test_victoria_park_options_are_not_coerced(tmp_path, option, value):
    with pytest.raises(dcslam.InvalidArgument, match=option):
        dcslam.datasets.victoria_park(write_vp(tmp_path), **{option: value})
