"""The surface heights as evidence of change (plugin.changes.surface): each session's surface height at a place from
its own images (a plane sweep registered on the ground around it), compared across the sessions as a likelihood
ratio calibrated on the pair's landmarks with a counterpart."""

from dataclasses import replace

import numpy as np
import pytest

from sosmatch.plugin.changes import (
    FLAT,
    GONE,
    KEPT,
    NEW,
    UNSEEN,
    KeyframeSegments,
    detect_changes,
    ground_height_field,
)
from sosmatch.plugin.changes.surface import (
    SWEEP_STEP_M,
    footprint_places,
    ground_sweep_noise,
    height_limit,
    height_log_ratio,
    heights_above_ground,
    relief_levels,
    shows_relief,
    spread_views,
    stands_above_ground,
)
from sosmatch.plugin.geometry import Camera, Poses, rotvec_to_matrix
from sosmatch.plugin.params import ChangeParams as _ChangeParams
from sosmatch.tools.toy_sessions import change_session, lawnmower, render_nadir_images, yaw_transform


def ChangeParams(**kw):  # noqa: N802 - stands in for the class in these tests
    """The detector's parameters with the segments' probability as the confidence: these toy observations have
    no relief to test for a standing object (`untested_object_rate`, tested in test_changes_cli)."""
    return _ChangeParams(**{"untested_object_rate": 1.0, **kw})


CAM = Camera(320, 240, 200.0, 200.0, 160.0, 120.0)  # 0.23 m a pixel from 45 m


@pytest.fixture(scope="module")
def scene():
    """25 objects (textured discs of radius 2 h, 3-8 m above a textured ground) and 40 ground-texture landmarks on
    90 x 90 m, and a dark ground patch (a shadow) that is at one place in A and at another in B. B lacks 4 of the
    objects; its segmenter missed object 5, and its landmark of it lies 5 m off (beyond the counterpart gate).
    Both sessions in one frame."""
    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(5) * 17.0 + 11.0, np.arange(5) * 17.0 + 11.0)
    objects = np.column_stack([gx.ravel() + rng.uniform(-2, 2, 25), gy.ravel() + rng.uniform(-2, 2, 25),
                               rng.uniform(3.0, 8.0, 25)])
    ground = np.column_stack([rng.uniform(5, 85, (40, 2)), np.zeros(40)])
    shadows = np.array([[40.0, 46.0, 0.0], [44.0, 41.0, 0.0]])  # index 65 in A only, 66 in B only
    positions = np.vstack([objects, ground, shadows])
    sizes = np.concatenate([rng.uniform(1.2, 2.2, 25), np.full(40, 1.0), np.full(2, 1.5)])
    removed = np.array([2, 8, 16, 22])
    present_a, present_b = _presence(removed)
    a, ids_a = change_session(positions, sizes, present_a, lawnmower(5, 85, 5, 85, 45, 10, 6), 1, camera=CAM)
    b, ids_b = change_session(positions, sizes, present_b, lawnmower(7, 87, 3, 83, 45, 10, 6), 2, camera=CAM)
    # B's landmark of object 5 lies 5 m off, and B's segments outline it in only every third keyframe
    j5 = int(np.flatnonzero(ids_b == 5)[0])
    b = replace(b, positions=b.positions + np.where(np.arange(len(ids_b)) == j5, 1.0, 0.0)[:, None] * [5.0, 0, 0])
    uv = np.array([(b.positions[j5] - c) @ r for r, c in zip(b.poses.rotations, b.poses.centers)])
    uv = uv[:, :2] / uv[:, 2:] * CAM.fx + [CAM.cx, CAM.cy]
    keep = [(np.linalg.norm(s.centroids - p, axis=1) > 40) | (k % 3 == 0)
            for k, (s, p) in enumerate(zip(b.segments, uv))]
    b = replace(b, segments=tuple(KeyframeSegments(s.centroids[m], s.sizes_px[m]) for s, m in zip(b.segments, keep)))
    images_a, images_b = _render(a, b, positions, sizes, removed)
    return positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b


