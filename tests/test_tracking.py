"""Segment tracker: purity and length on a synthetic nadir flight, each gate rejecting what it should, one-to-one
assignment, determinism. The scene is built here (no shared data): objects on a plane with relief, a straight
survey leg at 100 m, centroids projected with 3 px noise, sizes from radius * f / depth, SIFT descriptors as random
unit vectors per object (noisy, partially re-detected per observation), plus per-frame clutter masks. The ground
band gate (plugin/ground_band.py) at the end. Also the gates' geometry (plugin/epipolar.py) and the pair scores
(plugin/mask_scores.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sosmatch.plugin.epipolar import behind_camera, epipolar_distances, fundamental_matrix
from sosmatch.plugin.geometry import Camera, Poses, pixel_rays, project
from sosmatch.plugin.ground_band import MIN_GROUND_POINTS, band_distances, band_segments, local_ground
from sosmatch.plugin.mask_features import MaskFeatures
from sosmatch.plugin.mask_scores import desc_index, feature_scores, size_scores
from sosmatch.plugin.params import TrackingParams
from sosmatch.plugin.tracking import track_masks

CAM = Camera(640, 480, 800.0, 800.0, 320.0, 240.0)
NADIR = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # world_from_camera, looking down


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _features(xy, sizes, descs) -> MaskFeatures:
    """MaskFeatures from per-mask centroids, sizes and descriptor sets."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    k = len(xy)
    sizes = np.asarray(sizes, np.float64)
    owners = np.concatenate([np.full(len(d), i, np.int32) for i, d in enumerate(descs)] + [np.zeros(0, np.int32)])
    desc = np.concatenate([np.asarray(d, np.float32).reshape(-1, 128) for d in descs] + [np.zeros((0, 128))])
    cov = np.zeros((k, 2, 2))
    cov[:, 0, 0] = cov[:, 1, 1] = sizes**2
    return MaskFeatures(
        centroids=xy, covariances=cov, sizes=sizes, areas=np.round(np.pi * sizes**2 * 4).astype(np.int64),
        scores=np.ones(k, np.float32), sift_xy=np.repeat(xy, [len(d) for d in descs], axis=0).astype(np.float32),
        sift_desc=desc.astype(np.float32), sift_mask=owners,
    )


def _scene(seed: int = 0, n_frames: int = 40, n_objects: int = 150, clutter: int = 10, pixel_noise: float = 3.0):
    """Return (features, poses, motion_stats, labels per keyframe (object id or -1 for clutter), objects)."""
    rng = np.random.default_rng(seed)
    # objects: a jittered grid so neighbours are >= ~4 m apart (like crowns), relief up to 5 m
    gx, gy = np.meshgrid(np.arange(-40.0, 120.0, 8.0), np.arange(-32.0, 33.0, 8.0))
    pos = np.stack([gx.ravel(), gy.ravel()], 1)[:n_objects] + rng.uniform(-2.0, 2.0, (min(n_objects, gx.size), 2))
    n_obj = len(pos)
    centres = np.column_stack([pos, rng.uniform(0.0, 5.0, n_obj)])
    radii = rng.uniform(1.0, 3.5, n_obj)
    words = _unit(rng.standard_normal((n_obj, 16, 128)))
    centers = np.column_stack([np.arange(n_frames) * 2.0, np.zeros(n_frames), np.full(n_frames, 100.0)])
    poses = Poses([f"kf{i}" for i in range(n_frames)], np.repeat(NADIR[None], n_frames, 0), centers)
    feats, labels = [], []
    for t in range(n_frames):
        uv, depth = project(CAM, poses.rotations[t], poses.centers[t], centres)
        vis = np.flatnonzero((uv[:, 0] > 20) & (uv[:, 0] < 620) & (uv[:, 1] > 20) & (uv[:, 1] < 460) & (depth > 0))
        xy = uv[vis] + rng.normal(0.0, pixel_noise, (len(vis), 2))
        size = radii[vis] * CAM.fx / depth[vis] * (1.0 + rng.normal(0.0, 0.02, len(vis)))
        descs = []
        for o in vis:
            pick = rng.choice(16, size=10, replace=False)  # ~60% of each object's features re-detected
            descs.append(_unit(words[o, pick] + rng.normal(0.0, 0.03, (10, 128))))
        c_xy = rng.uniform([20, 20], [620, 460], (clutter, 2))
        c_size = rng.uniform(5.0, 30.0, clutter)
        c_desc = [_unit(rng.standard_normal((6, 128))) for _ in range(clutter)]
        order = rng.permutation(len(vis) + clutter)  # masks come in no particular order
        all_xy = np.concatenate([xy, c_xy])[order]
        all_size = np.concatenate([size, c_size])[order]
        all_desc = [(descs + c_desc)[i] for i in order]
        feats.append(_features(all_xy, all_size, all_desc))
        labels.append(np.concatenate([vis, np.full(clutter, -1)])[order])
    mu = 2.0 * CAM.fx / 100.0  # pixel motion of the ground for a 2 m step at ~100 m
    motion = [(0.0, 0.0)] + [(mu, 0.3)] * (n_frames - 1)
    return feats, poses, motion, labels


