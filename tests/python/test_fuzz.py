"""Property-based fuzzing of the Python API, the readers and the CLI (hypothesis), with a fixed
budget and a fixed derandomised seed so that CI runs the same examples every time.

The contract checked (docs/api.md, "Bad input"): any call either succeeds or raises a
``ValueError`` with a message; after a refused call the filter is bitwise what it was; a
corrupted file is refused with a ``ValueError`` naming the file (and for a bad field its line),
and what a reader accepts the filter runs; a command line either runs or ends in a short error
with a non-zero exit, never a traceback; nothing crashes the process (a crash would end the
pytest run itself).
"""

from __future__ import annotations

import gzip
import os
import re
import shutil
import traceback
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import dcslam
from dcslam import datasets

BUDGET = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# Numbers where filters break: non-finite, huge, tiny, negative zero, and ordinary ones.
awkward_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e155, -1e155, 1e6, 1e-12, -1e-7]),
    st.floats(-10, 10),
)
dtypes = st.sampled_from([np.float64, np.float32, np.int64, np.uint64, np.bool_, np.complex128])


def arrays(shapes):
    """Arrays of any of `dtypes` and `shapes`, or other Python objects where arrays belong."""
    numeric = dtypes.flatmap(lambda dtype: hnp.arrays(
        dtype, shapes, elements=awkward_floats if dtype is np.float64 else None))
    others = st.one_of(st.none(), st.text(max_size=4), st.integers(), st.lists(st.floats(), max_size=4),
                       st.just(object()))
    return st.one_of(numeric, numeric, numeric, others)


def filters():
    """A fresh filter of each kind, already past a few steps (so that refusals have a state to
    keep): the EKF, and D&C with tiny local maps in each join schedule (joins happen)."""
    sim = dcslam.simulate("loop", steps=12, seed=3, clutter=0.1)
    made = []
    for make, extra in ((dcslam.EkfSlam, {}), (dcslam.DCSlam, dict(amortize=False)), (dcslam.DCSlam, {}),
                        (dcslam.DCSlam, dict(threaded_joins=True))):
        slam = make(dcslam.SlamConfig(association="jcbb", join_association="rjc", local_map_features=4, **extra)
                    if make is dcslam.DCSlam else dcslam.SlamConfig(association="jcbb"))
        slam.run(sim.steps)
        made.append(slam)
    return made


def snapshot(slam):
    if isinstance(slam, dcslam.DCSlam):
        slam.finish_joins()
    estimate = slam.estimate()
    return estimate.robot.copy(), estimate.landmarks.copy(), estimate.covariance.copy()


def assert_same(before, after):
    for a, b in zip(before, after):
        assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def check_refusal_keeps_state(slam, call):
    before = snapshot(slam)
    try:
        call()
    except ValueError as error:
        assert str(error), "a refusal must say what was wrong"
        assert_same(before, snapshot(slam))


@pytest.fixture(scope="module")
def fuzzed_filters():
    return filters()


@BUDGET
@given(u=arrays(st.sampled_from([(3,), (2,), (3, 1), (0,)])), Q=arrays(st.sampled_from([(3, 3), (2, 2), (3,), (9,)])))
def test_predict_refuses_with_a_message_and_keeps_the_state(fuzzed_filters, u, Q):
    for slam in fuzzed_filters:
        check_refusal_keeps_state(slam, lambda: slam.predict(u, Q))


@BUDGET
@given(m=st.integers(0, 3), data=st.data())
def test_update_refuses_with_a_message_and_keeps_the_state(fuzzed_filters, m, data):
    # Plausible scans too, so that accepted updates (and the joins they start) are fuzzed as well.
    plausible_z = hnp.arrays(np.float64, (m, 2), elements=st.floats(0.1, 20))
    z = data.draw(st.one_of(plausible_z, arrays(st.sampled_from([(m, 2), (m, 3), (2,), (m,)]))), label="z")
    R = data.draw(st.one_of(st.just(np.diag([0.01, 0.001])),
                            arrays(st.sampled_from([(2, 2), (m, 2, 2), (2,), (3, 3)]))), label="R")
    ids = data.draw(st.one_of(st.none(), arrays(st.sampled_from([(m,), (m + 1,)]))), label="landmark_ids")
    for slam in fuzzed_filters:
        check_refusal_keeps_state(slam, lambda: slam.update(z, R, ids))


@BUDGET
@given(fields=st.dictionaries(
    st.sampled_from(["local_map_features", "gate_confidence", "rjc_b", "rjc_p_good", "merge_radius",
                     "tentative_window", "min_sightings", "amortize", "threaded_joins", "association",
                     "join_association", "seed", "join_feature_sigma", "final_merge_confidence"]),
    st.one_of(awkward_floats, st.integers(-3, 10 ** 20), st.booleans(), st.none(), st.text(max_size=6)),
    max_size=3))
def test_configs_are_refused_with_a_message(fields):
    try:
        config = dcslam.SlamConfig(**{"association": "jcbb", "join_association": "rjc", **fields})
        slam = dcslam.DCSlam(config)
    except ValueError as error:
        assert str(error)
        return
    slam.predict(np.zeros(3), 1e-4 * np.eye(3))  # an accepted config runs


