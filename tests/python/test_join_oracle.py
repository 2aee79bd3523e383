"""DCSlam.join_pairings() (what each join decided, by feature id) and the research oracle
DCSlam.set_join_oracle(), checked against the simulator's ids."""

import collections

import numpy as np
import pytest
from scipy.stats import chi2

import dcslam
from dcslam import evaluation


def run(sim, oracle=None, min_first_features=0, max_first_features=None):
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=0))
    if oracle is not None:
        slam.set_join_oracle(*oracle, min_first_features=min_first_features, max_first_features=max_first_features)
    returned = slam.run(sim.steps)
    slam.finish_joins()
    return slam, returned


@pytest.fixture(scope="module")
def scene():
    sim = dcslam.revisit_scenario("small_loop_laps", 0)
    slam, returned = run(sim)
    features, landmarks = evaluation.feature_landmarks(sim.true_ids, np.concatenate(returned))
    return sim, slam, returned, dict(zip(features.tolist(), landmarks.tolist())), (features, landmarks)


def test_join_pairings_match_the_join_events(scene):
    _, slam, _, _, _ = scene
    events = sorted(slam.stats.joins, key=lambda j: j["index"])
    records = slam.join_pairings()
    assert len(records) == len(events) > 10
    for event, record in zip(events, records):
        assert len(record["first_ids"]) == event["features_first"]
        assert len(record["second_ids"]) == event["features_second"]
        if event["deferred_pairings"] > 0:
            # A weak join's record lists the version a later join took: fewer pairs perhaps,
            # never fewer than it kept in every version.
            assert event["pairings"] - event["deferred_pairings"] <= len(record["pairs"]) <= event["pairings"]
        else:
            assert len(record["pairs"]) == event["pairings"]
        assert set(record["pairs"][:, 0]) <= set(record["first_ids"].tolist())
        assert set(record["pairs"][:, 1]) <= set(record["second_ids"].tolist())
        assert len(set(record["pairs"][:, 0])) == len(record["pairs"])  # each feature once
        assert len(set(record["pairs"][:, 1])) == len(record["pairs"])


def test_the_association_as_is_makes_wrong_pairs_here(scene):
    # The premise of the oracle: on this dense scene RJC pairs some features of different
    # landmarks (docs/data_association.md); otherwise the oracle tests below prove nothing.
    _, slam, _, label, _ = scene
    wrong = sum(label.get(int(i), -1) != label.get(int(j), -2)
                for record in slam.join_pairings() for i, j in record["pairs"])
    assert wrong > 0


def expected_pair_count(record, label):
    """The true pairs of a join: each landmark held by both maps, as many times as the map
    holding fewer of its features allows (a local map may hold a landmark twice)."""
    first = collections.Counter(label.get(i, -1) for i in record["first_ids"].tolist())
    second = collections.Counter(label.get(j, -1) for j in record["second_ids"].tolist())
    return sum(min(count, first[landmark]) for landmark, count in second.items() if landmark >= 0)


def test_truth_oracle_pairs_exactly_the_features_of_one_landmark(scene):
    sim, _, returned, label, oracle = scene
    slam, returned_again = run(sim, (*oracle, "truth"))
    # The local maps do not depend on the joins: the same ids come back.
    for first, second in zip(returned, returned_again):
        np.testing.assert_array_equal(first, second)
    for record in slam.join_pairings():
        for i, j in record["pairs"].tolist():
            assert label[i] == label[j] >= 0
        assert len(record["pairs"]) == expected_pair_count(record, label)
    scores = evaluation.evaluate_run(slam, slam.estimate(), returned_again, sim).association
    assert scores.pairwise_recall > 0.9


def test_remove_wrong_keeps_only_true_pairs(scene):
    sim, _, _, label, oracle = scene
    slam, _ = run(sim, (*oracle, "remove_wrong"))
    kept = [(i, j) for record in slam.join_pairings() for i, j in record["pairs"].tolist()]
    assert kept and all(label[i] == label[j] >= 0 for i, j in kept)


