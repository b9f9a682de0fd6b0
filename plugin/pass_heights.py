"""The passes of a flight (`flight_passes`), and do they put the same ground at the same height?

Two answers, both figures of `plugin.map_quality`: `pass_disagreement` compares neighbouring landmarks seen from
different passes with neighbours seen from one; `pass_height_offset` lets each pass triangulate alone:

A landmark seen from two passes (flight lines, `flight_passes`) can be triangulated twice: from the
observations of one pass only, then of the other. Both heights are of the same point on the ground, so the relief,
the slope, trees and roofs cancel exactly in their difference; what is left is triangulation noise (pixels over
the pass's own baseline) and whatever puts the two passes' poses at different heights (GPS altitude offsets
between lines, altitude drift, a tilted height error). `pass_disagreement` compares *neighbouring*
landmarks of different passes instead, and over relief the terrain between neighbours drowns an offset of tens
of metres (nu28: heights tilted 15 deg over 150 m relief, ratio 3.2 against the limit 6).

Per pair of passes, the differences of its landmarks are averaged with weights from each single-pass
triangulation's geometry (the height's variance for a unit angular noise: long baselines count more than short
ones), the noise scale is the differences' own robust scatter (Huber), and the offset is judged by its standard
error. `map_verdict.judge` refuses when an offset is both far beyond its standard error and a few % of the flying
height.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .ground_plane import plane_height, robust_plane_normal


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


def flight_passes(centers: np.ndarray, turn_deg: float = 60.0) -> np.ndarray:
    """(K,) pass number of every keyframe: a new pass starts where the heading (the direction of travel to the
    keyframe two ahead) has turned by more than `turn_deg` from the heading at the start of the current pass
    (a lawnmower's lines, a survey's legs; a smooth free-form path every `turn_deg` of turning)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)[:, :2]
    n = len(c)
    if n < 3:
        return np.zeros(n, np.int64)
    ahead = c[np.minimum(np.arange(n) + 2, n - 1)] - c
    behind = c - c[np.maximum(np.arange(n) - 2, 0)]
    heading = np.where(np.linalg.norm(ahead, axis=1, keepdims=True) > 0, ahead, behind)
    h = np.arctan2(heading[:, 1], heading[:, 0])
    out = np.zeros(n, np.int64)
    start = h[0]
    for k in range(1, n):
        if abs(np.degrees(np.angle(np.exp(1j * (h[k] - start))))) > turn_deg:
            start = h[k]
            out[k] = out[k - 1] + 1
        else:
            out[k] = out[k - 1]
    return out


class PassDisagreement(NamedTuple):
    """`pass_disagreement`'s figures for the worst pair of passes (the largest ratio): `ratio`, the lower quartile
    of their neighbours' |dz| over that of one pass's; `offset_m`, the same two quartiles' difference in metres
    (how far apart in height the two passes put the same ground). NaN without the data."""

    ratio: float
    offset_m: float
    # the largest ratio the pairs prove: over every pair of passes, the lower confidence bound of its quartile over
    # the upper one of one pass's (`PASS_EVIDENCE_SIGMAS`). The quartiles of 20-90 neighbour pairs are noisy, and the
    # largest of several noisy ratios more so: correct EKF maps of one world and flight read 1.6-9.6 (nu38; a row of
    # parked cars, each pair at one height, halved one pass's quartile), their bounds 0.3-2.2
    ratio_low: float = float("nan")


# the confidence a pass disagreement must have to be judged, in standard deviations of the quartiles' ranks (the
# pose check judges its fits at 2 sigma too: the evidence must be clear, not a noisy figure)
PASS_EVIDENCE_SIGMAS = 2.0


def quartile_bounds(values: np.ndarray, sigmas: float = PASS_EVIDENCE_SIGMAS) -> tuple[float, float]:
    """Distribution-free confidence bounds of the lower quartile of `values`: the order statistics at ranks
    n/4 -+ `sigmas` sqrt(n 3/16) (the binomial count of values under the true quartile), clipped to the sample."""
    x = np.sort(np.asarray(values, np.float64))
    n = len(x)
    if not n:
        return float("nan"), float("nan")
    spread = sigmas * np.sqrt(n * 0.1875)
    low = int(np.clip(np.floor(0.25 * n - spread), 0, n - 1))
    high = int(np.clip(np.ceil(0.25 * n + spread), 0, n - 1))
    return float(x[low]), float(x[high])


