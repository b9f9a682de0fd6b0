"""Object-level change detection (plugin.changes): the per-landmark verdicts on a small world with exact truth,
its building blocks, and invariance to B's frame."""

import numpy as np
import pytest

from sosmatch.plugin.changes import (
    GONE,
    KEPT,
    NEW,
    UNSEEN,
    KeyframeSegments,
    SessionObservations,
    counterparts,
    detect_changes,
    fit_logistic,
    ground_height_field,
    holder_pairs,
    in_view,
    predict_logistic,
    segment_evidence,
    tracks_from_matches,
)
from sosmatch.plugin.params import ChangeParams as _ChangeParams
from sosmatch.tools.toy_sessions import CHANGE_CAMERA, nadir_poses, toy_change_pair, yaw_transform


def ChangeParams(**kw):  # noqa: N802 - stands in for the class in these tests
    """The detector's parameters with the segments' probability as the confidence: these toy observations have
    no relief to test for a standing object (`untested_object_rate`, tested in test_changes_cli)."""
    return _ChangeParams(**{"untested_object_rate": 1.0, **kw})


CAM = CHANGE_CAMERA


@pytest.fixture(scope="module")
def pair():
    return toy_change_pair()


def test_removed_added_kept_and_unseen_objects_are_told_apart(pair):
    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = pair
    res = detect_changes(a, b, a_from_b, ChangeParams(), association_tolerance_m=2.0)
    seen_by_b = in_view(positions, sizes, b.transformed(a_from_b).poses, [CAM] * len(b.poses))[0].sum(0) >= 6
    seen_by_a = in_view(positions, sizes, a.poses, [CAM] * len(a.poses))[0].sum(0) >= 6
    label_a = dict(zip(ids_a.tolist(), res.a.label))
    label_b = dict(zip(ids_b.tolist(), res.b.label))
    removed = [o for o in ids_a if not present_b[o] and seen_by_b[o]]
    added = [o for o in ids_b if not present_a[o] and seen_by_a[o]]
    both = [o for o in ids_a if present_b[o] and o in label_b]
    assert len(removed) >= 3 and len(added) >= 3 and len(both) >= 30
    assert sum(label_a[o] == GONE for o in removed) >= 0.9 * len(removed)
    assert sum(label_b[o] == NEW for o in added) >= 0.9 * len(added)
    assert sum(label_a[o] == KEPT for o in both) >= 0.9 * len(both)
    # what the other session never saw is never a change
    assert all(label_a[o] == UNSEEN for o in ids_a if not seen_by_b[o] and
               in_view(positions[[o]], sizes[[o]], b.transformed(a_from_b).poses, [CAM] * len(b.poses))[0].sum() == 0)
    assert all(label_b[o] != NEW for o in ids_b if not seen_by_a[o])
    assert res.common_area.area > 0 and res.observed_a.area > res.common_area.area
    counts = res.counts()
    assert counts["gone"] == res.a.count(GONE) and "ha seen by both" in res.summary()


def test_verdicts_do_not_depend_on_the_frame_of_b_and_are_deterministic(pair):
    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = pair
    res = detect_changes(a, b, a_from_b, ChangeParams(), 2.0)
    b_world = b.transformed(a_from_b)  # B already in A's frame: identity transform
    again = detect_changes(a, b_world, yaw_transform(0.0, (0.0, 0.0, 0.0)), ChangeParams(), 2.0)
    assert np.array_equal(res.a.label, again.a.label) and np.array_equal(res.b.label, again.b.label)
    np.testing.assert_allclose(res.a.confidence, again.a.confidence, atol=1e-9)
    same = detect_changes(a, b, a_from_b, ChangeParams(), 2.0)
    assert np.array_equal(res.b.confidence, same.b.confidence)


def test_alignment_support_tells_the_true_transform_from_a_displaced_one(pair):
    *_, a, ids_a, b, ids_b, a_from_b = pair
    good = detect_changes(a, b, a_from_b, ChangeParams(), 2.0).support
    assert good.plausible() and good.rate > 0.8 and good.displaced_rate < 0.3
    off = yaw_transform(0.0, (20.0, -12.0, 0.0)).compose(a_from_b)
    bad = detect_changes(a, b, off, ChangeParams(), 2.0).support
    assert not bad.plausible() and bad.compared > 0


def test_min_confidence_turns_weak_claims_into_unseen(pair):
    *_, a, ids_a, b, ids_b, a_from_b = pair
    loose = detect_changes(a, b, a_from_b, ChangeParams(), 2.0)
    strict = detect_changes(a, b, a_from_b, ChangeParams(min_confidence=1.0), 2.0)
    assert loose.a.count(GONE) > 0 and strict.a.count(GONE) == 0 and strict.b.count(NEW) == 0
    moved = (loose.a.label == GONE) & (strict.a.label == UNSEEN)
    assert np.all(strict.a.evidence[moved] == "confidence")
    assert np.array_equal(loose.a.label == KEPT, strict.a.label == KEPT)


