"""Pose-free image matching (plugin.image_matching): features at a bounded size, matches, RANSAC models."""

import numpy as np

from sosmatch.plugin.image_matching import (
    downscale,
    fundamental_inliers,
    homography_inliers,
    orb_features,
    ratio_matches,
)


def _texture(h: int = 480, w: int = 640, seed: int = 0) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((h // 8, w // 8)).astype(np.float32)
    img = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    img += 0.5 * rng.random((h, w)).astype(np.float32)
    return np.clip(img / img.max() * 255, 0, 255).astype(np.uint8)


def test_colmap_points_follow_the_full_resolution_image():
    img = _texture(960, 1280)
    full = orb_features(img, 500)
    small = orb_features(img, 500, max_side=640)
    assert small.scale == 0.5 and full.scale == 1.0
    assert np.all(small.colmap_points >= 0) and small.colmap_points[:, 0].max() <= 1280
    # a corner found at half size and matched to the full-size image lies at the same full-resolution pixel
    m = ratio_matches(small.descriptors, full.descriptors, 0.7)
    assert len(m) > 20
    d = np.linalg.norm(small.colmap_points[m[:, 0]] - full.colmap_points[m[:, 1]], axis=1)
    assert np.median(d) < 1.5
    assert downscale(img, None)[1] == 1.0 and downscale(img, 2000)[1] == 1.0


def test_shifted_image_matches_under_both_models_and_deterministically():
    img = _texture()
    moved = np.roll(img, (12, 30), axis=(0, 1))
    fa, fb = orb_features(img, 1000), orb_features(moved, 1000)
    m = ratio_matches(fa.descriptors, fb.descriptors)
    assert len(m) > 100
    pa, pb = fa.points[m[:, 0]], fb.points[m[:, 1]]
    inl_f = fundamental_inliers(pa, pb, 1.0, seed=3)
    inl_h = homography_inliers(pa, pb, 2.0)
    assert inl_f is not None and inl_h is not None
    shift = np.median(pb[inl_f] - pa[inl_f], axis=0)
    assert np.allclose(shift, [30, 12], atol=0.5)
    assert inl_f.mean() > 0.8 and inl_h.mean() > 0.8
    # reseeded per call: the same matches give the same inliers whatever ran in between
    fundamental_inliers(pb, pa, 1.0, seed=9)
    assert np.array_equal(fundamental_inliers(pa, pb, 1.0, seed=3), inl_f)


def test_no_model_from_too_few_or_no_matches():
    assert fundamental_inliers(np.zeros((5, 2)), np.zeros((5, 2)), 1.0) is None
    assert homography_inliers(np.zeros((3, 2)), np.zeros((3, 2)), 1.0) is None
    assert len(ratio_matches(None, np.zeros((5, 32), np.uint8))) == 0
    blank = orb_features(np.zeros((100, 100), np.uint8), 100)
    assert len(blank) == 0 and blank.descriptors is None