def pass_disagreement(positions: np.ndarray, sizes_m: np.ndarray, observed_keyframes: list[np.ndarray],
                      passes: np.ndarray, neighbours: int = 8, min_pairs: int = 20) -> PassDisagreement:
    """How much more neighbouring landmarks disagree in height when two different passes of the flight saw them.

    Only landmarks seen from one pass (`flight_passes`) take part, with their heights above the map's robust
    ground plane (so a regional slope does not count). Neighbours (each landmark's `neighbours` nearest in the
    horizontal plane, duplicates of one object, closer than 2 max(h_S), left out) of the same pass were
    triangulated from one run of poses, neighbours of two passes from poses flown at different times. The ground
    does not know which pass saw it: in a consistent map both kinds of pairs differ in height alike (relief,
    objects, triangulation noise of similar views). Per pair of passes with at least `min_pairs` neighbour pairs,
    the lower quartile of |dz| (pairs on the same ground, which any map has plenty of) is divided by that of the
    same-pass pairs; the figure is the largest of these ratios: 1.0-3.5 on 32 consistent synthetic and real maps
    (the largest of up to 6 noisy ratios), while poses that disagree between passes (altitude drift, offsets
    between lines) stack the passes' landmarks at different heights (a 50 m GPS altitude drift over 100 frames:
    26; lines 30 m apart in height: 34). NaN without `min_pairs` same-pass pairs and one such pair of passes.

    The ratio is evidence that the passes, not the relief, differ; it says nothing of how much. Where one pass's
    neighbours agree to decimetres, a few metres between passes (what an EKF's scale drift along a pass does to
    triangulated depths: 2.7 m at 98 m, ratio 6.1, on world 64's summer EKF map, whose poses are 0.4-1.2 m off in
    height) make a large ratio too, so the offset in metres is returned beside it (`map_verdict.judge` weighs it
    against the flying height)."""
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    passes = np.asarray(passes, np.int64)
    pass_of = np.full(len(p), -1, np.int64)
    for i, kfs in enumerate(observed_keyframes):
        own = np.unique(passes[np.asarray(kfs, np.int64)])
        if len(own) == 1:
            pass_of[i] = own[0]
    pure = np.flatnonzero(pass_of >= 0)
    nothing = PassDisagreement(float("nan"), float("nan"))
    if len(pure) <= neighbours:
        return nothing
    from scipy.spatial import cKDTree

    q = p[pure]
    height = q[:, 2] - plane_height(robust_plane_normal(p), np.median(p, axis=0), q[:, :2])
    size = np.nan_to_num(np.asarray(sizes_m, np.float64)[pure], nan=0.0)
    _, idx = cKDTree(q[:, :2]).query(q[:, :2], k=neighbours + 1)
    i = np.repeat(np.arange(len(q)), neighbours)
    j = idx[:, 1:].ravel()
    keep = i < j  # each unordered pair once (pairs found from one side only are kept too)
    keep |= ~np.isin(j * len(q) + i, i * len(q) + j)
    keep &= np.hypot(*(q[i, :2] - q[j, :2]).T) > 2.0 * np.maximum(size[i], size[j])
    i, j = i[keep], j[keep]
    dz = np.abs(height[i] - height[j])
    a, b = pass_of[pure][i], pass_of[pure][j]
    same = a == b
    if np.count_nonzero(same) < min_pairs:
        return nothing
    base = float(np.percentile(dz[same], 25))
    base_high = quartile_bounds(dz[same])[1]
    key = np.minimum(a, b) * (int(passes.max()) + 1) + np.maximum(a, b)
    cross = [dz[~same & (key == k)] for k in np.unique(key[~same]) if np.count_nonzero(~same & (key == k)) >= min_pairs]
    if not cross:
        return nothing
    worst = max(float(np.percentile(c, 25)) for c in cross)  # the largest ratio: one base for every pair of passes
    proven = max(quartile_bounds(c)[0] for c in cross)
    return PassDisagreement(worst / max(base, 1e-9), worst - base, proven / max(base_high, 1e-9))