def test_in_view_needs_the_footprint_inside_the_image():
    poses = nadir_poses(np.array([[0.0, 0.0, 100.0]]))
    # the image spans x in [-80, 80], y in [-60, 60] at 100 m (f = 400 px, 640 x 480)
    pts = np.array([[0.0, 0.0, 0.0], [75.0, 0.0, 0.0], [75.0, 0.0, 0.0], [0.0, 0.0, 150.0]])
    seen, uv, depth = in_view(pts, np.array([1.0, 1.0, 4.0, 1.0]), poses, [CAM])
    assert seen[0].tolist() == [True, True, False, False]  # a 4 m object at 75 m reaches past the border
    np.testing.assert_allclose(uv[0, 0], [320.0, 240.0])
    assert depth[0, 3] < 0


def test_counterparts_respect_the_gate_and_the_size_ratio():
    p = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    q = np.array([[1.0, 0.0, 0.0], [10.0, 0.0, 3.0], [20.5, 0.0, 0.0], [21.0, 0.0, 0.0]])
    idx, dist = counterparts(p, np.array([2.0, 2.0, 2.0]), q, np.array([2.1, 2.0, 5.0, 2.2]), 2.0, 0.5, 0.5)
    assert idx.tolist() == [0, 1, 3]  # z counts half; the nearer one of the wrong size is skipped
    np.testing.assert_allclose(dist, [1.0, 1.5, 1.0])


def test_holders_are_larger_landmarks_whose_footprint_holds_the_point():
    p = np.array([[0.0, 0, 0], [1.5, 0, 0], [3.0, 0, 0], [30.0, 0, 0]])
    h = np.array([1.0, 2.0, 8.0, 1.0])
    i, j = holder_pairs(p, h, p, h, max_ratio=4.0, same_map=True)
    # 0 lies in the footprint of 1 (radius 4), 1 in that of 2; 2 is too large to hold 0 (8 > 4 x 1)
    assert list(zip(i.tolist(), j.tolist())) == [(0, 1), (1, 2)]
    i, j = holder_pairs(p, h, p, h, max_ratio=10.0, same_map=True)
    assert list(zip(i.tolist(), j.tolist())) == [(0, 1), (0, 2), (1, 2)]  # per landmark, nearest holder first


def test_segment_evidence_counts_views_with_a_matching_segment():
    poses = nadir_poses(np.array([[x, 0.0, 100.0] for x in range(0, 40, 4)]))
    target = np.array([[20.0, 0.0, 0.0]])
    _, uv, depth = in_view(target, np.array([2.0]), poses, [CAM] * len(poses))
    segs = [KeyframeSegments(uv[k] + 0.5, np.array([2.0 * CAM.fx / depth[k, 0]])) if k % 2 == 0
            else KeyframeSegments(np.zeros((0, 2)), np.zeros(0)) for k in range(len(poses))]
    hits, views, chance = segment_evidence(target, np.array([2.0]), poses, [CAM] * len(poses), segs, 2.0, 0.5, 8, 2.0)
    assert views[0] == len(poses) and hits[0] == (len(poses) + 1) // 2
    assert chance[0] < 0.1  # nothing around it
    wrong = segment_evidence(target, np.array([6.0]), poses, [CAM] * len(poses), segs, 2.0, 0.5, 8, 2.0)[0]
    assert wrong[0] == 0  # a segment of another size is no evidence


def test_ground_follows_the_low_landmarks():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 200, (600, 2))
    ground = 0.02 * xy[:, 0] + 5.0
    z = ground + np.where(rng.random(600) < 0.4, rng.uniform(3, 15, 600), rng.normal(0, 0.2, 600))
    field = ground_height_field(np.column_stack([xy, z]))
    probe = np.array([[50.0, 50.0], [150.0, 120.0]])
    np.testing.assert_allclose(field(probe[:, 0], probe[:, 1]), 0.02 * probe[:, 0] + 5.0, atol=0.6)


def test_ground_follows_a_slope():
    # a hillside (30 % grade across, 15 % along): the heights of the 30 nearest landmarks span +-5 m there, so
    # their low quantile is the ground downhill, 3 m under the place (nu28 relief 80); a plane through them is not
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 200, (500, 2))

    def plane(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return 0.3 * x - 0.15 * y + 40.0

    objects = rng.random(500) < 0.3
    z = plane(xy[:, 0], xy[:, 1]) + np.where(objects, rng.uniform(2, 15, 500), rng.normal(0, 0.3, 500))
    field = ground_height_field(np.column_stack([xy, z]))
    px, py = (a.ravel() for a in np.meshgrid(np.linspace(30, 170, 8), np.linspace(30, 170, 8)))
    err = field(px, py) - plane(px, py)
    assert abs(float(np.median(err))) < 0.5 and np.all(np.abs(err) < 1.0)
    # beyond the landmarks the ground is held, not extrapolated along a slope that is known only where they are
    far = field(np.array([-150.0, 350.0]), np.array([100.0, 100.0]))
    assert z.min() - 1.0 < far.min() and far.max() < z.max()


def test_ground_of_landmarks_along_a_line_stays_level_across_it():
    # one flight line of landmarks: the slope across it is unknown, so the ground beside the line is its own
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 200, 200)
    z = 0.1 * x + rng.normal(0, 0.2, 200)
    field = ground_height_field(np.column_stack([x, np.full(200, 50.0), z]))
    np.testing.assert_allclose(field(np.array([100.0]), np.array([60.0])), field(np.array([100.0]), np.array([50.0])),
                               atol=0.3)
    assert abs(float(field(100.0, 50.0)) - 10.0) < 0.6


