"""What changed between two aligned sessions, object by object (pure numpy; `sosmatch changes` wraps it).

Two sessions A and B of one place, B brought into A's frame by the accepted transform a_from_b. Every
landmark of either map gets one class:

- `unseen`: the other session cannot tell. Its keyframes should have seen the landmark (the landmark projected
  into the image with its own footprint, radius 2 h, as margin) fewer than `min_views` times: outside the
  other's flight, at the edge of it, or seen too rarely to have been mapped there. A landmark outside the
  common area is therefore never a change.
- `kept`: the other map has a counterpart, a landmark within the counterpart gate (`tolerance_factor` x
  theta_eps, distance in x, y and z_weight x z) of a compatible size (size ratio r <= `max_size_difference`);
  the size change is reported. One object is often several landmarks (a crown, its lit half, the clump it
  stands in: nested masks of the segmenter), and the other session may map other parts of it, so landmarks
  are judged by object: a landmark belongs to the best-supported landmark whose footprint holds it
  (`landmark_groups`), and a group with one member matched is kept as a whole. A group without a counterpart
  is still kept when the other session's own segments (every mask of its keyframes, tracked or not) show a
  size-compatible segment at the landmark's projection in significantly more keyframes than at probe points
  around it (`segment_evidence`): the object was there, only not mapped.
- `gone` (a landmark of A) / `new` (of B): seen well by the other session, no counterpart, no evidence.

Confidence (gone / new): how likely the other session would have mapped the object had it still been there.
It is the pair's own re-observation rate of landmarks like this one, fitted on every object group that the
other session saw (matched or not) by logistic regression on log size, log views and height above the ground
(`reobservation_model`): large, tall objects seen in many keyframes are found again, small ground-level
patches seldom are; a winter session re-observes summer crowns less often, and its claims get lower
confidence. Below `min_confidence` a claim is reported as unseen.

The ground under the landmarks (for heights above ground and the keyframes' ground footprints) is a coarse
height field of a low quantile of the nearby landmarks' heights (`ground_height_field`): most landmarks of a
survey are ground texture, and objects only stand above it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .association.gates import size_ratio
from .evaluation.footprints import HeightField, footprint_polygons
from .geometry import Camera, Poses, project
from .multisession import Sim3
from .params import ChangeParams

KEPT, GONE, NEW, UNSEEN = "kept", "gone", "new", "unseen"
CLASSES = (KEPT, GONE, NEW, UNSEEN)
# evidence behind a class
BY_LANDMARK, BY_NESTING, BY_PART, BY_SEGMENTS, NO_EVIDENCE, TOO_FEW_VIEWS, LOW_CONFIDENCE = (
    "landmark", "nested", "part", "segments", "none", "views", "confidence")

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
    evidence is then off for the other session's landmarks).
    """

    positions: np.ndarray
    sizes: np.ndarray
    poses: Poses
    cameras: tuple[Camera, ...]
    segments: tuple[KeyframeSegments, ...] | None = None
    support: np.ndarray | None = None

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
        if self.support is not None and len(self.support) != len(self.positions):
            raise ValueError(f"{len(self.positions)} landmarks but {len(self.support)} support values")

    def transformed(self, t: Sim3) -> SessionObservations:
        """The same session in another frame (x' = s R x + t): landmarks, sizes and camera poses moved; pixels
        do not change under a similarity, so the segments stay as they are."""
        poses = Poses(list(self.poses.names), np.einsum("ij,njk->nik", t.rotation, self.poses.rotations),
                      t.apply(self.poses.centers))
        return replace(self, positions=t.apply(self.positions), sizes=self.sizes * t.scale, poses=poses)


@dataclass(frozen=True)
class LandmarkChanges:
    """The verdict for every landmark of one map (arrays of its length, in landmark order)."""

    label: np.ndarray  # class: kept / gone / new / unseen
    evidence: np.ndarray  # why: landmark, nested, part, segments, none, views, confidence
    counterpart: np.ndarray  # index of the counterpart landmark in the other map (-1 none)
    distance_m: np.ndarray  # to the counterpart (gate metric), NaN without one
    size_change_m: np.ndarray  # counterpart size - own size, NaN without one
    views: np.ndarray  # keyframes of the other session that should have seen the landmark
    confidence: np.ndarray  # see the module docstring; 0 where the other session saw too little
    linked: np.ndarray  # the own landmark through which a part / whole was kept (-1 none)
    height_above_ground_m: np.ndarray

    def count(self, label: str) -> int:
        return int(np.count_nonzero(self.label == label))


