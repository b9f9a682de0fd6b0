"""Masks cut by the image border read as truncated views by the tracker (`plugin.truncation`,
`TrackingParams.truncation_aware`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from sosmatch.database.colmap_db import track_associations, verify_associations
from sosmatch.plugin.geometry import Camera, Poses, project
from sosmatch.plugin.mask_features import MaskFeatures, border_of
from sosmatch.plugin.params import TrackingParams
from sosmatch.plugin.tracking import track_masks
from sosmatch.plugin.truncation import cut_masks, outward_shifts, truncated_size_scores

CAM = Camera(640, 480, 800.0, 800.0, 320.0, 240.0)
NADIR = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # world_from_camera, looking down
AWARE = TrackingParams(truncation_aware=True)  # the default since fix76
OFF = TrackingParams(truncation_aware=False)  # the tracking of before (and of the "paper" preset)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _mask(xy, sigmas, desc) -> MaskFeatures:
    """One mask at `xy` with axis standard deviations `sigmas` (px) and descriptors `desc`."""
    cov = np.diag(np.asarray(sigmas, np.float64) ** 2)[None]
    return MaskFeatures(
        centroids=np.asarray(xy, np.float64).reshape(1, 2), covariances=cov, sizes=np.array([max(sigmas)], float),
        areas=np.array([100]), scores=np.ones(1, np.float32),
        sift_xy=np.repeat(np.asarray(xy, np.float32).reshape(1, 2), len(desc), axis=0),
        sift_desc=np.asarray(desc, np.float32), sift_mask=np.zeros(len(desc), np.int32),
    )


def _crown(seed: int = 1):
    rng = np.random.default_rng(seed)
    desc = _unit(rng.standard_normal((10, 128)))
    return desc, lambda: _unit(desc + rng.normal(0, 0.03, desc.shape))


def _edge_pair(cut_desc=None):
    """A crown whole in keyframe 0 (sigma 15 px, 2 px inside the left border) and, 4 m further (32 px of image
    motion), cut by the left border in keyframe 1: size 0.6 of the whole view's, centroid 10 px inward."""
    desc, noisy = _crown()
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [4.0, 0, 100]]))
    f0 = _mask([32.0, 240.0], [15.0, 15.0], noisy())
    f1 = _mask([10.0, 240.0], [6.0, 9.0], noisy() if cut_desc is None else cut_desc)
    return [f0, f1], poses, [(0.0, 0.0), (32.0, 1.0)]


def test_cut_masks_and_their_outward_box():
    feats, _, _ = _edge_pair()
    assert cut_masks(CAM, feats[0]).tolist() == [False] and cut_masks(CAM, feats[1]).tolist() == [True]
    # the object's half-extent (2 x 15) less the visible part's (2 x 6), towards the left border; nothing along y
    shift = outward_shifts(border_of(feats[1], CAM), feats[1].covariances, np.array([15.0]))
    assert np.allclose(shift, [[-18.0, 0.0]])
    assert np.allclose(outward_shifts(border_of(feats[0], CAM), feats[0].covariances, np.array([15.0])), 0.0)


def test_size_gate_is_one_sided_against_a_whole_view():
    qs = truncated_size_scores(np.array([15.0, 15.0]), np.array([True, False]), np.array([9.0, 15.0, 25.0]),
                               np.array([True, False, True]), 0.2)
    assert qs[0, 0] == 2.0  # a cut view smaller than the whole one: explained
    assert qs[0, 1] == 2.0 and qs[0, 2] == 0.0  # whole vs whole as before; a cut view larger: refused
    assert qs[1, 0] == 2.0 and qs[1, 1] == 2.0  # a lower bound: a cut view, a larger whole one
    assert truncated_size_scores(np.array([15.0]), np.array([False]), np.array([9.0]), np.array([False]),
                                 0.2)[0, 0] == 0.0  # a whole view smaller than a lower bound: refused


def test_crown_cut_by_the_border_is_linked_only_when_truncation_aware():
    feats, poses, motion = _edge_pair()
    assert track_masks(feats, CAM, poses, motion, OFF).num_tracks == 2  # size r 0.5 > theta_h
    assert track_masks(feats, CAM, poses, motion, AWARE).num_tracks == 1


def test_another_object_cut_by_the_border_is_still_refused():
    other = _unit(np.random.default_rng(9).standard_normal((10, 128)))
    feats, poses, motion = _edge_pair(cut_desc=other)
    assert track_masks(feats, CAM, poses, motion, AWARE).num_tracks == 2


