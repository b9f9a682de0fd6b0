"""Common landmarks against ground-truth objects, the oracle recall and the operating point of a PR curve."""

import numpy as np
import pytest

from sosmatch.plugin.evaluation.claims import observer_matrix
from sosmatch.plugin.evaluation.landmark_truth import (
    common_landmarks,
    eligible_objects,
    majority_objects,
    objects_under,
    oracle_recall,
    segmented_objects,
)
from sosmatch.plugin.evaluation.metrics import operating_point, pr_curve


def test_majority_objects_votes_and_measures_purity():
    objs = majority_objects([np.array([3, 3, 0, 3]), np.array([0, 0, 5]), np.array([], np.int64), np.array([2, 4])])
    assert objs.object_ids.tolist() == [3, 0, 0, 2]  # a tie goes to the smaller id
    assert objs.purity.tolist() == pytest.approx([0.75, 2 / 3, 0.0, 0.5])


def test_segmented_objects_counts_keyframes_not_segments():
    labels = np.zeros((4, 6), np.uint16)
    labels[1:3, 2:4] = 7
    labels[:, 5] = 9
    # COLMAP pixels: (2.0, 1.0) and (3.99, 2.99) are inside object 7's pixels, (1.99, 1.5) is not; off the image
    # the nearest border pixel counts (x = 40 -> column 5)
    assert objects_under(labels, np.array([[2.0, 1.0], [3.99, 2.99], [1.99, 1.5], [40.0, -3.0]])).tolist() == \
        [7, 7, 0, 9]
    # object 7 split into two segments in keyframe 0 counts once there: 2 keyframes; object 9 in 3; 0 never counts
    per_keyframe = [np.array([7, 7, 0]), np.array([9, 7]), np.array([9, 0]), np.array([9]), np.array([], np.int64)]
    assert segmented_objects(per_keyframe, 3).tolist() == [9]
    assert segmented_objects(per_keyframe, 2).tolist() == [7, 9]


def test_common_landmarks_pairs_the_closest_landmarks_of_each_object():
    a = majority_objects([np.array([1]), np.array([1]), np.array([2]), np.array([0]), np.array([7])])
    b = majority_objects([np.array([2]), np.array([1]), np.array([9])])
    pa = np.array([[0, 0, 0], [5, 0, 0], [20, 0, 0], [30, 0, 0], [40, 0, 0]], float)
    pb = np.array([[20.5, 0, 0], [4.0, 0, 0], [50, 0, 0]], float)
    ha, hb = np.array([1.0, 2.0, 3.0, 1.0, 1.0]), np.array([3.6, 2.2, 1.0])
    common = common_landmarks(a, b, pa, pb, ha, hb, eligible=np.array([1, 2, 3, 7]),
                              kind_of={1: "conifer", 2: "pond"})
    assert common.objects.tolist() == [1, 2]
    assert common.pairs.tolist() == [[1, 1], [2, 0]]  # object 1: A's landmark at x = 5 is closer to B's at 4
    assert common.offsets_m == pytest.approx([1.0, 0.5])
    assert common.ratio == pytest.approx([1.1, 1.2])
    assert common.mapped_a.tolist() == [1, 2, 7] and common.mapped_b.tolist() == [1, 2]
    s = common.summary(theta_r=0.15)
    assert s["common"] == 2 and s["eligible_objects"] == 4
    assert s["within_size_gate"] == pytest.approx(0.5)  # r = 0.095 passes, r = 0.18 does not
    assert s["common_by_kind"] == {"conifer": 1, "pond": 1}


def test_eligible_objects_need_both_sessions_and_enough_keyframes():
    got = eligible_objects(np.array([1, 2, 3, 4]), np.array([2, 3, 4, 5]), {2: 6, 3: 9, 4: 2}, {2: 7, 3: 5, 4: 9}, 6)
    assert got.tolist() == [2]


def test_each_map_makes_objects_eligible_by_the_theta_n_its_flight_allowed(tmp_path):
    """`sosmatch map` lowers theta_n where the flight's views allow fewer (run.json counts.min_observations): such a
    map made landmarks of objects in 3 keyframes, so those objects are eligible there; a map without the record
    (a merged model, an older run) keeps the configured theta_n."""
    import json

    from sosmatch.plugin.params import Params
    from sosmatch.workflows.evaluate.truth import keyframes_for_a_landmark

    low, old = tmp_path / "low", tmp_path / "old"
    low.mkdir()
    old.mkdir()
    (low / "run.json").write_text(json.dumps({"counts": {"min_observations": 2, "views_per_pass": 5.3}}))
    (old / "run.json").write_text(json.dumps({"counts": {"landmarks": 10}}))
    params = Params()
    least = [keyframes_for_a_landmark(params, m) for m in (low, old)]
    assert least == [3, params.triangulation.min_observations + 1]
    got = eligible_objects(np.array([1, 2, 3]), np.array([1, 2, 3]), {1: 3, 2: 6, 3: 4}, {1: 6, 2: 6, 3: 5}, *least)
    assert got.tolist() == [1, 2]  # 3 is in 5 keyframes of the old map: too few for a landmark there


