"""Masks cut by the image border of a lens camera: decided in the real image, where the border is, and carried
beside the undistorted masks that tracking, location and sizes read (`MaskFeatures.border`). The undistorted
image does not fill the pinhole's rectangle: barrel distortion (k1 < 0) pushes the real border outward of it,
pincushion (k1 > 0) inward, so testing the undistorted masks against that rectangle calls whole masks cut and cut
masks whole."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sosmatch.plugin.geometry import Camera, Poses
from sosmatch.plugin.landmark_size import cut_by_border, nadir_size
from sosmatch.plugin.mask_features import MaskFeatures, border_of, describe_masks, undistort_features
from sosmatch.plugin.params import SegmentationParams, TriangulationParams
from sosmatch.plugin.segmentation.base import MaskSet
from sosmatch.plugin.truncation import cut_masks, joined_shifts

W, H = 320, 240


def _lens(k1: float) -> Camera:
    """The synthetic sessions' camera (`synth --width 320 --height 240 --k1 K1`)."""
    return Camera.from_colmap("SIMPLE_RADIAL", W, H, [251.15, W / 2, H / 2, k1])


def _real_masks() -> MaskFeatures:
    """Discs segmented in a real (distorted) 320 x 240 image: 0 cut by its right border near a corner (2 sigma past
    it), 1 in the centre, 2 whole near the right border (2 sigma 11 px inside it)."""
    labels = np.full((H, W), -1, np.int32)
    for i, (center, radius) in enumerate([((W - 8, H - 40), 16), ((160, 120), 15), ((W - 22, H - 60), 10)]):
        disc = np.zeros((H, W), np.uint8)
        cv2.circle(disc, center, radius, 1, -1)
        labels[disc.astype(bool)] = i
    image = np.random.default_rng(0).uniform(0, 255, (H, W, 3)).astype(np.uint8)
    return describe_masks(image, MaskSet.from_labels(labels), SegmentationParams())


@pytest.mark.parametrize("k1", [-0.2, 0.15])
def test_a_mask_is_cut_where_the_real_image_border_cuts_it(k1):
    lens = _lens(k1)
    real = _real_masks()
    assert cut_by_border(lens, real.centroids, real.covariances).tolist() == [True, False, False]
    seen = undistort_features(real, lens)
    # tracking, location and sizes read the undistorted masks through the pinhole: the same answer
    assert cut_masks(lens.pinhole(), seen).tolist() == [True, False, False]
    assert border_of(seen, lens.pinhole())[0].tolist() == [[False, True], [False, False]]  # the right side
    # the pinhole's rectangle would have said otherwise (what this guards against)
    naive = cut_by_border(lens.pinhole(), seen.centroids, seen.covariances).tolist()
    assert naive == ([True, False, True] if k1 < 0 else [False, False, False])
    # a subset keeps each mask's answer
    assert cut_masks(lens.pinhole(), seen.subset(np.array([2, 0]))).tolist() == [False, True]


def test_the_outward_box_of_a_cut_mask_points_to_the_real_border():
    """Pincushion: the undistorted mask lies inside the pinhole's rectangle, yet the real border cut it on the
    right: its box reaches outward along +x (object size 10 px: half-extent 20 px less the visible 2 sigma)."""
    lens = _lens(0.15)
    seen = undistort_features(_real_masks(), lens)
    shifts = joined_shifts(lens.pinhole(), seen, cut_masks(lens.pinhole(), seen), np.full(3, 10.0))
    sigma_x = np.sqrt(seen.covariances[0, 0, 0])
    assert shifts[0] == pytest.approx([20.0 - 2.0 * sigma_x, 0.0])
    assert np.all(shifts[1:] == 0.0)


def test_the_answer_survives_the_cache_format(tmp_path):
    lens = _lens(-0.2)
    seen = undistort_features(_real_masks(), lens)
    np.savez(tmp_path / "f.npz", **seen.to_npz_dict())
    with np.load(tmp_path / "f.npz") as data:
        back = MaskFeatures.from_npz_dict(data)
    assert np.array_equal(back.border, seen.border)
    assert "border" not in _real_masks().to_npz_dict()  # the real image's masks: tested where they are


def test_sizes_leave_out_the_views_the_real_border_cuts():
    """`nadir_size` takes the real image's answer: a view the pinhole's rectangle calls whole is left out when
    the real border cut it (the size then equals that of the whole views alone)."""
    cam = Camera(W, H, 250.0, 250.0, W / 2, H / 2)
    nadir = np.diag([1.0, -1.0, -1.0])
    centers = np.stack([np.arange(6) * 3.0, np.zeros(6), np.full(6, 100.0)], 1)
    point = np.array([7.5, 0.0, 0.0])
    rots = np.repeat(nadir[None], 6, 0)
    cents = np.array([[160.0 - 7.5 * (c[0] - 7.5), 120.0] for c in centers])
    covs = np.repeat(np.diag([25.0, 25.0])[None], 6, 0)
    covs[0] *= 0.3  # the first view's mask is a part of the object: cut, though inside the rectangle
    whole = nadir_size(cam, rots[1:], centers[1:], point, cents[1:], covs[1:])
    cut = np.array([True, False, False, False, False, False])
    assert nadir_size(cam, rots, centers, point, cents, covs, cut=cut) == pytest.approx(whole)
    assert nadir_size(cam, rots, centers, point, cents, covs) != pytest.approx(whole)


def test_a_lens_camera_needs_the_real_answer_to_locate_landmarks(tmp_path):
    from sosmatch.workflows.triangulation import triangulate_landmarks

    lens = _lens(-0.2)
    poses = Poses(["a.jpg"], np.eye(3)[None], np.zeros((1, 3)))
    with pytest.raises(ValueError, match="cut_px"):
        triangulate_landmarks(tmp_path / "missing.db", lens, poses, [np.zeros(0)], [np.zeros(0, np.int64)],
                              TriangulationParams(), centroids_px=[np.zeros((0, 2))],
                              covariances_px=[np.zeros((0, 2, 2))])