def test_logistic_fit_recovers_a_monotone_rate():
    rng = np.random.default_rng(1)
    x = rng.normal(0, 1, (400, 1))
    y = rng.random(400) < 1 / (1 + np.exp(-(0.5 + 2.0 * x[:, 0])))
    w = fit_logistic(x, y, ridge=0.1)
    assert 1.4 < w[1] < 2.6 and -0.1 < w[0] < 1.1
    assert np.all(np.diff(predict_logistic(w, np.linspace(-2, 2, 5)[:, None])) > 0)
    flat = fit_logistic(x, np.ones(400, bool))  # one class only: finite, high
    assert np.all(np.isfinite(flat)) and predict_logistic(flat, x).min() > 0.9


def test_without_the_other_session_s_segments_a_landmark_is_scored_by_a_fit_it_took_no_part_in(pair):
    """rev44 D3: without B's database.db the fallback fitted the re-observation logistic on every compared landmark
    of A, the ones B's map lacks as its negatives, and scored those same landmarks with it (their rate pulled low),
    and wrote it as the confidence of kept landmarks too (the README: 0). Now each landmark's re-observation rate p
    is held out (its own label does not move it), the claim's confidence is the probability of absence at prior
    odds 1 given p, 1 / (2 - p) (an absent object always goes unmapped, a present one with 1 - p), and kept
    landmarks keep 0."""
    from dataclasses import replace

    from sosmatch.plugin.changes import held_out_logistic

    rng = np.random.default_rng(4)
    x = rng.normal(0, 1, (60, 2))
    y = rng.random(60) < 1 / (1 + np.exp(-(1.0 + 1.5 * x[:, 0])))
    p = held_out_logistic(x, y)
    for i in (0, 7, 33):
        flipped = y.copy()
        flipped[i] = ~flipped[i]
        assert held_out_logistic(x, flipped)[i] == pytest.approx(p[i], abs=1e-12)  # its own label does not count
    assert held_out_logistic(x[:1], y[:1])[0] == 0.5  # nothing else to fit on

    *_, a, ids_a, b, ids_b, a_from_b = pair
    res = detect_changes(a, replace(b, segments=None), a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    kept, judged = res.a.label == KEPT, res.a.label == GONE
    assert kept.sum() >= 30 and judged.sum() >= 3
    assert np.all(res.a.confidence[kept] == 0.0)
    assert np.all((res.a.confidence[judged] >= 0.5) & (res.a.confidence[judged] < 1.0))


def test_a_verified_alignment_needs_only_to_beat_chance():
    """match's verification answers whether the alignment is right; changes then refuses only a chance-level
    pairing. The audit's sparse summer/winter pair: 13 of 89 (15 %) against 6 % displaced, p 0.0015."""
    from sosmatch.plugin.changes import AlignmentSupport

    sparse = AlignmentSupport(compared=89, matched=13, displaced_rate=0.06, p_value=0.0015)
    assert not sparse.plausible() and sparse.plausible(max_p=1.0)
    chance = AlignmentSupport(compared=89, matched=7, displaced_rate=0.07, p_value=0.4)
    assert not chance.plausible(max_p=1.0)


def test_the_alignment_control_of_changes_and_merge_is_one_rule():
    """`implausible_alignment` is what `changes` and `merge` refuse by: the sparse verified pair stands, unverified
    it is refused (naming the rates and the control's shift); with nothing compared a verified alignment stands (its
    verification decided) and an unverified one is not confirmed."""
    from sosmatch.plugin.changes import AlignmentSupport, implausible_alignment

    sparse = AlignmentSupport(compared=89, matched=13, displaced_rate=0.06, p_value=0.0015)
    assert implausible_alignment(sparse, 3.0, verified=True) is None
    said = implausible_alignment(sparse, 3.0, verified=False)
    assert said.startswith("the transform does not bring the maps together: 15% of A's 89 compared") and "9 m" in said
    none = AlignmentSupport(compared=0, matched=0, displaced_rate=0.0, p_value=1.0)
    assert implausible_alignment(none, 3.0, verified=True) is None
    assert "nothing confirms" in implausible_alignment(none, 3.0, verified=False)


def test_presence_rate_follows_the_references_of_similar_size():
    from sosmatch.plugin.changes import presence_rate

    sizes = np.r_[np.full(40, 1.0), np.full(40, 4.0)]
    views = np.full(80, 20)
    hits = np.r_[np.full(40, 6), np.full(40, 18)]  # small objects show in 30 % of the views, large in 90 %
    rate = presence_rate(np.array([1.0, 4.0, 2.0, np.nan]), sizes, hits, views, bandwidth=0.3)
    assert abs(rate[0] - 0.3) < 0.02 and abs(rate[1] - 0.9) < 0.02
    assert rate[0] < rate[2] < rate[1] and abs(rate[3] - 0.6) < 0.02  # unknown size: the pooled rate


def test_the_dispersion_grows_with_the_views_as_correlated_looks_do():
    """Hits of n correlated views (beta-binomial, intra-class correlation rho) vary by 1 + (n - 1) rho times a
    binomial's: the correlation measured on references seen 40 times predicts the Pearson dispersion of places
    seen 8 times, which one factor for every count (the references' own, about 1 + 39 rho) overstated 3-4
    times, so a place seen in 8 views with no hit could never say absent."""
    from sosmatch.plugin.changes import absence_log_ratio, dispersion, view_correlation

    rng = np.random.default_rng(0)
    rho = 0.15

    def draw(n, m):
        p = rng.uniform(0.5, 0.9, m)
        q = rng.beta(p * (1 - rho) / rho, (1 - p) * (1 - rho) / rho)
        return rng.binomial(n, q), p

    ref_hits, ref_p = draw(40, 4000)
    est = view_correlation(ref_hits, np.full(4000, 40), ref_p)
    assert abs(est - rho) < 0.02
    few_hits, few_p = draw(8, 4000)
    pearson = np.mean((few_hits - 8 * few_p) ** 2 / (8 * few_p * (1 - few_p)))
    assert abs(dispersion(np.array([8]), est)[0] - pearson) < 0.15 * pearson
    assert dispersion(np.array([8]), est)[0] < 0.4 * dispersion(np.array([40]), est)[0]
    # independent views: no correction; too few counts to tell: none either
    assert view_correlation(rng.binomial(30, ref_p[:400]), np.full(400, 30), ref_p[:400]) < 0.01
    assert view_correlation(np.array([1]), np.array([5]), np.array([0.5])) == 0.0
    # a place seen 8 times, never shown, where objects show in 3 of 4 views: absent at odds above 4:1
    llr = absence_log_ratio(np.array([0]), np.array([8]), np.array([0.05]), np.array([0.75]),
                            dispersion(np.array([8]), est))
    assert llr[0] > np.log(4.0)


def test_absence_log_ratio_weighs_hits_against_presence_and_chance():
    from sosmatch.plugin.changes import absence_log_ratio

    chance, present = np.full(3, 0.05), np.full(3, 0.8)
    llr = absence_log_ratio(np.array([0, 24, 6]), np.full(3, 30), chance, present)
    assert llr[0] > 30 and llr[1] < -30  # nothing there vs. shown as often as present objects are
    assert abs(absence_log_ratio(np.array([0]), np.array([30]), chance[:1], present[:1], 5.0)[0] - llr[0] / 5) < 1e-9


def test_a_claim_needs_segments_that_say_absent(pair):
    """A removed object, whose place B's keyframes never show, is claimed with high confidence; the same place
    with a segment in seven of eight views (about as often as B's segments show the objects both mapped, which
    in this world is every view) is not: low probability of absence, kept by B's segments."""
    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = pair
    res = detect_changes(a, b, a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    gone = res.a.label == GONE
    assert np.any(gone) and np.all(res.a.confidence[gone] > 0.99)
    assert np.all(res.a.confidence[res.a.evidence == "landmark"] == 0.0)
    # put segments at the removed objects' places into seven of every eight of B's keyframes
    b_in_a = b.transformed(a_from_b)
    target = np.flatnonzero(gone)
    seen, uv, depth = in_view(res.positions_a[target], res.sizes_a[target], b_in_a.poses, [CAM] * len(b.poses))
    segs = []
    for k, seg in enumerate(b.segments):
        vis = np.flatnonzero(seen[k] & ((k + np.arange(len(target))) % 8 != 0))
        h = res.sizes_a[target][vis] * CAM.fx / depth[k, vis]
        segs.append(KeyframeSegments(np.vstack([seg.centroids, uv[k, vis]]), np.concatenate([seg.sizes_px, h])))
    b2 = SessionObservations(b.positions, b.sizes, b.poses, CAM, tuple(segs), b.support)
    again = detect_changes(a, b2, a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    assert np.all(again.a.confidence[target] < res.a.confidence[target])
    assert np.median(again.a.confidence[target]) < 0.1
    assert np.count_nonzero(again.a.label[target] == KEPT) >= 0.8 * len(target)


def test_an_object_mapped_whole_here_and_as_parts_there_is_kept():
    """A maps a crown whole (4 m) and as two halves; B maps only the halves. The whole has no counterpart of its
    size, but B's halves inside its footprint match A's halves: kept (evidence part, counterpart a half), where
    without part links it would be claimed gone."""
    centers = np.column_stack([np.linspace(-20.0, 20.0, 10), np.zeros(10), np.full(10, 60.0)])
    rng = np.random.default_rng(4)
    ground = np.column_stack([rng.uniform(-40, 40, (30, 2)), np.zeros(30)])
    parts = np.array([[-2.0, 0.0, 3.0], [2.0, 0.0, 3.0]])
    a = SessionObservations(np.vstack([[[0.0, 0.0, 3.0]], parts, ground]), np.r_[4.0, 2.0, 2.0, np.full(30, 1.5)],
                            nadir_poses(centers), CAM)
    b = SessionObservations(np.vstack([parts + 0.3, ground + 0.2]), np.r_[2.1, 1.9, np.full(30, 1.5)],
                            nadir_poses(centers + [3.0, 1.0, 0.0]), CAM)
    same = yaw_transform(0.0, (0.0, 0.0, 0.0))
    res = detect_changes(a, b, same, ChangeParams(min_confidence=0.0), 2.0)
    assert res.a.label[0] == KEPT and res.a.evidence[0] == "part" and res.a.counterpart[0] in (0, 1)
    assert np.all(res.a.label[1:3] == KEPT) and np.all(res.a.evidence[1:3] == "landmark")
    off = detect_changes(a, b, same, ChangeParams(min_confidence=0.0, part_max_ratio=0.0), 2.0)
    assert off.a.label[0] == GONE


def _segments_of(positions, sizes, poses, rng, clutter=20):
    """Every keyframe's segments: the projections of the given places with their sizes, plus random clutter."""
    seen, uv, depth = in_view(positions, sizes, poses, [CAM] * len(poses))
    segs = []
    for k in range(len(poses)):
        vis = np.flatnonzero(seen[k])
        cl = rng.uniform([0, 0], [CAM.width, CAM.height], (clutter, 2))
        segs.append(KeyframeSegments(np.vstack([uv[k, vis], cl]), np.concatenate(
            [sizes[vis] * CAM.fx / depth[k, vis], rng.uniform(2.0, 30.0, clutter)])))
    return tuple(segs)


def test_a_holder_vouches_only_when_this_session_shows_it_too():
    """A maps a tree (3 m) that B no longer has; where it stood B maps a larger ground patch (5.5 m) that A's
    images do not show: the patch is not the tree's whole, so the tree is gone. A also maps half of a crown
    (2 m) whose whole (3.5 m) only B mapped; A's images show the whole crown (segmented, never mapped), so the
    half is kept, nested in B's crown; without those segments nothing says B's crown is there in A, and the
    half is claimed."""
    centers = np.column_stack([np.linspace(-20.0, 40.0, 12), np.zeros(12), np.full(12, 60.0)])
    poses = nadir_poses(centers)
    rng = np.random.default_rng(7)
    ground = np.column_stack([rng.uniform([-30, -20], [50, 20], (80, 2)), np.zeros(80)])
    tree, half = np.array([[0.0, 0.0, 1.0]]), np.array([[20.0, 0.0, 4.0]])
    far = np.hypot(*(ground[:, None, :2] - np.vstack([tree, half])[None, :, :2]).transpose(2, 0, 1)).min(1) > 15.0
    ground = ground[far][:30]  # common ground texture, away from both objects
    patch, crown = np.array([[1.0, 0.0, 0.0]]), np.array([[20.5, 0.0, 4.0]])
    pos_a, size_a = np.vstack([tree, half, ground]), np.r_[3.0, 2.0, np.full(30, 1.5)]
    pos_b, size_b = np.vstack([patch, crown, ground + 0.2]), np.r_[5.5, 3.5, np.full(30, 1.5)]
    shown_a = _segments_of(np.vstack([pos_a, crown]), np.r_[size_a, 3.5], poses, rng)
    b = SessionObservations(pos_b, size_b, poses, CAM, _segments_of(pos_b, size_b, poses, rng))
    same = yaw_transform(0.0, (0.0, 0.0, 0.0))
    res = detect_changes(SessionObservations(pos_a, size_a, poses, CAM, shown_a), b, same, ChangeParams(), 2.0)
    assert res.a.label[0] == GONE and res.a.evidence[0] == "none" and res.a.confidence[0] > 0.99
    assert res.a.label[1] == KEPT and res.a.evidence[1] == "nested" and res.a.counterpart[1] == 1
    assert np.all(res.a.label[2:] == KEPT)  # the common ground
    unshown = detect_changes(SessionObservations(pos_a, size_a, poses, CAM, _segments_of(pos_a, size_a, poses, rng)),
                             b, same, ChangeParams(), 2.0)
    assert unshown.a.label[1] == GONE and unshown.a.label[0] == GONE


def test_tracks_are_the_connected_matches_of_one_segment_per_keyframe():
    # keyframe a, keyframe b, matched keypoints: one 3-view track (0:1, 1:0, 2:2), one 2-view track (0:0, 1:1) and
    # a component that holds two keypoints of keyframe 2 (no track of one segment)
    matches = [(0, 1, np.array([[1, 0], [0, 1]])), (1, 2, np.array([[0, 2]])), (0, 2, np.array([[1, 2]])),
               (1, 2, np.array([[2, 0], [2, 1]]))]
    tracks = tracks_from_matches(matches, [2, 3, 3])
    as_sets = sorted(sorted(map(tuple, t.tolist())) for t in tracks)
    assert as_sets == [[(0, 0), (1, 1)], [(0, 1), (1, 0), (2, 2)]]
    assert all(np.all(np.diff(t[:, 0]) > 0) for t in tracks)
    assert tracks_from_matches([], [2, 2]) == []


def _unmapped_pair(mapped_in_b: bool):
    """A strip flown twice over common ground texture. B has a bush (1.5 m) that A does not: B's images segment it
    in every view, but its track broke into pieces, the longest of 4 views, too short for a landmark (unless
    `mapped_in_b`). A's images show nothing of that size there."""
    centers = np.column_stack([np.linspace(-20.0, 40.0, 12), np.zeros(12), np.full(12, 60.0)])
    poses = nadir_poses(centers)
    rng = np.random.default_rng(11)
    ground = np.column_stack([rng.uniform([-30, -20], [50, 20], (120, 2)), np.zeros(120)])
    bush = np.array([[10.0, 3.0, 1.0]])
    ground = ground[np.hypot(ground[:, 0] - 10.0, ground[:, 1] - 3.0) > 12.0][:40]
    size_g = np.full(len(ground), 1.5)
    a = SessionObservations(ground, size_g, poses, CAM, _segments_of(ground, size_g, poses, rng))
    # B's segments: the bush first in every keyframe that sees it, then the ground and clutter
    segs = _segments_of(np.vstack([bush, ground + 0.2]), np.r_[1.5, size_g], poses, rng)
    seen = in_view(bush, np.r_[1.5], poses, [CAM] * len(poses))[0][:, 0]
    views = np.flatnonzero(seen)
    assert len(views) >= 8
    piece = np.column_stack([views[2:6], np.zeros(4, np.int64)])  # keypoint 0: the bush
    pos_b, size_b = (np.vstack([bush, ground + 0.2]), np.r_[1.5, size_g]) if mapped_in_b else (ground + 0.2, size_g)
    b = SessionObservations(pos_b, size_b, poses, CAM, segs, tracks=(piece,))
    return a, b, bush


def test_an_added_object_that_was_never_mapped_is_found_from_its_track():
    """B never mapped the bush (a 4-view track), but its own segments show it in every view and A's show nothing:
    it is reported new, as one of B's objects never mapped; landmarks alone cannot see it. Mapped as a landmark,
    the same track is no object of its own (the landmark explains it)."""
    a, b, bush = _unmapped_pair(mapped_in_b=False)
    same = yaw_transform(0.0, (0.0, 0.0, 0.0))
    res = detect_changes(a, b, same, ChangeParams(), 2.0)
    assert len(res.unmapped_b) == 1 and np.linalg.norm(res.unmapped_b.positions[0, :2] - bush[0, :2]) < 1.0
    assert 1.0 < res.unmapped_b.sizes[0] < 2.2 and res.unmapped_b.support[0] == 4
    assert res.tracks_b.label[0] == NEW and res.tracks_b.confidence[0] > 0.9
    assert res.counts()["new_unmapped"] == 1 and res.counts()["new"] == 0
    assert np.all(res.b.label == KEPT) and np.all(res.a.label == KEPT)  # the common ground
    off = detect_changes(a, b, same, ChangeParams(unmapped_objects=False), 2.0)
    assert off.tracks_b is None and len(off.unmapped_b) == 0 and off.counts()["new_unmapped"] == 0
    # the other way round A has no tracks: nothing to judge of A's
    assert res.tracks_a is None
    a2, b2, _ = _unmapped_pair(mapped_in_b=True)
    mapped = detect_changes(a2, b2, same, ChangeParams(), 2.0)
    assert len(mapped.unmapped_b) == 0 and mapped.b.label[0] == NEW


def test_batch_counts_and_words_are_those_of_sosmatch_changes():
    """rev44 D8: batch's pair row added the claims of objects never mapped to `gone` / `new` and its report called
    them "landmarks gone, new"; nu60 D1: it then called the sum "objects gone", where one tree is often two
    landmarks and again in another pair. The batch's line is now `sosmatch changes`'s line of the counts summed
    over its pairs: landmarks and objects never mapped apart, each as what it is."""
    from pathlib import Path

    from sosmatch.plugin.changes import COUNT_KEYS, counts_summary
    from sosmatch.workflows.batch.report import BatchReport

    a, b, _ = _unmapped_pair(mapped_in_b=False)
    res = detect_changes(a, b, yaw_transform(0.0, (0.0, 0.0, 0.0)), ChangeParams(), 2.0)
    c = res.counts()
    assert c["new"] == 0 and c["new_unmapped"] == 1 and set(c) == set(COUNT_KEYS)
    one = BatchReport(Path("out"), pairs=[{"changes_status": "done", **c}])
    # the one-pair line is the command's, without the area seen by both
    assert one.changes_line() == f"changes summed over 1 pair(s): {res.summary().rsplit('; ', 1)[0]}"
    assert "0 gone, 1 new of" in one.changes_line() and "objects gone" not in one.changes_line()
    other = {k: 2 * v + 1 for k, v in c.items()}
    two = BatchReport(Path("out"), pairs=[{"changes_status": "done", **c}, {"changes_status": "done", **other},
                                          {"changes_status": "failed"}])
    assert two.changes_line() == (f"changes summed over 2 pair(s): {counts_summary({k: 3 * c[k] + 1 for k in c})}; "
                                  "change detection failed on 1 pair(s)")


def test_a_track_is_an_object_only_where_its_own_segments_show_it_and_its_place_is_fixed():
    a, b, bush = _unmapped_pair(mapped_in_b=False)
    same = yaw_transform(0.0, (0.0, 0.0, 0.0))
    # the same 4 views, but B's other keyframes do not segment the bush: one piece of track is no object
    piece = b.tracks[0]
    segs = list(b.segments)
    for k in set(range(len(segs))) - set(piece[:, 0].tolist()):
        segs[k] = KeyframeSegments(segs[k].centroids[1:], segs[k].sizes_px[1:]) if len(segs[k].centroids) else segs[k]
    flicker = SessionObservations(b.positions, b.sizes, b.poses, CAM, tuple(segs), tracks=b.tracks)
    assert len(detect_changes(a, flicker, same, ChangeParams(), 2.0).unmapped_b) == 0
    # views along one flight line fix the height poorly: two neighbouring views leave it open by more than the
    # counterpart gate at 3 px of centroid noise, the 4 views of the piece do so only at 10 px
    short = SessionObservations(b.positions, b.sizes, b.poses, CAM, b.segments, tracks=(piece[:2],))
    assert len(detect_changes(a, short, same, ChangeParams(), 2.0).unmapped_b) == 0
    assert len(detect_changes(a, b, same, ChangeParams(), 2.0).unmapped_b) == 1
    assert len(detect_changes(a, b, same, ChangeParams(unmapped_pixel_sigma_px=10.0), 2.0).unmapped_b) == 0


def test_the_two_directions_are_judged_alike(pair):
    """Swapping the sessions mirrors the verdicts: A's gone landmarks are the new ones of the swapped pair and
    vice versa, with the same evidence (only the coarse ground grid, laid out in the first session's frame,
    moves the confidences a little). Removed and added objects are told apart by one rule."""
    *_, a, _, b, _, a_from_b = pair
    ab = detect_changes(a, b, a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    ba = detect_changes(b, a, a_from_b.inverse(), ChangeParams(min_confidence=0.0), 2.0)
    swap = {GONE: NEW, NEW: GONE}
    mirrored_a = np.array([swap.get(x, x) for x in ba.b.label])
    mirrored_b = np.array([swap.get(x, x) for x in ba.a.label])
    assert np.array_equal(ab.a.label, mirrored_a) and np.array_equal(ab.b.label, mirrored_b)
    assert np.array_equal(ab.a.evidence, ba.b.evidence) and np.array_equal(ab.b.evidence, ba.a.evidence)
    assert ab.a.count(GONE) >= 3 and ab.b.count(NEW) >= 3
    assert np.allclose(ab.a.confidence, ba.b.confidence, atol=0.05)


def test_a_fragment_far_above_the_surface_its_images_show_is_a_wrong_triangulation():
    # nu29: a track no landmark holds, triangulated 9 m above a conifer's tip (16.7 m above the ground where B's
    # own sweep reads 0.5 m), was claimed new at 0.999. Landmark heights scatter by 1.5 m (MAD), the sweep by 0.4 m
    from sosmatch.plugin.changes.observations import above_the_surface

    rng = np.random.default_rng(5)
    map_h = np.concatenate([rng.normal(0.0, 1.0, 200), rng.uniform(2.0, 12.0, 100)])
    scale = np.hypot(1.4826 * np.median(np.abs(map_h - np.median(map_h))), 0.4)
    heights = np.array([16.65, 8.0, 8.0, 16.65, np.nan, 16.65])
    surface = np.array([0.5, 7.0, 0.0, 15.0, 0.0, np.nan])
    far = above_the_surface(heights, surface, map_h, 4.0, 0.4)
    assert 4.0 * scale < 16.0  # the fragment is far above; a tree's fragment at its top is not
    assert far.tolist() == [True, False, bool(8.0 > 4.0 * scale), False, False, False]
    # a map of flat ground (no scatter of landmark heights): the sweep's noise alone scales the test
    flat = np.zeros(50)
    assert above_the_surface(np.array([1.0, 3.0]), np.zeros(2), flat, 4.0, 0.4).tolist() == [False, True]
    assert not above_the_surface(np.array([3.0]), np.zeros(1), flat, 4.0, float("nan"))[0]  # noise unknown


def test_a_landmark_below_the_ground_is_compared_with_nothing(pair):
    """A ground patch triangulated tens of metres deep (two patches linked into one track) lies under the
    ground its session looked at: its place is as wrong as its height, and it fell inside the other session's
    images though it lay outside its footprint. It is never a change, whatever the other session shows; a
    landmark at the ground's usual scatter is judged as before."""
    from sosmatch.plugin.changes import BELOW_GROUND, below_the_ground

    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = pair
    params = ChangeParams(min_confidence=0.0)
    res = detect_changes(a, b, a_from_b, params, 2.0)
    gone = np.flatnonzero(res.a.label == GONE)
    kept = np.flatnonzero(res.a.label == KEPT)
    assert len(gone) >= 2 and len(kept) >= 2
    deep, shallow = gone[0], gone[1]
    moved = a.positions.copy()
    moved[deep, 2] -= 30.0  # 30 m under the ground
    moved[kept[0], 2] -= 30.0  # a kept one too: deep is wrong, not absent
    moved[shallow, 2] -= 0.5  # within the ground's scatter
    a2 = SessionObservations(moved, a.sizes, a.poses, CAM, a.segments, a.support)
    again = detect_changes(a2, b, a_from_b, params, 2.0)
    assert again.a.label[deep] == UNSEEN and again.a.evidence[deep] == BELOW_GROUND
    assert again.a.label[kept[0]] == UNSEEN and again.a.evidence[kept[0]] == BELOW_GROUND
    assert again.a.label[shallow] == GONE
    others = np.setdiff1d(np.arange(len(moved)), [deep, kept[0], shallow])
    assert np.mean(again.a.label[others] == res.a.label[others]) > 0.97
    # the scale is the map's own: heights of 2 m scatter put -30 m far out, -3 m within
    h = np.random.default_rng(1).normal(0.0, 2.0, 500)
    assert below_the_ground(np.array([-30.0, -3.0, np.nan]), h, 4.0).tolist() == [True, False, False]


def test_the_presence_rate_of_a_landmark_follows_how_often_its_own_session_shows_it(pair):
    """A landmark that its own session segments in only some of its views (a crown's fragment) would be shown as
    rarely by the other session if it were there: few hits there say less that it went. The same removed
    objects, with their own session's segments taken out of half of its keyframes, are claimed with less
    confidence; the other claims are as before."""
    from sosmatch.plugin.changes import landmark_presence_rate

    # the pair's rate for objects of this size, scaled by the landmark's own repeatability against its size's
    rate = landmark_presence_rate(np.array([2.0, 2.0]), np.array([20, 9]), np.array([20, 20]), np.full(40, 2.0),
                                  np.full(40, 16), np.full(40, 20), np.full(40, 19), np.full(40, 20), 0.3)
    assert 0.78 < rate[0] <= 0.85 and abs(rate[1] - rate[0] * 10 / 21) < 0.01
    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = pair
    params = ChangeParams(min_confidence=0.0)
    res = detect_changes(a, b, a_from_b, params, 2.0)
    gone = np.flatnonzero(res.a.label == GONE)
    target = gone[:3]
    assert len(target) == 3
    seen, uv, _ = in_view(a.positions[target], a.sizes[target], a.poses, [CAM] * len(a.poses))
    segs = []
    for k, seg in enumerate(a.segments):
        if k % 2 or not np.any(seen[k]):
            segs.append(seg)
            continue
        near = np.linalg.norm(seg.centroids[:, None, :] - uv[k][None, seen[k]], axis=2).min(1) < 3.0
        segs.append(KeyframeSegments(seg.centroids[~near], seg.sizes_px[~near]))
    a2 = SessionObservations(a.positions, a.sizes, a.poses, CAM, tuple(segs), a.support)
    again = detect_changes(a2, b, a_from_b, params, 2.0)
    assert np.all(again.a.label[target] == GONE)
    assert np.all(again.a.confidence[target] < res.a.confidence[target] - 1e-6)


def test_a_claim_shown_at_a_confidence_passes_min_confidence_at_that_value(pair):
    """changes.csv rounded confidences to nearest: a claim at 0.9996 read "1.000" while `--min-confidence 1`
    dropped it (nu24). Shown values are rounded down, so every row shown at c passes c."""
    import csv
    import io

    from sosmatch.database.changes_io import format_changes_csv, shown_confidence

    *_, a, ids_a, b, ids_b, a_from_b = pair
    res = detect_changes(a, b, a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    claimed = res.a.label == GONE
    assert claimed.any()
    res.a.confidence[np.flatnonzero(claimed)[0]] = 0.99962
    rows = list(csv.DictReader(io.StringIO(format_changes_csv(res))))
    for row, conf in zip(rows, res.a.confidence):
        if row["confidence"]:
            assert float(row["confidence"]) <= conf  # shown never above the value --min-confidence compares
    assert "0.999" in {r["confidence"] for r in rows} and shown_confidence(0.57) == 0.57
