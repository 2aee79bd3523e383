"""EkfSlam data association without landmark ids ("nn", "jcbb") and the spurious-measurement
policy, scored against the true ids of a simulated run with clutter."""

import collections
import math
from types import SimpleNamespace

import numpy as np
import pytest

import dcslam
from dcslam import geometry as g

SENSOR_RANGE = 3.0


def field_scenario(seed, laps=2, side=12, clutter=0.10, odometry_scale=1.0, density=0.55):
    """docs/design.md §7's simulator in miniature: a uniform field of point landmarks, the robot
    driving a square loop `laps` times at 1 m a step, range-bearing sensor of 3 m (sigma 5 % of
    the range, 1 deg), odometry sigma (0.10 m along, 0.05 m across, 0.5 deg) x odometry_scale,
    and `clutter` spurious measurements per true one, uniform over the sensor's disc."""
    rng = np.random.default_rng(seed)
    margin = SENSOR_RANGE + 1
    area = (side + 2 * margin) ** 2
    landmarks = rng.uniform(-margin, side + margin, size=(rng.poisson(density * area), 2))
    Q = np.diag([0.10**2, 0.05**2, math.radians(0.5) ** 2]) * odometry_scale**2
    pose = np.zeros(3)
    steps = []
    for _ in range(laps):
        for corner in range(4):
            for k in range(side):
                turn = math.pi / 2 if k == side - 1 else 0.0
                u_true = np.array([1.0, 0.0, turn])
                pose = g.compose(pose, u_true)
                u = u_true + rng.multivariate_normal(np.zeros(3), Q)
                z, R, ids = [], [], []
                for j, lm in enumerate(landmarks):
                    r, b = g.observe("range_bearing", np.zeros(3), pose, lm)
                    if not 0.3 < r < SENSOR_RANGE:
                        continue
                    Rj = np.diag([(0.05 * r) ** 2, math.radians(1.0) ** 2])
                    zj = np.array([r, b]) + rng.multivariate_normal(np.zeros(2), Rj)
                    z.append(zj)
                    R.append(Rj)
                    ids.append(j)
                for _ in range(rng.poisson(clutter * len(ids))):
                    r = SENSOR_RANGE * math.sqrt(rng.uniform(0.01, 1.0))
                    z.append([r, rng.uniform(-math.pi, math.pi)])
                    R.append(np.diag([(0.05 * r) ** 2, math.radians(1.0) ** 2]))
                    ids.append(-1)
                order = rng.permutation(len(ids))
                steps.append(SimpleNamespace(
                    u=u, Q=Q, z=np.array(z, dtype=float).reshape(-1, 2)[order],
                    R=np.array(R, dtype=float).reshape(-1, 2, 2)[order],
                    true_ids=np.array(ids, dtype=np.int64)[order]))
    return SimpleNamespace(landmarks=landmarks, steps=steps)


def score(slam, scenario):
    """Runs the scenario and scores its pairings. A feature belongs to the true landmark (or
    clutter, -1) most of its measurements came from, so a feature born from clutter and then
    taken over by a landmark counts as that landmark. Precision: correct pairings / pairings
    with a feature that existed before the scan. Recall: correct pairings / measurements of a
    landmark that had a feature before the scan."""
    history = []
    for s in scenario.steps:
        slam.predict(s.u, s.Q)
        live = set(slam.estimate().landmark_ids.tolist())
        history.append((live, slam.update(s.z, s.R).tolist(), s.true_ids.tolist()))
    votes = collections.defaultdict(collections.Counter)
    for _, ids, true_ids in history:
        for got, true in zip(ids, true_ids):
            if got != -1:
                votes[got][true] += 1
    owner = {f: counts.most_common(1)[0][0] for f, counts in votes.items()}
    pairings = correct = pairable = 0
    for live, ids, true_ids in history:
        mapped = {owner[f] for f in live}
        for got, true in zip(ids, true_ids):
            pairable += true != -1 and true in mapped
            if got in live:
                pairings += 1
                correct += true != -1 and owner[got] == true
    final = slam.estimate().landmark_ids.tolist()
    seen = {t for s in scenario.steps for t in s.true_ids.tolist() if t != -1}
    return SimpleNamespace(
        precision=correct / pairings, recall=correct / pairable,
        pairings=pairings, correct=correct, pairable=pairable,
        features=len(final), clutter_features=sum(owner[f] == -1 for f in final),
        landmarks_seen=len(seen), landmarks_mapped=len({owner[f] for f in final} - {-1}),
        final=final, resolved_removed=slam.resolve(np.array(sorted(set(owner) - set(final)), dtype=np.int64)))