def test_among_candidates_pairs_only_true_pairs(scene):
    sim, _, _, label, oracle = scene
    slam, _ = run(sim, (*oracle, "among_candidates"))
    for record in slam.join_pairings():
        for i, j in record["pairs"].tolist():
            assert label[i] == label[j] >= 0
        assert len(record["pairs"]) <= expected_pair_count(record, label)


def test_oracle_limited_to_large_joins_corrects_only_those(scene):
    # Joins of two local maps (first map below the threshold) see inputs no join has touched,
    # so they decide exactly as without the oracle; every join at or above it is the truth.
    sim, slam_as_is, _, label, oracle = scene
    threshold = 60
    slam, _ = run(sim, (*oracle, "truth"), min_first_features=threshold)
    events = sorted(slam.stats.joins, key=lambda j: j["index"])
    as_is = slam_as_is.join_pairings()
    corrected = untouched = made_wrong = 0
    for event, record, before in zip(events, slam.join_pairings(), as_is):
        pairs = {tuple(p) for p in record["pairs"].tolist()}
        own = {tuple(p) for p in record["own_pairs"].tolist()}
        if len(record["first_ids"]) >= threshold:
            assert pairs == {tuple(p) for p in record["truth_pairs"].tolist()}
            assert all(label[i] == label[j] >= 0 for i, j in pairs)
            corrected += 1
            made_wrong += any(label.get(i, -1) != label.get(j, -2) for i, j in own)
        else:
            assert own == pairs  # the oracle left these joins' own decision as it was
            if event["leaves"] == 2:
                assert pairs == {tuple(p) for p in before["pairs"].tolist()}
                untouched += 1
    # own_pairs keeps what the association chose where the oracle corrected it.
    assert corrected > 0 and untouched > 0 and made_wrong > 0


def test_oracle_limited_to_a_window_of_sizes_corrects_only_those(scene):
    # The same with an upper bound: the joins above it decide for themselves again, so the
    # oracle can single out the joins of one level of the tree.
    sim, _, _, label, oracle = scene
    low, high = 40, 60
    slam, _ = run(sim, (*oracle, "truth"), min_first_features=low, max_first_features=high)
    inside = above_and_wrong = 0
    events = sorted(slam.stats.joins, key=lambda j: j["index"])
    for event, record in zip(events, slam.join_pairings()):
        pairs = {tuple(p) for p in record["pairs"].tolist()}
        truth = {tuple(p) for p in record["truth_pairs"].tolist()}
        size = len(record["first_ids"])
        if low <= size <= high:
            assert pairs == truth
            inside += 1
        else:
            own = {tuple(p) for p in record["own_pairs"].tolist()}
            # A weak join lists the version a later join took: its own pairs, or some of them.
            assert pairs <= own if event["deferred_pairings"] > 0 else pairs == own
            above_and_wrong += size > high and pairs != truth
    # Joins above the window that the truth would have changed: the bound is what kept them.
    assert inside > 0 and above_and_wrong > 0


def test_bad_oracle_calls_are_named_errors():
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc"))
    with pytest.raises(ValueError, match="mode"):
        slam.set_join_oracle([1], [2], "bogus")
    with pytest.raises(ValueError, match="one length"):
        slam.set_join_oracle([1, 2], [2], "truth")
    with pytest.raises(ValueError, match="integers"):
        slam.set_join_oracle([1.5], [2], "truth")
    with pytest.raises(ValueError, match="min_first_features"):
        slam.set_join_oracle([1], [2], "truth", min_first_features=-1)
    with pytest.raises(ValueError, match="min_first_features"):
        slam.set_join_oracle([1], [2], "truth", min_first_features=2.5)
    with pytest.raises(ValueError, match="max_first_features"):
        slam.set_join_oracle([1], [2], "truth", min_first_features=5, max_first_features=4)
    with pytest.raises(ValueError, match="max_first_features must be an integer"):
        slam.set_join_oracle([1], [2], "truth", max_first_features=2.5)
    with pytest.raises(ValueError, match="min_first_features must be an integer, got True"):
        slam.set_join_oracle([1], [2], "truth", min_first_features=True)
    slam.predict(np.zeros(3), 1e-4 * np.eye(3))
    with pytest.raises(ValueError, match="before the first predict"):
        slam.set_join_oracle([1], [2], "truth")