VICTORIA_PARK = Path(dcslam.__file__).parent / "data" / "victoria_park"
SCANS = 20


def head_lines(path: Path, keep) -> bytes:
    """The header and the data lines of a gzip CSV for which ``keep(fields)`` holds."""
    with gzip.open(path, "rb") as file:
        header, *rows = file.read().splitlines(keepends=True)
    return header + b"".join(row for row in rows if keep(row.split(b",")))


@pytest.fixture(scope="module")
def small_victoria_park(tmp_path_factory):
    """The bundled Victoria Park data cut to its first scans (a valid, small dataset)."""
    folder = tmp_path_factory.mktemp("vp")
    last_time = float(head_lines(VICTORIA_PARK / "vp_scans.csv.gz", lambda f: int(f[0]) == SCANS - 1)
                      .splitlines()[1].split(b",")[1])
    cuts = {"vp_scans.csv.gz": lambda f: int(f[0]) < SCANS, "vp_trees.csv.gz": lambda f: int(f[0]) < SCANS,
            "vp_odometry.csv.gz": lambda f: float(f[0]) <= last_time + 1.0,
            "vp_gps.csv.gz": lambda f: float(f[0]) <= last_time + 1.0}
    for name, keep in cuts.items():
        (folder / name).write_bytes(gzip.compress(head_lines(VICTORIA_PARK / name, keep)))
    assert len(datasets.victoria_park(folder).steps) > 10  # the premise: the cut files load
    return folder


@BUDGET
@given(name=st.sampled_from(["vp_odometry.csv.gz", "vp_scans.csv.gz", "vp_trees.csv.gz"]),
       where=st.floats(0, 1), garbage=st.binary(min_size=1, max_size=12), compressed=st.booleans())
def test_corrupted_victoria_park_files_are_refused_by_name(small_victoria_park, tmp_path_factory, name, where,
                                                          garbage, compressed):
    folder = tmp_path_factory.mktemp("corrupt")
    for source in small_victoria_park.iterdir():
        shutil.copy(source, folder / source.name)
    target = folder / name
    raw = gzip.decompress(target.read_bytes())
    data = gzip.compress(raw) if compressed else raw
    at = int(where * (len(data) - 1))
    target.write_bytes(data[:at] + garbage + data[at + len(garbage):])
    try:
        datasets.victoria_park(folder)
    except ValueError as error:
        assert name in str(error) or "victoria_park" in str(error), str(error)


# A small valid iSAM file: two poses, landmarks seen from both (the LANDMARK covariances are
# the measurement's, in the pose's frame).
ISAM_LINES = [
    b"ODOMETRY 0 1 1 0 0 1e-4 0 0 4e-6 0 4e-6",
    b"LANDMARK 1 5 1 2 0.1 0 0.1",
    b"LANDMARK 1 6 2 -1 0.1 0.01 0.2",
    b"ODOMETRY 1 2 1 0.1 0.05 1e-4 0 0 4e-6 0 4e-6",
    b"LANDMARK 2 5 0.1 2.1 0.1 0 0.1",
    b"# a comment",
    b"LANDMARK 2 6 1.2 -1 0.1 0 0.1",
]
# Tokens where a reader breaks: non-numbers, non-finite and extreme numbers, hex floats,
# negative and huge ids, bytes that are not UTF-8, NUL, nothing.
awkward_tokens = st.one_of(
    st.sampled_from([b"nan", b"inf", b"-inf", b"1e400", b"1e300", b"-1e300", b"1e-300", b"0", b"-0", b"-1",
                     b"0x1p3", b"9223372036854775808", b"-9223372036854775809", b"1.5", b"abc", b"\xff",
                     b"\x00", b"", b"1e", b"--1", b"ODOMETRY", b"LANDMARK", b"1 2"]),
    st.binary(max_size=6),
)


def isam_bytes(lines):
    return b"\n".join(lines) + b"\n"


def corrupt_isam(data):
    """Corruptions of ISAM_LINES: a token replaced, bytes overwritten, a cut, lines dropped or
    repeated."""
    token = st.tuples(st.integers(0, len(ISAM_LINES) - 1), st.integers(0, 11), awkward_tokens).map(
        lambda c: [b" ".join(c[2] if i == c[1] else t for i, t in enumerate(line.split(b" ")))
                   if n == c[0] else line for n, line in enumerate(ISAM_LINES)])
    lines = data.draw(st.one_of(st.just(ISAM_LINES), token, st.permutations(ISAM_LINES),
                                st.lists(st.sampled_from(ISAM_LINES), max_size=9)), label="lines")
    raw = isam_bytes(lines)
    where, garbage = data.draw(st.floats(0, 1), label="where"), data.draw(st.binary(max_size=8), label="garbage")
    at = int(where * len(raw))
    raw = data.draw(st.sampled_from([raw, raw, raw[:at] + garbage + raw[at + len(garbage):], raw[:at]]), label="damage")
    return raw