def _purity_and_lengths(result, labels):
    """Observation-weighted purity over tracks with >= 2 observations, and per object its longest track."""
    pure = total = 0
    longest: dict[int, int] = {}
    for tid in range(result.num_tracks):
        kf, mk = result.observations(tid)
        lab = np.array([labels[k][m] for k, m in zip(kf, mk)])
        assert len(np.unique(kf)) == len(kf), "a track holds at most one mask per keyframe"
        if len(lab) < 2:
            continue
        # clutter never repeats: each clutter observation is its own 'object'
        keys = [int(x) if x >= 0 else -1 - 1000 * int(k) - int(m) for x, k, m in zip(lab, kf, mk)]
        vals, counts = np.unique(keys, return_counts=True)
        pure += counts.max()
        total += len(keys)
        major = int(vals[np.argmax(counts)])
        if major >= 0:
            longest[major] = max(longest.get(major, 0), int(counts.max()))
    return pure / max(total, 1), longest


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_tracks_are_pure_and_long(scene):
    feats, poses, motion, labels = scene
    res = track_masks(feats, CAM, poses, motion, TrackingParams())
    assert res.num_tracks == len(np.unique(np.concatenate(res.track_ids)))
    assert sum(res.track_lengths()) == sum(len(f) for f in feats)
    purity, longest = _purity_and_lengths(res, labels)
    assert purity >= 0.98
    seen = np.bincount(np.concatenate([lab[lab >= 0] for lab in labels]))
    well_seen = np.flatnonzero(seen >= 6)
    assert len(well_seen) > 50
    # almost every object seen >= 6 times is followed by one track for most of its sightings
    covered = np.array([longest.get(int(o), 0) / seen[o] for o in well_seen])
    assert np.mean(covered >= 0.8) >= 0.9
    # ids increase with first sighting
    firsts = [np.min(np.flatnonzero([np.any(ids == tid) for ids in res.track_ids]))
              for tid in range(0, res.num_tracks, 37)]
    assert firsts == sorted(firsts)
    assert len(res.tracks_longer_than(5)) >= 0.5 * len(well_seen)


def test_deterministic(scene):
    feats, poses, motion, _ = scene
    a = track_masks(feats, CAM, poses, motion, TrackingParams())
    b = track_masks(feats, CAM, poses, motion, TrackingParams())
    assert a.num_tracks == b.num_tracks
    assert all(np.array_equal(x, y) for x, y in zip(a.track_ids, b.track_ids))