def test_audit_changes_nothing_and_records_the_true_pairs(scene):
    sim, slam_as_is, returned, label, oracle = scene
    slam, returned_again = run(sim, (*oracle, "audit"))
    for first, second in zip(returned, returned_again):
        np.testing.assert_array_equal(first, second)
    # The pruning gate: a tenth of the decision gate's tail.
    gate = chi2.ppf(1.0 - (1.0 - dcslam.SlamConfig().gate_confidence) / 10.0, 2)
    reasons = collections.Counter()
    events = sorted(slam.stats.joins, key=lambda j: j["index"])
    for event, record, plain in zip(events, slam.join_pairings(), slam_as_is.join_pairings()):
        np.testing.assert_array_equal(record["pairs"], plain["pairs"])
        own, listed = {tuple(p) for p in record["own_pairs"].tolist()}, {tuple(p) for p in plain["pairs"].tolist()}
        # A weak join lists the version a later join took: its own pairs, or some of them.
        assert listed <= own if event["deferred_pairings"] > 0 else listed == own
        assert len(plain["truth_pairs"]) == len(plain["own_pairs"]) == 0  # no oracle, no audit
        truth = record["truth_pairs"]
        assert len(truth) == expected_pair_count(record, label)
        for i, j in truth.tolist():
            assert label[i] == label[j] >= 0
        distance = record["truth_distance_sq"]
        assert distance.shape == record["truth_candidate"].shape == record["truth_consistent"].shape == (len(truth),)
        np.testing.assert_array_equal(record["truth_candidate"], distance <= gate)
        assert not np.any(record["truth_consistent"] & ~record["truth_candidate"])
        paired = {int(j): int(i) for i, j in record["pairs"]}
        for (i, j), candidate, consistent in zip(truth.tolist(), record["truth_candidate"], record["truth_consistent"]):
            made = paired.get(j) == i
            reasons["made" if made else "not a candidate" if not candidate else
                    "inconsistent" if not consistent else "lost"] += 1
            if made:
                assert candidate  # the search only pairs candidates
    # On this scene the joins make most true pairs and lose some of every kind but the first.
    assert reasons["made"] > 10 * (reasons["lost"] + reasons["inconsistent"]) > 0


def test_fold_joins_report_each_join_of_the_final_fold(scene):
    sim, *_ = scene
    slam, _ = run(sim)
    assert slam.stats.fold_joins == []  # no estimate() yet
    slam.estimate()
    fold, records = slam.stats.fold_joins, slam.fold_pairings()
    assert len(fold) == len(records) == len(slam.stats.stack) > 0
    local_maps = [maps for maps, _ in reversed(slam.stats.stack)]  # the fold takes the stack top first
    for k, (join, record) in enumerate(zip(fold, records)):
        assert join["index"] == k
        assert join["leaves"] == 1 + sum(local_maps[: k + 1])  # the open local map and those folded
        assert join["step_created"] == join["step_finished"] == len(sim.steps)
        assert join["features_first"] == len(record["first_ids"])
        assert join["features_second"] == len(record["second_ids"])
        # A weak fold join's record lists the pairs of the version the next one took.
        if join["deferred_pairings"] == 0:
            assert join["pairings"] == len(record["pairs"])
        else:
            assert join["pairings"] >= len(record["pairs"])
        # The fold keeps every tentative feature (none is dropped as a real join's may be).
        assert join["features_joined"] == join["features_first"] + join["features_second"] - join["pairings"]
        assert join["seconds"] > 0.0
    # The fold's last join holds the whole map before the final duplicate merge.
    assert fold[-1]["leaves"] == 1 + sum(local_maps)


