"""The surface height at a place from one session's own images (multi-view photo-consistency, a local plane sweep).

Removed and added trees, buildings and boulders change the surface; moved shadows, ground texture and a
season's looks do not. So each session's surface height at a place is estimated from its own keyframes alone: a
small horizontal patch around the place is swept through candidate heights from below the local ground to far
above it, sampled in the keyframes of the session that see it from the most different directions, and the height
at which those views agree best (mean pairwise zero-mean normalised correlation of the patch's grey levels) is
the surface there. A wrong height shifts the patch's projection with the parallax of each view, so the views
disagree; within one session the illumination is one, so the grey levels compare directly. What is compared
across sessions is a height in metres, never a look.

Pure numpy: the images come in as a sequence of grey arrays per keyframe (read on demand by the caller)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry import Camera, Poses, project

PATCH_CELLS = 15  # cells across the swept patch
PATCH_HALF_M = 1.0  # the swept patch's half width: small, so the top of a crown or a roof fills it (BENCHMARKS)
MIN_PATCH_HALF_M = 1.0  # a smaller patch holds too little texture to agree or disagree
# a view resolves the patch when it spans this many of its pixels: below that the correlation of 15 x 15
# interpolated cells rests on a few independent pixels and agrees as well at any height (views of a 1 m/px
# orthophoto: the patch is 2 pixels wide). A drone survey at 100 m sees it across 8-15 pixels.
MIN_PATCH_PIXELS = 5.0
SWEEP_VIEWS = 6
REFERENCE_LIMIT = 200  # reference places (evenly spaced) for the calibration: bounded cost on large maps
SWEEP_STEP_M = 0.5
SWEEP_BELOW_M = 3.0  # below the local ground (its estimate from the landmarks is coarse)
SWEEP_ABOVE_M = 30.0  # above it: taller than any tree or building of a survey
REGISTER_HALF_M = 10.0  # half width of the ground window that registers the views to one another
REGISTER_HOLE_M = 5.0  # the window's centre left out (an object at the place: scope objects have radius <= 6 m)
REGISTER_CELL_M = 0.4
REGISTER_SLACK_M = 2.0  # how far one keyframe's map pose may put the ground from where another puts it


def spread_views(inside: np.ndarray, centers: np.ndarray, off_centre: np.ndarray, count: int) -> np.ndarray:
    """(count, N) keyframe indices (-1 none) per point: among the keyframes where `inside` (K, N), first the one
    that sees the point nearest its image centre (`off_centre` (K, N)), then in turn the one whose camera centre
    is farthest (horizontally) from those chosen: the widest baselines, so a wrong height shows the most parallax.
    Ties go to the lower keyframe index (deterministic)."""
    k_count, n = inside.shape
    out = np.full((count, n), -1, dtype=np.int64)
    if not k_count or not n:
        return out
    first = np.argmin(np.where(inside, off_centre, np.inf), axis=0)
    has = inside[first, np.arange(n)]
    out[0] = np.where(has, first, -1)
    xy = np.asarray(centers, dtype=np.float64)[:, :2]
    nearest = np.where(has[None], np.linalg.norm(xy[:, None, :] - xy[first][None, :, :], axis=2), -np.inf)
    for c in range(1, count):
        cand = np.where(inside, nearest, -np.inf)
        pick = np.argmax(cand, axis=0)
        ok = np.isfinite(cand[pick, np.arange(n)]) & (cand[pick, np.arange(n)] > 0)
        out[c] = np.where(ok, pick, -1)
        d = np.linalg.norm(xy[:, None, :] - xy[pick][None, :, :], axis=2)
        nearest = np.where(ok[None], np.minimum(nearest, d), nearest)
        nearest[pick[ok], np.flatnonzero(ok)] = -np.inf
    return out


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The image's values at array coordinates (x column, y row), bilinear; coordinates must lie inside."""
    x0 = np.clip(np.floor(x).astype(np.int64), 0, image.shape[1] - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, image.shape[0] - 2)
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def sweep_levels(ground_z: float) -> np.ndarray:
    """The candidate heights of one place: SWEEP_STEP_M apart from the ground - SWEEP_BELOW_M to + SWEEP_ABOVE_M."""
    return ground_z + np.arange(-SWEEP_BELOW_M, SWEEP_ABOVE_M + 1e-9, SWEEP_STEP_M)


