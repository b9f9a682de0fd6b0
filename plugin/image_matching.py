"""Image features matched without poses: ORB keypoints at a bounded resolution, descriptor matching, and the
RANSAC models that keep only the geometrically consistent matches (OpenCV on arrays; no file I/O).

One implementation for every consumer that matches images directly: the image-motion statistics of tracking
(`plugin.motion`, cross-checked matches + homography), the tie points of the pose refinement
(`workflows.pose_refinement`, ratio test + homography) and the pose check (`plugin.pose_check`, ratio test +
fundamental matrix: the general two-view model, which keeps the matches on trees and roofs that a ground
homography drops as parallax).

Pixel conventions: `OrbFeatures.points` are OpenCV pixels of the working (possibly downscaled) image, as the
RANSAC thresholds of the callers are tuned there; `colmap_points` are COLMAP pixels of the full-resolution
image (centre of the top-left pixel at (0.5, 0.5)), which scale exactly with the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def gray_u8(img: np.ndarray) -> np.ndarray:
    """A 2-D uint8 grey image from grey, RGB or RGBA input of any numeric type (floats in [0, 1] or [0, 255])."""
    img = np.asarray(img)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a 2-D grayscale (or HxWx3) image, got shape {img.shape}")
    if img.dtype != np.uint8:
        img = img.astype(np.float64)
        if img.max(initial=0.0) <= 1.0:  # float images in [0, 1]
            img = img * 255.0
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def downscale(gray: np.ndarray, max_side: int | None) -> tuple[np.ndarray, float]:
    """`gray` resized (area interpolation) so that its longer side is at most `max_side` (None: as it is), and the
    scale factor (<= 1) that took it there."""
    scale = 1.0 if not max_side else min(1.0, float(max_side) / max(gray.shape[:2]))
    if scale >= 1.0:
        return gray, 1.0
    size = (max(1, round(gray.shape[1] * scale)), max(1, round(gray.shape[0] * scale)))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA), scale


@dataclass(frozen=True)
class OrbFeatures:
    """ORB keypoints of one image: `points` (N, 2) OpenCV pixels of the working image, `descriptors` (N, 32)
    uint8 (None without keypoints), and `scale` = working size / full size."""

    points: np.ndarray
    descriptors: np.ndarray | None
    scale: float = 1.0

    def __len__(self) -> int:
        return len(self.points)

    @property
    def colmap_points(self) -> np.ndarray:
        """The keypoints in COLMAP pixels of the full-resolution image."""
        return (self.points + 0.5) / self.scale


def orb_features(gray: np.ndarray, max_features: int, max_side: int | None = None,
                 mask: np.ndarray | None = None) -> OrbFeatures:
    """ORB features (OpenCV's defaults, `max_features` strongest) of a grey image, detected at most `max_side`
    pixels on the longer side (None: at full resolution). `mask` (uint8, any size; resized to the working image,
    nearest neighbour): features only where it is non-zero, so that a region known to be no ground (an overlay,
    `plugin.fixed_in_frame`) does not take the feature budget (ORB keeps a fixed number per pyramid level)."""
    work, scale = downscale(gray_u8(gray), max_side)
    if mask is not None and mask.shape != work.shape:
        mask = cv2.resize(np.asarray(mask, np.uint8), (work.shape[1], work.shape[0]), interpolation=cv2.INTER_NEAREST)
    keypoints, descriptors = cv2.ORB_create(int(max_features)).detectAndCompute(work, mask)
    points = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
    return OrbFeatures(points, descriptors if len(points) else None, scale)


def cross_checked_matches(desc_a: np.ndarray | None, desc_b: np.ndarray | None) -> np.ndarray:
    """(M, 2) index pairs of mutual nearest neighbours (Hamming distance), in OpenCV's order."""
    if desc_a is None or desc_b is None or not len(desc_a) or not len(desc_b):
        return np.zeros((0, 2), dtype=np.int64)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(desc_a, desc_b)
    return np.array([(m.queryIdx, m.trainIdx) for m in matches], dtype=np.int64).reshape(-1, 2)


def ratio_matches(desc_a: np.ndarray | None, desc_b: np.ndarray | None, ratio: float = 0.8) -> np.ndarray:
    """(M, 2) index pairs whose nearest neighbour (Hamming distance) is closer than `ratio` x the second nearest
    (Lowe's ratio test), in the order of `desc_a`."""
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_a, desc_b, k=2)
    return np.array([(m[0].queryIdx, m[0].trainIdx) for m in knn
                     if len(m) == 2 and m[0].distance < ratio * m[1].distance], dtype=np.int64).reshape(-1, 2)


def homography_inliers(points_a: np.ndarray, points_b: np.ndarray, ransac_px: float) -> np.ndarray | None:
    """Boolean mask of the matches (points_a[k] <-> points_b[k]) consistent with one RANSAC homography within
    `ransac_px`, or None when no homography was found. OpenCV's homography RANSAC seeds itself: deterministic."""
    if len(points_a) < 4:
        return None
    homography, mask = cv2.findHomography(np.asarray(points_a), np.asarray(points_b), cv2.RANSAC, float(ransac_px))
    if homography is None or mask is None:
        return None
    return mask.ravel().astype(bool)


def fundamental_inliers(points_a: np.ndarray, points_b: np.ndarray, ransac_px: float, seed: int = 0,
                        confidence: float = 0.999, iterations: int = 5000) -> np.ndarray | None:
    """Boolean mask of the matches consistent with one RANSAC fundamental matrix (epipolar distance within
    `ransac_px`), or None when none was found. OpenCV's fundamental-matrix RANSAC draws from the thread's global
    generator, so it is reseeded with `seed` first: the same matches give the same inliers in any call order."""
    if len(points_a) < 8:
        return None
    cv2.setRNGSeed(int(seed))
    fundamental, mask = cv2.findFundamentalMat(np.asarray(points_a, np.float64), np.asarray(points_b, np.float64),
                                               cv2.FM_RANSAC, float(ransac_px), float(confidence), int(iterations))
    if fundamental is None or mask is None or fundamental.shape != (3, 3):
        return None
    return mask.ravel().astype(bool)
