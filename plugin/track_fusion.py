"""One landmark per object: fusing the tracks a segment tracker splits (ours; the paper triangulates every track
on its own).

A survey sees an object on 2-4 passes. The tracker follows a segment through consecutive keyframes (a track
may wait `theta_t` keyframes for a missed segment), so every pass, and every longer segmentation gap, starts a
new track, and each track becomes its own landmark. Measured on 100-frame synthetic sessions (BENCHMARKS.md,
"Split tracks"): a landmark on an object holds a median of 8 observations while the object is visible in 29
keyframes, 40-45 pairs of landmarks per map are the same object, and the common landmarks of a summer and a
winter map can vouch for 52 % of the overlapping keyframe pairs when each object keeps one landmark, against
89 % when all its pieces count. Pieces shorter than theta_n + 1 observations are not landmarks at all; after
fusion several of them are (a winter object that the segmenter misses every other frame).

Two tracks are the same object when all hold:
- they never share a keyframe (two segments of one keyframe are two regions: nested masks or neighbours,
  which a segmenter returns together; pieces of one object come one after the other);
- their points are horizontally within `radius_factor` x the larger metric size (inside each other's
  footprint; two distinct touching objects are 2 (h_1 + h_2) apart, as for duplicate suppression);
- their metric sizes agree within `size_tolerance` (relative difference r), and so do the smallest and the
  largest size of the group they would make: compared pair by pair only, groups chained past the tolerance
  (rev50 D8: 4 of 130 fused groups held members further apart in size than it);
- one point explains every observation of both: the least-squares point of the joined observations reprojects
  within `max_error_px` on average and within 2 x that everywhere (the pixel noise test COLMAP uses to merge
  tracks; drift of the poses between passes shows up here).
Clusters grow greedily, closest pairs first, and every merge re-checks the whole cluster. Deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Camera, Poses, pixel_rays, project


@dataclass(frozen=True)
class TrackPiece:
    """One triangulated track: observing keyframes (n,), observed pixels (n, 2), point (3,) and metric size."""

    keyframes: np.ndarray
    pixels: np.ndarray
    point: np.ndarray
    size_m: float


def intersect_rays(camera: Camera, poses: Poses, keyframes: np.ndarray, pixels: np.ndarray,
                   iterations: int = 3) -> np.ndarray:
    """The point of n observations: least-squares intersection of their rays, refined by Gauss-Newton on the
    pixel error (poses fixed). keyframes (n,) index `poses`; pixels (n, 2) COLMAP convention."""
    kf = np.asarray(keyframes, np.int64)
    r, c = poses.rotations[kf], poses.centers[kf]
    d = np.stack([pixel_rays(camera, pixels[i:i + 1], r[i])[0] for i in range(len(kf))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    x = np.linalg.lstsq(proj.sum(0), np.einsum("nij,nj->i", proj, c), rcond=None)[0]
    for _ in range(iterations):
        projected = _pinhole_projection(camera, r, c, x)
        if projected is None:
            break
        uv, jac = projected
        step = np.linalg.lstsq(jac.reshape(-1, 3), -(uv - pixels).ravel(), rcond=None)[0]
        x = x + step
        if np.linalg.norm(step) < 1e-4:
            break
    return x


def _pinhole_projection(camera: Camera, r: np.ndarray, c: np.ndarray, x: np.ndarray,
                        ) -> tuple[np.ndarray, np.ndarray] | None:
    """Pixels (n, 2) of point x in the pinhole cameras (rotations r (n, 3, 3) world_from_camera, centres c) and
    their Jacobians (n, 2, 3) with respect to x; None when x is behind a camera."""
    f = np.array([camera.fx, camera.fy])
    p = np.einsum("nji,nj->ni", r, x[None, :] - c)  # camera coordinates R^T (X - C)
    z = p[:, 2:3]
    if np.any(z <= 1e-9):
        return None
    rt = np.transpose(r, (0, 2, 1))  # rows of R_cw
    jac = f[None, :, None] * (rt[:, :2, :] / z[:, :, None] - p[:, :2, None] * rt[:, 2:3, :] / z[:, :, None] ** 2)
    return f * p[:, :2] / z + [camera.cx, camera.cy], jac


def point_covariance(camera: Camera, poses: Poses, keyframes: np.ndarray, point: np.ndarray,
                     sigma_px: float) -> np.ndarray:
    """(3, 3) covariance of a point triangulated from its observations in the pinhole `camera` (poses fixed) with
    independent pixel noise sigma_px: sigma^2 (J^T J)^-1 of the reprojection Jacobian; infinite when the views do
    not fix the point (behind a camera, or rays too alike)."""
    kf = np.asarray(keyframes, np.int64)
    projected = _pinhole_projection(camera, poses.rotations[kf], poses.centers[kf], np.asarray(point, np.float64))
    if projected is None:
        return np.full((3, 3), np.inf)
    jac = projected[1].reshape(-1, 3)
    info = jac.T @ jac
    if np.linalg.cond(info) > 1e12:
        return np.full((3, 3), np.inf)
    return sigma_px ** 2 * np.linalg.inv(info)


def reprojection_errors(camera: Camera, poses: Poses, keyframes: np.ndarray, pixels: np.ndarray,
                        point: np.ndarray) -> np.ndarray:
    """(n,) pixel distance between each observation and the projection of `point` (inf behind the camera)."""
    out = np.empty(len(keyframes))
    for i, k in enumerate(np.asarray(keyframes, np.int64)):
        uv, depth = project(camera, poses.rotations[k], poses.centers[k], np.asarray(point)[None])
        out[i] = np.linalg.norm(uv[0] - pixels[i]) if depth[0] > 1e-9 else np.inf
    return out


def candidate_pairs(xy: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i < j, each once, of the points xy (n, 2) within max(radii[i], radii[j]) of each other
    (at least those: callers apply their exact criterion to the pairs returned). Each point is queried with its
    own radius, so the pairs are only those some point's radius admits and memory grows with them, not with
    the largest radius: one piece of a wrong track far below the ground (a size of hundreds of metres) once set
    the radius of every piece, and 8000 pieces of 2 m over 1 km2 took 2 GB. A NaN radius admits nothing, an
    infinite one everything."""
    n = len(xy)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    from scipy.spatial import cKDTree

    # a hair wider than the radius, so that no pair the callers' own (float) comparison admits is missed
    r = np.asarray(radii, np.float64) * (1.0 + 1e-9)
    balls = cKDTree(xy).query_ball_point(xy, r)
    counts = np.fromiter((len(b) for b in balls), np.int64, n)
    i = np.repeat(np.arange(n, dtype=np.int64), counts)
    j = np.fromiter((k for b in balls for k in b), np.int64, int(counts.sum()))
    a, b = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(a[a != b] * n + b[a != b])  # a pair both radii admit comes twice
    return key // n, key % n