def sample_grid(image: np.ndarray, camera: Camera, rotation: np.ndarray, center: np.ndarray,
                points: np.ndarray) -> np.ndarray | None:
    """The image's grey values at world points (bilinear, COLMAP pixels); None when any falls outside the image
    or behind the camera."""
    uv, depth = project(camera, rotation, center, points)
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5  # COLMAP pixels: centre of the first pixel at 0.5
    h, w = image.shape[:2]
    if not (np.all(depth > 0) and np.all(np.isfinite(uv)) and x.min() >= 0 and y.min() >= 0
            and x.max() <= w - 1 and y.max() <= h - 1):
        return None
    return bilinear(image, x, y)


def grid_points(xy: np.ndarray, half_m: float, cells: int, z: float) -> np.ndarray:
    """(cells * cells, 3) points of a horizontal square grid around xy at height z (row-major, y then x)."""
    step = 2.0 * half_m / cells
    t = -half_m + step * (np.arange(cells) + 0.5)
    gx, gy = np.meshgrid(xy[0] + t, xy[1] + t)
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(z))])


def register_views(xy: np.ndarray, ground_z: float, views: Sequence[int], images: Sequence[np.ndarray | None],
                   poses: Poses, cameras: Sequence[Camera]) -> tuple[list[int], np.ndarray]:
    """The views that hold the registration window, and for each a horizontal offset (V, 2) in metres that
    brings its look of the ground around xy onto the first view's (best zero-mean normalised correlation of the
    ortho images at the ground height within REGISTER_SLACK_M, refined to a fraction of a cell).

    A map's keyframe poses are off by a fraction of a degree and of a metre (a metre on the ground from 100 m),
    more than the parallax of a few metres of height; registered on the ground around the place, the views keep
    only the parallax of what stands above it (plane plus parallax), so the sweep measures the height above the
    local ground even where the ground model is off. The window leaves out a disc of REGISTER_HOLE_M around the
    place: an object standing there would pull the registration onto itself and take its own parallax away."""
    from numpy.lib.stride_tricks import sliding_window_view

    s = int(round(REGISTER_SLACK_M / REGISTER_CELL_M))
    m = int(round(2 * REGISTER_HALF_M / REGISTER_CELL_M))
    big = m + 2 * s
    pts = grid_points(xy, REGISTER_HALF_M + s * REGISTER_CELL_M, big, ground_z)
    kept, looks = [], []
    for k in views:
        image = images[k] if k >= 0 else None
        if image is None:
            continue
        g = sample_grid(image, cameras[k], poses.rotations[k], poses.centers[k], pts)
        if g is not None:
            kept.append(int(k))
            looks.append(g.reshape(big, big))
    offsets = np.zeros((len(kept), 2))
    if len(kept) < 2:
        return kept, offsets
    t = (np.arange(m) + 0.5) * REGISTER_CELL_M - REGISTER_HALF_M
    w = (np.hypot(*np.meshgrid(t, t)) > REGISTER_HOLE_M).astype(np.float64)
    w /= w.sum()
    ref = looks[0][s:s + m, s:s + m]
    ref = ref - np.sum(w * ref)
    ref = w * ref / max(float(np.sqrt(np.sum(w * ref * ref))), 1e-6)
    for v in range(1, len(kept)):
        win = sliding_window_view(looks[v], (m, m))  # (2s+1, 2s+1, m, m)
        mu = np.einsum("uv,ijuv->ij", w, win)
        var = np.einsum("uv,ijuv->ij", w, win * win) - mu * mu
        r = np.einsum("uv,ijuv->ij", ref, win) / np.sqrt(np.maximum(var, 1e-12))
        i, j = np.unravel_index(int(np.argmax(r)), r.shape)
        di = _parabola(r[i - 1, j], r[i, j], r[i + 1, j]) if 0 < i < 2 * s else 0.0
        dj = _parabola(r[i, j - 1], r[i, j], r[i, j + 1]) if 0 < j < 2 * s else 0.0
        offsets[v] = [(j + dj - s) * REGISTER_CELL_M, (i + di - s) * REGISTER_CELL_M]
    return kept, offsets


