"""dcslam.evaluation against brute force over every pair of measurements, and on runs broken
on purpose: a scorer that cannot see a split landmark or a wrong merge fails here."""

import itertools
import math

import numpy as np
import pytest

import dcslam
from dcslam import evaluation


def brute_force(truth, features, min_measurements=3):
    same_feature = same_landmark = both = 0
    for i, j in itertools.combinations(range(len(truth)), 2):
        in_one_feature = features[i] >= 0 and features[i] == features[j]
        of_one_landmark = truth[i] >= 0 and truth[i] == truth[j]
        same_feature += in_one_feature
        same_landmark += of_one_landmark
        both += in_one_feature and of_one_landmark
    per_landmark = []
    for landmark in set(t for t in truth if t >= 0):
        mine = [f for t, f in zip(truth, features) if t == landmark]
        if len(mine) >= min_measurements:
            per_landmark.append(sum(1 for f in set(mine) if f >= 0 and mine.count(f) >= 2))
    wrong = sum(1 for f in set(features) if f >= 0 and len({t for t, g in zip(truth, features) if g == f and t >= 0}) >= 2)
    rejected_pairs = split_pairs = 0
    for i, j in itertools.combinations(range(len(truth)), 2):
        if truth[i] >= 0 and truth[i] == truth[j]:
            if features[i] < 0 or features[j] < 0:
                rejected_pairs += 1
            elif features[i] != features[j]:
                split_pairs += 1
    return dict(
        precision=both / same_feature if same_feature else 1.0,
        recall=both / same_landmark if same_landmark else 1.0,
        lost_to_rejected=rejected_pairs / same_landmark if same_landmark else 0.0,
        lost_to_splits=split_pairs / same_landmark if same_landmark else 0.0,
        features_per_landmark=np.mean(per_landmark) if per_landmark else math.nan,
        wrong_merges=wrong,
    )


@pytest.mark.parametrize("seed", range(20))
def test_scores_equal_brute_force_on_random_clusterings(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    truth = rng.integers(-1, 8, n)
    features = np.where(rng.random(n) < 0.7, truth + 100 * rng.integers(0, 2, n), rng.integers(-1, 12, n))
    scores = evaluation.association_scores(truth, features)
    expected = brute_force(truth.tolist(), features.tolist())
    assert scores.pairwise_precision == pytest.approx(expected["precision"])
    assert scores.pairwise_recall == pytest.approx(expected["recall"])
    if math.isnan(expected["features_per_landmark"]):
        assert math.isnan(scores.features_per_landmark)
    else:
        assert scores.features_per_landmark == pytest.approx(expected["features_per_landmark"])
    assert scores.wrong_merges == expected["wrong_merges"]
    assert scores.recall_lost_to_rejected == pytest.approx(expected["lost_to_rejected"])
    assert scores.recall_lost_to_splits == pytest.approx(expected["lost_to_splits"])
    assert scores.rejected == int(np.sum(features < 0)) and scores.clutter == int(np.sum(truth < 0))


@pytest.fixture(scope="module")
def known_run():
    sim = dcslam.simulate("loop", steps=120, seed=3, clutter=0.1)
    slam = dcslam.EkfSlam(dcslam.SlamConfig(association="known"))
    returned = slam.run(sim.steps)
    return sim, slam, slam.estimate(), returned


def test_a_perfect_run_scores_perfectly(known_run):
    sim, slam, estimate, returned = known_run
    scores = evaluation.evaluate_run(slam, estimate, returned, sim)
    assert scores.association.pairwise_precision == 1.0
    assert scores.association.pairwise_recall == 1.0
    assert scores.association.features_per_landmark == 1.0
    assert scores.association.wrong_merges == 0 and scores.association.duplicated_landmarks == 0
    assert scores.map_size == len(estimate.landmarks)


def test_a_split_landmark_is_seen_where_the_majority_score_is_blind(known_run):
    sim, _, _, returned = known_run
    truth = np.asarray(sim.true_ids)
    features = np.concatenate(returned).copy()
    # Every landmark's later half of measurements goes to a second feature: each is mapped twice.
    for landmark in np.unique(truth[truth >= 0]):
        rows = np.flatnonzero(truth == landmark)
        features[rows[len(rows) // 2:]] = 10_000 + landmark
    broken = evaluation.association_scores(truth, features)
    assert broken.pairwise_precision == 1.0
    assert broken.pairwise_recall < 0.6
    # Every lost pair is a split one: nothing was rejected.
    assert broken.recall_lost_to_rejected == 0.0
    assert broken.recall_lost_to_splits == pytest.approx(1.0 - broken.pairwise_recall)
    assert broken.features_per_landmark > 1.9
    majority = evaluation.majority_scores(truth, features)
    assert majority.precision == 1.0  # the older score cannot see it


def test_rejected_measurements_are_told_apart_from_splits(known_run):
    sim, _, _, returned = known_run
    truth = np.asarray(sim.true_ids)
    features = np.concatenate(returned).copy()
    features[::3] = -1  # a third of the measurements rejected, the rest in their own features
    scores = evaluation.association_scores(truth, features)
    assert scores.recall_lost_to_splits == 0.0
    assert scores.recall_lost_to_rejected > 0.3
    assert scores.pairwise_recall + scores.recall_lost_to_rejected == pytest.approx(1.0)


def test_a_wrong_merge_is_counted(known_run):
    sim, _, _, returned = known_run
    truth = np.asarray(sim.true_ids)
    features = np.concatenate(returned).copy()
    landmarks = np.unique(truth[truth >= 0])
    features[truth == landmarks[1]] = landmarks[0]
    scores = evaluation.association_scores(truth, features)
    assert scores.wrong_merges == 1
    assert scores.pairwise_precision < 1.0 and scores.pairwise_recall == 1.0


def test_robot_scores_are_the_nees_of_the_pose(known_run):
    sim, _, estimate, _ = known_run
    truth = sim.poses[-1]
    scores = evaluation.robot_scores(estimate, truth)
    error = estimate.robot - truth
    error[2] = math.remainder(error[2], 2 * math.pi)
    assert scores.nees == pytest.approx(error @ np.linalg.solve(estimate.covariance[:3, :3], error))
    assert scores.position_error == pytest.approx(np.hypot(*error[:2]))
    assert scores.consistent99 == (scores.nees <= 11.344866730144375)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="feature_ids"):
        evaluation.association_scores([1, 2], [1])
    with pytest.raises(ValueError, match="integer"):
        evaluation.association_scores([1.5], [1])
    with pytest.raises(ValueError, match="true_pose"):
        evaluation.robot_scores(dcslam.EkfSlam().estimate(), [0.0, 0.0])
