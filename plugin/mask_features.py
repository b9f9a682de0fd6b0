"""Per-mask description (SOS-Match step 3): centroid, covariance, size, area and SIFT features inside each mask.

Pixel convention: COLMAP's, the centre of the top-left pixel is (0.5, 0.5); OpenCV keypoints (centre at 0, 0)
are shifted by +0.5 on the way out.

SIFT: one OpenCV SIFT pass per image on a downscaled copy (`SegmentationParams.sift_max_side`), keypoints kept
inside the union of the masks (`segment_and_describe` runs the detection beside the backend); each keypoint is
assigned to every mask that contains its pixel and each mask keeps its `max_sift_per_mask` strongest keypoints.
Descriptors are RootSIFT (L1-normalise, square root; the result has unit L2 norm), so Euclidean distances and
Lowe's ratio test behave like the Hellinger kernel.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields, replace

import cv2
import numpy as np

from .geometry import Camera
from .landmark_size import border_sides
from .params import SegmentationParams
from .segmentation.base import MaskSet, check_image_u8


@dataclass
class MaskFeatures:
    """Description of the K masks of one image (all arrays indexed by mask, or by keypoint for `sift_*`)."""

    centroids: np.ndarray  # (K, 2) float64, COLMAP pixel convention
    covariances: np.ndarray  # (K, 2, 2) float64 pixel covariance of the mask (population, in px^2)
    sizes: np.ndarray  # (K,) float64, h = sqrt(lambda_max(covariance))
    areas: np.ndarray  # (K,) int64 pixel count
    scores: np.ndarray  # (K,) float32 backend confidence (1.0 if the backend has none)
    sift_xy: np.ndarray  # (M, 2) float32 keypoint positions, COLMAP convention
    sift_desc: np.ndarray  # (M, 128) float32 RootSIFT descriptors (unit L2 norm)
    sift_mask: np.ndarray  # (M,) int32 index of the owning mask (a keypoint in two masks appears twice)
    mask_ids: np.ndarray | None = None  # (K,) int64 index of each described mask in the input MaskSet
    # (K, 2, 2) bool [mask, axis (x, y), side (low, high)]: the sides of the real image's border that cut each mask
    # (`landmark_size.border_sides`), set by `undistort_features` whose centroids are no longer the real image's;
    # None: the centroids are the real image's own, test them there (`border_of`)
    border: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.mask_ids is None:
            self.mask_ids = np.arange(len(self.centroids), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.centroids)

    @classmethod
    def empty(cls) -> MaskFeatures:
        return cls(
            np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.float32),
            np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32), np.zeros(0, np.int32),
        )

    def sift_of(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(xy (m, 2), desc (m, 128)) of mask k."""
        sel = self.sift_mask == k
        return self.sift_xy[sel], self.sift_desc[sel]

    def to_npz_dict(self) -> dict[str, np.ndarray]:
        """Plain arrays for `np.savez` (one file per keyframe caches the description); `border` only when set."""
        return {f.name: np.asarray(getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None}

    @classmethod
    def from_npz_dict(cls, data: object) -> MaskFeatures:
        """Inverse of `to_npz_dict`; accepts a dict or an `np.load` result. Dtypes are restored."""
        dtypes = {
            "centroids": np.float64, "covariances": np.float64, "sizes": np.float64, "areas": np.int64,
            "scores": np.float32, "sift_xy": np.float32, "sift_desc": np.float32, "sift_mask": np.int32,
            "mask_ids": np.int64, "border": np.bool_,
        }
        kwargs = {}
        for name, dtype in dtypes.items():
            if name in data:
                kwargs[name] = np.asarray(data[name], dtype=dtype)
            elif name not in ("mask_ids", "border"):
                raise KeyError(f"mask features lack {name!r}")
        if "border" in kwargs:
            kwargs["border"] = kwargs["border"].reshape(-1, 2, 2)
        kwargs["centroids"] = kwargs["centroids"].reshape(-1, 2)
        kwargs["covariances"] = kwargs["covariances"].reshape(-1, 2, 2)
        kwargs["sift_xy"] = kwargs["sift_xy"].reshape(-1, 2)
        kwargs["sift_desc"] = kwargs["sift_desc"].reshape(-1, 128)
        return cls(**kwargs)

    def subset(self, indices: np.ndarray) -> MaskFeatures:
        """The masks `indices` (in that order) with their keypoints; `sift_mask` is renumbered to match."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        lut = np.full(len(self), -1, np.int64)
        lut[indices] = np.arange(len(indices))
        new_owner = lut[self.sift_mask] if len(self.sift_mask) else np.zeros(0, np.int64)
        keep = new_owner >= 0
        order = np.argsort(new_owner[keep], kind="stable")
        sel = np.flatnonzero(keep)[order]
        return MaskFeatures(
            self.centroids[indices], self.covariances[indices], self.sizes[indices], self.areas[indices],
            self.scores[indices], self.sift_xy[sel], self.sift_desc[sel],
            new_owner[sel].astype(np.int32), self.mask_ids[indices],
            None if self.border is None else self.border[indices],
        )


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 gray of an (H, W) or (H, W, 3) uint8 RGB image (ValueError for others: `check_image_u8`)."""
    check_image_u8(image)
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def mask_moments(masks: MaskSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(areas (K,) int64, centroids (K, 2) COLMAP convention, covariances (K, 2, 2)) of every mask."""
    k = len(masks)
    if k == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2))
    # OpenCV's C moments per bounding-box crop: the work is the total box area, not K passes over the image.
    m = np.array([_crop_moments(masks.crop(i)[1]) for i in range(k)], np.float64).reshape(-1, 6)
    n, m10, m01, mu20, mu11, mu02 = m.T
    safe = np.maximum(n, 1)
    boxes = masks.bboxes.astype(np.float64)
    mx = m10 / safe + boxes[:, 0]
    my = m01 / safe + boxes[:, 1]
    sxx, sxy, syy = mu20 / safe, mu11 / safe, mu02 / safe
    cent = np.stack([mx + 0.5, my + 0.5], axis=1)
    cov = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)
    return n.astype(np.int64), cent, cov


def _crop_moments(crop: np.ndarray) -> tuple[float, float, float, float, float, float]:
    mo = cv2.moments(crop.view(np.uint8), binaryImage=True)
    return mo["m00"], mo["m10"], mo["m01"], mo["mu20"], mo["mu11"], mo["mu02"]


def covariance_size(cov: np.ndarray) -> np.ndarray:
    """h = sqrt(largest eigenvalue) of (K, 2, 2) symmetric matrices, in closed form."""
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    lam = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    return np.sqrt(np.maximum(lam, 0.0))


@dataclass
class SiftDetection:
    """SIFT keypoints of a whole image, before any mask is known (see `detect_sift`)."""

    shape: tuple[int, int]  # (H, W) of the full-resolution image
    work: np.ndarray  # the (possibly downscaled) gray image SIFT ran on
    keypoints: list  # OpenCV keypoints at the working scale
    sift: cv2.SIFT
    descriptors: np.ndarray | None = None  # raw SIFT descriptors of every keypoint, when computed with them


def detect_sift(image: np.ndarray, params: SegmentationParams, with_descriptors: bool = False) -> SiftDetection:
    """SIFT detection on the whole image at `params.sift_max_side` (no mask needed).

    OpenCV applies a detection mask only after detection (KeyPointsFilter::runByPixelsMask), so detecting
    without one and filtering later gives the same keypoints; this lets detection run while the segmentation
    backend works (`segment_and_describe`). `with_descriptors`: describe every keypoint in the same pass (one
    scale-space pyramid instead of two), worth it when the detection runs beside the segmentation anyway. The
    descriptors equal a later `compute()` on the same keypoints whenever that pyramid also starts at octave -1,
    i.e. some chosen keypoint comes from it (checked bit for bit on 16 synthetic frames); otherwise they may
    differ in the last bits."""
    gray = to_gray_u8(image)
    h, w = gray.shape
    scale = min(1.0, params.sift_max_side / max(h, w)) if params.sift_max_side > 0 else 1.0
    if scale < 1.0:
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
    sift = cv2.SIFT_create(contrastThreshold=params.sift_contrast_threshold)
    if with_descriptors:
        kps, desc = sift.detectAndCompute(gray, None)
        return SiftDetection((h, w), gray, list(kps), sift, desc)
    return SiftDetection((h, w), gray, list(sift.detect(gray, None)), sift)


def _sift_in_union(det: SiftDetection, union: np.ndarray) -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
    """The detection's keypoints inside the union of the masks, filtered exactly as OpenCV's detection mask
    does (mask at the working scale by nearest neighbour, keypoint pixel (int)(pt + 0.5)).

    Returns (xy (M, 2) COLMAP convention full-image pixels, responses (M,), OpenCV keypoints, their indices in
    `det.keypoints`)."""
    h, w = det.shape
    wh, ww = det.work.shape
    mask = union
    if (wh, ww) != (h, w):
        mask = cv2.resize(union.view(np.uint8), (ww, wh), interpolation=cv2.INTER_NEAREST) > 0
    kps = det.keypoints
    index = np.arange(len(kps))
    if kps:
        pts = np.array([kp.pt for kp in kps], np.float32)
        col = np.clip((pts[:, 0] + np.float32(0.5)).astype(np.int64), 0, ww - 1)
        row = np.clip((pts[:, 1] + np.float32(0.5)).astype(np.int64), 0, wh - 1)
        index = np.flatnonzero(mask[row, col])
        kps = [kps[i] for i in index]
    xy = _keypoint_xy(kps, w / ww, h / wh)
    resp = np.array([kp.response for kp in kps], np.float32)
    return xy, resp, kps, index


def segment_and_describe(
    image: np.ndarray, backend: Callable[[np.ndarray], MaskSet], params: SegmentationParams
) -> tuple[MaskSet, MaskFeatures]:
    """`backend(image)` and `describe_masks` with the SIFT detection running in a second thread meanwhile.

    Same result as calling them one after the other; on two cores the detection's time is hidden behind the
    segmentation's (OpenCV releases the GIL)."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        future = pool.submit(detect_sift, image, params, True)
        masks = backend(image)
        detection = future.result()
    return masks, describe_masks(image, masks, params, detection)


def _keypoint_xy(kps: list, sx: float, sy: float) -> np.ndarray:
    """OpenCV keypoints at a working scale -> (M, 2) float32 COLMAP-convention full-resolution positions."""
    if not kps:
        return np.zeros((0, 2), np.float32)
    pts = np.array([kp.pt for kp in kps], np.float64)
    return np.stack([(pts[:, 0] + 0.5) * sx, (pts[:, 1] + 0.5) * sy], axis=1).astype(np.float32)


def _root_sift(desc: np.ndarray) -> np.ndarray:
    desc = desc.astype(np.float32)
    desc /= np.maximum(desc.sum(axis=1, keepdims=True), 1e-12)
    return np.sqrt(desc, out=desc)


def _assign_keypoints(xy: np.ndarray, masks: MaskSet) -> tuple[np.ndarray, np.ndarray]:
    """(keypoint index, mask index) for every (keypoint, containing mask) pair."""
    h, w = masks.shape
    col = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.floor(xy[:, 1]).astype(np.int64), 0, h - 1)
    if masks.labels is not None:
        owner = masks.labels[row, col]
        kp = np.flatnonzero(owner >= 0)
        return kp, owner[kp].astype(np.int64)
    kp_list, mask_list = [], []
    boxes = masks.boxes
    for k, crop in enumerate(masks.crops):
        x0, y0, x1, y1 = boxes[k]
        cand = np.flatnonzero((col >= x0) & (col < x1) & (row >= y0) & (row < y1))
        inside = cand[crop[row[cand] - y0, col[cand] - x0]]
        kp_list.append(inside)
        mask_list.append(np.full(len(inside), k, np.int64))
    if not kp_list:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(kp_list), np.concatenate(mask_list)


def describe_masks(
    image: np.ndarray, masks: MaskSet, params: SegmentationParams, detection: SiftDetection | None = None
) -> MaskFeatures:
    """Describe every mask of `masks` with at least `params.min_mask_area_px` pixels.

    Each mask keeps its strongest `max_sift_per_mask` SIFT keypoints; if the image would then have more than
    `sift_max_keypoints` distinct keypoints, the per-mask cap is lowered for all masks alike.

    Args:
        image: (H, W, 3) uint8 RGB or (H, W) uint8 gray, the image the masks were computed on.
        masks: the backend's masks (same H, W).
        params: segmentation parameters (`min_mask_area_px`, `max_sift_per_mask`, `sift_*`).
        detection: `detect_sift(image, params)` if already computed (e.g. while the backend ran).

    Returns:
        MaskFeatures of the kept masks, in MaskSet order; `mask_ids` maps them back to `masks`.
    """
    check_image_u8(image)
    if image.shape[:2] != masks.shape:
        raise ValueError(f"image shape {image.shape[:2]} != mask shape {masks.shape}")
    areas, cent, cov = mask_moments(masks)
    keep = np.flatnonzero(areas >= max(1, params.min_mask_area_px))
    if len(keep) == 0:
        return MaskFeatures.empty()
    if len(keep) < len(masks):
        masks = masks.subset(keep)
        areas, cent, cov = areas[keep], cent[keep], cov[keep]
    sizes = covariance_size(cov)

    if detection is None:
        detection = detect_sift(image, params)
    elif detection.shape != masks.shape:
        raise ValueError(f"SIFT detection of a {detection.shape} image for masks of {masks.shape}")
    xy, resp, kps, det_index = _sift_in_union(detection, masks.union())
    kp, owner = _assign_keypoints(xy, masks) if len(xy) else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    # Cap per mask: sort by (mask, -response) and keep the first max_sift_per_mask of each group.
    order = np.lexsort((-resp[kp], owner))
    kp, owner = kp[order], owner[order]
    if len(owner):
        first = np.searchsorted(owner, owner, side="left")
        rank = np.arange(len(owner)) - first
        cap = params.max_sift_per_mask
        if params.sift_max_keypoints > 0:
            # Bound the descriptor work per image fairly: lower the per-mask cap (the same for every mask)
            # until at most sift_max_keypoints distinct keypoints remain.
            lo, hi = 0, cap
            while lo < hi:
                mid = (lo + hi + 1) // 2
                if len(np.unique(kp[rank < mid])) <= params.sift_max_keypoints:
                    lo = mid
                else:
                    hi = mid - 1
            cap = max(lo, 1)
        sel = rank < cap
        kp, owner = kp[sel], owner[sel]
    # Descriptors only for keypoints some mask kept (one compute call; shared keypoints computed once).
    uniq, inverse = np.unique(kp, return_inverse=True)
    desc = np.zeros((len(uniq), 128), np.float32)
    if len(uniq) and detection.descriptors is not None:
        desc = _root_sift(detection.descriptors[det_index[uniq]])
    elif len(uniq):
        chosen = [kps[int(i)] for i in uniq]
        out_kps, raw = detection.sift.compute(detection.work, chosen)
        if raw is None or len(out_kps) != len(chosen):  # OpenCV keeps provided keypoints; guard anyway
            raise RuntimeError("OpenCV SIFT dropped provided keypoints")
        desc = _root_sift(raw)
    return MaskFeatures(
        centroids=cent,
        covariances=cov,
        sizes=sizes,
        areas=areas.astype(np.int64),
        scores=masks.scores.astype(np.float32),
        sift_xy=xy[kp].reshape(-1, 2),
        sift_desc=desc[inverse].reshape(-1, 128),
        sift_mask=owner.astype(np.int32),
        mask_ids=keep.astype(np.int64),
    )


def border_of(features: MaskFeatures, camera: Camera) -> np.ndarray:
    """(K, 2, 2) bool: the sides of the real image's border that cut each mask (`landmark_size.border_sides`,
    its 2-sigma extent): `features.border` when `undistort_features` set it, else tested on the centroids
    against `camera`'s image (they are that image's own)."""
    if features.border is not None:
        return features.border
    return border_sides(camera, features.centroids, features.covariances)


def undistort_features(features: MaskFeatures, camera: Camera) -> MaskFeatures:
    """The masks as `camera.pinhole()` sees them: centroids through the lens model, covariances carried by its
    Jacobian (J Sigma J^T), sizes from those; SIFT sets unchanged (tracking compares only their descriptors).
    The same object when `camera` is already a pinhole. Tracking and the geometric gates use this; the COLMAP
    database keeps the real, distorted centroids and shapes.

    Which masks the image border cuts is decided here, on the real centroids and covariances against the real
    image (`border`): the undistorted image does not fill the pinhole's rectangle (barrel distortion spreads it
    beyond, pincushion leaves its corners empty), so the same test on the undistorted masks would call whole
    masks cut and cut ones whole (k1 -0.2: 214 of 2594 masks called cut wrongly; +0.15: 765 cut ones called
    whole; BENCHMARKS.md, "The image border of a lens camera")."""
    if camera.is_pinhole or not len(features):
        return features
    border = border_of(features, camera)
    centroids = camera.undistort_points(features.centroids)
    covariances = camera.undistort_covariances(features.centroids, features.covariances)
    return replace(features, centroids=centroids, covariances=covariances, sizes=covariance_size(covariances),
                   border=border)
