"""Checkpoint and resume: a filter pickled mid-run and resumed in another process goes on
bitwise as the uninterrupted run (the oracle: the same run, never stopped); deepcopy likewise;
damaged checkpoints raise ValueError."""

import copy
import dataclasses
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import dcslam

STEPS, SPLIT = 1200, 600
# 1,200 steps round a 60 m square with 5 % clutter, no ids: a map of about 200 features
# that the EKF also runs in a second; every place is revisited (joins match features).
SCENE = dict(trajectory="loop", steps=STEPS, seed=4, side_steps=15, clutter=0.05, features_per_step=10)
CASES = {
    "ekf": ("ekf", dict()),
    "dc_amortized": ("dc", dict(amortize=True)),
    "dc_threaded": ("dc", dict(threaded_joins=True)),
    # the kept local maps and tree shape go into the checkpoint: the resumed estimate()
    # re-linearises the same tree
    "dc_tree": ("dc", dict(tree_relinearisation=2)),
    # the base each closed local map was localised at, and the localisation under way at the
    # split (spread over the steps after its closure), go into the checkpoint: the resumed
    # online poses are the uninterrupted run's. Local maps of 60 features last long enough
    # (about 6 steps) for a localisation to span steps.
    "dc_localised": ("dc", dict(online_localisation_sigma=1.0, local_map_features=60)),
}


def scene():
    parameters = dict(SCENE)
    return dcslam.simulate(parameters.pop("trajectory"), **parameters)


def make_filter(case):
    name, options = CASES[case]
    config = dcslam.SlamConfig(**{"local_map_features": 20, **options})
    return dcslam.EkfSlam(config) if name == "ekf" else dcslam.DCSlam(config)


def run_batch(slam, sim, begin, end):
    offsets = sim.step_offsets
    return slam.run_batch(sim.odometry[begin:end], sim.Q, sim.measurements[offsets[begin]:offsets[end]],
                          sim.measurement_covariances[offsets[begin]:offsets[end]],
                          offsets[begin:end + 1] - offsets[begin])


def run_steps(slam, sim, begin, end):
    return run_batch(slam, sim, begin, end).ids


def final(slam):
    if isinstance(slam, dcslam.DCSlam):
        slam.finish_joins()
    return slam.estimate()


def pending_join_step(slam):
    """A step at or after SPLIT at which an amortized join has started and not finished."""
    for join in slam.stats.joins:
        if join["step_created"] < SPLIT <= join["step_finished"] - 1:
            return SPLIT
    for join in slam.stats.joins:
        if join["step_created"] >= SPLIT and join["step_finished"] - join["step_created"] >= 2:
            return join["step_created"] + 1
    raise AssertionError("no join in progress after the split")


def pending_localisation_step(case, sim):
    """The first step at or after SPLIT after which a localisation is under way."""
    slam = make_filter(case)
    run_steps(slam, sim, 0, SPLIT)
    for step in range(SPLIT, STEPS):
        if slam.stats.counters["localisation_under_way"]:
            return step
        run_steps(slam, sim, step, step + 1)
    raise AssertionError("no localisation under way after the split")


@pytest.fixture(scope="module")
def sim():
    return scene()


@pytest.fixture(scope="module")
def uninterrupted(sim):
    runs = {}
    for case in CASES:
        slam = make_filter(case)
        result = run_batch(slam, sim, 0, STEPS)
        runs[case] = (slam, result.ids, final(slam), result.trajectory)
    return runs


RESUME = textwrap.dedent("""
    import pickle, sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    import test_checkpoint as t
    with open({path!r}, "rb") as file:
        slam = pickle.load(file)
    sim = t.scene()
    result = t.run_batch(slam, sim, {split}, t.STEPS)
    ids, trajectory = result.ids, result.trajectory
    estimate = t.final(slam)
    np.savez({out!r}, ids=ids, trajectory=trajectory, robot=estimate.robot, landmarks=estimate.landmarks,
             landmark_ids=estimate.landmark_ids, covariance=estimate.covariance,
             resolved=slam.resolve(np.arange(-1, 4000)))
""")


@pytest.mark.parametrize("case", list(CASES))
def test_a_filter_resumed_in_another_process_is_bitwise_the_uninterrupted_run(sim, uninterrupted, case, tmp_path):
    reference, reference_ids, reference_estimate, reference_trajectory = uninterrupted[case]
    split = {"dc_amortized": lambda: pending_join_step(reference),
             "dc_localised": lambda: pending_localisation_step(case, sim)}.get(case, lambda: SPLIT)()
    slam = make_filter(case)
    first_ids = run_steps(slam, sim, 0, split)
    if case == "dc_amortized":
        assert any(j["step_created"] < split and j["step_finished"] == -1 for j in slam.stats.joins)
    if case == "dc_localised":
        assert slam.stats.counters["localisation_under_way"] == 1
    path = tmp_path / "filter.pkl"
    with open(path, "wb") as file:
        pickle.dump(slam, file)
    out = tmp_path / "resumed.npz"
    script = RESUME.format(tests=str(__import__("pathlib").Path(__file__).parent), path=str(path), split=split,
                           out=str(out))
    subprocess.run([sys.executable, "-c", script], check=True, timeout=300)
    resumed = np.load(out)
    np.testing.assert_array_equal(np.concatenate([first_ids, resumed["ids"]]), reference_ids)
    if case != "dc_threaded":  # threaded, the online pose depends on when the worker finishes a join
        np.testing.assert_array_equal(resumed["trajectory"], reference_trajectory[split:])
    for field in ("robot", "landmarks", "landmark_ids", "covariance"):
        np.testing.assert_array_equal(resumed[field], getattr(reference_estimate, field), err_msg=field)
    np.testing.assert_array_equal(resumed["resolved"], reference.resolve(np.arange(-1, 4000)))