def _parabola(a: float, b: float, c: float) -> float:
    """The vertex of the parabola through (-1, a), (0, b), (1, c) (a sub-cell peak), within half a cell."""
    den = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) if den < 0 else 0.0


def sweep_agreement(xy: np.ndarray, half_m: float, levels: np.ndarray, views: Sequence[int],
                    images: Sequence[np.ndarray | None], poses: Poses, cameras: Sequence[Camera],
                    offsets: np.ndarray | None = None, cells: int = PATCH_CELLS) -> tuple[np.ndarray, int]:
    """(len(levels),) mean pairwise zero-mean normalised correlation of the grey patch around xy (half width
    half_m) at each height in the views (those that hold the whole patch at every level; a flat patch agrees
    0), and the number of views used (the agreement is NaN with fewer than two). `offsets` (V, 2): each view's
    registration offset (`register_views`), added to the points it samples."""
    flat = grid_points(xy, half_m, cells, 0.0)
    m = len(flat)
    pts = np.column_stack([np.tile(flat[:, 0], len(levels)), np.tile(flat[:, 1], len(levels)),
                           np.repeat(levels, m)])
    patches = []
    for v, k in enumerate(views):
        image = images[k] if k >= 0 else None
        if image is None:
            continue
        shift = np.zeros(3) if offsets is None else np.array([offsets[v, 0], offsets[v, 1], 0.0])
        g = sample_grid(image, cameras[k], poses.rotations[k], poses.centers[k], pts + shift)
        if g is None:
            continue
        p = g.reshape(len(levels), m)
        p = p - p.mean(axis=1, keepdims=True)
        norm = np.linalg.norm(p, axis=1, keepdims=True)
        patches.append(np.where(norm > 1e-6, p / np.maximum(norm, 1e-12), 0.0))
    v = len(patches)
    if v < 2:
        return np.full(len(levels), np.nan), v
    s = np.sum(patches, axis=0)
    # mean over the v (v - 1) / 2 pairs of unit vectors: (|sum|^2 - sum of |p|^2) / (v (v - 1))
    self_terms = np.sum([np.sum(p * p, axis=1) for p in patches], axis=0)
    return (np.sum(s * s, axis=1) - self_terms) / (v * (v - 1)), v