def test_noisy_poses_within_margin_still_track():
    """EKF-like pose error (0.3 deg attitude, 0.3 m position) must not fragment tracks at the default margin."""
    feats, poses, motion, labels = _scene(seed=1, n_frames=25)
    rng = np.random.default_rng(5)
    rots = np.stack([r @ _rot_x(a) for r, a in zip(poses.rotations, rng.normal(0, 0.3, len(poses)))])
    noisy = Poses(poses.names, rots, poses.centers + rng.normal(0, 0.3, poses.centers.shape))
    res = track_masks(feats, CAM, noisy, motion, TrackingParams())
    purity, longest = _purity_and_lengths(res, labels)
    assert purity >= 0.97
    assert np.median(list(longest.values())) >= 6


def test_fundamental_matrix_and_epipolar_gate_rejects_wrong_pose():
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(-20, 20, 30), rng.uniform(-15, 15, 30), rng.uniform(0, 5, 30)])
    centers = np.array([[0.0, 0.0, 100.0], [2.0, 0.3, 100.5]])
    rots = np.stack([NADIR, NADIR @ _rot_x(0.5)])
    poses = Poses(["a", "b"], rots, centers)
    uv0, _ = project(CAM, rots[0], centers[0], pts)
    uv1, _ = project(CAM, rots[1], centers[1], pts)
    f = fundamental_matrix(CAM, poses, 0, 1)
    h0 = np.column_stack([uv0, np.ones(30)])
    h1 = np.column_stack([uv1, np.ones(30)])
    d = epipolar_distances(CAM, poses, 0, 1, uv0, uv1)
    assert np.allclose(np.einsum("ni,ij,nj->n", h1, f, h0), 0.0, atol=1e-9)
    assert np.diag(d).max() < 1e-6
    # the same pixels with camera 1 believed rolled by another 2 degrees: ~28 px across-track error
    wrong = Poses(["a", "b"], np.stack([NADIR, rots[1] @ _rot_x(2.0)]), centers)
    dw = np.diag(epipolar_distances(CAM, wrong, 0, 1, uv0, uv1))
    assert dw.min() > TrackingParams().epipolar_margin_px
    # and the tracker keeps them apart: two frames, a perfect object each, wrong pose -> two tracks
    desc = [_unit(rng.standard_normal((8, 128))) for _ in range(30)]
    feats = [_features(uv0, np.full(30, 15.0), desc), _features(uv1, np.full(30, 15.0), desc)]
    motion = [(0.0, 0.0), (float(np.linalg.norm(uv1 - uv0, axis=1).mean()), 2.0)]
    good = track_masks(feats, CAM, poses, motion, TrackingParams())
    assert np.array_equal(good.track_ids[1], good.track_ids[0])
    bad = track_masks(feats, CAM, wrong, motion, TrackingParams())
    assert bad.num_tracks == 60


def test_zero_baseline_uses_rotation_homography():
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR @ _rot_x(1.0)]), np.array([[0.0, 0, 100], [0.0, 0, 100]]))
    pts = np.array([[3.0, 4.0, 0.0], [-10.0, 2.0, 3.0]])
    uv0, _ = project(CAM, poses.rotations[0], poses.centers[0], pts)
    uv1, _ = project(CAM, poses.rotations[1], poses.centers[1], pts)
    d = epipolar_distances(CAM, poses, 0, 1, uv0, uv1)
    assert np.diag(d).max() < 1e-6 and d[0, 1] > 50


def _pair_world(dx_px: float, size_j: float, seed: int = 3):
    """One object in keyframe 0 at the image centre and one candidate in keyframe 1 displaced by dx_px
    along the flight direction (the epipolar line), with the object's own descriptors."""
    rng = np.random.default_rng(seed)
    desc = _unit(rng.standard_normal((10, 128)))
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [2.0, 0, 100]]))
    f0 = _features([[320.0, 240.0]], [15.0], [desc])
    f1 = _features([[320.0 + dx_px, 240.0]], [size_j], [_unit(desc + rng.normal(0, 0.03, desc.shape))])
    return [f0, f1], poses