def _three_views(cut_xy, cut_sigmas):
    """A ground crown at x = 0 seen whole from keyframes 0 and 20 m on (its rays meet at 11 degrees: the track has
    a point) and, 40 m on, where it projects onto the left border, as a cut mask at `cut_xy`."""
    desc, noisy = _crown(3)
    centers = np.array([[0.0, 0, 100], [20.0, 0, 100], [40.0, 0, 100]])
    poses = Poses(["a", "b", "c"], np.stack([NADIR] * 3), centers)
    feats = [_mask([320.0, 240.0], [15.0, 15.0], noisy()), _mask([160.0, 240.0], [15.0, 15.0], noisy()),
             _mask(cut_xy, cut_sigmas, noisy())]
    return feats, poses, [(0.0, 0.0), (np.nan, np.nan), (np.nan, np.nan)]


def test_point_transfer_accepts_the_centroid_in_the_outward_box_only():
    params = dataclasses.replace(AWARE, epipolar_margin_px=6.0)
    # the point projects onto the border (0, 240); the cut view's centroid lies 10 px inward: in the box
    feats, poses, motion = _three_views([10.0, 240.0], [6.0, 9.0])
    assert track_masks(feats, CAM, poses, motion, params).num_tracks == 1
    assert track_masks(feats, CAM, poses, motion, dataclasses.replace(params, truncation_aware=False)).num_tracks == 2
    # 25 px inward with a visible extent (2 x 13 px) nearly the object's: the truncation explains 4 px, not 25
    feats, poses, motion = _three_views([25.0, 240.0], [13.0, 9.0])
    assert track_masks(feats, CAM, poses, motion, params).num_tracks == 2


def test_track_point_comes_from_whole_views():
    """A view cut by the border does not enter the track's point: with it, the track's third view (cut, its
    centroid 10 px inward) would pull the point off, and a whole fourth view of the same crown, seen where the
    whole views put it, would no longer pass the point-transfer gate."""
    desc, noisy = _crown(5)
    # flight along -x: the crown (x = 0) enters at the right border; cut in keyframe 0, whole in 1-3
    centers = np.array([[-40.0, 0, 100], [-30.0, 0, 100], [-20.0, 0, 100], [-10.0, 0, 100]])
    poses = Poses(list("abcd"), np.stack([NADIR] * 4), centers)
    uv = [320.0 + 8.0 * (0.0 - c[0]) for c in centers]  # 640, 560, 480, 400
    feats = [_mask([uv[0] - 10.0, 240.0], [6.0, 9.0], noisy())] + [_mask([u, 240.0], [15.0, 15.0], noisy())
                                                                     for u in uv[1:]]
    motion = [(0.0, 0.0)] + [(80.0, 1.0)] * 3
    params = dataclasses.replace(AWARE, epipolar_margin_px=3.0, point_gate_min_ray_angle_deg=5.0)
    res = track_masks(feats, CAM, poses, motion, params)
    assert res.num_tracks == 1
    kf, _ = res.observations(0)
    assert kf.tolist() == [0, 1, 2, 3]


def test_database_check_of_a_cut_view_uses_its_box():
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [4.0, 0, 100]]))
    # keyframe b's mask is cut by the top border; its centroid 10 px below the epipolar line (y = 20)
    centroids = [np.array([[320.0, 20.0]]), np.array([[288.0, 30.0]])]
    pairs = {(0, 1): np.array([[0, 0]])}
    kept, removed = verify_associations(CAM, poses, centroids, pairs, 6.0)
    assert removed == 1 and not kept
    shifts = [np.zeros((1, 2)), np.array([[0.0, -20.0]])]
    kept, removed = verify_associations(CAM, poses, centroids, pairs, 6.0, shifts)
    assert removed == 0 and kept[(0, 1)].tolist() == [[0, 0]]


def _masks(items) -> MaskFeatures:
    """Several masks in one keyframe: `items` of (xy, sigmas, desc) as `_mask`."""
    parts = [_mask(*it) for it in items]

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])

    return MaskFeatures(
        centroids=cat("centroids"), covariances=cat("covariances"), sizes=cat("sizes"), areas=cat("areas"),
        scores=cat("scores"), sift_xy=cat("sift_xy"), sift_desc=cat("sift_desc"),
        sift_mask=np.concatenate([p.sift_mask + k for k, p in enumerate(parts)]).astype(np.int32),
    )


