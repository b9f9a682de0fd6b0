"""Do the passes of a flight put the same ground at the same height? Each pass triangulates alone.

A landmark seen from two passes (flight lines, `map_quality.flight_passes`) can be triangulated twice: from the
observations of one pass only, then of the other. Both heights are of the same point on the ground, so the relief,
the slope, trees and roofs cancel exactly in their difference; what is left is triangulation noise (pixels over
the pass's own baseline) and whatever puts the two passes' poses at different heights (GPS altitude offsets
between lines, altitude drift, a tilted height error). `map_quality.pass_disagreement` compares *neighbouring*
landmarks of different passes instead, and over relief the terrain between neighbours drowns an offset of tens
of metres (nu28: heights tilted 15 deg over 150 m relief, ratio 3.2 against the limit 6).

Per pair of passes, the differences of its landmarks are averaged with weights from each single-pass
triangulation's geometry (the height's variance for a unit angular noise: long baselines count more than short
ones), the noise scale is the differences' own robust scatter (Huber), and the offset is judged by its standard
error. `judge` refuses when an offset is both far beyond its standard error and a few % of the flying height.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class PassOffset(NamedTuple):
    """The pair of passes with the largest offset that stands out of its noise (`pass_height_offset`); NaN
    without two passes sharing enough landmarks. `offset_m`: mean height of that pair's landmarks from the first
    pass minus from the second (absolute); `z`: `offset_m` over its standard error; `landmarks`: behind it."""

    offset_m: float
    z: float
    landmarks: int


def single_pass_heights(rays: np.ndarray, centers: np.ndarray, point: np.ndarray,
                        min_base_ratio: float = 0.0) -> tuple[float, float]:
    """(height, variance of the height for unit angular noise) of the point nearest to rays from `centers`
    (n, 3) along directions `rays` (n, 3), weighted by 1 / range^2 (the ranges to `point`, the map's landmark):
    an angular error moves a ray by range x angle at the point. (NaN, inf) for parallel rays, a point behind a
    camera, or a baseline (the centres' widest distance) under `min_base_ratio` x the mean range."""
    if not (np.all(np.isfinite(rays)) and np.all(np.isfinite(centers)) and np.all(np.isfinite(point))):
        return float("nan"), float("inf")  # a pixel the lens model cannot lift (rev21: eigvalsh raised on NaN)
    d = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    rng = np.linalg.norm(point - centers, axis=1)
    base = float(np.max(np.linalg.norm(centers[:, None] - centers[None], axis=2)))
    if base < min_base_ratio * float(np.mean(rng)):
        return float("nan"), float("inf")
    w = 1.0 / np.maximum(rng, 1e-9) ** 2
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # (n, 3, 3) onto the plane across each ray
    a = np.einsum("n,nij->ij", w, proj)
    b = np.einsum("n,nij,nj->i", w, proj, centers)
    evals = np.linalg.eigvalsh(a)
    if not np.all(np.isfinite(evals)) or evals[0] <= 1e-6 * evals[-1]:
        return float("nan"), float("inf")
    cov = np.linalg.inv(a)
    x = cov @ b
    if np.any(np.einsum("ij,ij->i", x - centers, d) <= 0):
        return float("nan"), float("inf")
    return float(x[2]), float(cov[2, 2])


def _huber_mean(diff: np.ndarray, weight: np.ndarray, k: float = 1.5, iterations: int = 20) -> tuple[float, float]:
    """(robust weighted mean, its standard error) of `diff` with inverse-variance weights known up to one scale,
    the scale taken from the standardised residuals' MAD (Huber's M-estimator of location)."""
    sw = np.sqrt(weight)
    mean = float(np.median(diff))
    scale = 1.0
    h = np.ones_like(diff)
    for _ in range(iterations):
        r = (diff - mean) * sw
        scale = 1.4826 * float(np.median(np.abs(r))) + 1e-12
        u = np.abs(r) / scale
        h = np.where(u <= k, 1.0, k / np.maximum(u, 1e-12))
        new = float(np.sum(h * weight * diff) / np.sum(h * weight))
        if abs(new - mean) < 1e-9 * (1.0 + abs(mean)):
            mean = new
            break
        mean = new
    return mean, scale / float(np.sqrt(np.sum(h * weight)))


def pass_height_offset(observed_keyframes: list[np.ndarray], rays: list[np.ndarray], positions: np.ndarray,
                       centers: np.ndarray, passes: np.ndarray, min_landmarks: int = 8,
                       margin: float = 5.0, min_base_ratio: float = 0.3) -> PassOffset:
    """The offset in height between the passes' own triangulations of their common landmarks (module doc).

    Args:
        observed_keyframes: per landmark, the keyframe indices observing it; rays: per landmark, (n, 3) world
            directions of those observations (`geometry.pixel_rays`); positions: (L, 3) the map's landmarks.
        centers: (K, 3) keyframe centres; passes: (K,) pass number of every keyframe.
        min_landmarks: a pair of passes needs this many landmarks triangulated by both (two observations each).
        margin: the pair reported is, among those whose offset exceeds `margin` standard errors, the one
            furthest apart in metres; without such a pair, the one with the largest |offset| - margin x SE (then
            `z` <= margin).
        min_base_ratio: a pass's height of a landmark counts only from a baseline of at least this many times its
            range (base-to-height ratio). The frames' attitude errors are shared by all the landmarks a pass
            sees, so they do not average out, and they grow into height by range / base: nu28's EKF poses (within
            0.4 m of the truth in height) put the short turn legs (13-21 m at 107 m, ratio ~0.15) 8-18 m off the
            lines, while lines agreed to 0.3-2 m (ratios 0.5-1).
    """
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    passes = np.asarray(passes, np.int64)
    by_pair: dict[tuple[int, int], list[tuple[float, float]]] = {}
    for i, kfs in enumerate(observed_keyframes):
        kfs = np.asarray(kfs, np.int64)
        own = passes[kfs]
        heights = {}
        for k in np.unique(own):
            sel = own == k
            if np.count_nonzero(sel) >= 2:
                z, var = single_pass_heights(np.asarray(rays[i], np.float64)[sel], c[kfs[sel]], p[i],
                                             min_base_ratio)
                if np.isfinite(z) and np.isfinite(var) and var > 0:
                    heights[int(k)] = (z, var)
        ks = sorted(heights)
        for ia, a in enumerate(ks):
            for b in ks[ia + 1:]:
                by_pair.setdefault((a, b), []).append((heights[a][0] - heights[b][0], heights[a][1] + heights[b][1]))
    # among the pairs beyond `margin` standard errors, the one furthest apart in metres (a sharper pair just under
    # the metre limit must not hide one beyond it: rev21, a third pass made a refused map acceptable); without
    # such a pair, the one closest to standing out
    best = PassOffset(float("nan"), float("nan"), 0)
    best_key = (False, -np.inf)
    for pair in sorted(by_pair):
        rows = by_pair[pair]
        if len(rows) < min_landmarks:
            continue
        diff, var = np.array(rows).T
        mean, se = _huber_mean(diff, 1.0 / var)
        significant = abs(mean) > margin * se
        key = (significant, abs(mean) if significant else abs(mean) - margin * se)
        if key > best_key:
            best_key = key
            best = PassOffset(abs(mean), abs(mean) / max(se, 1e-12), len(rows))
    return best