def test_motion_gate():
    params = TrackingParams(centroid_sigma_px=0.0)
    motion = [(0.0, 0.0), (16.0, 1.0)]
    feats, poses = _pair_world(-16.0, 15.0)  # ground moves backwards by 16 px: a match
    assert track_masks(feats, CAM, poses, motion, params).num_tracks == 1
    feats, poses = _pair_world(-21.0, 15.0)  # 5 sigma too far
    assert track_masks(feats, CAM, poses, motion, params).num_tracks == 2
    # unknown image motion (NaN) disables the motion gate instead of rejecting everything
    assert track_masks(feats, CAM, poses, [(0.0, 0.0), (np.nan, np.nan)], params).num_tracks == 1
    feats, poses = _pair_world(-19.5, 15.0)  # 3.5 sigma: inside theta_v = 4
    assert track_masks(feats, CAM, poses, motion, params).num_tracks == 1
    # the centroid-noise term widens the gate: 5 px off is fine with the default 3 px centroid sigma
    feats, poses = _pair_world(-21.0, 15.0)
    assert track_masks(feats, CAM, poses, motion, TrackingParams()).num_tracks == 1
    # across a gap of two keyframes the expected motion adds up
    f0, f1 = _pair_world(-32.0, 15.0)[0]
    poses3 = Poses(["a", "b", "c"], np.stack([NADIR] * 3), np.array([[0.0, 0, 100], [2.0, 0, 100], [4.0, 0, 100]]))
    res = track_masks([f0, MaskFeatures.empty(), f1], CAM, poses3, [(0, 0), (16.0, 1.0), (16.0, 1.0)], params)
    assert res.num_tracks == 1
    assert track_masks([f0, MaskFeatures.empty(), f1], CAM, poses3, [(0, 0), (16.0, 1.0), (16.0, 1.0)],
                       dataclasses.replace(params, max_track_age_keyframes=1)).num_tracks == 2


def test_size_gate_and_size_score():
    qs = size_scores(np.array([10.0]), np.array([10.0, 10.5, 11.0, 12.5]), 0.2)[0]
    assert qs[0] == pytest.approx(2.0)
    assert qs[0] > qs[1] > qs[2] > 0 and qs[3] == 0.0  # r = 0.049, 0.095, 0.222
    motion = [(0.0, 0.0), (16.0, 1.0)]
    feats, poses = _pair_world(-16.0, 15.0 * 1.25)  # r = 0.22 > theta_h
    assert track_masks(feats, CAM, poses, motion, TrackingParams()).num_tracks == 2
    feats, poses = _pair_world(-16.0, 15.0 * 1.1)
    assert track_masks(feats, CAM, poses, motion, TrackingParams()).num_tracks == 1


def test_cheirality_rejects_mirror_candidate():
    motion = [(0.0, 0.0), (16.0, 1.0)]
    feats, poses = _pair_world(+16.0, 15.0)  # right distance, wrong direction: would be a point behind the camera
    assert track_masks(feats, CAM, poses, motion, TrackingParams()).num_tracks == 2
    assert track_masks(feats, CAM, poses, motion, TrackingParams(cheirality_check=False)).num_tracks == 1
    xy = np.array([[320.0, 240.0]])
    assert behind_camera(CAM, poses, 0, 1, xy, np.array([[336.0, 240.0], [304.0, 240.0]]), 3.0).tolist() == [
        [True, False]
    ]