@dataclass(frozen=True)
class ChangeResult:
    """`detect_changes` output: per-landmark verdicts of both maps, everything in A's frame."""

    a: LandmarkChanges
    b: LandmarkChanges
    positions_a: np.ndarray
    positions_b: np.ndarray  # B's landmarks in A's frame
    sizes_a: np.ndarray
    sizes_b: np.ndarray
    tolerance_m: float
    ground: HeightField
    observed_a: object  # shapely geometry: union of A's keyframe ground footprints (A's frame)
    observed_b: object  # the same for B
    params: ChangeParams = field(default_factory=ChangeParams)
    support: AlignmentSupport | None = None  # how much better the transform pairs the maps than a displaced one

    @property
    def common_area(self) -> object:
        import shapely

        return shapely.intersection(self.observed_a, self.observed_b)

    def counts(self) -> dict[str, int]:
        """Landmarks per class: kept (of A and of B), gone (A), new (B), unseen (of both maps)."""
        return {"kept_a": self.a.count(KEPT), "kept_b": self.b.count(KEPT), "gone": self.a.count(GONE),
                "new": self.b.count(NEW), "unseen_a": self.a.count(UNSEEN), "unseen_b": self.b.count(UNSEEN)}

    def summary(self) -> str:
        """One line: counts per class and the common area."""
        c = self.counts()
        area_ha = float(self.common_area.area) / 1e4
        return (f"{c['gone']} gone, {c['new']} new, {c['kept_a']} + {c['kept_b']} kept, {c['unseen_a']} + "
                f"{c['unseen_b']} unseen landmarks (A + B), {area_ha:.1f} ha seen by both")


# --- what the keyframes saw ---------------------------------------------------------------------------------


def in_view(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
            margin_factor: float = FOOTPRINT_MARGIN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which keyframes should have seen each point: the point in front of the camera and inside the image with
    its footprint (radius margin_factor x h, projected) as margin, so that a segment of it would not touch the
    image border. Returns (K, N) bool, (K, N, 2) pixels and (K, N) depths."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    h = np.nan_to_num(np.asarray(sizes, dtype=np.float64).reshape(-1), nan=0.0)
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
        u, v = uv[k, :, 0], uv[k, :, 1]
        seen[k] = (d > 0) & (u >= r) & (u <= cam.width - r) & (v >= r) & (v <= cam.height - r)
    return seen, uv, depth


def ground_height_field(points: np.ndarray, cell_m: float = GROUND_CELL_M, neighbours: int = GROUND_NEIGHBOURS,
                        quantile: float = GROUND_QUANTILE, margin_m: float = 200.0) -> HeightField:
    """A coarse ground model from landmark heights: at every node of a `cell_m` grid over the landmarks (plus
    `margin_m`, where the footprints of oblique views reach), the `quantile` of the heights of the `neighbours`
    nearest landmarks. Objects stand on the ground and most landmarks of a survey are ground texture, so a low
    quantile follows the terrain; bilinear in between, constant beyond."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if not len(p):
        raise ValueError("no landmarks to estimate the ground from")
    lo, hi = p[:, :2].min(0) - margin_m, p[:, :2].max(0) + margin_m
    nx = max(2, int(np.ceil((hi[0] - lo[0]) / cell_m)) + 1)
    ny = max(2, int(np.ceil((hi[1] - lo[1]) / cell_m)) + 1)
    gx, gy = np.meshgrid(lo[0] + cell_m * np.arange(nx), lo[1] + cell_m * np.arange(ny))
    k = min(neighbours, len(p))
    _, idx = cKDTree(p[:, :2]).query(np.column_stack([gx.ravel(), gy.ravel()]), k=k)
    idx = np.asarray(idx).reshape(-1, k)
    z = np.quantile(p[idx, 2], quantile, axis=1).reshape(ny, nx)
    return HeightField(z, float(lo[0]), float(lo[1]), cell_m, cell_m)


def observed_area(poses: Poses, cameras: Sequence[Camera], ground: HeightField) -> object:
    """Union of the keyframes' ground footprints (shapely geometry, world x, y)."""
    import shapely

    if not len(poses):
        return shapely.Polygon()
    polys = []
    for cam in dict.fromkeys(cameras):  # footprints per distinct camera
        idx = [k for k, c in enumerate(cameras) if c == cam]
        polys.extend(footprint_polygons(cam, poses.rotations[idx], poses.centers[idx], ground, per_side=4))
    return shapely.union_all(polys)


# --- objects and counterparts ---------------------------------------------------------------------------------


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
                  max_ratio: float) -> np.ndarray:
    """For each landmark, the nearest landmark of the other map that holds it (`holder_pairs`): the other session
    mapped the object as a whole (or a bigger part of it) where this map has a part; a removed object leaves, at
    most, smaller ground patches. Returns (N,) index or -1."""
    out = np.full(len(np.asarray(points).reshape(-1, 3)), -1, dtype=np.int64)
    i, j = holder_pairs(points, sizes, other_points, other_sizes, max_ratio)
    first = np.r_[True, i[1:] != i[:-1]] if len(i) else np.zeros(0, bool)  # sorted by i, then distance
    out[i[first]] = j[first]
    return out