REPORTED = ("leaves", "step_created", "features_first", "features_second", "features_joined", "overlap", "pairings",
            "deferred_pairings", "alternatives_taken", "duplicates_merged", "tries", "chunked", "widened", "iterations")


def test_side_joins_report_the_pending_joins_as_the_real_joins_make_them():
    sim = dcslam.revisit_scenario("small_loop_laps", 0)
    slam = dcslam.DCSlam(dcslam.SlamConfig(association="jcbb", join_association="rjc", seed=0))
    side, side_records, pending = [], [], set()
    for k, step in enumerate(sim.steps):
        slam.predict(step.u, step.Q)
        slam.update(step.z, step.R)
        waiting = {j["index"] for j in slam.stats.joins if j["step_finished"] == -1}
        if len(waiting) >= 2 and not pending:
            slam.estimate()
            side, side_records, pending = slam.stats.side_joins, slam.side_join_pairings(), waiting
            # Asked again before any of them has run: taken as computed, the step of the first call.
            slam.estimate()
            assert slam.stats.side_joins == side
            break
    assert pending, "no step with two joins pending"
    assert [j["index"] for j in side] == sorted(pending)  # every pending join, in creation order
    assert all(j["step_finished"] == k + 1 for j in side)
    slam.finish_joins()
    real = {j["index"]: j for j in slam.stats.joins}
    records = slam.join_pairings()
    for join, record in zip(side, side_records):
        assert real[join["index"]]["step_finished"] >= join["step_created"]  # it has run now
        assert {key: join[key] for key in REPORTED} == {key: real[join["index"]][key] for key in REPORTED}
        assert np.array_equal(record["pairs"], records[join["index"]]["pairs"])
        assert np.array_equal(record["first_ids"], records[join["index"]]["first_ids"])
    assert any(join["pairings"] > 0 for join in side)
    # An estimate() with nothing pending reports no side join.
    slam.estimate()
    assert slam.stats.side_joins == [] and slam.side_join_pairings() == []


def test_audit_of_a_truth_run_marks_every_pair_made():
    sim = dcslam.revisit_scenario("loop_both_ways", 1)
    _, returned = run(sim)
    features, landmarks = evaluation.feature_landmarks(sim.true_ids, np.concatenate(returned))
    slam, _ = run(sim, (features, landmarks, "truth"))
    for record in slam.join_pairings():
        made = {(int(i), int(j)) for i, j in record["pairs"]}
        assert made == {(int(i), int(j)) for i, j in record["truth_pairs"]}


def test_fold_pairings_record_the_final_fold(scene):
    sim, _, returned, label, oracle = scene
    slam, _ = run(sim, (*oracle, "audit"))
    assert slam.fold_pairings() == []  # no estimate() yet
    estimate = slam.estimate()
    fold = slam.fold_pairings()
    assert len(fold) == len(slam._core.stack_shape()) > 0
    for record in fold:
        assert set(record["pairs"][:, 0]) <= set(record["first_ids"].tolist())
        assert set(record["pairs"][:, 1]) <= set(record["second_ids"].tolist())
        assert len(record["truth_pairs"]) == expected_pair_count(record, label)
    # Each fold joins the next stack map with everything after it: the last one holds the map.
    last = fold[-1]
    joined = len(last["first_ids"]) + len(last["second_ids"]) - len(last["pairs"])
    merged = joined - len(estimate.landmark_ids)  # the estimate's duplicate merge comes after
    assert 0 <= merged < 0.1 * joined
    assert set(estimate.landmark_ids.tolist()) <= set(last["first_ids"].tolist()) | set(last["second_ids"].tolist())