def sweep_views(points: np.ndarray, half_m: np.ndarray, ground_z: np.ndarray, poses: Poses,
                cameras: Sequence[Camera], views: int) -> np.ndarray:
    """(views, N) keyframes per point for the sweep (`spread_views`): those that hold the patch at the bottom
    and the top of the sweep and the registration window at the ground, and resolve the patch (at least
    MIN_PATCH_PIXELS across at the ground; a coarser view leaves the place without a height)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n, k_count = len(p), len(poses)
    inside = np.ones((k_count, n), dtype=bool)
    off = np.zeros((k_count, n))
    reach = REGISTER_HALF_M + REGISTER_SLACK_M
    for dz, wide in ((-SWEEP_BELOW_M, half_m), (SWEEP_ABOVE_M, half_m), (0.0, np.maximum(half_m, reach))):
        for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
            corner = np.column_stack([p[:, 0] + sx * wide, p[:, 1] + sy * wide, ground_z + dz])
            for k in range(k_count):
                cam = cameras[k]
                uv, depth = project(cam, poses.rotations[k], poses.centers[k], corner)
                inside[k] &= (depth > 0) & (uv[:, 0] >= 1) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] >= 1) & (
                    uv[:, 1] <= cam.height - 1)
    for k in range(k_count):
        cam = cameras[k]
        uv, depth = project(cam, poses.rotations[k], poses.centers[k], np.column_stack([p[:, :2], ground_z]))
        off[k] = np.hypot(uv[:, 0] - cam.width / 2.0, uv[:, 1] - cam.height / 2.0) / max(cam.width, cam.height)
        # the patch's width in this view's pixels at the ground (the nearest, widest place of the sweep is above)
        with np.errstate(divide="ignore", invalid="ignore"):
            inside[k] &= 2.0 * half_m * min(cam.fx, cam.fy) / np.maximum(depth, 1e-9) >= MIN_PATCH_PIXELS
    return spread_views(inside, poses.centers, off, views)


def sweep_curves(points: np.ndarray, half_m: np.ndarray, ground_z: np.ndarray,
                 images: Sequence[np.ndarray | None], poses: Poses, cameras: Sequence[Camera],
                 views: int = SWEEP_VIEWS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sweep of every point with a patch of half width `half_m` (per point, at least MIN_PATCH_HALF_M) in
    the `views` keyframes that see it from the most different directions: the levels relative to the local
    ground (L,), the (N, L) agreement (smoothed over neighbouring levels; NaN rows where fewer than two views),
    and the views used per point."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(p)
    g = np.asarray(ground_z, dtype=np.float64).reshape(-1)
    half = np.maximum(np.nan_to_num(np.asarray(half_m, dtype=np.float64) * np.ones(n), nan=MIN_PATCH_HALF_M),
                      MIN_PATCH_HALF_M)
    chosen = sweep_views(p, half, g, poses, cameras, views)
    rel = sweep_levels(0.0)
    curve = np.full((n, len(rel)), np.nan)
    used = np.zeros(n, dtype=np.int64)
    for i in range(n):
        kept, offsets = register_views(p[i, :2], float(g[i]), chosen[:, i], images, poses, cameras)
        score, used[i] = sweep_agreement(p[i, :2], float(half[i]), g[i] + rel, kept, images, poses, cameras, offsets)
        if used[i] >= 2:
            curve[i] = np.convolve(np.pad(score, 1, mode="edge"), [0.25, 0.5, 0.25], mode="valid")
    return rel, curve, used


def heights_above_ground(points: np.ndarray, ground_z: np.ndarray, images: Sequence[np.ndarray | None] | None,
                         poses: Poses, cameras: Sequence[Camera], views: int = SWEEP_VIEWS) -> np.ndarray:
    """The surface height above the local ground at each point's (x, y) in one session: the best-agreeing level
    of the sweep (`sweep_curves`, a PATCH_HALF_M patch; the views are registered on the ground around the place,
    so the height is relative to it). NaN where fewer than two views hold the sweep, or without images."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if images is None or not len(p):
        return np.full(len(p), np.nan)
    g = np.asarray(ground_z, dtype=np.float64).reshape(-1)
    rel, curve, _ = sweep_curves(p, np.full(len(p), PATCH_HALF_M), g, images, poses, cameras, views)
    ok = np.all(np.isfinite(curve), axis=1)
    best = np.argmax(np.where(ok[:, None], curve, -np.inf), axis=1)
    return np.where(ok, g + rel[best], np.nan) - g


def _height_scale(h: np.ndarray) -> np.ndarray:
    """Heights on the scale their errors are alike on: log(1 + h / 1 m), the ground band (h <= 0) at 0 (a sweep
    misses a 10 m crown by metres, the ground by centimetres)."""
    return np.log1p(np.maximum(np.asarray(h, dtype=np.float64), 0.0))


def _log_conditional(x: np.ndarray, y: np.ndarray, rx: np.ndarray, ry: np.ndarray, bx: float,
                     by: float) -> np.ndarray:
    """log p(y | x) of a Gaussian kernel estimate on the reference pairs (rx, ry) with bandwidths bx, by."""
    from scipy.special import logsumexp

    wx = -0.5 * ((x[:, None] - rx[None, :]) / bx) ** 2
    wy = -0.5 * ((y[:, None] - ry[None, :]) / by) ** 2
    return logsumexp(wx + wy, axis=1) - logsumexp(wx, axis=1) - np.log(by * np.sqrt(2.0 * np.pi))