def segment_evidence(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
                     segments: Sequence[KeyframeSegments], gate_m: float, max_size_difference: float,
                     probe_count: int, probe_radius_factor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How often another session's segments show something like each landmark where it should be.

    In every keyframe that should have seen the landmark (`in_view`), a hit is a segment whose centroid lies
    within the gate (projected: gate_m x f / depth pixels) of the landmark's projection and whose pixel size
    matches size x f / depth (ratio r <= max_size_difference). The same count at `probe_count` points on a
    circle around the landmark (radius probe_radius_factor x gate_m + 2 h, same height) gives the local chance
    rate of such segments (ground texture, neighbours). Returns (hits (N,), views (N,), chance rate (N,)),
    the rate with a Laplace prior ((probe hits + 1) / (probe views + 2)).
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
    hits = _segment_hits(all_pts, all_h, poses, cameras, segments, gate_m, max_size_difference)
    seen, _, _ = in_view(all_pts, all_h, poses, cameras)
    views = seen.sum(0)
    probe_hits = hits[n:].reshape(n, probe_count).sum(1)
    probe_views = views[n:].reshape(n, probe_count).sum(1)
    chance = (probe_hits + 1.0) / (probe_views + 2.0)
    return hits[:n], views[:n], chance


def _segment_hits(points: np.ndarray, sizes: np.ndarray, poses: Poses, cameras: Sequence[Camera],
                  segments: Sequence[KeyframeSegments], gate_m: float, max_size_difference: float) -> np.ndarray:
    from scipy.spatial import cKDTree

    seen, uv, depth = in_view(points, sizes, poses, cameras)
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
    return hits


def binomial_tail(hits: np.ndarray, trials: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """P(X >= hits) for X ~ Binomial(trials, rate), elementwise."""
    from scipy.stats import binom

    hits = np.asarray(hits)
    return np.where(hits <= 0, 1.0, binom.sf(hits - 1, trials, rate))


# --- confidence -----------------------------------------------------------------------------------------------


def reobservation_features(sizes: np.ndarray, views: np.ndarray, heights: np.ndarray,
                           support: np.ndarray | None) -> np.ndarray:
    """(N, 4) features of how findable a landmark is: log size, log views by the other session, height above
    the ground (clipped to -2..15 m) and log of its own observations (a long track is a stable object; a
    6-view track a marginal one that the other session may well have missed too). Unknown sizes take the
    median size, unknown support the median support."""
    s = np.asarray(sizes, dtype=np.float64)
    ok = np.isfinite(s) & (s > 0)
    s = np.where(ok, s, float(np.median(s[ok])) if np.any(ok) else 1.0)
    sup = np.ones(len(s)) if support is None else np.asarray(support, dtype=np.float64)
    return np.column_stack([np.log(s), np.log(np.maximum(views, 1)),
                            np.clip(np.nan_to_num(heights, nan=0.0), -2.0, 15.0), np.log(np.maximum(sup, 1))])


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1.0, iterations: int = 50) -> np.ndarray:
    """Weights (intercept first) of a logistic regression P(y | x), by Newton's method on standardised features
    with a ridge penalty on the slopes: deterministic, and finite on a separable or tiny sample."""
    x = np.asarray(x, dtype=np.float64).reshape(len(y), -1)
    y = np.asarray(y, dtype=np.float64)
    mu, sd = x.mean(0), x.std(0)
    sd = np.where(sd > 0, sd, 1.0)
    z = np.column_stack([np.ones(len(y)), (x - mu) / sd])
    w = np.zeros(z.shape[1])
    w[0] = np.log((y.sum() + 1.0) / (len(y) - y.sum() + 1.0))
    penalty = np.diag([0.0] + [ridge] * (z.shape[1] - 1))
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(z @ w)))
        grad = z.T @ (y - p) - penalty @ w
        hess = (z * (p * (1 - p))[:, None]).T @ z + penalty + 1e-9 * np.eye(len(w))
        step = np.linalg.solve(hess, grad)
        w = w + step
        if np.max(np.abs(step)) < 1e-8:
            break
    slopes = w[1:] / sd  # back to the unstandardised features
    return np.concatenate([[w[0] - slopes @ mu], slopes])