def _presence(removed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of the scene's 67 places each session holds: B lacks the removed objects, the shadow is at 65 in A
    and at 66 in B."""
    present_a, present_b = np.ones(67, bool), np.ones(67, bool)
    present_b[removed] = False
    present_a[66], present_b[65] = False, False
    return present_a, present_b


def _render(a, b, positions: np.ndarray, sizes: np.ndarray, removed: np.ndarray) -> tuple[list, list]:
    """Both sessions' keyframe images of the scene's objects and shadows (the ground-texture landmarks are not
    drawn), B under another gain and offset."""
    drawn = (np.arange(67) < 25) | (np.arange(67) >= 65)
    present_a, present_b = _presence(removed)
    return (render_nadir_images(a.poses, CAM, positions, sizes, drawn & present_a, 7, noise_seed=1),
            render_nadir_images(b.poses, CAM, positions, sizes, drawn & present_b, 7, gain=0.8, offset=25.0,
                                noise_seed=2))


def _tilted(poses: Poses, sigma_deg: float, seed: int) -> Poses:
    """The poses with each keyframe turned by a small random rotation (sigma_deg per axis: a map's attitude
    errors)."""
    rng = np.random.default_rng(seed)
    turn = rotvec_to_matrix(np.radians(sigma_deg) * rng.normal(size=(len(poses), 3)))
    return Poses(poses.names, turn @ poses.rotations, poses.centers)


def test_the_sweep_finds_the_surface_despite_a_maps_pose_errors(scene):
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    poses = _tilted(a.poses, 0.3, 0)  # 0.5 deg: 0.4 m on the ground from 45 m, two pixels
    for ids, want in ((np.arange(25), positions[:25, 2]), (np.arange(25, 65), np.zeros(40))):
        keep = np.isin(ids, ids_a)
        pts = positions[ids[keep]]
        h = heights_above_ground(pts, np.zeros(len(pts)), images_a, poses, [CAM] * len(poses))
        assert np.all(np.isfinite(h))
        err = np.abs(h - want[keep])
        assert np.median(err) < 0.5 and np.mean(err < 1.0) >= 0.9
    # views too coarse for the patch (2 m across under MIN_PATCH_PIXELS of them): no height, never a guess
    coarse = Camera(320, 240, 100.0, 100.0, 160.0, 120.0)  # 0.45 m a pixel from 45 m: the patch is 4.4 px wide
    pts = positions[:5]
    assert np.all(np.isnan(heights_above_ground(pts, np.zeros(5), images_a, a.poses, [coarse] * len(a.poses))))
    assert not shows_relief(np.full(50, np.nan), 0.01)
    # no images: no height
    assert np.all(np.isnan(heights_above_ground(positions[:3], np.zeros(3), None, a.poses, [CAM] * len(a.poses))))


def test_the_widest_views_are_chosen_deterministically():
    inside = np.array([[True], [True], [True], [False]])
    centers = np.array([[0.0, 0, 50], [5.0, 0, 50], [30.0, 0, 50], [60.0, 0, 50]])
    off = np.array([[0.3], [0.0], [0.2], [0.1]])
    v = spread_views(inside, centers, off, 4)[:, 0]
    assert v.tolist() == [1, 2, 0, -1]  # the most central, then the farthest from it, then the rest


def test_the_height_ratio_is_calibrated_on_the_references():
    rng = np.random.default_rng(0)
    own = np.concatenate([np.zeros(150), rng.uniform(3, 12, 50)])
    other = np.where(own > 0, own + rng.normal(0, 0.8, 200), np.abs(rng.normal(0, 0.1, 200)))
    llr = height_log_ratio(np.array([8.0, 8.0, 0.0, 0.0]), np.array([0.0, 7.5, 0.0, 6.0]), own, other)
    assert llr[0] > 2.0  # high here, ground there: absent
    assert llr[1] < -2.0  # high in both: present
    assert abs(llr[2]) < 0.1 and abs(llr[3]) < 0.1  # no height of its own: no evidence either way
    assert np.all(np.abs(llr) <= np.log(199) + 1e-9)
    assert np.all(height_log_ratio(np.array([8.0]), np.array([np.nan]), own, other) == 0)
    assert np.all(height_log_ratio(np.array([8.0]), np.array([0.0]), own[:5], other[:5]) == 0)  # too few


def test_the_surface_says_present_where_the_other_map_lost_the_object(scene):
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    i5 = int(np.flatnonzero(ids_a == 5)[0])
    plain = detect_changes(a, b, same_frame, ChangeParams(), 2.0)
    assert plain.a.label[i5] == GONE  # no counterpart within the gate, no segment: a false claim
    seen = detect_changes(replace(a, images=images_a), replace(b, images=images_b), same_frame, ChangeParams(), 2.0)
    assert seen.a.label[i5] != GONE  # B's own images show a surface as high as A's there
    for o in removed:  # B's images show the ground where they stood
        i = int(np.flatnonzero(ids_a == o)[0])
        assert seen.a.label[i] == GONE and seen.a.confidence[i] >= plain.a.confidence[i]
    kept = np.isin(ids_a, np.setdiff1d(np.arange(65), removed))
    assert np.mean(seen.a.label[kept] == KEPT) >= 0.95
    # the shadow moved: no height in either session, so no evidence either way (the segments decide)
    s = int(np.flatnonzero(ids_a == 65)[0])
    assert seen.a.confidence[s] == pytest.approx(plain.a.confidence[s], abs=0.05)
    off = detect_changes(replace(a, images=images_a), replace(b, images=images_b), same_frame,
                         ChangeParams(surface_evidence=False), 2.0)
    assert np.array_equal(off.a.label, plain.a.label) and np.array_equal(off.a.confidence, plain.a.confidence)


def test_a_moved_shadow_is_no_object_that_went(scene):
    # the shadow at 65 (A only) and 66 (B only): the other session's segments do not show it, but neither
    # session's surface stands above the ground there, so it is no object and no change; the removed objects are
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    a_img, b_img = replace(a, images=images_a), replace(b, images=images_b)
    blind = detect_changes(a_img, b_img, same_frame, ChangeParams(object_height_p=1.0), 2.0)
    seen = detect_changes(a_img, b_img, same_frame, ChangeParams(), 2.0)
    s_a, s_b = int(np.flatnonzero(ids_a == 65)[0]), int(np.flatnonzero(ids_b == 66)[0])
    assert blind.a.label[s_a] == GONE and blind.b.label[s_b] == NEW  # without the test: claimed
    assert (seen.a.label[s_a], seen.a.evidence[s_a]) == (UNSEEN, FLAT)
    assert (seen.b.label[s_b], seen.b.evidence[s_b]) == (UNSEEN, FLAT)
    counts = seen.counts()
    assert counts["flat_a"] == int(np.sum(seen.a.evidence == FLAT)) >= 1 and "flat" in seen.summary()
    assert blind.counts()["flat_a"] == 0 and "flat" not in blind.summary()
    assert seen.without_relief == ()  # the scene's objects stand: its images show relief
    for o in removed:
        i = int(np.flatnonzero(ids_a == o)[0])
        assert seen.a.label[i] == GONE
    # everything else is as without the test
    other = np.ones(len(ids_a), bool)
    other[s_a] = False
    assert np.array_equal(seen.a.label[other], blind.a.label[other])


def test_the_ground_noise_is_mirrored_from_the_places_at_or_below_the_ground():
    rng = np.random.default_rng(1)
    ground = rng.normal(0.0, 0.6, 400)
    objects = rng.uniform(2.0, 15.0, 300)  # objects only add height: they must not widen the noise
    sigma = ground_sweep_noise(np.concatenate([ground, objects, [np.nan]]))
    assert sigma == pytest.approx(0.6, rel=0.15)
    assert np.isnan(ground_sweep_noise(np.array([-0.1, 0.0, 3.0])))  # too few places
    heights = np.array([0.3, 1.0, 2.0, 5.0, np.nan, -2.0])
    up = stands_above_ground(heights, np.concatenate([ground, objects]), 0.01)  # 2.33 sigma = 1.4 m
    assert up.tolist() == [False, False, True, True, False, False]
    assert stands_above_ground(heights, ground, 1.0).all()  # off
    assert stands_above_ground(heights, objects, 0.01).all()  # no place at ground level: no noise, no test
    # never finer than the sweep itself
    assert not stands_above_ground(np.array([SWEEP_STEP_M]), np.zeros(50), 0.01)[0]


def test_the_highest_of_several_places_is_tested_at_their_joint_level():
    rng = np.random.default_rng(4)
    ground = rng.normal(0.0, 0.5, 4000)
    one, seven = height_limit(ground, 0.01), height_limit(ground, 0.01, places=7)
    assert one == pytest.approx(2.326 * 0.5, rel=0.1) and seven == pytest.approx(2.976 * 0.5, rel=0.1)
    assert np.isnan(height_limit(ground, 1.0)) and np.isnan(height_limit(np.array([1.5, 3.0]), 0.01))
    # bare ground swept at 7 places each: the highest passes the joint limit about as often as one place at p
    maxima = rng.normal(0.0, 0.5, (20000, 7))
    rate = np.mean(stands_above_ground(maxima, ground, 0.01, places=7))
    assert 0.005 < rate < 0.02
    assert 0.03 < np.mean(stands_above_ground(maxima, ground, 0.01, places=1)) < 0.1  # uncorrected: ~7 x p
    # unknown places do not count; a row with none known does not stand
    h = np.array([[np.nan, 0.2, 3.0], [np.nan, np.nan, np.nan], [0.1, np.nan, 0.0], [5.0, np.nan, np.nan]])
    assert stands_above_ground(h, ground, 0.01, places=3).tolist() == [True, False, False, True]
    assert stands_above_ground(h[:, :0], ground, 0.01).tolist() == [False] * 4


def test_the_ring_lies_inside_the_footprint():
    pts = np.array([[10.0, 20.0, 3.0], [0.0, 0.0, 0.0]])
    ring = footprint_places(pts, np.array([1.5, np.nan]), 6)
    assert ring.shape == (2, 6, 3)
    d = np.linalg.norm(ring[0, :, :2] - pts[0, :2], axis=1)
    assert np.allclose(d, 1.5) and np.allclose(ring[0, :, 2], 3.0)  # half the footprint's radius 2 h
    assert np.allclose(ring[1], 0.0)  # no size: the place itself
    assert np.array_equal(ring, footprint_places(pts, np.array([1.5, np.nan]), 6))


def test_an_object_beside_its_landmark_is_found_on_the_ring(scene):
    # A's landmark of a removed object lies 2.6 h off the object's centre, beyond the edge of its top (radius
    # 2 h), where a patch around the landmark is ground: its own place does not stand; the ring (at h around it)
    # reaches the object
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    b_img = replace(b, images=images_b)
    for o in removed:
        i = int(np.flatnonzero(ids_a == o)[0])
        shift = np.where(np.arange(len(ids_a)) == i, 1.0, 0.0)[:, None] * [2.6 * sizes[o], 0.0, 0.0]
        a_img = replace(a, positions=a.positions + shift, images=images_a)
        centre_only = detect_changes(a_img, b_img, same_frame, ChangeParams(object_height_ring=0), 2.0)
        ring = detect_changes(a_img, b_img, same_frame, ChangeParams(), 2.0)
        assert (centre_only.a.label[i], centre_only.a.evidence[i]) == (UNSEEN, FLAT)
        assert ring.a.label[i] == GONE


def test_a_shadow_beside_a_kept_object_is_not_that_object(scene):
    # the shadow that moved lies just beyond the edge of a crown both sessions have: the ring around the shadow's
    # landmark reaches the crown, which stands there in B's images too, so nothing that stands there went
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    moved = positions.copy()
    moved[65, :2] = positions[0, :2] + [2.0 * sizes[0] + 1.0, 0.0]
    a_images, b_images = _render(a, b, moved, sizes, removed)
    s_a = int(np.flatnonzero(ids_a == 65)[0])
    a_moved = replace(a, positions=np.where((np.arange(len(ids_a)) == s_a)[:, None], moved[65], a.positions),
                      images=a_images)
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    seen = detect_changes(a_moved, replace(b, images=b_images), same_frame, ChangeParams(), 2.0)
    i0 = int(np.flatnonzero(ids_a == 0)[0])
    assert seen.a.label[i0] == KEPT and seen.a.counterpart[i0] >= 0
    assert (seen.a.label[s_a], seen.a.evidence[s_a]) == (UNSEEN, FLAT)


def test_a_shadow_beside_a_kept_object_is_not_that_object_whatever_the_other_images_make_of_its_edge(scene):
    # nu29: a noon shadow just beyond a crown's edge stands in the noon images (its 2 x 2 m patch catches the
    # crown's edge) and the overcast images sweep that edge to the ground, so "it stands in both sessions" failed
    # and the shadow was called gone at 0.999. Here B's images show crown 0 at half its radius: its centre stands
    # in both sessions, its outer half in A only. The shadow stands in A only within reach of crown 0, outside it
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    drawn_b = ((np.arange(67) < 25) | (np.arange(67) >= 65)) & _presence(removed)[1]
    shrunk = sizes.copy()
    shrunk[0] *= 0.5

    def b_with(drawn: np.ndarray):
        return replace(b, images=render_nadir_images(b.poses, CAM, positions, shrunk, drawn, 7, gain=0.8,
                                                     offset=25.0, noise_seed=2))

    b_edge, b_none = b_with(drawn_b), b_with(drawn_b & (np.arange(67) != 0))
    s_a, i0 = int(np.flatnonzero(ids_a == 65)[0]), int(np.flatnonzero(ids_a == 0)[0])
    for off in (0.5, 1.0):  # its own place within the patch's reach of the crown's footprint; its ring inside it
        moved = positions.copy()
        moved[65, :2] = positions[0, :2] + [2.0 * sizes[0] + off, 0.0]
        a_images = _render(a, b, moved, sizes, removed)[0]
        a_moved = replace(a, positions=np.where((np.arange(len(ids_a)) == s_a)[:, None], moved[65], a.positions),
                          images=a_images)
        seen = detect_changes(a_moved, b_edge, same_frame, ChangeParams(), 2.0)
        assert seen.a.label[i0] == KEPT and seen.a.counterpart[i0] >= 0
        assert (seen.a.label[s_a], seen.a.evidence[s_a]) == (UNSEEN, FLAT)
        for o in removed:  # objects that went, far from any kept one, are still gone
            assert seen.a.label[int(np.flatnonzero(ids_a == o)[0])] == GONE
        # crown 0 nowhere in B's images: its landmark's counterpart alone does not make it an object of both
        # sessions (a chance pairing), so nothing explains what stands beside it
        alone = detect_changes(a_moved, b_none, same_frame, ChangeParams(), 2.0)
        assert alone.a.label[i0] == KEPT and alone.a.label[s_a] == GONE


def test_without_relief_in_the_images_the_objectness_test_stands_aside(scene):
    # the same sessions with every object drawn flat on the ground (an orthophoto's views): no place stands, so
    # the test cannot tell objects from texture; it says so and the segments and heights decide as without it
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    flat_a, flat_b = _render(a, b, positions * [1.0, 1.0, 0.0], sizes, removed)
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    a_img, b_img = replace(a, images=flat_a), replace(b, images=flat_b)
    on = detect_changes(a_img, b_img, same_frame, ChangeParams(), 2.0)
    off = detect_changes(a_img, b_img, same_frame, ChangeParams(object_height_p=1.0), 2.0)
    assert on.without_relief == ("A", "B") and off.without_relief == ()
    assert not np.any(on.a.evidence == FLAT) and not np.any(on.b.evidence == FLAT)
    assert np.array_equal(on.a.label, off.a.label) and np.array_equal(on.b.label, off.b.label)


def test_relief_is_what_the_ground_noise_alone_would_not_raise():
    rng = np.random.default_rng(2)
    ground = np.round(rng.normal(0.0, 0.5, 200) * 2) / 2  # the sweep's 0.5 m steps
    assert not shows_relief(ground, 0.01)  # bare ground, or an orthophoto's views: its few high places are noise
    assert not shows_relief(np.zeros(200), 0.01)
    trees = np.concatenate([ground[:150], rng.uniform(3.0, 15.0, 50)])
    assert shows_relief(trees, 0.01)
    assert shows_relief(np.concatenate([ground[:190], rng.uniform(3.0, 15.0, 10)]), 0.01)  # 5 % stand
    assert not shows_relief(trees, 1.0) and not shows_relief(np.array([np.nan]), 0.01)


def test_a_few_places_far_above_the_noise_are_relief_and_a_few_just_above_it_are_not():
    """The twenty-fourth sweep: 3 of 52 reference places stood 3-9 m up against a 1.03 m limit (noise 0.44 m);
    counted at the limit alone (binomial tail 0.0155 against rate p) that was "no relief", and the session's 5
    new claims, made without the objectness test, were all false. Far above the noise, where ground noise rises
    at rate p^2 or p^3, three are no chance."""
    rng = np.random.default_rng(5)
    ground = np.round(rng.normal(0.0, 0.44, 49) * 2) / 2
    assert shows_relief(np.concatenate([ground, [3.5, 6.0, 9.0]]), 0.01)
    # the same three just above the limit are what noise raises now and then
    assert not shows_relief(np.concatenate([ground, [1.1, 1.2, 1.1]]), 0.01)
    assert [relief_levels(n, 0.01) for n in (1, 52, 200, 5000)] == [2, 3, 3, 4]
    # bare ground: its highest places are noise at each level (the noise measured on a few tens of places: t)
    for n in (52, 200):
        assert sum(shows_relief(np.random.default_rng(seed).normal(0.0, 0.5, n), 0.01) for seed in range(100)) <= 3


def test_the_ground_field_is_where_the_sweep_starts(scene):
    positions, sizes, removed, a, ids_a, b, ids_b, images_a, images_b = scene
    g = ground_height_field(a.positions)
    assert abs(float(g(45.0, 45.0))) < 1.0


def test_keyframe_images_are_read_on_demand_within_a_memory_bound(tmp_path):
    import cv2

    from sosmatch.database.session_images import KeyframeImages
    from sosmatch.plugin.errors import InputError

    rng = np.random.default_rng(1)
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    roomy = KeyframeImages(tmp_path, ["f0.png", "f1.png", "f2.png"], [(32, 24)] * 3)
    tight = KeyframeImages(tmp_path, ["f0.png", "f1.png", "f2.png"], [(32, 24)] * 3, max_bytes=1)
    for k in (0, 1, 2, 0, 2):
        assert roomy[k].shape == (24, 32) and np.array_equal(roomy[k], tight[k])
    assert len(tight._cache) == 1 and len(roomy._cache) == 3
    with pytest.raises(InputError, match="f1.png.*another session"):
        KeyframeImages(tmp_path, ["f0.png", "f1.png"], [(32, 24), (64, 48)])[1]



def test_the_ground_noise_is_measured_beside_the_landmarks_when_the_references_are_all_objects():
    """A pair whose counterparts are all objects (a small map, or summer against winter, where the ground's own
    texture is segmented otherwise): no reference place lies at ground level, so the sweep's ground noise was
    unmeasurable and the objectness test let every place stand without a word (a 60 m summer-winter pair of the
    seventh new-user sweep: 46 gone and 10 new claimed, none right). The bare places beside the compared
    landmarks measure it: the moved shadow is flat again, the removed objects are still gone."""
    rng = np.random.default_rng(5)
    gx, gy = np.meshgrid(np.arange(5) * 17.0 + 11.0, np.arange(5) * 17.0 + 11.0)
    objects = np.column_stack([gx.ravel() + rng.uniform(-2, 2, 25), gy.ravel() + rng.uniform(-2, 2, 25),
                               rng.uniform(3.0, 8.0, 25)])
    shadows = np.array([[40.0, 46.0, 0.0], [44.0, 41.0, 0.0]])  # 25 in A only, 26 in B only
    positions = np.vstack([objects, shadows])
    sizes = np.concatenate([rng.uniform(1.2, 2.2, 25), np.full(2, 1.5)])
    removed = np.array([2, 8, 16, 22])
    present_a, present_b = np.ones(27, bool), np.ones(27, bool)
    present_b[removed], present_a[26], present_b[25] = False, False, False
    a, ids_a = change_session(positions, sizes, present_a, lawnmower(5, 85, 5, 85, 45, 10, 6), 1, camera=CAM)
    b, ids_b = change_session(positions, sizes, present_b, lawnmower(7, 87, 3, 83, 45, 10, 6), 2, camera=CAM)
    a = replace(a, images=render_nadir_images(a.poses, CAM, positions, sizes, present_a, 7, noise_seed=1))
    b = replace(b, images=render_nadir_images(b.poses, CAM, positions, sizes, present_b, 7, gain=0.8, offset=25.0,
                                              noise_seed=2))
    result = detect_changes(a, b, yaw_transform(0.0, (0.0, 0.0, 0.0)), ChangeParams(), 2.0)
    s_a, s_b = int(np.flatnonzero(ids_a == 25)[0]), int(np.flatnonzero(ids_b == 26)[0])
    assert (result.a.label[s_a], result.a.evidence[s_a]) == (UNSEEN, FLAT)
    assert (result.b.label[s_b], result.b.evidence[s_b]) == (UNSEEN, FLAT)
    assert all(result.a.label[int(np.flatnonzero(ids_a == o)[0])] == GONE for o in removed)
    assert result.without_ground_noise == ()