def height_log_ratio(own_h: np.ndarray, other_h: np.ndarray, ref_own_h: np.ndarray,
                     ref_other_h: np.ndarray) -> np.ndarray:
    """log P(other's height | absent there) - log P(other's height | present) of each place, from the surface
    heights above the ground of its own session (own_h) and of the other session (other_h), calibrated on the
    pair's reference places (both heights of landmarks with a counterpart, present in both).

    Present: the other's height as the references with an own height like this one show it (a kernel estimate of
    p(other | own); it holds how well the two sessions' sweeps agree, and a season's leaf-off crowns). Absent: the
    other session sees there what it sees where its own session sees the ground, p(other | own = 0). So a place
    with no height in its own session (ground texture, a shadow, a flat object, a sweep that missed) gets no
    evidence either way, and a crown whose place the other session also sees high is present. Bounded by the
    references' count (n samples resolve no odds beyond n); 0 where a height is unknown or the references are
    fewer than 10."""
    own_h, other_h = np.asarray(own_h, dtype=np.float64), np.asarray(other_h, dtype=np.float64)
    out = np.zeros(len(own_h))
    ref = np.isfinite(ref_own_h) & np.isfinite(ref_other_h)
    ok = np.isfinite(own_h) & np.isfinite(other_h)
    if np.count_nonzero(ref) < 10 or not np.any(ok):
        return out
    rx, ry = _height_scale(ref_own_h[ref]), _height_scale(ref_other_h[ref])
    n = len(rx)
    bx, by = (max(float(np.std(r)) * n ** (-1.0 / 6.0), 0.1) for r in (rx, ry))  # Scott's rule, 2 dimensions
    x, y = _height_scale(own_h[ok]), _height_scale(other_h[ok])
    llr = _log_conditional(np.zeros_like(x), y, rx, ry, bx, by) - _log_conditional(x, y, rx, ry, bx, by)
    bound = float(np.log(n - 1))
    out[ok] = np.clip(llr, -bound, bound)
    return out


def ground_noise_fit(ref_heights: np.ndarray, step: float = SWEEP_STEP_M) -> tuple[float, float, int]:
    """The sweep's ground noise from reference places' heights above the ground: its standard deviation sigma (m),
    the degrees of freedom of a normal sample that would measure it as precisely, and the number of places whose
    level is at or below the ground's.

    The sweep's heights are its levels, SWEEP_STEP_M apart (`heights_above_ground` takes the best level, it does
    not interpolate), so a 0 stands for anything within half a step of the ground, half of it above. Objects only
    ever add height, so only the places at or below the ground's level are ground alone. sigma is the maximum
    likelihood fit of a zero-mean normal rounded to the levels (the bottom level holds all below it), given that
    the level is at most the ground's: exact for such heights. (The root mean square of the heights at or below 0
    counts every 0 as a whole place below the ground and measures sigma at 0.87 of it at 0.5 m; Sheppard's
    correction, - step^2 / 12, would lower it further.) The degrees of freedom are n x the Fisher information per
    place on log sigma / 2, which is n for unrounded heights: a level says less than the height it rounds.
    `step`: the grid the heights lie on (a mean of k levels lies on one of SWEEP_STEP_M / k)."""
    from scipy.stats import norm

    h = np.asarray(ref_heights, dtype=np.float64)
    bottom = int(round(SWEEP_BELOW_M / step))
    depth = np.minimum(-np.round(h[np.isfinite(h)] / step), bottom)  # levels below the ground's
    depth = depth[depth >= 0].astype(np.int64)
    n = len(depth)
    if not np.any(depth > 0):  # all within half a step of the ground: no noise the levels can show
        return 0.0, float(n), n
    counts = np.bincount(depth, minlength=bottom + 1)
    lower = (np.arange(bottom + 2) - 0.5) * step  # depth j: the ground lies (j +- 1/2) steps above
    lower[-1] = np.inf  # the bottom level: everything deeper

    def log_p(log_sigma: np.ndarray) -> np.ndarray:
        """(S, bottom + 1) log P(depth j | depth >= 0) at each sigma."""
        tail = norm.logsf(lower[None, :] / np.exp(log_sigma)[:, None])  # log P(depth above lower edge j)
        with np.errstate(divide="ignore"):
            cell = tail[:, :-1] + np.log(-np.expm1(tail[:, 1:] - tail[:, :-1]))
        return cell - tail[:, :1]

    grid = np.linspace(np.log(1e-3), np.log(1e2), 1101)  # 1 % apart, then the parabola's vertex
    like = log_p(grid) @ counts
    i = int(np.clip(np.argmax(like), 1, len(grid) - 2))
    log_sigma = grid[i] + _parabola(like[i - 1], like[i], like[i + 1]) * (grid[1] - grid[0])
    q = np.exp(log_p(np.array([log_sigma])))[0]
    d = np.diff(log_p(log_sigma + np.array([-1e-4, 1e-4])), axis=0)[0] / 2e-4  # d log P / d log sigma
    info = float(np.sum(q * d * d))  # per place; 2 for an unrounded half-normal
    return float(np.exp(log_sigma)), n * info / 2.0, n