def predict_logistic(weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64).reshape(-1, len(weights) - 1)
    return 1.0 / (1.0 + np.exp(-(weights[0] + x @ weights[1:])))


# --- is the alignment plausible? -------------------------------------------------------------------------------


@dataclass(frozen=True)
class AlignmentSupport:
    """How many compared landmarks of A find a counterpart in B with the given transform, against the same count
    with B displaced (the chance level of counterparts at this map density and these sizes)."""

    compared: int  # landmarks of A that B's keyframes saw >= min_views times
    matched: int  # of those, with a counterpart under the transform
    displaced_rate: float  # the highest counterpart rate with B moved CONTROL_SHIFTS x gate in 6 directions
    p_value: float  # P(>= matched | compared, displaced_rate): the transform explains no more than chance

    @property
    def rate(self) -> float:
        return self.matched / self.compared if self.compared else 0.0

    def plausible(self, max_p: float = 1e-3, min_ratio: float = 1.5) -> bool:
        """The transform pairs the maps clearly better than chance: significant, and 1.5x the chance rate."""
        return self.p_value < max_p and self.rate >= min_ratio * self.displaced_rate


CONTROL_SHIFT = 3.0  # x the counterpart gate: a displacement beyond any landmark scatter the gate allows


def alignment_support(a: SessionObservations, b_in_a: SessionObservations, gate_m: float,
                      params: ChangeParams) -> AlignmentSupport:
    """Counterpart rate of A's compared landmarks with B as given and with B displaced horizontally by
    CONTROL_SHIFT x the gate in 6 directions (a control: the same maps, no true pairs). A wrong transform (an
    accepted match of the wrong place, a mirrored map) gives as many counterparts as the control."""
    seen, _, _ = in_view(a.positions, a.sizes, b_in_a.poses, b_in_a.cameras)
    compared = np.flatnonzero(seen.sum(0) >= params.min_views)
    pa, ha = a.positions[compared], a.sizes[compared]

    def matched(shift: np.ndarray) -> int:
        idx, _ = counterparts(pa, ha, b_in_a.positions + shift, b_in_a.sizes, gate_m, params.max_size_difference,
                              params.z_weight)
        return int(np.count_nonzero(idx >= 0))

    n = len(compared)
    real = matched(np.zeros(3))
    ang = np.arange(6) * np.pi / 3.0
    shifts = CONTROL_SHIFT * gate_m * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(6)])
    control = max((matched(d) for d in shifts), default=0) / n if n else 0.0
    p = float(binomial_tail(np.array([real]), np.array([n]), np.array([max(control, 1.0 / max(n, 1))]))[0])
    return AlignmentSupport(n, real, control, p)


# --- the verdict ----------------------------------------------------------------------------------------------


