"""What the images show without the poses: the matches of one image pair (`plugin.image_matching`), in
normalised camera coordinates through the lens model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fixed_in_frame import FixedInFrame
from ..geometry import Camera
from ..image_matching import OrbFeatures, fundamental_inliers, ratio_matches
from ..params import PoseCheckParams


@dataclass(frozen=True)
class PairMatches:
    """Pose-free matches of images a and b: normalised camera coordinates (through the lens model) of the RANSAC
    inliers, the ratio-test matches they came from, and the image motion (median inlier displacement, px)."""

    a: int
    b: int
    x_a: np.ndarray
    x_b: np.ndarray
    matches: int
    flow_px: float

    @property
    def inliers(self) -> int:
        return len(self.x_a)


def match_pair(a: int, b: int, feat_a: OrbFeatures, feat_b: OrbFeatures, camera: Camera,
               params: PoseCheckParams, fixed: FixedInFrame | None = None,
               ratio: np.ndarray | None = None) -> PairMatches | None:
    """The pose-free matches of two images (None when fewer than `params.min_inliers` agree on one fundamental
    matrix): ratio test (`ratio`: its matches when already made), matches with an end in a region `fixed` in the
    image frame left out (`plugin.fixed_in_frame`, in pixels of the working size), then RANSAC on the undistorted
    pixels, the threshold given at the working size."""
    m = ratio_matches(feat_a.descriptors, feat_b.descriptors, params.ratio) if ratio is None else ratio
    if fixed is not None and len(m):
        m = m[fixed.keep(feat_a.points[m[:, 0]], feat_b.points[m[:, 1]])]
    if len(m) < params.min_inliers:
        return None
    uv_a = camera.undistort_points(feat_a.colmap_points[m[:, 0]])
    uv_b = camera.undistort_points(feat_b.colmap_points[m[:, 1]])
    ok = np.all(np.isfinite(uv_a), axis=1) & np.all(np.isfinite(uv_b), axis=1)
    uv_a, uv_b = uv_a[ok], uv_b[ok]
    inl = fundamental_inliers(uv_a, uv_b, params.ransac_px / min(feat_a.scale, feat_b.scale), seed=a * 100003 + b)
    if inl is None or int(inl.sum()) < params.min_inliers:
        return None
    pin = camera.pinhole()
    flow = float(np.median(np.linalg.norm(uv_b[inl] - uv_a[inl], axis=1)))
    return PairMatches(a, b, pin.cam_from_img(uv_a[inl]), pin.cam_from_img(uv_b[inl]), len(m), flow)