def ground_sweep_noise(ref_heights: np.ndarray, min_places: int = 10) -> float:
    """The standard deviation of the sweep's height at places of bare ground, from reference places' heights above
    the ground in one session (`ground_noise_fit`: objects only ever add height, so the places at or below the
    ground are ground alone; the heights are the sweep's levels). NaN with fewer than `min_places` such places
    (a scale for a test that has no use for the fit's precision; `ground_noise_limit` tests with any number)."""
    sigma, _, n = ground_noise_fit(ref_heights)
    return sigma if n >= min_places else float("nan")


def ground_noise_limit(ref_heights: np.ndarray, rate: float, step: float = SWEEP_STEP_M) -> float:
    """The height above the ground that a new place of bare ground exceeds at one-sided rate `rate`, by the
    sweep's ground noise as measured on the session's reference places (`ground_noise_fit`, on the grid `step`
    the heights lie on: a mean of k sweeps lies on one of SWEEP_STEP_M / k), and at least one sweep step. NaN only
    where no reference place lies at or below the ground's level (no fit at all).

    sigma is measured, not known: the new place's height over it is Student-t with the fit's degrees of freedom,
    not normal. The quantile widens as the ground places thin (so a fit on a handful of places still makes a
    test, a stricter one) and reaches the normal's on many; a count below which the noise counts as unmeasured
    switched the test off whole, and on small pairs that count sat at their ground places' number, so which
    session set the frame decided whether every place stood (nu39: 11 vs 9 ground places in the two orders of
    one unchanged pair, 3 vs 24 false claims)."""
    from scipy.stats import t

    sigma, dof, n = ground_noise_fit(ref_heights, step)
    if not n or not 0.0 < rate < 1.0:
        return float("nan")
    # dof < n on the levels (a level says less than the height it rounds); sigma 0 (no place below the ground's
    # level) leaves the floor of one step
    return max(float(t.isf(rate, max(dof, 1e-3))) * sigma if sigma > 0 else 0.0, SWEEP_STEP_M)