def test_feature_score():
    rng = np.random.default_rng(4)
    a = _unit(rng.standard_normal((12, 128)))
    b = _unit(rng.standard_normal((7, 128)))
    same = _unit(a[:8] + rng.normal(0, 0.03, (8, 128)))
    f1 = _features([[0, 0], [5, 5], [9, 9]], [5, 5, 5], [a, b, np.zeros((0, 128))])
    f2 = _features([[0, 0], [5, 5]], [5, 5], [same, b[:1]])

    qf = feature_scores(desc_index(f1), desc_index(f2), np.array([0, 1, 0, 2]), np.array([0, 0, 1, 0]), 0.8)
    assert qf[0] == pytest.approx(2 * 8 / 20)  # 8 of a's 12 re-detected: all 8 survive on both sides
    assert qf[1] < 0.15  # unrelated sets: the ratio test kills almost everything
    assert qf[2] <= 2 / 13 + 1e-9  # one unrelated descriptor: at most one mutual match
    assert qf[3] == 0.0  # a mask without SIFT features can never score


def test_hungarian_is_one_to_one():
    """Two equally good candidates for one track: exactly one is taken, the other starts a track."""
    rng = np.random.default_rng(6)
    desc = _unit(rng.standard_normal((10, 128)))
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [2.0, 0, 100]]))
    f0 = _features([[320.0, 240.0], [320.0, 300.0]], [15.0, 15.0], [desc, _unit(rng.standard_normal((10, 128)))])
    twin = [_unit(desc + rng.normal(0, 0.03, desc.shape)) for _ in range(2)]
    f1 = _features([[304.0, 240.0], [305.0, 241.0]], [15.0, 15.0], twin)
    res = track_masks([f0, f1], CAM, poses, [(0, 0), (16.0, 1.0)], TrackingParams())
    ids1 = res.track_ids[1]
    assert len(set(ids1.tolist())) == 2
    assert (ids1 == 0).sum() == 1 and res.num_tracks == 3
    kf, mk = res.observations(0)
    assert kf.tolist() == [0, 1]


def test_empty_keyframes_and_input_checks():
    poses = Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0, 100], [2.0, 0, 100]]))
    res = track_masks([MaskFeatures.empty(), MaskFeatures.empty()], CAM, poses, [(0, 0), (1, 1)], TrackingParams())
    assert res.num_tracks == 0 and len(res.track_lengths()) == 0 and len(res.tracks_longer_than(0)) == 0
    with pytest.raises(ValueError):
        track_masks([MaskFeatures.empty()], CAM, poses, [(0, 0), (1, 1)], TrackingParams())



def test_non_finite_poses_and_centroids_are_refused_naming_the_keyframe(scene):
    # a NaN camera centre made every track point NaN (twice the tracks, no error); a NaN centroid failed in an
    # eigen-solver (rev50 D5)
    feats, poses, motion, _ = scene
    feats, poses = feats[:6], poses.subset(range(6))
    bad = Poses(poses.names, poses.rotations, poses.centers.copy())
    bad.centers[4, 0] = np.nan
    with pytest.raises(ValueError, match=f"keyframe 4 \\({poses.names[4]}\\): NaN or infinite pose"):
        track_masks(feats, CAM, bad, motion[:6], TrackingParams())
    cent = feats[3].centroids.copy()
    cent[0, 1] = np.inf
    broken = list(feats)
    broken[3] = dataclasses.replace(feats[3], centroids=cent)
    with pytest.raises(ValueError, match="keyframe 3 .*NaN or infinite mask centroid"):
        track_masks(broken, CAM, poses, motion[:6], TrackingParams())

def _three_views(decoy_dx_px: float, seed: int = 5):
    """One ground object seen from three nadir keyframes 20 m apart (rays meet at ~11 degrees); in keyframe 2 a
    decoy with the object's exact descriptors sits `decoy_dx_px` further along the epipolar line than the true
    (noisier) observation."""
    rng = np.random.default_rng(seed)
    desc = _unit(rng.standard_normal((10, 128)))
    centers = np.array([[0.0, 0, 100], [20.0, 0, 100], [40.0, 0, 100]])
    poses = Poses(["a", "b", "c"], np.stack([NADIR] * 3), centers)
    obj = np.array([[30.0, 5.0, 0.0]])
    uv = [project(CAM, NADIR, c, obj)[0][0] for c in centers]
    noisy = lambda: _unit(desc + rng.normal(0, 0.08, desc.shape))  # noqa: E731
    f0 = _features([uv[0]], [15.0], [noisy()])
    f1 = _features([uv[1]], [15.0], [noisy()])
    f2 = _features([uv[2], uv[2] + [decoy_dx_px, 0.0]], [15.0, 15.0], [noisy(), desc])
    return [f0, f1, f2], poses


