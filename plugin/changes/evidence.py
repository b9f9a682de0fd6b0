"""What the other session shows at a landmark's place: counterpart landmarks, larger landmarks that hold it, and
segments of its keyframes (with the local chance rate of such segments)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..association.gates import size_ratio
from ..geometry import Camera, Poses
from .observations import FOOTPRINT_MARGIN, KeyframeSegments, in_view


def holder_pairs(points: np.ndarray, sizes: np.ndarray, holders: np.ndarray, holder_sizes: np.ndarray,
                 max_ratio: float, same_map: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) where landmark j of `holders` holds landmark i of `points`: j is at least as large (h_i <= h_j
    <= max_ratio h_i) and i lies inside j's footprint (ground distance <= 2 h_j). One object mapped as a whole
    in one place and as parts in another (nested masks, split tracks) is linked this way. `same_map`: both
    arrays are one map; a landmark does not hold itself. Unknown sizes hold nothing and are held by nothing."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)[:, :2]
    q = np.asarray(holders, dtype=np.float64).reshape(-1, 3)[:, :2]
    h = np.asarray(sizes, dtype=np.float64).reshape(-1)
    hq = np.asarray(holder_sizes, dtype=np.float64).reshape(-1)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    finite = np.isfinite(hq)
    if not len(p) or not np.any(finite) or max_ratio < 1:
        return empty
    reach = FOOTPRINT_MARGIN * float(np.max(hq[finite]))
    pairs = cKDTree(p).sparse_distance_matrix(cKDTree(q), reach, output_type="ndarray")
    i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    with np.errstate(invalid="ignore"):
        ok = (hq[j] >= h[i]) & (hq[j] <= max_ratio * h[i]) & (d <= FOOTPRINT_MARGIN * hq[j])
    if same_map:
        ok &= i != j
    i, j, d = i[ok], j[ok], d[ok]
    order = np.lexsort((j, d, i))
    return i[order], j[order]


def nested_pairs(points: np.ndarray, sizes: np.ndarray, holders: np.ndarray, holder_sizes: np.ndarray,
                 gate_m: float, z_weight: float, same_map: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """`holder_pairs` of any size ratio whose two landmarks lie at one height (z_weight x |dz| <= gate_m): nested
    in 3D, a fragment of a mapped crown or a mask of a building's roof inside the whole's landmark. A tree
    standing in a mapped field or meadow rises above the field's landmark and is not nested in it, so only the
    height, not a size limit, keeps ground regions from holding the objects on them."""
    i, j = holder_pairs(points, sizes, holders, holder_sizes, np.inf, same_map)
    zi = np.asarray(points, dtype=np.float64).reshape(-1, 3)[i, 2]
    zj = np.asarray(holders, dtype=np.float64).reshape(-1, 3)[j, 2]
    ok = z_weight * np.abs(zi - zj) <= gate_m
    return i[ok], j[ok]


def counterparts(points: np.ndarray, sizes: np.ndarray, other_points: np.ndarray, other_sizes: np.ndarray,
                 gate_m: float, max_size_difference: float, z_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """For each landmark, the nearest landmark of the other map within `gate_m` (distance in x, y and
    z_weight x z) whose size ratio r is at most `max_size_difference` (NaN sizes pass). Many landmarks may share
    one counterpart (nested masks of one object). Returns ((N,) index or -1, (N,) distance or NaN)."""
    from scipy.spatial import cKDTree

    scale = np.array([1.0, 1.0, z_weight])
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3) * scale
    q = np.asarray(other_points, dtype=np.float64).reshape(-1, 3) * scale
    index = np.full(len(p), -1, dtype=np.int64)
    dist = np.full(len(p), np.nan)
    if not len(p) or not len(q):
        return index, dist
    pairs = cKDTree(p).sparse_distance_matrix(cKDTree(q), gate_m, output_type="ndarray")
    i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    ok = size_ratio(np.asarray(sizes, np.float64)[i], np.asarray(other_sizes, np.float64)[j]) <= max_size_difference
    i, j, d = i[ok], j[ok], d[ok]
    order = np.lexsort((j, d, i))  # per landmark: nearest first, ties by index
    first = np.r_[True, i[order][1:] != i[order][:-1]] if len(order) else np.zeros(0, bool)
    index[i[order][first]] = j[order][first]
    dist[i[order][first]] = d[order][first]
    return index, dist


def inside_larger(points: np.ndarray, sizes: np.ndarray, other_points: np.ndarray, other_sizes: np.ndarray,
                  max_ratio: float, eligible: np.ndarray | None = None) -> np.ndarray:
    """For each landmark, the nearest landmark of the other map that holds it (`holder_pairs`): the other session
    mapped the object as a whole (or a bigger part of it) where this map has a part; a removed object leaves, at
    most, smaller ground patches. Returns (N,) index or -1."""
    out = np.full(len(np.asarray(points).reshape(-1, 3)), -1, dtype=np.int64)
    i, j = holder_pairs(points, sizes, other_points, other_sizes, max_ratio)
    if eligible is not None:
        keep = np.asarray(eligible, dtype=bool)[j]
        i, j = i[keep], j[keep]
    first = np.r_[True, i[1:] != i[:-1]] if len(i) else np.zeros(0, bool)  # sorted by i, then distance
    out[i[first]] = j[first]
    return out


def segment_evidence(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
                     segments: Sequence[KeyframeSegments], gate_m: float, max_size_difference: float,
                     probe_count: int, probe_radius_factor: float, min_area_px: float = 0.0,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How often another session's segments show something like each landmark where it should be.

    In every keyframe that should have seen the landmark (`in_view`), a hit is a segment whose centroid lies
    within the gate (projected: gate_m x f / depth pixels) of the landmark's projection and whose pixel size
    matches size x f / depth (ratio r <= max_size_difference) (`segment_hits`). The same count at `probe_count`
    points on a circle around the landmark (radius probe_radius_factor x gate_m + 2 h, same height) gives the
    local chance rate of such segments (ground texture, neighbours). Returns (hits (N,), views (N,), chance rate
    (N,)), the rate with a Laplace prior ((probe hits + 1) / (probe views + 2)).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    h = np.asarray(sizes, dtype=np.float64).reshape(-1)
    n = len(pts)
    ang = 2.0 * np.pi * np.arange(probe_count) / max(probe_count, 1)
    radius = probe_radius_factor * gate_m + FOOTPRINT_MARGIN * np.nan_to_num(h, nan=0.0)
    offsets = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], 1)
    probes = (pts[:, None, :] + radius[:, None, None] * offsets[None]).reshape(-1, 3)
    all_pts = np.vstack([pts, probes])
    all_h = np.concatenate([h, np.repeat(h, probe_count)])
    hits, views = segment_hits(all_pts, all_h, poses, cameras, segments, gate_m, max_size_difference, min_area_px)
    probe_hits = hits[n:].reshape(n, probe_count).sum(1)
    probe_views = views[n:].reshape(n, probe_count).sum(1)
    chance = (probe_hits + 1.0) / (probe_views + 2.0)
    return hits[:n], views[:n], chance


def segment_hits(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
                 segments: Sequence[KeyframeSegments], gate_m: float, max_size_difference: float,
                 min_area_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per point: in how many keyframes that should have seen it (`in_view`) a segment of compatible size lies
    within the projected gate of its projection (hits), and in how many keyframes it was in view (views; with
    `min_area_px`, the segmenter's smallest mask, as `in_view` counts them)."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sizes = np.asarray(sizes, dtype=np.float64).reshape(-1)
    seen, uv, depth = in_view(points, sizes, poses, cameras, min_area_px=min_area_px,
                              size_tolerance=max_size_difference)
    hits = np.zeros(len(points), dtype=np.int64)
    for k, seg in enumerate(segments):
        idx = np.flatnonzero(seen[k])
        if not len(idx) or not len(seg.centroids):
            continue
        f = float(np.sqrt(cameras[k].fx * cameras[k].fy))
        radius_px = gate_m * f / depth[k, idx]
        pred_px = sizes[idx] * f / depth[k, idx]
        near = cKDTree(seg.centroids).query_ball_point(uv[k, idx], radius_px)
        for m, cand in zip(range(len(idx)), near):
            if cand and np.any(size_ratio(seg.sizes_px[cand], np.full(len(cand), pred_px[m]))
                               <= max_size_difference):
                hits[idx[m]] += 1
    return hits, seen.sum(0)


def presence_rate(sizes: np.ndarray, reference_sizes: np.ndarray, reference_hits: np.ndarray,
                  reference_views: np.ndarray, bandwidth: float) -> np.ndarray:
    """Per landmark, the per-keyframe rate at which the other session's segments show an object of its size that
    is there: measured on the reference landmarks (those with a counterpart landmark, so present in both
    sessions), pooled with a Gaussian kernel of `bandwidth` in log size, with a Laplace prior
    ((hits + 1) / (views + 2)). It is the pair's own rate, so a winter session, a coarser camera or another
    segmenter calibrate it themselves. Unknown sizes take the pooled rate of every reference."""
    s = np.log(np.asarray(sizes, dtype=np.float64).reshape(-1))
    rs = np.log(np.asarray(reference_sizes, dtype=np.float64).reshape(-1))
    rh = np.asarray(reference_hits, dtype=np.float64).reshape(-1)
    rv = np.asarray(reference_views, dtype=np.float64).reshape(-1)
    ok = np.isfinite(rs)
    rs, rh, rv = rs[ok], rh[ok], rv[ok]
    w = np.exp(-0.5 * ((s[:, None] - rs[None, :]) / bandwidth) ** 2)
    w = np.where(np.isfinite(s)[:, None], w, 1.0)
    return (w @ rh + 1.0) / (w @ rv + 2.0)


def landmark_presence_rate(sizes: np.ndarray, own_hits: np.ndarray, own_views: np.ndarray,
                           reference_sizes: np.ndarray, reference_hits: np.ndarray, reference_views: np.ndarray,
                           reference_own_hits: np.ndarray, reference_own_views: np.ndarray,
                           bandwidth: float) -> np.ndarray:
    """Per landmark, the rate at which the other session's segments would show it if it were there: the other
    session's rate for objects of its size (`presence_rate` of the references' hits there) times how much more or
    less often its own session shows this landmark than landmarks of that size (its own hits (+1) / views (+2)
    over the references' rate in their own session). A fragment of a crown that its own session segments in half
    of its views is segmented as rarely by the other one, however present: 1 hit in 20 views of the other session
    says little against it, where a standalone tree that its own session shows in every view is absent. Clipped to
    [0.001, 0.999]."""
    other_rate = presence_rate(sizes, reference_sizes, reference_hits, reference_views, bandwidth)
    own_rate = presence_rate(sizes, reference_sizes, reference_own_hits, reference_own_views, bandwidth)
    mine = (np.asarray(own_hits, dtype=np.float64) + 1.0) / (np.asarray(own_views, dtype=np.float64) + 2.0)
    return np.clip(other_rate * mine / own_rate, 1e-3, 1.0 - 1e-3)


def view_correlation(hits: np.ndarray, views: np.ndarray, rate: np.ndarray) -> float:
    """Intra-class correlation rho of the views of one place, from hit counts against their rates (moment
    estimate of the beta-binomial, clipped to [0, 1)): the keyframes that see a landmark are neighbours along a
    strip and segment it alike, so its hits vary by n p (1 - p) (1 + (n - 1) rho) instead of n p (1 - p). 0 with
    fewer than 3 counts (too few to tell: no correction)."""
    h = np.asarray(hits, dtype=np.float64)
    n = np.asarray(views, dtype=np.float64)
    p = np.clip(np.asarray(rate, dtype=np.float64), 1e-6, 1 - 1e-6)
    ok = n > 1
    if np.count_nonzero(ok) < 3:
        return 0.0
    h, n, p = h[ok], n[ok], p[ok]
    var = n * p * (1 - p)
    excess = float(np.sum((h - n * p) ** 2) - np.sum(var))
    return float(np.clip(excess / float(np.sum(var * (n - 1))), 0.0, 1.0 - 1e-6))


def dispersion(views: np.ndarray, rho: float) -> np.ndarray:
    """The quasi-likelihood dispersion of a count of n correlated views, 1 + (n - 1) rho (`view_correlation`):
    8 views of one pass are barely more than one look, but 40 views of four passes are several. Measured on
    the references (sosmatch changes, BENCHMARKS.md), the Pearson dispersion grows with n as this predicts
    (rho 0.13-0.23 same season: about 2 at 8 views, 8-10 at 45), so one factor for all (their mean, 5-7)
    overstated few-view evidence's dependence and understated many-view evidence's."""
    return 1.0 + (np.maximum(np.asarray(views, dtype=np.float64), 1.0) - 1.0) * float(rho)


def absence_log_ratio(hits: np.ndarray, views: np.ndarray, chance: np.ndarray, present: np.ndarray,
                      dispersion_factor: float | np.ndarray = 1.0, visible: float | np.ndarray = 1.0) -> np.ndarray:
    """log P(hits | the object is absent) - log P(hits | present), divided by the dispersion factor (per count,
    `dispersion`): hits are binomial over the views with the local chance rate (absent: only ground texture and
    neighbours show such segments) or with the presence rate of objects of its size (present). `visible`: the
    share of present objects without a counterpart that the other session sees at all (`visible_share`); the
    rest show at the chance rate, so the present rate is visible x presence + (1 - visible) x chance (at 0 the
    segments say nothing). Positive: the segments say absent."""
    from scipy.stats import binom

    h = np.asarray(hits)
    n = np.asarray(views)
    w = np.clip(np.asarray(visible, dtype=np.float64), 0.0, 1.0)
    present = w * np.asarray(present, dtype=np.float64) + (1.0 - w) * np.asarray(chance, dtype=np.float64)
    lo = binom.logpmf(h, n, np.clip(chance, 1e-6, 1 - 1e-6))
    lp = binom.logpmf(h, n, np.clip(present, 1e-6, 1 - 1e-6))
    return (lo - lp) / np.maximum(np.asarray(dispersion_factor, dtype=np.float64), 1.0)


def binomial_tail(hits: np.ndarray, trials: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """P(X >= hits) for X ~ Binomial(trials, rate), elementwise."""
    from scipy.stats import binom

    hits = np.asarray(hits)
    return np.where(hits <= 0, 1.0, binom.sf(hits - 1, trials, rate))


def seen_shares(sizes: np.ndarray, reference_sizes: np.ndarray, matched: np.ndarray, shown: np.ndarray,
                bandwidth: float) -> tuple[np.ndarray, np.ndarray]:
    """How much of one map the other session sees, per size: of the map's compared landmarks (`reference_sizes`:
    well in the other session's view), the share it mapped (`matched`: a counterpart; its detection rate d) and
    the share it shows at all (`shown`: a counterpart, or its segments significantly above chance; v), pooled
    with a Gaussian kernel of `bandwidth` in log size, with a Laplace prior. Unknown sizes take the pooled shares.
    Returns (d, v)."""
    s = np.log(np.asarray(sizes, dtype=np.float64).reshape(-1))
    rs = np.log(np.asarray(reference_sizes, dtype=np.float64).reshape(-1))
    m = np.asarray(matched, dtype=np.float64).reshape(-1)
    v = np.maximum(np.asarray(shown, dtype=np.float64).reshape(-1), m)
    ok = np.isfinite(rs)
    rs, m, v = rs[ok], m[ok], v[ok]
    wt = np.exp(-0.5 * ((s[:, None] - rs[None, :]) / bandwidth) ** 2)
    wt = np.where(np.isfinite(s)[:, None], wt, 1.0)
    total = wt.sum(1) + 2.0
    return (wt @ m + 1.0) / total, (wt @ v + 1.0) / total


def visible_share(sizes: np.ndarray, mine: tuple[np.ndarray, np.ndarray, np.ndarray],
                  theirs: tuple[np.ndarray, np.ndarray, np.ndarray], bandwidth: float) -> np.ndarray:
    """Per size, the share of objects present without a counterpart that the other session sees at all.

    A present object the other session neither maps nor segments (a thermal camera on a bush as warm as the
    grass, a low-contrast flight) looks exactly as a removed one there, so the absence of hits is evidence of
    change only in proportion to how reliably that session sees such objects. It is measured on the pair, in
    both directions (`mine`, `theirs`: sizes, matched, shown of each map's compared landmarks, `seen_shares`):
    v_mine = (1 - gone) s_other and v_theirs = (1 - new) s_own for the sessions' sensing rates s; with as many
    objects gone as new, s_other / s_own = v_mine / v_theirs, and the better-seeing session is taken to see
    everything (so alike sessions stay at 1 whatever their share of changes). The other session misses
    1 - s_other of the objects, all of them among those it did not map (1 - d): visible = 1 - (1 - s) / (1 - d).
    """
    d, v_mine = seen_shares(sizes, *mine, bandwidth)
    _, v_theirs = seen_shares(sizes, *theirs, bandwidth)
    s_other = np.minimum(1.0, v_mine / v_theirs)
    return np.clip(1.0 - (1.0 - s_other) / np.maximum(1.0 - d, 1e-9), 0.0, 1.0)


@dataclass(frozen=True)
class Sensing:
    """How the other session sees one map's landmarks over the common area (pooled over sizes): `compared`
    landmarks of this map in its view, the share it `mapped` (a counterpart), the share it `shows` (counterpart
    or segments above chance) and `visible`, the weight its absence of hits gets (`visible_share`)."""

    compared: int
    mapped: float
    shows: float
    visible: float


def sensing(mine: tuple[np.ndarray, np.ndarray, np.ndarray], theirs: tuple[np.ndarray, np.ndarray, np.ndarray],
            bandwidth: float) -> Sensing:
    """`Sensing` of the map whose compared landmarks are `mine` by the session whose map's are `theirs`."""
    pooled = np.array([np.nan])  # an unknown size takes the pooled shares
    d, v = seen_shares(pooled, *mine, bandwidth)
    return Sensing(len(mine[0]), float(d[0]), float(v[0]), float(visible_share(pooled, mine, theirs, bandwidth)[0]))