@BUDGET
@given(data=st.data(), compressed=st.sampled_from([False, False, True]))
def test_corrupted_isam_files_are_refused_by_file_and_line_or_run(tmp_path_factory, data, compressed):
    raw = corrupt_isam(data)
    if compressed:
        packed = gzip.compress(raw)
        at = data.draw(st.integers(0, len(packed)), label="gzip cut")
        raw = data.draw(st.sampled_from([packed, packed[:at], packed + b"\x00"]), label="gzip damage")
    name = "graph.txt.gz" if compressed else "graph.txt"
    path = tmp_path_factory.mktemp("isam") / name
    path.write_bytes(raw)
    try:
        dataset = datasets.read_isam2d(path)
    except ValueError as error:
        event("refused")
        message = str(error)
        assert name in message and len(message) < 400, message
        if "field '" in message:
            assert re.search(re.escape(name) + r":\d+", message), message
        return
    # What the reader accepts, the filter takes: every value it would refuse has its line above.
    event("accepted")
    slam = dcslam.EkfSlam(dataset.slam_config())
    slam.run(dataset)
    assert np.all(np.isfinite(slam.estimate().covariance))


def test_the_small_isam_file_is_valid(tmp_path):
    path = tmp_path / "graph.txt"
    path.write_bytes(isam_bytes(ISAM_LINES))
    assert len(datasets.read_isam2d(path).steps) == 2


# The CLI, in-process (typer's runner): each base command runs in well under a second when
# valid (a tiny iSAM file, the cut Victoria Park data, two selfcheck samples); fuzzed options
# of that command come after it (the last value of an option wins), now and then one it does
# not have. montecarlo and `run mrclam` are left out: a valid invocation runs a whole
# experiment. Their options go through the same typer machinery.
CLI_VALUES = ["-5", "0", "1", "2", "abc", "", "1.5", "nan", "inf", "1e400", "\x00", "é", "--"]
RUN_OPTIONS = {"--filter": ["ekf", "dc", "both"], "--max-steps": ["3", "99999999999999999999"],
               "--association": ["known", "nn", "jcbb"], "--join-association": ["known", "rjc", "jcbb"],
               "--local-map-features": ["3", "99999999999999999999"], "--join-iterations": ["3"],
               "--output": ["{blocked}", "{out}"], "--plots": None, "--no-plots": None,
               "--keep-local-map-poses": None, "--online-localisation-sigma": ["5", "inf"], "--progress": None}
CLI_OPTIONS = [RUN_OPTIONS, dict(RUN_OPTIONS, **{"--data-dir": ["{blocked}", "{isam}", "{vp}"]}),
               {"--samples": ["1", "3"]}]
UNKNOWN_OPTIONS = {"--nope": ["1"], "--help": None}


@pytest.fixture(scope="module")
def cli_bases(small_victoria_park, tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    isam = folder / "graph.txt"
    isam.write_bytes(isam_bytes(ISAM_LINES))
    (folder / "a_file").write_text("")
    (folder / "cwd").mkdir()
    paths = {"{cwd}": str(folder / "cwd"), "{out}": str(folder / "out"), "{blocked}": str(folder / "a_file" / "out"), "{isam}": str(isam),
             "{vp}": str(small_victoria_park)}
    bases = [["run", "isam", str(isam), "--output", paths["{out}"], "--no-plots", "--no-progress"],
             ["run", "victoria-park", "--data-dir", paths["{vp}"], "--output", paths["{out}"], "--no-plots",
              "--no-progress"],
             ["selfcheck", "--samples", "2"]]
    return bases, paths


@settings(BUDGET, max_examples=25)
@given(base=st.integers(0, 2), data=st.data())
def test_fuzzed_command_lines_end_in_a_short_error_or_a_run_never_a_traceback(cli_bases, base, data):
    from typer.testing import CliRunner

    from dcslam.cli import app

    bases, paths = cli_bases
    args = list(bases[base])
    for _ in range(data.draw(st.integers(0, 3), label="options")):
        options = data.draw(st.sampled_from([CLI_OPTIONS[base]] * 4 + [UNKNOWN_OPTIONS]), label="which")
        option = data.draw(st.sampled_from(sorted(options)), label="option")
        args.append(option)
        if options[option] is not None:
            value = data.draw(st.sampled_from(CLI_VALUES + options[option] * 3), label=option)
            args.append(paths.get(value, value))
    here = os.getcwd()
    os.chdir(paths["{cwd}"])  # a relative --output ("nan", "1") is written in a temporary folder
    try:
        result = CliRunner().invoke(app, args)
    finally:
        os.chdir(here)
    output = result.output
    event(f"exit {result.exit_code}" + (" (the app's own error)" if output.startswith("error:") else ""))
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        args, "".join(traceback.format_exception(result.exception)))
    assert "Traceback" not in output, (args, output)
    if result.exit_code != 0:
        assert "rror" in output and len(output) < 2000, (args, output)
        if output.startswith("error:"):
            assert output.count("\n") == 1, (args, output)  # one line
