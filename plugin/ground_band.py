"""The ground band gate of segment tracking (ours): with fixed poses, where a segment can reappear is predicted by
the poses and the height of the ground, not only by the image motion.

A mask centroid m_i of keyframe s is the image of a point somewhere on its ray. The epipolar gate only says that
its partner in keyframe t lies near the projection of the whole ray (the epipolar line); on a survey whose frames
are 300-550 px apart that line crosses most of the image and admits every segment along it. The objects a map is
made of stand on the ground, so the point lies between two heights, and the partner near the projection of that
stretch of the ray: an epipolar *segment*. The gate keeps a pair when m_j is within `margin_px` of the segment
(`band_distances`), so pixel noise and short baselines (where the segment shrinks to a point and the margin
decides, as the epipolar gate would) are handled in pixels, where the centroid noise is known.

The heights come from the map itself (`local_ground`): the points of the tracks that already triangulate (their
rays meet at the point gate's angle) and were seen recently, i.e. the ground under the current keyframes; the band
is their median height +- `sigmas` robust standard deviations (1.4826 x the median absolute deviation) of those
heights, which holds the local relief and the objects' heights and follows a sloping site as the flight moves on.
Wrong tracks among those points lie anywhere along their epipolar lines (hundreds of metres off); the median and
the MAD ignore them while they are a minority. Until enough points exist (`MIN_GROUND_POINTS`) there is no band
and the gate is off.

Measured on Seneca (BENCHMARKS.md, "Seneca from its JPEGs"): 72 of 165 consecutive keyframe pairs have no image
motion measurement; without the band 805 of the 1000 long tracks hold exactly 3 observations and 621 of those do
not triangulate consistently (a wrong partner along the line won the assignment), 575 database matches fail the
epipolar check and 184 landmarks remain; with it 573 long tracks, 3 failing matches, 283 landmarks (3.42 px).
The band follows the ground at +-5-20 m there; a fixed band of +-10-40 m around the true ground gives 253-288.
On synthetic sessions (2 m keyframes, motion measured) it changes little (BENCHMARKS.md).
"""

from __future__ import annotations

import numpy as np

from .geometry import Camera, Poses, pixel_rays, project
from .landmark_filters import MAD_TO_SIGMA

MIN_GROUND_POINTS = 10  # fewer triangulated track points than this give no ground estimate: no band


def local_ground(heights: np.ndarray, sigmas: float) -> tuple[float, float] | None:
    """(lowest, highest) height of the ground band from the heights (z) of triangulated track points; None when
    there are fewer than `MIN_GROUND_POINTS` finite ones or `sigmas` <= 0."""
    z = np.asarray(heights, np.float64)
    z = z[np.isfinite(z)]
    if sigmas <= 0 or len(z) < MIN_GROUND_POINTS:
        return None
    mid = float(np.median(z))
    half = sigmas * MAD_TO_SIGMA * float(np.median(np.abs(z - mid)))
    return mid - half, mid + half


def band_segments(camera: Camera, poses: Poses, s: int, t: int, xy_s: np.ndarray,
                  band: tuple[float, float]) -> np.ndarray:
    """(n, 2, 2) the two ends in image t (pixels) of the stretch of each ray of keyframe s's pixels `xy_s` between
    the band's heights; NaN rows where that stretch is not wholly in front of both cameras (a ray that does not
    descend, a band reaching up to camera s): no prediction there."""
    xy_s = np.asarray(xy_s, np.float64).reshape(-1, 2)
    out = np.full((len(xy_s), 2, 2), np.nan)
    if not len(xy_s):
        return out
    c_s = poses.centers[s]
    d = pixel_rays(camera, xy_s, poses.rotations[s])
    lo, hi = band
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_near = (hi - c_s[2]) / d[:, 2]  # the band's top is met first on a descending ray
        lam_far = (lo - c_s[2]) / d[:, 2]
    ok = np.isfinite(lam_near) & np.isfinite(lam_far) & (lam_near > 0) & (lam_far >= lam_near)
    if not ok.any():
        return out
    ends = []
    front = ok.copy()
    for lam in (lam_near, lam_far):
        pts = c_s[None, :] + np.where(ok, lam, 0.0)[:, None] * d
        uv, depth = project(camera, poses.rotations[t], poses.centers[t], pts)
        front &= np.isfinite(depth) & (depth > 1e-9)
        ends.append(uv)
    out[front, 0] = ends[0][front]
    out[front, 1] = ends[1][front]
    return out


def band_distances(segments: np.ndarray, xy_t: np.ndarray) -> np.ndarray:
    """(n, m) pixel distance of every point of `xy_t` (m, 2) to every segment of `band_segments` (n, 2, 2); NaN
    for the NaN segments."""
    a = segments[:, 0][:, None, :]  # (n, 1, 2)
    ab = (segments[:, 1] - segments[:, 0])[:, None, :]
    ap = np.asarray(xy_t, np.float64)[None, :, :] - a  # (n, m, 2)
    den = np.einsum("nmk,nmk->nm", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(den > 0, np.einsum("nmk,nmk->nm", ap, ab) / np.where(den > 0, den, 1.0), 0.0)
    u = np.clip(u, 0.0, 1.0)
    return np.linalg.norm(ap - u[:, :, None] * ab, axis=2)
