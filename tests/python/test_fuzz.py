"""Property-based fuzzing of the Python API and the readers (hypothesis), with a fixed budget
and a fixed derandomised seed so that CI runs the same examples every time.

The contract checked (docs/api.md, "Bad input"): any call either succeeds or raises a
``ValueError`` with a message; after a refused call the filter is bitwise what it was; a
corrupted file is refused with a ``ValueError`` naming the file; nothing crashes the process
(a crash would end the pytest run itself).
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
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
                     "join_association", "seed", "join_feature_sigma"]),
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