def test_database_check_keeps_the_links_the_tracker_made():
    """A crown whole near the top border in keyframe 0 (size 10 px) and cut by it in keyframe 1, its visible part
    larger (12 px: the size gate allows a cut view up to theta_h above a whole one) and 18 px inward. The tracker
    gates the link with the box of the larger size; the database's check uses the same box (the tracker's
    `shifts`) and keeps the link, where a box from the track's whole view (10 px) would drop it."""
    desc, noisy = _crown(7)
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [10.0, -5.25, 100]]))
    ground = np.array([[0.0, 26.0, 0.0]])
    uv0 = project(CAM, poses.rotations[0], poses.centers[0], ground)[0][0]  # (320, 32)
    uv1 = project(CAM, poses.rotations[1], poses.centers[1], ground)[0][0]  # (240, -10): above the frame
    feats = [_mask(uv0, [10.0, 10.0], noisy()), _mask([uv1[0], 8.0], [12.0, 5.0], noisy())]
    params = dataclasses.replace(AWARE, epipolar_margin_px=3.0)
    res = track_masks(feats, CAM, poses, [(0.0, 0.0), (np.nan, np.nan)], params)
    assert res.num_tracks == 1
    # the box the link was gated with: object size max(10, 12), towards the top border
    assert np.allclose(res.shifts[0], 0.0) and np.allclose(res.shifts[1], [[0.0, -(2 * 12.0 - 2 * 5.0)]])
    pairs = track_associations(res.track_ids, "all", 1)
    centroids = [f.centroids for f in feats]
    kept, removed = verify_associations(CAM, poses, centroids, pairs, 3.0, res.shifts)
    assert removed == 0 and kept[(0, 1)].tolist() == [[0, 0]]
    whole_box = [np.zeros((1, 2)), outward_shifts(border_of(feats[1], CAM), feats[1].covariances, np.array([10.0]))]
    assert verify_associations(CAM, poses, centroids, pairs, 3.0, whole_box)[1] == 1
    assert track_masks(feats, CAM, poses, [(0.0, 0.0), (np.nan, np.nan)], OFF).shifts is None


def test_a_cut_view_confirms_no_ground_point():
    """Eleven ground crowns seen whole from keyframes 0 and 1 (their rays meet: points on the ground) and cut by
    the left border in keyframe 2: three observations, two rays. A tree top 15 m up, seen whole from keyframes 2
    and 3, is 5.6 px off where the ground under its keyframe-2 ray would put it. Those two-ray points do not make
    a ground band (a third ray would confirm them): the tree top is linked; counted with their cut views, they
    made a band at the ground and the band gate refused it."""
    rng = np.random.default_rng(11)
    centers = np.array([[0.0, 0, 100], [4.0, 0, 100], [8.0, 0, 100], [12.0, 0, 100]])
    poses = Poses(list("abcd"), np.stack([NADIR] * 4), centers)
    ground = np.array([[-30.0, 25.0 - 5.0 * k, 0.0] for k in range(11)])  # x = -30: u 80, 48, 16 in keyframes 0-2
    descs = [_unit(rng.standard_normal((10, 128))) for _ in range(12)]
    tree = np.array([[10.0, 0.0, 15.0]])

    def uv(k, pts):
        return project(CAM, poses.rotations[k], poses.centers[k], pts)[0]

    feats = [_masks([(uv(k, ground)[i], [10.0, 10.0], descs[i]) for i in range(11)]) for k in (0, 1)]
    # cut: the visible half at the border, its centroid where the crown's is (nothing for the box to explain)
    feats.append(_masks([(uv(2, ground)[i], [9.0, 10.0], descs[i]) for i in range(11)]
                        + [(uv(2, tree)[0], [10.0, 10.0], descs[11])]))
    feats.append(_mask(uv(3, tree)[0], [10.0, 10.0], descs[11]))
    assert cut_masks(CAM, feats[2])[:11].all() and not cut_masks(CAM, feats[1]).any()
    motion = [(0.0, 0.0)] + [(np.nan, np.nan)] * 3
    params = dataclasses.replace(AWARE, epipolar_margin_px=3.0, point_gate_min_ray_angle_deg=2.0)
    res = track_masks(feats, CAM, poses, motion, params)
    assert res.num_tracks == 12  # every ground crown one track over the three keyframes
    assert res.track_ids[3][0] == res.track_ids[2][11]  # the tree top linked