def fuse_tracks(pieces: list[TrackPiece], camera: Camera, poses: Poses, radius_factor: float,
                size_tolerance: float, max_error_px: float) -> list[list[int]]:
    """Groups of piece indices that are one object (module doc); every piece is in exactly one group, groups
    and their members in ascending order. `radius_factor` <= 0 returns singletons."""
    n = len(pieces)
    groups = [[i] for i in range(n)]
    if n < 2 or radius_factor <= 0:
        return groups
    xy = np.array([p.point[:2] for p in pieces])
    sizes = np.array([p.size_m for p in pieces], np.float64)
    finite = np.where(np.isfinite(sizes), sizes, 0.0)
    i, j = candidate_pairs(xy, radius_factor * finite)
    if len(i) == 0:
        return groups
    dist = np.linalg.norm(xy[i] - xy[j], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = 2.0 * np.abs(sizes[i] - sizes[j]) / (sizes[i] + sizes[j])
    ok = (dist <= radius_factor * np.maximum(finite[i], finite[j])) & (r <= size_tolerance)
    order = np.lexsort((j[ok], i[ok], dist[ok]))
    i, j = i[ok][order], j[ok][order]
    owner = np.arange(n)
    frames = [set(p.keyframes.tolist()) for p in pieces]
    low, high = finite.copy(), finite.copy()  # each group's smallest and largest size (by its first member)
    for a, b in zip(i.tolist(), j.tolist()):
        ga, gb = owner[a], owner[b]
        if ga == gb:
            continue
        fa = set().union(*(frames[k] for k in groups[ga]))
        fb = set().union(*(frames[k] for k in groups[gb]))
        if fa & fb:
            continue
        lo, hi = min(low[ga], low[gb]), max(high[ga], high[gb])
        if 2.0 * (hi - lo) / (hi + lo) > size_tolerance:  # the pairs' relative difference, of the extremes
            continue
        members = groups[ga] + groups[gb]
        kf = np.concatenate([pieces[k].keyframes for k in members])
        px = np.concatenate([pieces[k].pixels for k in members])
        point = intersect_rays(camera, poses, kf, px)
        err = reprojection_errors(camera, poses, kf, px, point)
        if not (np.mean(err) <= max_error_px and np.max(err) <= 2.0 * max_error_px):
            continue
        keep, drop = min(ga, gb), max(ga, gb)
        groups[keep] = sorted(members)
        groups[drop] = []
        low[keep], high[keep] = lo, hi
        owner[groups[keep]] = keep
    return [g for g in groups if g]