def footprint_places(points: np.ndarray, sizes: np.ndarray, ring: int) -> np.ndarray:
    """(N, ring, 3) places on a ring around each landmark at half its footprint's radius (h of a disc is half its
    radius, so the ring lies at distance h, inside the object), at `ring` fixed angles (deterministic), at the
    landmark's height. A landmark's centroid may sit beside a small crown's top (a fragment, a lit half, a cone
    whose top is a point): the ring looks where the object's top may be."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    h = np.nan_to_num(np.asarray(sizes, dtype=np.float64).reshape(-1), nan=0.0)
    angle = 2.0 * np.pi * np.arange(ring) / max(ring, 1)
    out = np.repeat(p[:, None, :], ring, axis=1)
    out[:, :, 0] += h[:, None] * np.cos(angle)[None, :]
    out[:, :, 1] += h[:, None] * np.sin(angle)[None, :]
    return out


def height_limit(ref_heights: np.ndarray, p: float, places: int = 1) -> float:
    """The height above the ground that the ground's sweep noise (`ground_noise_limit` of the session's reference
    places: a Student-t quantile with the noise fit's degrees of freedom) exceeds with one-sided probability p
    over `places` places (Sidak: each at 1 - (1 - p)^(1/places), so the highest of several sweeps of bare ground
    passes as rarely as one sweep does at p), and at least one sweep step. NaN when the test cannot be made
    (p >= 1, or no reference place at ground level to measure the noise on)."""
    if p >= 1.0:
        return float("nan")
    each = -np.expm1(np.log1p(-p) / max(int(places), 1))
    return ground_noise_limit(ref_heights, each)


def stands_above_ground(heights: np.ndarray, ref_heights: np.ndarray, p: float, places: int = 1) -> np.ndarray:
    """Whether the surface at each place stands above the local ground (`heights_above_ground` of its session):
    higher than `height_limit` at one-sided significance p. `heights` (N,) one place per landmark, or (N, K) the
    sweeps of K places of each (its centroid and `footprint_places`): the highest known one is tested, at the
    limit for `places` places. An unknown height (NaN everywhere) does not stand; p >= 1 lets every place stand
    (the test is off), and so do all where no reference place lies at ground level to measure the noise on."""
    h = np.asarray(heights, dtype=np.float64)
    limit = height_limit(ref_heights, p, places)
    if not np.isfinite(limit):
        return np.ones(len(h), dtype=bool)
    if h.ndim == 2:
        known = np.isfinite(h)
        h = np.where(known.any(axis=1), np.max(np.where(known, h, -np.inf), axis=1) if h.shape[1] else np.nan,
                     np.nan)
    return np.isfinite(h) & (h > limit)


def relief_levels(places: int, p: float) -> int:
    """How many levels `shows_relief` tests: the levels 1..L of chance rates p, p^2, ... p^L, where L is the first
    at which one standing place out of `places` alone is significant at p after the Bonferroni correction over the
    L levels. A higher level adds nothing: every place standing there stands at level L too, where one is already
    enough."""
    level = 1
    while -np.expm1(places * np.log1p(-(p ** level))) >= p / level and p ** level > 1e-300:
        level += 1
    return level


def shows_relief(ref_heights: np.ndarray, p: float) -> bool:
    """Whether a session's images show any relief at its reference places: at some level, more of them stand
    above the ground than its ground noise alone would raise there. Level k is `height_limit` at p^k (the
    ground noise raises a place above it at rate p^k); its count is tested against that rate (binomial tail),
    at p / L for the L levels (`relief_levels`, Bonferroni). One level at p alone misses a few places standing far
    above the noise (the twenty-fourth sweep: 3 of 52 at more than 3x the 1.03 m limit, tail 0.0155 at rate p,
    so "no relief" and 5 of 5 new claims false; at rate p^2 their tail is 2e-8). An orthophoto rendered as views,
    or a survey of bare fields, shows none, nor do images too coarse for a height at any reference place (all
    NaN): there the objectness test cannot tell an object from ground texture and is not applied."""
    from scipy.stats import binom, t

    h = np.asarray(ref_heights, dtype=np.float64)
    h = h[np.isfinite(h)]
    if p >= 1.0 or not len(h):
        return False
    sigma, dof, ground = ground_noise_fit(h)
    levels = relief_levels(len(h), p)
    for level in range(1, levels + 1):
        rate = chance = p ** level
        if ground:
            # the noise is measured on a few tens of places: a new place's height over it is Student-t with the
            # fit's degrees of freedom, whose tail far out is much heavier than the normal's
            limit = ground_noise_limit(h, rate)
            dof = max(dof, 1e-3)
            standing = int(np.count_nonzero(h > limit))
            if sigma > 0:
                # a height is a level: the ground stands above the limit wherever it rounds to the first level
                # above it, which starts up to half a step below the limit (at sigma 0.5 m and p 0.05: rate 0.067,
                # not 0.05, so 300 places of bare ground showed relief in a quarter of the sessions); never
                # taken below the level's rate, which the floor of one step and the untested tails far out keep
                first = (np.floor(limit / SWEEP_STEP_M + 1e-9) + 0.5) * SWEEP_STEP_M
                chance = max(rate, float(t.sf(first / sigma, dof)))
        else:  # no place at ground level to measure the noise on: every place stands (as `stands_above_ground`)
            standing = len(h)
        if binom.sf(standing - 1, len(h), chance) < p / levels:
            return True
    return False