def _judge(own: SessionObservations, own_pos: np.ndarray, own_h: np.ndarray, other: SessionObservations,
           other_pos: np.ndarray, other_h: np.ndarray, heights: np.ndarray, change_label: str, gate_m: float,
           params: ChangeParams) -> LandmarkChanges:
    """Classify one map's landmarks against the other session (both already in one frame)."""
    n = len(own_pos)
    seen, _, _ = in_view(own_pos, own_h, other.poses, other.cameras)
    views = seen.sum(0)
    compared = views >= params.min_views
    index, dist = counterparts(own_pos, own_h, other_pos, other_h, gate_m, params.max_size_difference,
                               params.z_weight)
    index = np.where(compared, index, -1)
    holder = np.full(n, -1, dtype=np.int64)
    if params.nest_max_ratio >= 1:
        holder = np.where(compared & (index < 0), inside_larger(own_pos, own_h, other_pos, other_h,
                                                                params.nest_max_ratio), -1)
    label = np.full(n, UNSEEN, dtype=object)
    evidence = np.full(n, TOO_FEW_VIEWS, dtype=object)
    direct = compared & ((index >= 0) | (holder >= 0))
    label[direct] = KEPT
    evidence[index >= 0] = BY_LANDMARK
    evidence[(index < 0) & (holder >= 0)] = BY_NESTING
    # one object, several landmarks of this map: a part inside the footprint of a larger matched landmark (at
    # most part_max_ratio times its size) is kept with it
    link = np.full(n, -1, dtype=np.int64)
    if params.part_max_ratio >= 1:
        part, whole = holder_pairs(own_pos, own_h, own_pos, own_h, params.part_max_ratio, same_map=True)
        hit = compared[part] & ~direct[part] & direct[whole]
        hp, hw = part[hit], whole[hit]  # sorted by part, then distance: the nearest whole first
        first = np.r_[True, hp[1:] != hp[:-1]] if len(hp) else np.zeros(0, bool)
        link[hp[first]] = hw[first]
    by_part = link >= 0
    label[by_part] = KEPT
    evidence[by_part] = BY_PART
    open_ = compared & ~direct & ~by_part
    if other.segments is not None and np.any(open_):
        idx = np.flatnonzero(open_)
        hits, trials, chance = segment_evidence(own_pos[idx], own_h[idx], other.poses, other.cameras,
                                                other.segments, gate_m, params.max_size_difference,
                                                params.probe_count, params.probe_radius_factor)
        present = idx[binomial_tail(hits, trials, chance) < params.segment_evidence_p]
        label[present] = KEPT
        evidence[present] = BY_SEGMENTS
        open_[present] = False
    label[open_] = change_label
    evidence[open_] = NO_EVIDENCE
    # confidence: this pair's re-observation rate of landmarks like this one
    confidence = np.zeros(n)
    if np.any(compared):
        idx = np.flatnonzero(compared)
        feats = reobservation_features(own_h[idx], views[idx], heights[idx],
                                       None if own.support is None else own.support[idx])
        confidence[idx] = predict_logistic(fit_logistic(feats, label[idx] == KEPT), feats)
    weak = (label == change_label) & (confidence < params.min_confidence)
    label[weak] = UNSEEN
    evidence[weak] = LOW_CONFIDENCE
    # the counterpart of a kept landmark: its match, else the larger landmark that holds it
    index = np.where(index >= 0, index, holder)
    scale = np.array([1.0, 1.0, params.z_weight])
    if len(other_pos):
        dist = np.where(index >= 0, np.linalg.norm((own_pos - other_pos[np.maximum(index, 0)]) * scale, axis=1),
                        np.nan)
        size_change = np.where(index >= 0, other_h[np.maximum(index, 0)] - own_h, np.nan)
    else:
        dist = size_change = np.full(n, np.nan)
    return LandmarkChanges(label.astype(str), evidence.astype(str), index, dist, size_change, views, confidence,
                           link, heights)


def detect_changes(a: SessionObservations, b: SessionObservations, a_from_b: Sim3, params: ChangeParams,
                   association_tolerance_m: float) -> ChangeResult:
    """Classify every landmark of A and B as kept, gone (A), new (B) or unseen; see the module docstring.

    a_from_b brings B into A's frame (x_A = s R x_B + t). association_tolerance_m is theta_eps of the
    association that aligned the maps; the counterpart gate is `params.tolerance_factor` times it.
    """
    b_in_a = b.transformed(a_from_b)
    gate = params.tolerance_factor * association_tolerance_m
    all_pts = np.vstack([a.positions, b_in_a.positions])
    ground = ground_height_field(all_pts)
    heights_a = a.positions[:, 2] - ground(a.positions[:, 0], a.positions[:, 1])
    heights_b = b_in_a.positions[:, 2] - ground(b_in_a.positions[:, 0], b_in_a.positions[:, 1])
    res_a = _judge(a, a.positions, a.sizes, b_in_a, b_in_a.positions, b_in_a.sizes, heights_a, GONE, gate, params)
    res_b = _judge(b_in_a, b_in_a.positions, b_in_a.sizes, a, a.positions, a.sizes, heights_b, NEW, gate, params)
    return ChangeResult(
        a=res_a, b=res_b, positions_a=a.positions, positions_b=b_in_a.positions, sizes_a=a.sizes,
        sizes_b=b_in_a.sizes, tolerance_m=gate, ground=ground,
        observed_a=observed_area(a.poses, a.cameras, ground),
        observed_b=observed_area(b_in_a.poses, b_in_a.cameras, ground), params=params,
        support=alignment_support(a, b_in_a, gate, params),
    )


__all__ = ["CLASSES", "GONE", "KEPT", "NEW", "UNSEEN", "AlignmentSupport", "ChangeResult", "KeyframeSegments",
           "LandmarkChanges", "SessionObservations", "alignment_support", "counterparts", "detect_changes",
           "fit_logistic", "ground_height_field", "holder_pairs", "in_view", "observed_area", "predict_logistic",
           "reobservation_features", "segment_evidence"]
