"""The shared interface and matcher of the RANSAC baselines (the paper's configuration).

Per keyframe: up to 500 features. Per keyframe pair: brute-force cross-checked descriptor matches, the best
20 % by distance, a fundamental matrix by RANSAC (5.0 px, 2000 iterations, confidence 0.995); the score of
the pair is the RANSAC inlier count, and a threshold on it is swept for the precision-recall curve.
Determinism: the RANSAC random generator is reseeded before every pair, so a pair's count does not depend on
the order or the subset of pairs evaluated.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ...workflows.progress import progress_iter

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BaselineConfig:
    """Parameters of a RANSAC baseline (defaults: the paper's)."""

    max_features: int = 500
    best_match_fraction: float = 0.2
    ransac_threshold_px: float = 5.0
    ransac_iterations: int = 2000
    ransac_confidence: float = 0.995
    seed: int = 0
    threads: int = 0  # worker threads over keyframe pairs; 0: one per core


@dataclass
class Features:
    """Per-keyframe keypoints (N_i, 2) float32 pixels and descriptors (N_i, D) of one session."""

    keypoints: list[np.ndarray]
    descriptors: list[np.ndarray]
    norm: int  # cv2.NORM_HAMMING or cv2.NORM_L2
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def nbytes(self) -> int:
        """Map size: every keypoint (x, y float32) and descriptor (native dtype) in bytes."""
        return int(sum(k.nbytes for k in self.keypoints) + sum(d.nbytes for d in self.descriptors))


def to_gray(image: np.ndarray) -> np.ndarray:
    """uint8 grey image from RGB/BGR/grey input."""
    image = np.asarray(image)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(image.astype(np.uint8, copy=False))


def extract_with(detector: cv2.Feature2D, images: list[np.ndarray], norm: int, desc_dim: int,
                 desc_dtype: type) -> Features:
    """Run an OpenCV detector+descriptor on every image; images without features get empty arrays."""
    t0 = time.perf_counter()
    kps, descs = [], []
    for image in progress_iter(images, len(images), "features", "img", len(images) >= 50, leave=False):
        kp, desc = detector.detectAndCompute(to_gray(image), None)
        kps.append(np.array([k.pt for k in kp], dtype=np.float32).reshape(-1, 2))
        descs.append(desc if desc is not None else np.zeros((0, desc_dim), dtype=desc_dtype))
    return Features(kps, descs, norm, time.perf_counter() - t0)


def match_pair(fa: Features, i: int, fb: Features, j: int, config: BaselineConfig,
               matcher: cv2.DescriptorMatcher) -> int:
    """RANSAC inlier count of keyframe i of A against keyframe j of B (0 when fewer than 8 matches)."""
    da, db = fa.descriptors[i], fb.descriptors[j]
    if len(da) < 8 or len(db) < 8:
        return 0
    matches = matcher.match(da, db)
    if len(matches) < 8:
        return 0
    dist = np.fromiter((m.distance for m in matches), dtype=np.float32, count=len(matches))
    keep = max(8, math.ceil(config.best_match_fraction * len(matches)))
    order = np.argsort(dist, kind="stable")[:keep]
    qi = np.fromiter((matches[k].queryIdx for k in order), dtype=np.int64, count=len(order))
    ti = np.fromiter((matches[k].trainIdx for k in order), dtype=np.int64, count=len(order))
    return fundamental_inliers(fa.keypoints[i][qi], fb.keypoints[j][ti], config)


def fundamental_inliers(pa: np.ndarray, pb: np.ndarray, config: BaselineConfig) -> int:
    """RANSAC inlier count of a fundamental matrix between the matched points `pa` (N,2) and `pb` (N,2).

    0 when OpenCV finds no model: it then returns its inlier mask without writing it (uninitialised memory: 29,
    or the ones of an earlier call's freed mask), so a degenerate pair (SIFT's keypoints repeated at one spot
    with other orientations) was scored by what was in memory: evaluate's SIFT curve changed between identical
    runs (nu56 D9). The mask is also given zeroed, so no entry is ever read unwritten."""
    cv2.setRNGSeed(config.seed)
    mask = np.zeros((len(pa), 1), dtype=np.uint8)
    fundamental, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, config.ransac_threshold_px,
                                               config.ransac_confidence, config.ransac_iterations, mask=mask)
    return 0 if fundamental is None or mask is None else int(np.count_nonzero(mask))


def match_all(fa: Features, fb: Features, config: BaselineConfig | None = None) -> tuple[np.ndarray, float]:
    """Inlier-count matrix (K_a, K_b) int32 of every cross-session keyframe pair, and the search seconds.

    Rows are spread over `config.threads` worker threads (0: one per core): OpenCV releases the GIL in matching
    and RANSAC, and each pair reseeds the RNG, so the counts do not depend on the number of threads.
    """
    from concurrent.futures import ThreadPoolExecutor

    config = config or BaselineConfig()
    workers = config.threads or os.cpu_count() or 1
    out = np.zeros((len(fa.descriptors), len(fb.descriptors)), dtype=np.int32)

    def row(i: int) -> None:
        matcher = cv2.BFMatcher(fa.norm, crossCheck=True)
        for j in range(len(fb.descriptors)):
            out[i, j] = match_pair(fa, i, fb, j, config, matcher)

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(progress_iter(pool.map(row, range(len(fa.descriptors))), len(fa.descriptors), "baseline pairs", "row",
                           out.size >= 5000, leave=False))
    return out, time.perf_counter() - t0