def test_point_transfer_gate_picks_the_observation_where_the_track_point_projects():
    feats, poses = _three_views(-25.0)
    unknown_motion = [(0.0, 0.0), (np.nan, np.nan), (np.nan, np.nan)]
    params = TrackingParams(epipolar_margin_px=12.0)
    with_gate = track_masks(feats, CAM, poses, unknown_motion, params)
    without = track_masks(feats, CAM, poses, unknown_motion, dataclasses.replace(params, point_transfer_gate=False))
    track = with_gate.track_ids[0][0]
    assert with_gate.track_ids[1][0] == track
    # the epipolar line of the last observation lets the better-scoring decoy in; the track's point does not
    assert without.track_ids[2][1] == without.track_ids[0][0] and without.track_ids[2][0] != without.track_ids[0][0]
    assert with_gate.track_ids[2][0] == track and with_gate.track_ids[2][1] != track
    # a track with a point ignores the motion gate (across flight lines the summed image motion means nothing) ...
    wrong_motion = [(0.0, 0.0), (np.nan, np.nan), (500.0, 1.0)]
    assert track_masks(feats, CAM, poses, wrong_motion, params).track_ids[2][0] == track
    # ... and rays closer than point_gate_min_ray_angle_deg leave the track on the epipolar and motion gates
    near_parallel = dataclasses.replace(params, point_gate_min_ray_angle_deg=20.0)
    assert track_masks(feats, CAM, poses, wrong_motion, near_parallel).track_ids[2][0] != track



def _two_views() -> Poses:
    return Poses(["a", "b"], np.stack([NADIR, NADIR]), np.array([[0.0, 0.0, 100.0], [20.0, 0.0, 100.0]]))


def test_segment_holds_the_points_between_the_band_heights():
    poses = _two_views()
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-20, 40, 30), rng.uniform(-20, 20, 30), rng.uniform(-3.0, 8.0, 30)])
    uv_a, _ = project(CAM, poses.rotations[0], poses.centers[0], pts)
    uv_b, _ = project(CAM, poses.rotations[1], poses.centers[1], pts)
    seg = band_segments(CAM, poses, 0, 1, uv_a, (-5.0, 10.0))
    d = band_distances(seg, uv_b)
    assert np.diag(d).max() < 1e-6  # every point between the heights lies on its segment
    # the ends are the images of the ray at the band's top and bottom
    ray = pixel_rays(CAM, uv_a[:1], poses.rotations[0])[0]
    top = poses.centers[0] + (10.0 - 100.0) / ray[2] * ray
    assert np.allclose(seg[0, 0], project(CAM, poses.rotations[1], poses.centers[1], top[None])[0][0])
    # a point on the same ray 60 m below the band projects on the epipolar line but far off the segment
    deep = poses.centers[0] + (-65.0 - 100.0) / ray[2] * ray
    uv_deep, _ = project(CAM, poses.rotations[1], poses.centers[1], deep[None])
    assert band_distances(seg[:1], uv_deep)[0, 0] > 50.0
    # a band reaching up to the camera gives no prediction (NaN), not a gate
    assert np.isnan(band_segments(CAM, poses, 0, 1, uv_a[:3], (-5.0, 150.0))).all()