def test_oracle_recall_counts_the_keyframe_pairs_common_landmarks_vouch_for():
    # 3 keyframes per session; landmark i of A seen in keyframe i, landmark j of B in keyframe j
    obs_a = observer_matrix([[0], [1], [2]], 3)
    obs_b = observer_matrix([[0], [1], [2]], 3)
    iou = np.eye(3) * 0.8
    got = oracle_recall(np.array([[0, 0], [1, 1]]), obs_a, obs_b, iou)
    assert got == {"associations": 2, "recall": pytest.approx(2 / 3), "precision": 1.0}
    assert oracle_recall(np.zeros((0, 2), int), obs_a, obs_b, iou)["recall"] == 0.0


def test_operating_point_takes_the_claims_above_the_threshold():
    iou = np.array([0.5, 0.5, 0.1, 0.0, 0.5, 0.0, 0.5])
    scores = np.array([9.0, 8.0, 7.0, 7.0, 5.0, np.nan, np.nan])
    c = pr_curve(scores, iou)
    op = operating_point(c, 7.5)  # claims with score >= 7.5: two right ones of 4 positives
    assert op["precision"] == 1.0 and op["recall"] == 0.5 and op["f1"] == pytest.approx(2 / 3)
    op = operating_point(c, 6)  # one false claim joins
    assert op["precision"] == pytest.approx(2 / 3) and op["tp"] == 2 and op["fp"] == 1
    assert operating_point(c, 10)["recall"] == 0.0 and operating_point(c, 10)["precision"] == 1.0


def test_overlap_test_claims_only_cameras_the_association_places_close():
    from sosmatch.plugin.evaluation.claims import Hypothesis, claim_scores, observer_geometry, separation_ratio

    # one landmark per map at the origin, seen by three keyframes each: cameras 100 m up at x = -50, 0, +50
    centers = np.array([[-50.0, 0, 100], [0.0, 0, 100], [50.0, 0, 100]])
    obs = observer_matrix([[0, 1, 2]], 3)
    landmark = np.zeros((1, 3))
    geo = observer_geometry(obs, landmark, centers)
    ratio = separation_ratio(640, 480, 500.0)  # 0.8 x 480 / 500: cameras up to 76.8 m apart at 100 m
    assert ratio == pytest.approx(0.768)
    hyp = [Hypothesis(np.array([[0, 0]]), 7.0)]
    plain = claim_scores(hyp, obs, obs)
    assert np.isfinite(plain).all()  # the old rule: all 9 observer pairs
    got = claim_scores(hyp, obs, obs, (geo, geo, ratio))
    assert np.isfinite(got).tolist() == [[True, True, False], [True, True, True], [False, True, True]]  # 100 m apart
    # B's frame turned by 180 degrees: its observer at +50 is where A's at -50 is (the hypothesis' rotation)
    turn = np.diag([-1.0, -1.0, 1.0])
    got = claim_scores([Hypothesis(np.array([[0, 0]]), 7.0, True, turn)], obs, obs, (geo, geo, ratio))
    assert np.isfinite(got).tolist() == [[False, True, True], [True, True, True], [True, True, False]]


def test_a_hand_edited_record_without_keyframe_names_is_one_error_naming_it(tmp_path):
    import json

    from sosmatch.database.session_io import map_keyframe_names
    from sosmatch.plugin.errors import InputError

    assert map_keyframe_names(tmp_path) is None  # no record: a merged model, an older run
    (tmp_path / "run.json").write_text(json.dumps({"counts": {}}))
    assert map_keyframe_names(tmp_path) is None
    (tmp_path / "run.json").write_text(json.dumps({"keyframes": ["a.jpg", "b.jpg"]}))
    assert map_keyframe_names(tmp_path) == ["a.jpg", "b.jpg"]
    for bad in ({"keyframes": 5}, {"keyframes": ["a.jpg", 3]}, {"keyframes": None}):
        (tmp_path / "run.json").write_text(json.dumps(bad))
        with pytest.raises(InputError, match="keyframe names") as err:
            map_keyframe_names(tmp_path)
        assert "run.json" in str(err.value)