@pytest.mark.parametrize("case", ["ekf", "dc_amortized"])
def test_a_deep_copy_goes_on_as_the_original(sim, uninterrupted, case):
    _, reference_ids, reference_estimate, _ = uninterrupted[case]
    slam = make_filter(case)
    first_ids = run_steps(slam, sim, 0, 700)
    twin = copy.deepcopy(slam)
    for filter_ in (slam, twin):
        later_ids = run_steps(filter_, sim, 700, 1000)
        np.testing.assert_array_equal(np.concatenate([first_ids, later_ids]), reference_ids[: sim.step_offsets[1000]])
    np.testing.assert_array_equal(final(twin).covariance, final(slam).covariance)
    assert len(twin.stats.step_seconds) == len(slam.stats.step_seconds) == 1000


def test_a_copy_keeps_the_last_estimates_fold_and_side_joins(sim):
    slam = make_filter("dc_amortized")
    run_steps(slam, sim, 0, 700)
    slam.estimate()  # with the joins still pending at step 700 computed on the side
    twin = copy.deepcopy(slam)
    assert len(slam.stats.fold_joins) > 0 and len(slam.stats.side_joins) > 0
    assert twin.stats.fold_joins == slam.stats.fold_joins  # their seconds too: the record is kept
    assert twin.stats.side_joins == slam.stats.side_joins


def core_state(case):
    slam = make_filter(case)
    run_steps(slam, scene(), 0, 100)
    return slam._core.__getstate__()


def restored(core_class, state):
    filter_ = core_class.__new__(core_class)
    filter_.__setstate__(state)
    return filter_


@pytest.mark.parametrize("damage, message", [
    (lambda b: b[: len(b) // 2], "truncated"),
    (lambda b: b[:20], "not a dcslam checkpoint|truncated"),
    (lambda b: b"", "not a dcslam checkpoint"),
    (lambda b: b[:200] + bytes([b[200] ^ 0x40]) + b[201:], "corrupted"),
    (lambda b: b[:8] + (99).to_bytes(4, "little") + b[12:], r"format version 99, this dcslam reads version \d+"),
    (lambda b: b + b"\0", "extended"),
])
def test_damaged_checkpoints_raise_value_error(damage, message):
    state = core_state("dc_amortized")
    with pytest.raises(ValueError, match=f"checkpoint: .*({message})"):
        restored(dcslam._core.DCSlam, damage(state))


def test_a_checkpoint_of_one_filter_is_refused_by_the_other():
    with pytest.raises(ValueError, match="checkpoint of an EkfSlam, not of a DCSlam"):
        restored(dcslam._core.DCSlam, core_state("ekf"))
    with pytest.raises(ValueError, match="checkpoint of a DCSlam, not of an EkfSlam"):
        restored(dcslam._core.EkfSlam, core_state("dc_amortized"))


def test_a_filter_with_a_join_oracle_is_not_saved():
    slam = dcslam.DCSlam(dcslam.SlamConfig())
    slam.set_join_oracle([1], [1], "audit")
    with pytest.raises(ValueError, match="join oracle"):
        pickle.dumps(slam)


# A value other than the default for each optional field; unset (None) is checked too, which a
# field whose default is set (join_rival_margin, confirmed_first_confidence) once lost.
OPTIONAL_VALUES = {"confirmed_first_confidence": 0.95, "final_merge_confidence": 0.999,
                   "join_rival_margin": 5, "online_localisation_sigma": 7.0}


def test_every_optional_config_field_is_listed():
    optional = {field.name for field in dataclasses.fields(dcslam.SlamConfig)
                if "Optional" in str(field.type)}
    assert optional == set(OPTIONAL_VALUES)


@pytest.mark.parametrize("filter_class", [dcslam.EkfSlam, dcslam.DCSlam])
@pytest.mark.parametrize("name", sorted(OPTIONAL_VALUES))
@pytest.mark.parametrize("set_", [False, True])
def test_a_checkpoint_keeps_an_optional_config_field_set_or_unset(filter_class, name, set_):
    value = OPTIONAL_VALUES[name] if set_ else None
    slam = filter_class(dcslam.SlamConfig(**{name: value}))
    restored = pickle.loads(pickle.dumps(slam))
    assert getattr(restored.config, name) == value
    assert getattr(restored._core.config, name) == value  # what the resumed filter runs with