def test_local_ground_is_robust_to_a_minority_of_wrong_points():
    rng = np.random.default_rng(1)
    z = np.concatenate([rng.normal(200.0, 2.0, 60), rng.uniform(-500.0, 100.0, 25)])  # 30 % wrong tracks
    lo, hi = local_ground(z, 6.0)
    # holds the ground's +-3 sigma, and the MAD, inflated by the wrong points, stays far tighter than they are
    assert 170.0 < lo < 194.0 and 206.0 < hi < 230.0
    assert local_ground(z[: MIN_GROUND_POINTS - 1], 6.0) is None
    assert local_ground(z, 0.0) is None  # off


def test_tracker_takes_the_partner_on_the_ground():
    """A survey leg at 100 m, 20 m between keyframes (160 px of image motion, reported unknown), objects on the
    ground with 0-5 m relief. Object O first seen in keyframe 5; in keyframe 6 a decoy lies on O's epipolar line
    where a point 60 m under the ground would be, with O's own descriptors (a better score than O's true mask).
    Without the band the decoy wins; with it O's track continues to its true mask."""
    rng = np.random.default_rng(4)
    n_kf = 10
    centers = np.column_stack([np.arange(n_kf) * 20.0, np.zeros(n_kf), np.full(n_kf, 100.0)])
    poses = Poses([f"kf{i}" for i in range(n_kf)], np.repeat(NADIR[None], n_kf, 0), centers)
    gx, gy = np.meshgrid(np.arange(-40.0, 240.0, 9.0), np.arange(-30.0, 31.0, 9.0))
    objects = np.column_stack([gx.ravel(), gy.ravel(), rng.uniform(0.0, 5.0, gx.size)])
    words = _unit(rng.standard_normal((len(objects), 12, 128)))
    first = {}
    per_kf = []
    for t in range(n_kf):
        uv, depth = project(CAM, poses.rotations[t], poses.centers[t], objects)
        vis = np.flatnonzero((uv[:, 0] > 10) & (uv[:, 0] < 630) & (uv[:, 1] > 10) & (uv[:, 1] < 470) & (depth > 0))
        for o in vis:
            first.setdefault(int(o), t)
        xy = uv[vis] + rng.normal(0.0, 2.0, (len(vis), 2))
        sizes = np.full(len(vis), 2.0 * CAM.fx / 100.0)
        descs = [_unit(words[o] + rng.normal(0.0, 0.1, words[o].shape)) for o in vis]
        per_kf.append([vis, xy, sizes, descs])
    o = next(k for k, t in sorted(first.items(), key=lambda kv: kv[0]) if t == 5
             and k in per_kf[6][0] and k in per_kf[7][0])
    i5 = int(np.flatnonzero(per_kf[5][0] == o)[0])
    ray = pixel_rays(CAM, per_kf[5][1][i5:i5 + 1], poses.rotations[5])[0]
    deep = poses.centers[5] + (objects[o, 2] - 60.0 - 100.0) / ray[2] * ray
    uv_deep, _ = project(CAM, poses.rotations[6], poses.centers[6], deep[None])
    vis6, xy6, sizes6, descs6 = per_kf[6]
    per_kf[6] = [np.append(vis6, -1), np.vstack([xy6, uv_deep]), np.append(sizes6, sizes6[0]),
                 descs6 + [per_kf[5][3][i5]]]  # the decoy carries exactly O's descriptors of keyframe 5
    feats = [_features(xy, sizes, descs) for _, xy, sizes, descs in per_kf]
    motion = [(0.0, 0.0)] + [(np.nan, np.nan)] * (n_kf - 1)
    base = TrackingParams(epipolar_margin_px=12.0, size_tolerance=0.5, ground_band_sigmas=6.0)

    def partner_of_o(params: TrackingParams) -> int:
        res = track_masks(feats, CAM, poses, motion, params)
        tid = res.track_ids[5][i5]
        return int(per_kf[6][0][int(np.flatnonzero(res.track_ids[6] == tid)[0])])

    assert partner_of_o(dataclasses.replace(base, ground_band_sigmas=0.0)) == -1  # the decoy
    assert partner_of_o(base) == o