def config(mode, **overrides):
    return dcslam.SlamConfig(observation="range_bearing", association=mode, **overrides)


def test_jcbb_pairs_with_high_precision_and_recall_and_keeps_clutter_out_of_the_map():
    # Pooled over seeds: one swap of two close landmarks (5 % range noise) costs every later
    # sighting of both, so a single short run is a noisy score.
    pairings = correct_p = pairable = correct_r = 0
    for seed in range(1, 5):
        result = score(dcslam.EkfSlam(config("jcbb", gate_confidence=0.9999)),
                       field_scenario(seed=seed, laps=1, density=0.2))
        print(seed, {k: v for k, v in vars(result).items() if k not in ("resolved_removed", "final")})
        pairings += result.pairings
        correct_p += result.correct
        pairable += result.pairable
        # About one feature per landmark seen: clutter does not fill the map, landmarks are
        # not duplicated (a landmark glimpsed once at the edge of the range may be dropped).
        assert result.clutter_features <= 0.15 * result.landmarks_seen
        assert 0.85 * result.landmarks_seen <= result.landmarks_mapped <= result.landmarks_seen
        assert result.features <= 1.15 * result.landmarks_seen
        # An id no longer in the map was removed as spurious (-1) or merged into a feature
        # that is.
        assert all(r == -1 or r in set(result.final) for r in result.resolved_removed.tolist())
    precision, recall = correct_p / pairings, correct_p / pairable
    print("pooled precision", precision, "recall", recall)
    assert precision >= 0.97 and recall >= 0.98


def test_nn_is_worse_than_jcbb_at_high_odometry_noise():
    scenario = field_scenario(seed=2, laps=1, density=0.2, odometry_scale=3.0)
    jcbb = score(dcslam.EkfSlam(config("jcbb", gate_confidence=0.9999)), scenario)
    nn = score(dcslam.EkfSlam(config("nn", gate_confidence=0.9999)), scenario)
    print("jcbb", jcbb.precision, jcbb.recall, "nn", nn.precision, nn.recall)
    assert nn.precision < jcbb.precision
    assert jcbb.precision >= 0.9


def test_known_mode_never_removes_features_and_counts_jcbb_work():
    scenario = field_scenario(seed=3, laps=1, side=6, clutter=0.0)
    known = dcslam.EkfSlam(config("known"))
    for s in scenario.steps[:3]:
        known.predict(s.u, s.Q)
        known.update(s.z, s.R, s.true_ids)
    assert "tentative_removed" not in known.stats.counters
    jcbb = dcslam.EkfSlam(config("jcbb"))
    jcbb.run(scenario.steps)
    assert jcbb.stats.counters["jcbb_nodes"] > 0 and jcbb.stats.counters["jcbb_bound_hits"] == 0
    # Association time is part of each step's time, measured whenever there is a scan.
    stats = jcbb.stats
    assert np.all(stats.association_seconds <= stats.step_seconds)
    assert stats.association_seconds[stats.measurements > 0].min() > 0


def test_min_sightings_one_turns_the_policy_off():
    scenario = field_scenario(seed=4, laps=1, side=6, clutter=0.3)
    slam = dcslam.EkfSlam(config("jcbb", min_sightings=1))
    slam.run(scenario.steps)
    assert "tentative_removed" not in slam.stats.counters
    default = dcslam.EkfSlam(config("jcbb"))
    default.run(scenario.steps)
    assert default.stats.counters["tentative_removed"] > 0
    assert len(default.estimate().landmark_ids) < len(slam.estimate().landmark_ids)


@pytest.mark.parametrize("field, value", [
    ("association", "nearest"),
    ("gate_confidence", 0.0),
    ("gate_confidence", 1.0),
    ("jcbb_max_nodes", 0),
    ("unexplained_density", -0.1),
    ("unexplained_density", float("inf")),
    ("min_sightings", 0),
    ("tentative_window", 0),
    ("tentative_window", 2.5),
])
def test_bad_association_options_raise_value_error_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        dcslam.EkfSlam(dcslam.SlamConfig(**{field: value}))
    with pytest.raises(ValueError, match=field):
        dcslam.DCSlam(dcslam.SlamConfig(**{field: value}))
