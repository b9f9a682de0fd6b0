"""Mask description: moments in COLMAP's pixel convention, SIFT inside masks, caching helpers."""

import cv2
import numpy as np

from sosmatch.plugin.mask_features import MaskFeatures, describe_masks
from sosmatch.plugin.params import SegmentationParams
from sosmatch.plugin.segmentation.base import MaskSet


def _texture(h=240, w=320, seed=0):
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (h // 4, w // 4)).astype(np.float32)
    img = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    img = np.clip(img, 0, 255).astype(np.uint8)
    return np.repeat(img[:, :, None], 3, axis=2)


def _ellipse_mask(shape, center, axes, angle):
    m = np.zeros(shape, np.uint8)
    cv2.ellipse(m, center, axes, angle, 0, 360, 1, -1)
    return m.astype(bool)


def test_rectangle_moments_follow_colmap_convention():
    labels = np.full((50, 60), -1, np.int32)
    labels[10:20, 5:25] = 0  # 20 wide, 10 high
    labels[30:31, 40:41] = 1  # one pixel: dropped (< 3 px)
    labels[40:44, 50:52] = 2
    feats = describe_masks(_texture(50, 60), MaskSet.from_labels(labels), SegmentationParams())
    assert len(feats) == 2 and feats.mask_ids.tolist() == [0, 2]
    assert np.allclose(feats.centroids[0], [5 + 10, 10 + 5])  # centre of pixel (5, 10) is (5.5, 10.5)
    assert np.allclose(feats.centroids[1], [51.0, 42.0])
    assert np.allclose(feats.covariances[0], np.diag([(20**2 - 1) / 12, (10**2 - 1) / 12]))
    assert np.isclose(feats.sizes[0], np.sqrt((20**2 - 1) / 12))
    assert feats.areas.tolist() == [200, 8] and feats.areas.dtype == np.int64


def test_rotated_ellipse_size_and_both_representations_agree():
    shape = (200, 240)
    m1 = _ellipse_mask(shape, (120, 100), (60, 20), 30)
    m2 = _ellipse_mask(shape, (50, 50), (15, 15), 0)
    labels = np.full(shape, -1, np.int32)
    labels[m1] = 0
    labels[m2 & ~m1] = 1
    image = _texture(*shape)
    params = SegmentationParams()
    a = describe_masks(image, MaskSet.from_labels(labels), params)
    b = describe_masks(image, MaskSet.from_masks([labels == 0, labels == 1]), params)
    assert np.allclose(a.centroids, b.centroids) and np.allclose(a.covariances, b.covariances)
    assert np.array_equal(a.areas, b.areas)
    # a filled ellipse with semi-axis a has variance a^2 / 4 along it
    assert abs(a.sizes[0] - 30.0) < 0.6
    evals, evecs = np.linalg.eigh(a.covariances[0])
    major = evecs[:, 1] * np.sign(evecs[0, 1])
    assert abs(np.degrees(np.arctan2(major[1], major[0])) - 30) < 1.0  # y down, cv2 angle is clockwise
    assert np.allclose(a.centroids[0], [120.5, 100.5], atol=0.05)
    assert np.array_equal(a.sift_mask, b.sift_mask) and np.allclose(a.sift_xy, b.sift_xy)


def test_sift_inside_masks_capped_and_overlaps_duplicate():
    shape = (240, 320)
    big = np.zeros(shape, bool)
    big[20:220, 20:300] = True
    small = np.zeros(shape, bool)
    small[60:180, 80:200] = True  # inside `big`: its keypoints belong to both masks
    params = SegmentationParams(max_sift_per_mask=100000, sift_max_side=0)
    masks = MaskSet.from_masks([big, small], scores=[0.9, 0.5])
    f = describe_masks(_texture(*shape), masks, params)
    assert f.scores.dtype == np.float32 and np.allclose(f.scores, [0.9, 0.5])
    n_big, n_small = np.bincount(f.sift_mask, minlength=2)
    assert n_small > 10 and n_big > n_small
    for k, m in enumerate([big, small]):
        xy, desc = f.sift_of(k)
        cols, rows = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
        assert m[rows, cols].all()
        assert np.allclose(np.linalg.norm(desc, axis=1), 1.0, atol=1e-4)  # RootSIFT has unit L2 norm
    # every keypoint of the small mask is also one of the big mask's (same position)
    sm = {tuple(p) for p in f.sift_of(1)[0].round(3).tolist()}
    bg = {tuple(p) for p in f.sift_of(0)[0].round(3).tolist()}
    assert sm <= bg
    capped = describe_masks(_texture(*shape), masks, SegmentationParams(max_sift_per_mask=7, sift_max_side=0))
    assert np.bincount(capped.sift_mask, minlength=2).tolist() == [7, 7]
    # the image-wide cap lowers the per-mask cap for every mask alike
    few = describe_masks(_texture(*shape), masks, SegmentationParams(sift_max_keypoints=20, sift_max_side=0))
    counts = np.bincount(few.sift_mask, minlength=2)
    assert len(np.unique(few.sift_xy, axis=0)) <= 20 and counts[0] == counts[1] >= 10


def test_downscaled_sift_lands_at_the_same_places():
    shape = (480, 640)
    img = np.zeros(shape + (3,), np.uint8)
    rng = np.random.default_rng(1)
    for cx, cy in rng.uniform(40, [600, 440], size=(25, 2)):
        cv2.circle(img, (int(cx), int(cy)), 6, (255, 255, 255), -1)
    masks = MaskSet.from_labels(np.zeros(shape, np.int32))
    full = describe_masks(img, masks, SegmentationParams(sift_max_side=0, max_sift_per_mask=10000))
    half = describe_masks(img, masks, SegmentationParams(sift_max_side=320, max_sift_per_mask=10000))
    assert len(half.sift_xy) > 10
    # each blob keypoint found at half resolution lies near one found at full resolution
    d = np.linalg.norm(half.sift_xy[:, None] - full.sift_xy[None], axis=2).min(axis=1)
    assert np.median(d) < 1.5


def test_npz_round_trip_subset_and_empty(tmp_path):
    shape = (120, 160)
    labels = np.full(shape, -1, np.int32)
    labels[10:60, 10:70] = 0
    labels[70:110, 20:60] = 1
    labels[20:100, 90:150] = 2
    f = describe_masks(_texture(*shape), MaskSet.from_labels(labels), SegmentationParams(sift_max_side=0))
    np.savez(tmp_path / "f.npz", **f.to_npz_dict())
    g = MaskFeatures.from_npz_dict(np.load(tmp_path / "f.npz"))
    for name, value in f.to_npz_dict().items():
        assert np.array_equal(getattr(g, name), value) and getattr(g, name).dtype == value.dtype
    s = f.subset([2, 0])
    assert len(s) == 2 and np.allclose(s.centroids, f.centroids[[2, 0]])
    assert np.array_equal(s.sift_of(0)[1], f.sift_of(2)[1]) and np.array_equal(s.sift_of(1)[0], f.sift_of(0)[0])
    assert set(s.sift_mask.tolist()) <= {0, 1}
    empty = describe_masks(_texture(*shape), MaskSet.empty(shape), SegmentationParams())
    assert len(empty) == 0 and empty.sift_desc.shape == (0, 128)
    assert len(MaskFeatures.from_npz_dict(empty.to_npz_dict())) == 0


def test_detection_beside_the_backend_gives_the_same_description():
    """`segment_and_describe` (SIFT detection in a thread, mask applied afterwards) == backend + describe_masks
    (both at full size and at a downscaled SIFT resolution); a detection of another image size is refused."""
    import pytest

    from sosmatch.plugin.mask_features import detect_sift, segment_and_describe

    image = _texture(300, 400, seed=3)
    labels = np.full(image.shape[:2], -1, np.int32)
    labels[_ellipse_mask(labels.shape, (120, 140), (70, 40), 20)] = 0
    labels[_ellipse_mask(labels.shape, (290, 160), (50, 60), -10)] = 1
    masks = MaskSet.from_labels(labels)
    for side in (0, 240):
        params = SegmentationParams(sift_max_side=side, max_sift_per_mask=40)
        ref = describe_masks(image, masks, params)
        got_masks, got = segment_and_describe(image, lambda im: masks, params)
        assert got_masks is masks
        assert len(ref.sift_xy) > 20
        for name in ("centroids", "sift_xy", "sift_desc", "sift_mask", "mask_ids"):
            assert np.array_equal(getattr(ref, name), getattr(got, name)), name
        # keypoints outside both masks were found by the whole-image detection but are not described
        assert len(detect_sift(image, params).keypoints) > len(np.unique(ref.sift_xy, axis=0))
    with pytest.raises(ValueError, match="SIFT detection"):
        describe_masks(image, masks, params, detect_sift(image[:200], params))


def test_images_other_than_8_bit_are_refused_not_cast():
    # a cast kept a 16-bit value's low byte and zeroed a 0..1 float: no SIFT and no error (rev50 D6); the CLI reads
    # every image to 8 bits by the flight's white level (database.images.to_rgb_u8)
    import pytest

    from sosmatch.plugin.mask_features import to_gray_u8
    from sosmatch.plugin.segmentation.classical import segment_classical

    image = _texture()
    masks = MaskSet.from_masks([np.ones(image.shape[:2], bool)])
    for other in (image.astype(np.uint16) * 256, image.astype(np.float32) / 255):
        with pytest.raises(ValueError, match=f"image dtype {other.dtype}: expected uint8"):
            describe_masks(other, masks, SegmentationParams())
        with pytest.raises(ValueError, match="expected uint8"):
            to_gray_u8(other)
        with pytest.raises(ValueError, match="expected uint8"):
            segment_classical(other)
    rgba = np.concatenate([image, np.full(image.shape[:2] + (1,), 255, np.uint8)], axis=2)
    with pytest.raises(ValueError, match=r"shape \(240, 320, 4\)"):
        segment_classical(rgba)
    assert len(describe_masks(image, masks, SegmentationParams()).sift_mask) > 0


def test_label_images_of_any_integer_dtype_and_sparse_labels():
    import pytest

    rng = np.random.default_rng(0)
    labels = rng.integers(0, 5, (60, 80))
    ref = MaskSet.from_labels(labels.astype(np.int32))
    # unsigned label images raised OverflowError (max with initial=-1); they have no background: 0 is a label
    for dtype in (np.uint8, np.uint16, np.uint32, np.uint64):
        assert np.array_equal(MaskSet.from_labels(labels.astype(dtype)).labels, ref.labels)
    # a label far beyond the pixel count asked bincount for 64 GiB: renumbered alike
    sparse = np.where(labels == 4, 2**33, labels)
    sparse[0, 0] = -1
    dense = np.where(labels == 4, 4, labels)
    dense[0, 0] = -1
    got = MaskSet.from_labels(sparse)
    assert np.array_equal(got.labels, MaskSet.from_labels(dense).labels) and len(got) == 5
    with pytest.raises(ValueError, match="NaN"):
        MaskSet.from_labels(np.where(labels == 0, np.nan, labels))


def test_no_masks_need_the_image_shape():
    import pytest

    image = _texture(60, 80)
    with pytest.raises(ValueError, match="give the image's shape"):
        MaskSet.from_masks([])
    none = MaskSet.from_masks([], shape=(60, 80))
    assert none.shape == (60, 80) and len(describe_masks(image, none, SegmentationParams())) == 0
    with pytest.raises(ValueError, match=r"mask 1 has shape \(60, 81\)"):
        MaskSet.from_masks([np.ones((60, 80), bool), np.ones((60, 81), bool)])
