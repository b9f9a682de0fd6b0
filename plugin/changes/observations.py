"""What each session observed: its landmarks and keyframe segments (`SessionObservations`), which keyframes
should have seen a point (`in_view`), the ground under the landmarks (`ground_height_field`) and the keyframes'
ground footprints (`observed_area`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..evaluation.footprints import HeightField, footprint_polygons
from ..geometry import Camera, Poses, project
from ..multisession import Sim3

GROUND_QUANTILE = 0.2  # of the nearby landmarks' heights: below every object, robust to a few low outliers
GROUND_NEIGHBOURS = 30
GROUND_CELL_M = 10.0
FOOTPRINT_MARGIN = 2.0  # x h: an object's footprint radius (h = sqrt(lambda_max) is half a disc's radius)

@dataclass(frozen=True)
class KeyframeSegments:
    """The segments one keyframe saw (every mask, tracked or not): centroids (K, 2) in COLMAP pixels and pixel
    sizes h = sqrt(lambda_max) (K,) (NaN where unknown)."""

    centroids: np.ndarray
    sizes_px: np.ndarray


@dataclass(frozen=True)
class SessionObservations:
    """One session as change detection sees it: its landmarks and what its keyframes looked at.

    positions (N, 3) and sizes (N,) (metres, NaN unknown) of the landmarks; support (N,) their number of
    observations (ranks the landmarks of one object; None: by size); poses of the keyframes (world_from_camera)
    with one camera each; segments per keyframe (None: the session's database is not available, the segment
    evidence is then off for the other session's landmarks); tracks that no landmark holds (from the database).
    """

    positions: np.ndarray
    sizes: np.ndarray
    poses: Poses
    cameras: tuple[Camera, ...]
    segments: tuple[KeyframeSegments, ...] | None = None
    support: np.ndarray | None = None
    # the session's tracks that no landmark holds ((n, 2) rows: keyframe index, keypoint index into segments),
    # for the objects it saw but never mapped (`unmapped.unmapped_objects`); None: not available
    tracks: tuple[np.ndarray, ...] | None = None
    # the keyframes' images as grey arrays, in keyframe order (a sequence that may read them on demand; an item
    # None where unreadable); None: not available, the surface evidence is then off (`surface`)
    images: Sequence[np.ndarray | None] | None = None
    # theta_n the session's map was made with (run.json; the flight's views may have lowered the configured one,
    # `params.for_flight`); None: unknown, changes.min_views alone decides (`views_needed`)
    min_observations: int | None = None
    # the smallest mask (pixels of its cameras) its segmentation kept (`smallest_mask_area`, from run.json's
    # params): a place it looked at from so far that an object there gives a smaller mask was not seen (`in_view`);
    # 0: no limit
    smallest_mask_px: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "positions", np.asarray(self.positions, dtype=np.float64).reshape(-1, 3))
        object.__setattr__(self, "sizes", np.asarray(self.sizes, dtype=np.float64).reshape(-1))
        cams = (self.cameras,) * len(self.poses) if isinstance(self.cameras, Camera) else tuple(self.cameras)
        object.__setattr__(self, "cameras", cams)
        if len(self.sizes) != len(self.positions):
            raise ValueError(f"{len(self.positions)} positions but {len(self.sizes)} sizes")
        if len(cams) != len(self.poses):
            raise ValueError(f"{len(self.poses)} keyframes but {len(cams)} cameras")
        if self.segments is not None and len(self.segments) != len(self.poses):
            raise ValueError(f"{len(self.poses)} keyframes but {len(self.segments)} segment sets")
        if self.images is not None and len(self.images) != len(self.poses):
            raise ValueError(f"{len(self.poses)} keyframes but {len(self.images)} images")
        if self.support is not None and len(self.support) != len(self.positions):
            raise ValueError(f"{len(self.positions)} landmarks but {len(self.support)} support values")

    def views_needed(self, min_views: int) -> int:
        """How many of this session's keyframes must see a place for it to be compared: `min_views`
        (changes.min_views, theta_n + 1), at most one more than the theta_n this session's map was made with: a
        flight whose views lowered theta_n mapped landmarks from fewer views, so fewer views could have mapped one."""
        return min_views if self.min_observations is None else min(min_views, self.min_observations + 1)

    def transformed(self, t: Sim3) -> SessionObservations:
        """The same session in another frame (x' = s R x + t): landmarks, sizes and camera poses moved; pixels
        do not change under a similarity, so the segments and images stay as they are."""
        poses = Poses(list(self.poses.names), np.einsum("ij,njk->nik", t.rotation, self.poses.rotations),
                      t.apply(self.poses.centers))
        return replace(self, positions=t.apply(self.positions), sizes=self.sizes * t.scale, poses=poses)



def in_view(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
            margin_factor: float = FOOTPRINT_MARGIN, min_area_px: float = 0.0, size_tolerance: float = 0.0,
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which keyframes should have seen each point: the point in front of the camera, within the lens model's
    reach (`Camera.fold_radius`: beyond it the model turns back and puts far-away points inside the image; the
    projection is NaN there), inside the image with its footprint (radius margin_factor x h, projected) as margin
    so that a segment of it would not touch the image border, and near enough to be segmented: the largest mask
    that would still be taken for the object (a disc of radius 2 h', projected, h' the largest size within the
    size ratio `size_tolerance` of h: `changes.max_size_difference`) covers at least `min_area_px` pixels (the
    smallest mask the keyframes' segmenter keeps, `SessionObservations.smallest_mask_px`; a point of unknown size
    is not held to it). Returns (K, N) bool, (K, N, 2) pixels and (K, N) depths."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sizes = np.asarray(sizes, dtype=np.float64).reshape(-1)
    h = np.nan_to_num(sizes, nan=0.0)
    largest = _largest_size(h, size_tolerance) if size_tolerance < 2.0 else np.full_like(h, np.inf)
    k_count = len(poses)
    seen = np.zeros((k_count, len(pts)), dtype=bool)
    uv = np.zeros((k_count, len(pts), 2))
    depth = np.zeros((k_count, len(pts)))
    for k in range(k_count):
        cam = cameras[k]
        uv[k], depth[k] = project(cam, poses.rotations[k], poses.centers[k], pts)  # through the lens model
        d = depth[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = margin_factor * h * np.sqrt(cam.fx * cam.fy) / d
            # without a smallest mask every point in front is resolved: the (K, N) test is skipped
            resolved = (~np.isfinite(sizes) | (np.pi * (2.0 * largest * np.sqrt(cam.fx * cam.fy) / d) ** 2
                                               >= min_area_px)) if min_area_px > 0 else True
        u, v = uv[k, :, 0], uv[k, :, 1]
        seen[k] = (d > 0) & (u >= r) & (u <= cam.width - r) & (v >= r) & (v <= cam.height - r) & resolved
    return seen, uv, depth


def _largest_size(h: np.ndarray | float, size_tolerance: float) -> np.ndarray | float:
    """The largest size s still taken for an object of size h: r = 2 |s - h| / (s + h) <= tolerance reaches
    s = h (2 + r) / (2 - r) (a tolerance of 2 or more admits any size: the callers take no limit there)."""
    return h * (2.0 + size_tolerance) / (2.0 - size_tolerance)


def smallest_mask_area(backend: str, min_mask_area_px: float, classical_min_area_px: float) -> float:
    """The smallest mask (full-resolution pixels) a segmentation keeps: `segmentation.min_mask_area_px` for every
    backend, and the classical backend's `classical_min_area_px` too (both as scaled to the image, `for_image`,
    and to the ground resolution, `for_ground_resolution`: as a map's run.json records them)."""
    return float(max(min_mask_area_px, classical_min_area_px if backend == "classical" else 0.0))


def resolution_depth(size_m: float, camera: Camera, min_area_px: float, size_tolerance: float = 0.0) -> float:
    """The depth beyond which an object of size `size_m` (h = sqrt(lambda_max)) gives no mask of `min_area_px`
    pixels in `camera` that would be taken for it (the `in_view` limit solved for depth); inf without a limit or
    a size."""
    if not min_area_px > 0 or not np.isfinite(size_m) or size_m <= 0 or size_tolerance >= 2.0:
        return float("inf")
    largest = _largest_size(size_m, size_tolerance)
    return float(2.0 * largest * np.sqrt(camera.fx * camera.fy) * np.sqrt(np.pi / min_area_px))


def ground_height_field(points: np.ndarray, cell_m: float = GROUND_CELL_M, neighbours: int = GROUND_NEIGHBOURS,
                        quantile: float = GROUND_QUANTILE, margin_m: float = 200.0) -> HeightField:
    """A coarse ground model from landmark heights: at every node of a `cell_m` grid over the landmarks (plus
    `margin_m`, where the footprints of oblique views reach), the low plane of the `neighbours` nearest
    landmarks (`low_planes`: their `quantile` about their median slope) evaluated at the node, or where the
    node's direction leaves the landmarks' reach (constant beyond, not extrapolated). Objects stand on the
    ground and most landmarks of a survey are ground texture, so a low quantile follows the terrain; about a
    plane rather than of the heights alone, because on a slope the neighbours span metres of height and their
    low quantile is the ground downhill of the node, not under it. Bilinear in between, constant beyond."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if not len(p):
        raise ValueError("no landmarks to estimate the ground from")
    lo, hi = p[:, :2].min(0) - margin_m, p[:, :2].max(0) + margin_m
    nx = max(2, int(np.ceil((hi[0] - lo[0]) / cell_m)) + 1)
    ny = max(2, int(np.ceil((hi[1] - lo[1]) / cell_m)) + 1)
    gx, gy = np.meshgrid(lo[0] + cell_m * np.arange(nx), lo[1] + cell_m * np.arange(ny))
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    k = min(neighbours, len(p))
    _, idx = cKDTree(p[:, :2]).query(nodes, k=k)
    near = p[np.asarray(idx).reshape(-1, k)]  # (M, k, 3)
    centre = near[:, :, :2].mean(axis=1)
    offsets = near[:, :, :2] - centre[:, None, :]
    level, slope = low_planes(offsets, near[:, :, 2], quantile)
    # the plane holds within the neighbours' reach toward the node; beyond it (the margin, where the nearest
    # landmarks are those along the map's edge) its slope would extrapolate its error over a hundred metres
    off = nodes - centre
    dist = np.linalg.norm(off, axis=1)
    toward = off / np.maximum(dist, 1e-9)[:, None]
    reach = np.maximum(np.einsum("mkj,mj->mk", offsets, toward).max(axis=1), 0.0)
    off = toward * np.minimum(dist, reach)[:, None]
    z = level + np.einsum("mj,mj->m", off, slope)
    return HeightField(z.reshape(ny, nx), float(lo[0]), float(lo[1]), cell_m, cell_m)


def low_planes(offsets: np.ndarray, heights: np.ndarray, quantile: float,
               iterations: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """For M groups of k points at horizontal `offsets` (M, k, 2) from their centroid with `heights` (M, k): the
    plane z = level + slope . offset (levels (M,), slopes (M, 2)) under which the `quantile` of the points lie.

    The slope is the median regression plane's (least absolute deviations by iteratively reweighted least
    squares, vectorised over the groups): robust to the objects above the ground while they are fewer than half,
    and of the robust fits the one least shaken by the landmarks' height noise (on the nu28 maps the slope of the
    0.2 quantile plane put the flat ground 0.9 m deeper at p10). The slope toward a direction the points barely
    spread in (all of them along a line) is held at level by a ridge worth a square metre of spread. The level is
    then the `quantile` of the heights about that slope, so that a flat group gives the `quantile` of its
    heights, as a level model would."""
    d = np.asarray(offsets, dtype=np.float64)
    z = np.asarray(heights, dtype=np.float64)
    m, k = z.shape
    x = np.concatenate([np.ones((m, k, 1)), d], axis=2)  # (M, k, 3)
    ridge = np.diag([0.0, 1.0, 1.0])
    w = np.ones((m, k))
    beta = np.zeros((m, 3))
    for _ in range(iterations):
        a = np.einsum("mk,mki,mkj->mij", w, x, x) + w.sum(axis=1)[:, None, None] * ridge
        beta = np.linalg.solve(a, np.einsum("mk,mki,mk->mi", w, x, z)[..., None])[..., 0]
        r = z - np.einsum("mki,mi->mk", x, beta)
        w = 1.0 / np.maximum(np.abs(r), 0.01)  # |r| as a weighted square, the weight floored at a centimetre
    slope = beta[:, 1:]
    level = np.quantile(z - np.einsum("mkj,mj->mk", d, slope), quantile, axis=1)
    return level, slope


def below_the_ground(heights: np.ndarray, map_heights: np.ndarray, max_sigmas: float) -> np.ndarray:
    """Which heights above the ground lie lower than `max_sigmas` robust standard deviations of the map's
    landmark heights (`map_heights`; 1.4826 x their median absolute deviation) below the ground: nothing a
    camera saw lies under the ground it looked at, so such a point is a wrong triangulation, its place as wrong
    as its height. Unknown heights are not below."""
    h = np.asarray(heights, dtype=np.float64).reshape(-1)
    ref = np.asarray(map_heights, dtype=np.float64).reshape(-1)
    ref = ref[np.isfinite(ref)]
    if not len(ref):
        return np.zeros(len(h), dtype=bool)
    scale = 1.4826 * float(np.median(np.abs(ref - np.median(ref))))
    with np.errstate(invalid="ignore"):
        return np.isfinite(h) & (h < -max_sigmas * scale)


def above_the_surface(heights: np.ndarray, surface: np.ndarray, map_heights: np.ndarray, max_sigmas: float,
                      sweep_noise: float) -> np.ndarray:
    """Which heights above the ground lie higher than `max_sigmas` robust standard deviations of the map's
    landmark heights (as `below_the_ground`) above the surface their own session's images show at their place
    (`surface`, its sweep's height above the ground there), the two scatters combined with the sweep's own noise
    (`sweep_noise`, `surface.ground_sweep_noise`: a map of flat ground has landmark heights of no scatter): what a
    camera saw lies on that surface, so a point floating far above it is a wrong triangulation (a track joining
    two objects' segments), as one under the ground is. Unknown heights, surfaces or noise are not above."""
    h = np.asarray(heights, dtype=np.float64).reshape(-1)
    top = np.asarray(surface, dtype=np.float64).reshape(-1)
    ref = np.asarray(map_heights, dtype=np.float64).reshape(-1)
    ref = ref[np.isfinite(ref)]
    if not len(ref):
        return np.zeros(len(h), dtype=bool)
    scale = np.hypot(1.4826 * float(np.median(np.abs(ref - np.median(ref)))), sweep_noise)
    with np.errstate(invalid="ignore"):
        return np.isfinite(h) & np.isfinite(top) & np.isfinite(scale) & (h - top > max_sigmas * scale)


def observed_area(poses: Poses, cameras: Sequence[Camera], ground: HeightField, size_m: float = float("nan"),
                  min_area_px: float = 0.0, size_tolerance: float = 0.0) -> object:
    """Union of the keyframes' ground footprints (shapely geometry, world x, y), each cut where an object of
    `size_m` (the session's typical landmark) would no longer give a mask of `min_area_px` pixels taken for it
    (`resolution_depth`: the same limit as `in_view`'s, `size_tolerance` as there), so that an oblique view's
    footprint does not run out to ground it saw at a fraction of a pixel; without a size or a limit at
    `footprint_points`' default range."""
    import shapely

    if not len(poses):
        return shapely.Polygon()
    polys = []
    for cam in dict.fromkeys(cameras):  # footprints per distinct camera
        idx = [k for k, c in enumerate(cameras) if c == cam]
        depth = resolution_depth(size_m, cam, min_area_px, size_tolerance)
        polys.extend(footprint_polygons(cam, poses.rotations[idx], poses.centers[idx], ground, per_side=4,
                                        max_depth_m=depth if np.isfinite(depth) else None))
    return shapely.union_all(polys)
