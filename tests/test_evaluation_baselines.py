"""RANSAC baselines find the match between two overlapping (warped) images and not between unrelated ones."""

import cv2
import numpy as np
import pytest

from sosmatch.tools.baselines import get_backend
from sosmatch.tools.baselines.base import BaselineConfig


def _texture(seed, h=300, w=400):
    """Blobs and lines at several scales: corners for ORB, blobs for SIFT."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = rng.integers(60, 120, 3)
    for _ in range(150):
        c = tuple(int(v) for v in rng.integers(0, [w, h]))
        color = tuple(int(v) for v in rng.integers(0, 255, 3))
        if rng.random() < 0.5:
            cv2.circle(img, c, int(rng.integers(3, 20)), color, -1)
        else:
            d = tuple(int(v) for v in np.array(c) + rng.integers(-40, 40, 2))
            cv2.rectangle(img, c, d, color, -1)
    return img


def _warp(img, seed):
    rng = np.random.default_rng(seed)
    h, w = img.shape[:2]
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = src + rng.uniform(-25, 25, src.shape).astype(np.float32) + np.float32([30, 10])
    return cv2.warpPerspective(img, cv2.getPerspectiveTransform(src, dst), (w, h))


@pytest.mark.parametrize("name", ["orb_ransac", "sift_ransac"])
def test_baseline_separates_overlap_from_unrelated(name):
    backend = get_backend(name)
    config = BaselineConfig(seed=0)
    a = [_texture(1), _texture(2)]
    b = [_warp(a[0], 5), _texture(3)]
    fa, fb = backend.extract(a, config), backend.extract(b, config)
    assert fa.nbytes == sum(k.nbytes + d.nbytes for k, d in zip(fa.keypoints, fa.descriptors)) > 0
    counts, seconds = backend.match_all(fa, fb, config)
    assert counts.shape == (2, 2) and seconds >= 0
    assert counts[0, 0] >= 20  # the warped copy
    assert counts[0, 0] > 2 * max(counts[0, 1], counts[1, 0], counts[1, 1])
    again, _ = backend.match_all(fa, fb, config)
    np.testing.assert_array_equal(counts, again)  # deterministic


def test_unknown_backend():
    with pytest.raises(KeyError):
        get_backend("nope")
