"""How good a landmark map is, and whether its geometry can be real: pure numpy on the map's arrays.

A map made on wrong poses can still show low reprojection errors (the bundle adjustment fits points to whatever
poses it is given), so the figures here compare the map with facts that hold for every survey, whatever the
camera, the terrain or the flying height:

- **support**: landmarks, landmarks per keyframe, the share of keyframes that observe any landmark, and the
  share of long tracks (more than theta_n observations) that became landmarks: with wrong relative poses the
  tracks' observations do not meet in one point and fail the reprojection limit.
- **reprojection** p50 / p90 of the landmarks' mean errors (after the points-only bundle adjustment).
- **flying height** H: per keyframe, its height above the median height of the landmarks it observes (the ground
  it sees); H is the median over keyframes, and `height_above_ground_spread` their p10-p90 range over H (a level
  flight over level ground: ~0; hills: the relief over H).
- **ground roughness** `height_spread`: p90 of |landmark height - median height of its 8 nearest landmarks| (the
  local ground, slope-free to first order) over H. Trees and roofs stand out of the ground by a fraction of
  the flying height (an aircraft flies above what it maps); beyond 1 H the map is refused: a tenth of it would
  sit farther from its neighbours' ground than the cameras fly above it.
- **landmarks above a camera**: landmarks higher than a camera whose ground position is within the landmark's
  own footprint (2 h_S) of it: the aircraft would have flown through the object. Any camera, any terrain.
- **tilt**: the ground's tilt (normal of a robust plane through the landmarks against world up), the cameras'
  (mean viewing direction against straight down), and the block tilt, the part of the tilt that both share
  (`block_tilt`). A whole block rotated off gravity (georegistration from camera centres that are nearly
  collinear or coplanar leaves that rotation free) tilts the ground and the cameras together, keeping the views
  perpendicular to the ground; a real slope under a levelled (gimbal or IMU-levelled) camera tilts only the
  ground, an oblique camera over level ground only the cameras.

`judge` turns the figures into refusals (the map is unusable) and warnings, with limits in `QualityParams`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numpy as np

from .georegistration import NADIR_SOURCE
from .image_quality import FlightImages, blank_warning, image_causes
from .landmark_filters import neighbour_height_residuals
from .params import QualityParams
from .pass_heights import PassOffset, pass_height_offset

_UP = np.array([0.0, 0.0, 1.0])

# a ground tilted beyond this many of that vertical's sigmas is said (`judge`): level ground reads the vertical
# too, and the two readings disagree. Real sites slope 1-2 deg (synthetic and real maps); the nadir sigma is 3 deg,
# so only a ground past 4.5 deg is said. Seneca without GPS altitude (a camera 6.6 deg nose-up, the block 4.8 deg
# off): 5.2 deg, 1.7 sigmas; its reference map's ground 1.5 deg (nu58 D1)
NADIR_GROUND_TILT_SIGMAS = 1.5


@dataclass(frozen=True)
class MapQuality:
    """The quality figures of one map (see the module doc); NaN where a figure has no data."""

    landmarks: int
    keyframes: int
    landmarks_per_keyframe: float
    keyframes_with_landmarks: float  # share of keyframes observing at least one landmark
    track_yield: float  # landmarks / tracks long enough to become one
    reprojection_p50_px: float
    reprojection_p90_px: float
    flying_height_m: float  # median keyframe height above the ground it sees
    height_above_ground_spread: float  # (p90 - p10) of the keyframes' heights above their ground, over H
    height_spread: float  # p90 |landmark height - its neighbours' median| over H
    landmarks_above_cameras: int
    landmarks_under_cameras: int  # landmarks within 2 h_S of some camera's ground position (where "above" can be told)
    passes: int
    passes_without_landmarks: int  # passes of >= 3 keyframes none of which sees a landmark
    pass_disagreement: float  # worst pair of passes: lower quartile of |dz| of their neighbours / of one pass
    pass_offset_m: float  # the same pair: the two quartiles' difference in metres
    ground_tilt_deg: float
    view_tilt_deg: float
    block_tilt_deg: float
    # the passes' own triangulations of their common landmarks (`plugin.pass_heights`): the worst pair's offset
    # in height and that offset over its standard error (NaN: no observation rays given, or no such pair)
    pass_height_offset_m: float = float("nan")
    pass_height_offset_z: float = float("nan")
    # the pass disagreement the pairs prove (`PassDisagreement.ratio_low`): what `judge` weighs
    pass_disagreement_low: float = float("nan")
    # what the poses' vertical rests on and its sigma, from their `sosmatch poses` record (poses.json's
    # `vertical_source`, `vertical_sigma_deg`; "" / NaN: not known). The tilts above are measured against that
    # vertical, so none of them can see its error; with the nadir assumption alone (`NADIR_SOURCE`), `judge`
    # weighs the ground's tilt against the sigma (nu58 D1)
    vertical_source: str = ""
    vertical_sigma_deg: float = float("nan")

    def to_dict(self) -> dict[str, float | int]:
        return {k: (round(v, 4) if isinstance(v, float) and np.isfinite(v) else v if not isinstance(v, float)
                    else None) for k, v in asdict(self).items()}

    def line(self) -> str:
        """A short summary for the end of `sosmatch map`'s one-line report."""
        def fmt(v: float, spec: str) -> str:
            return format(v, spec) if np.isfinite(v) else "n/a"

        # the tilts are against the poses' own vertical: "block tilt" alone read as the block's error against
        # gravity, which no figure of the map can see (nu58 D1: "block tilt 1 deg" on a block 4.8 deg off)
        vertical = "the poses' vertical"
        if self.vertical_source:
            sigma = f" +-{self.vertical_sigma_deg:.1f} deg" if np.isfinite(self.vertical_sigma_deg) else ""
            vertical += f" ({self.vertical_source}{sigma})"
        return (f"reprojection p50/p90 {fmt(self.reprojection_p50_px, '.1f')}/{fmt(self.reprojection_p90_px, '.1f')}"
                f" px, {fmt(self.landmarks_per_keyframe, '.1f')} landmarks/keyframe, height spread "
                f"{fmt(self.height_spread, '.2f')} H (H {fmt(self.flying_height_m, '.0f')} m), tilt against "
                f"{vertical}: ground {fmt(self.ground_tilt_deg, '.0f')} deg, views {fmt(self.view_tilt_deg, '.0f')} "
                f"deg, both together {fmt(self.block_tilt_deg, '.0f')} deg")


@dataclass
class Verdict:
    """`judge`'s result: refusals make the map unusable; warnings say what looks doubtful."""

    refusals: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.refusals


def robust_plane_normal(points: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Upward unit normal of a plane through (N, 3) points, by iteratively reweighted total least squares
    (Cauchy weights at 2 robust sigmas of the distances): trees, roofs and wrong landmarks do not tilt it. The
    first weights are those of the horizontal plane through the median height: from uniform weights, a few
    landmarks hundreds of metres below a narrow strip of the others made a vertical plane the best fit, and the
    iteration stayed there (Seneca mapped with the default parameters: a 89 deg "ground tilt" over flat fields;
    1.4 deg from this start). A sloped site still pulls the fit onto its slope."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normal = _UP.copy()
    w = _cauchy_weights(p[:, 2] - np.median(p[:, 2])) if len(p) else np.ones(0)
    for _ in range(iterations):
        c = np.average(p, axis=0, weights=w)
        d = p - c
        cov = (d * w[:, None]).T @ d
        _, vecs = np.linalg.eigh(cov)
        normal = vecs[:, 0]
        w = _cauchy_weights(d @ normal)
    return normal if normal[2] >= 0 else -normal


def _cauchy_weights(dist: np.ndarray) -> np.ndarray:
    """Cauchy weights of distances to a plane at 2 robust sigmas (1.4826 x their median absolute value)."""
    scale = 1.4826 * np.median(np.abs(dist)) + 1e-9
    return 1.0 / (1.0 + (dist / (2.0 * scale)) ** 2)


def shared_tilt_deg(ground_up: np.ndarray, camera_up: np.ndarray) -> float:
    """The tilt (deg) that the ground's normal and the cameras' up direction (opposite of the view) share: the
    smaller of their horizontal components, counted only as far as they lean the same way."""
    tg, tc = np.asarray(ground_up, float)[:2], np.asarray(camera_up, float)[:2]
    ng, nc = float(np.hypot(*tg)), float(np.hypot(*tc))
    if ng < 1e-12 or nc < 1e-12:
        return 0.0
    cos_phi = float(tg @ tc) / (ng * nc)
    s = min(ng, nc) * max(0.0, cos_phi)
    return float(np.degrees(np.arcsin(min(1.0, s))))


def heights_seen_by_keyframe(heights: np.ndarray, observed_keyframes: Sequence[np.ndarray],
                             num_keyframes: int) -> list[list[float]]:
    """Per keyframe, the heights of the landmarks it observes (`heights[i]` for landmark i, observed in the
    keyframes `observed_keyframes[i]`); empty for a keyframe that observes none. The map's flying height above
    what each keyframe sees is read from these (`assess_map`: their median; the take-off check of `map`: a low
    quantile)."""
    seen: list[list[float]] = [[] for _ in range(num_keyframes)]
    for i, kfs in enumerate(observed_keyframes):
        for k in np.asarray(kfs, np.int64):
            seen[k].append(heights[i])
    return seen


def assess_map(
    positions: np.ndarray,
    sizes_m: np.ndarray,
    errors_px: np.ndarray,
    observed_keyframes: list[np.ndarray],
    camera_centers: np.ndarray,
    camera_axes: np.ndarray,
    long_tracks: int,
    neighbours: int = 8,
    observation_rays: list[np.ndarray] | None = None,
    pass_offset_margin: float = 5.0,
) -> MapQuality:
    """The quality figures of a map.

    Args:
        positions: (L, 3) landmarks (world frame, z up); sizes_m: (L,) metric sizes h_S; errors_px: (L,) mean
            reprojection errors.
        observed_keyframes: per landmark, the keyframe indices observing it.
        camera_centers: (K, 3) keyframe centres; camera_axes: (K, 3) viewing directions (camera z in the world).
        long_tracks: tracks long enough to become landmarks (more than theta_n observations).
        neighbours: landmarks whose median height is a landmark's local ground.
        observation_rays: per landmark, (n, 3) world directions of its observations (order of
            `observed_keyframes`); with them the passes' heights are compared landmark by landmark
            (`pass_heights.pass_height_offset`, reporting the pair beyond `pass_offset_margin` standard errors).
    """
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    centers = np.asarray(camera_centers, np.float64).reshape(-1, 3)
    axes = np.asarray(camera_axes, np.float64).reshape(-1, 3)
    n_l, n_k = len(p), len(centers)
    nan = float("nan")
    errors = np.asarray(errors_px, np.float64)
    p50, p90 = (float(v) for v in np.percentile(errors, [50, 90])) if n_l else (nan, nan)
    ground_of_kf = heights_seen_by_keyframe(p[:, 2], observed_keyframes, n_k)
    seen = np.array([bool(g) for g in ground_of_kf], bool)
    agl = np.array([centers[k, 2] - np.median(g) for k, g in enumerate(ground_of_kf) if g])
    flying = float(np.median(agl)) if len(agl) else nan
    agl_spread = float((np.percentile(agl, 90) - np.percentile(agl, 10)) / abs(flying)) \
        if len(agl) >= 2 and flying != 0 else nan
    resid = neighbour_height_residuals(p, neighbours)
    spread = float(np.percentile(np.abs(resid), 90) / abs(flying)) if resid is not None and flying != 0 else nan
    above, under = _landmarks_above_cameras(p, np.asarray(sizes_m, np.float64), centers)
    passes = flight_passes(centers)
    disagreement, pass_offset, disagreement_low = pass_disagreement(p, sizes_m, observed_keyframes, passes, neighbours)
    offset = pass_height_offset(observed_keyframes, observation_rays, p, centers, passes, margin=pass_offset_margin) \
        if observation_rays is not None else PassOffset(nan, nan, 0)
    long_passes = [k for k in np.unique(passes) if np.count_nonzero(passes == k) >= 3]
    empty = sum(1 for k in long_passes if not seen[passes == k].any()) if n_l else 0
    mean_axis = axes.sum(axis=0)
    mean_axis = mean_axis / np.linalg.norm(mean_axis) if np.linalg.norm(mean_axis) > 0 else -_UP
    camera_up = -mean_axis
    view_tilt = float(np.degrees(np.arccos(np.clip(camera_up @ _UP, -1.0, 1.0))))
    if n_l >= 3:
        normal = robust_plane_normal(p)
        ground_tilt = float(np.degrees(np.arccos(np.clip(normal @ _UP, -1.0, 1.0))))
        block_tilt = shared_tilt_deg(normal, camera_up)
    else:
        ground_tilt = block_tilt = nan
    return MapQuality(
        landmarks=n_l, keyframes=n_k, landmarks_per_keyframe=n_l / n_k if n_k else nan,
        keyframes_with_landmarks=float(seen.mean()) if n_k else nan,
        track_yield=n_l / long_tracks if long_tracks else nan,
        reprojection_p50_px=p50, reprojection_p90_px=p90, flying_height_m=flying,
        height_above_ground_spread=agl_spread, height_spread=spread, landmarks_above_cameras=above,
        landmarks_under_cameras=under, passes=len(long_passes), passes_without_landmarks=empty,
        pass_disagreement=disagreement, pass_offset_m=pass_offset, pass_disagreement_low=disagreement_low,
        ground_tilt_deg=ground_tilt, view_tilt_deg=view_tilt, block_tilt_deg=block_tilt,
        pass_height_offset_m=offset.offset_m, pass_height_offset_z=offset.z,
    )


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
    height) make a large ratio too, so the offset in metres is returned beside it (`judge` weighs it against the
    flying height)."""
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
    height = q[:, 2] - _plane_height(robust_plane_normal(p), np.median(p, axis=0), q[:, :2])
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


def _plane_height(normal: np.ndarray, point: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height of the plane through `point` with upward `normal` at horizontal positions xy (M, 2)."""
    return point[2] - (normal[0] * (xy[:, 0] - point[0]) + normal[1] * (xy[:, 1] - point[1])) / normal[2]


def _landmarks_above_cameras(positions: np.ndarray, sizes_m: np.ndarray, centers: np.ndarray) -> tuple[int, int]:
    """(landmarks higher than some camera that was within the landmark's footprint (2 h_S, ground plane),
    landmarks with any camera within their footprint)."""
    if not len(positions) or not len(centers):
        return 0, 0
    from scipy.spatial import cKDTree

    radius = 2.0 * np.where(np.isfinite(sizes_m), sizes_m, 0.0)
    tree = cKDTree(centers[:, :2])
    above = under = 0
    for i, near in enumerate(tree.query_ball_point(positions[:, :2], radius)):
        if near:
            under += 1
            above += int(positions[i, 2] > centers[near, 2].min())
    return above, under


def isolated_cameras(centers: np.ndarray, flying_height_m: float, half_diagonal_px: float,
                     focal_px: float) -> np.ndarray:
    """Indices of cameras that share no ground with any other: their nearest other centre is farther than the
    diagonal of one image's ground footprint at the flying height (2 H x half diagonal / focal; nadir views).
    Such a camera can hold no track; in a pose file it is a wrong position (a failed registration placed a Seneca
    frame 2000 km off). Empty without a flying height or with fewer than 2 cameras."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(c) < 2 or not np.isfinite(flying_height_m) or flying_height_m <= 0 or focal_px <= 0:
        return np.zeros(0, np.int64)
    from scipy.spatial import cKDTree

    nearest, _ = cKDTree(c).query(c, k=2)
    reach = 2.0 * flying_height_m * half_diagonal_px / focal_px
    return np.flatnonzero(nearest[:, 1] > reach)


def _likely_cause(poses: str, poses_fit: str, causes: list[str]) -> str:
    """The cause a warning names: the images when they measure poor, the poses otherwise, but never the poses
    alone when the pose check found them fitting (`poses_fit`, its phrase)."""
    if causes:
        short = ", ".join(c.split(":")[0] for c in causes)  # the figures stand in the images' own warning
        return f"more likely the images: {short}" + (f"; {poses_fit}" if poses_fit else "")
    if poses_fit:
        return f"{poses}, though {poses_fit}: poor images?"
    return poses


def _nadir_ground_tilt(q: MapQuality) -> str:
    """A warning when the poses' vertical rests on the nadir assumption alone (`georegistration.NADIR_SOURCE`) and
    the mapped ground tilts more than `NADIR_GROUND_TILT_SIGMAS` of its sigma against it; "" otherwise. Level
    ground is a reading of the vertical too, and neither is measured: the site may slope, or the cameras were
    tilted on average (a fixed-wing's pitch) and the whole block with them. Both are said; nothing is corrected."""
    sigma = q.vertical_sigma_deg
    if q.vertical_source != NADIR_SOURCE or not (np.isfinite(sigma) and sigma > 0) or \
            not (np.isfinite(q.ground_tilt_deg) and q.ground_tilt_deg > NADIR_GROUND_TILT_SIGMAS * sigma):
        return ""
    return (f"the mapped ground tilts {q.ground_tilt_deg:.1f} deg against the poses' vertical, "
            f"{q.ground_tilt_deg / sigma:.1f} x the +-{sigma:.1f} deg of the nadir assumption it rests on (no "
            "attitude tags, no GPS heights): either the site slopes that much, or the cameras looked that far off "
            "straight down on average (a fixed-wing's pitch) and the whole map is tilted with them, positions off "
            f"by about the flying height x tan({q.ground_tilt_deg:.1f} deg)"
            + (f" = {abs(q.flying_height_m) * np.tan(np.radians(q.ground_tilt_deg)):.0f} m"
               if np.isfinite(q.flying_height_m) else "")
            + "; not corrected: give attitude tags (--telemetry) or the GPS altitudes to measure the vertical")


def landmark_views(theta_n: int | None = None) -> str:
    """What a landmark needs, in words: the demo's refusal of too few frames and the map's of no landmarks on too
    few keyframes say it alike (`theta_n`: the value, when known)."""
    return f"a landmark needs more than theta_n{'' if theta_n is None else f' = {theta_n}'} views, one per keyframe"


def judge(q: MapQuality, limits: QualityParams, min_landmarks: int = 1,
          images_flying_height_m: float = float("nan"), poses_fit: str = "",
          images: FlightImages | None = None, contrast: str = "", min_observations: int = 0,
          remedy: str = "") -> Verdict:
    """Refusals and warnings for a map's figures (limits and their reasons: `QualityParams`). `min_landmarks`:
    fewer make no usable map (`sosmatch map` passes association.min_associations + 1: a match needs more than
    theta_S landmarks in common). `images_flying_height_m`: the flying height the pose check's own matches
    triangulate to (NaN: not checked), which the map's must agree with. `poses_fit`: the pose check's phrase
    when it found the poses fitting the images (`pose_check.poses_fit_images`, "" otherwise); `images`: the
    keyframes' image figures (`plugin.image_quality`). With them, warnings about a thin map name the images
    (blank keyframes, noise, blur) rather than the poses. `contrast`: the flight's low contrast as a cause
    (`FlightContrast.cause`, "" when it was normal), said when the map is thin. `min_observations`: the theta_n the
    map was made with (0: unknown); a map of no more keyframes than that can hold no landmark, which is said as the
    cause. `remedy`: what the flight's own figures say would map it better (`params.survey_preset_remedy`), said
    with a thin, empty or refused-as-too-small map (nu58 D5: the refusal blamed the ground and the images only)."""
    tail = f"; {remedy}" if remedy else ""
    v = Verdict()
    causes = image_causes(images, limits.min_image_contrast_to_noise, limits.min_image_sharpness,
                          limits.min_jpeg_quality, limits.max_motion_smear_px)
    blank = blank_warning(images, q.keyframes)
    if blank:
        v.warnings.append(blank)
    if q.landmarks == 0 and 0 < q.keyframes <= min_observations:
        # the cause is certain, whatever the images (nu49: a 5-frame flight refused with no cause named)
        v.refusals.append(f"the map has no landmarks: {landmark_views(min_observations)}, and the flight has "
                          f"{q.keyframes} keyframes (fly more frames, or set triangulation.min_observations lower)")
        return v
    if q.landmarks == 0:
        said = causes + ([contrast] if contrast else [])
        v.refusals.append("the map has no landmarks" + (f" ({'; '.join(said)})" if said else "")
                          + (f" ({blank.split(' (')[0]})" if blank else "") + tail)
        return v
    # a thin map may still match, but the user must know it is thin, and why, before trusting a "no match"
    thin = 0 < q.landmarks_per_keyframe < limits.warn_landmarks_per_keyframe
    said = causes + ([contrast] if contrast and thin else [])
    if said:
        v.warnings.append(f"{'; '.join(said)}: expect a thin map (here {q.landmarks_per_keyframe:.2f} landmarks "
                          f"per keyframe, {q.landmarks} in all){tail}")
    elif thin:
        v.warnings.append(f"a thin map: {q.landmarks_per_keyframe:.2f} landmarks per keyframe, {q.landmarks} in "
                          f"all (normal maps have {limits.warn_landmarks_per_keyframe:g} or more): few distinct "
                          "objects on the ground, or images that do not show them (see the figure)" + tail)
    if q.landmarks < min_landmarks:
        v.refusals.append(f"only {q.landmarks} landmark(s): a map needs at least {min_landmarks} to be matched"
                          + tail)
    if q.landmarks_under_cameras and \
            q.landmarks_above_cameras / q.landmarks_under_cameras > limits.max_share_above_cameras:
        v.refusals.append(f"{q.landmarks_above_cameras} of the {q.landmarks_under_cameras} landmarks under the flight "
                          "path lie above a camera that flew over them (the poses do not fit the images)")
    if np.isfinite(q.block_tilt_deg) and q.block_tilt_deg > limits.max_block_tilt_deg:
        v.refusals.append(f"the block is tilted {q.block_tilt_deg:.0f} deg against gravity: ground and cameras lean "
                          f"together (ground {q.ground_tilt_deg:.0f} deg, view {q.view_tilt_deg:.0f} deg); the "
                          "poses' vertical is wrong")
    if np.isfinite(q.flying_height_m) and q.flying_height_m <= 0:
        v.refusals.append(f"the cameras fly below the ground they see (height {q.flying_height_m:.1f} m)")
    h_map, h_images = q.flying_height_m, images_flying_height_m
    if np.isfinite(h_map) and np.isfinite(h_images) and h_map > 0 and h_images > 0 and \
            max(h_map / h_images, h_images / h_map) > limits.max_height_disagreement:
        v.refusals.append(f"the landmarks put the cameras {h_map:.0f} m above the ground, the images' own matches "
                          f"{h_images:.0f} m (at most {limits.max_height_disagreement:g} x apart): the landmarks are "
                          "triangulated wrong (poses that do not fit the images, or wrong tracks)")
    if np.isfinite(q.height_spread) and q.height_spread > limits.max_height_spread:
        v.refusals.append(f"landmark heights scatter by {q.height_spread:.1f} x the flying height "
                          f"({q.flying_height_m:.0f} m) around their neighbours' ground (at most "
                          f"{limits.max_height_spread:g}): wrong tracks or wrong poses")
    # judged on what the pairs prove (figures made before that bound existed: the ratio itself)
    proven = q.pass_disagreement_low if np.isfinite(q.pass_disagreement_low) else q.pass_disagreement
    if np.isfinite(proven) and proven > limits.max_pass_disagreement:
        offset_limit = limits.max_pass_offset * abs(q.flying_height_m)
        said = (f"landmarks seen from two passes of the flight disagree in height {q.pass_disagreement:.1f} x more "
                f"than neighbours of one pass (at least {proven:.1f} x at {PASS_EVIDENCE_SIGMAS:g} sigma; at most "
                f"{limits.max_pass_disagreement:g}), by {q.pass_offset_m:.1f} m")
        if not np.isfinite(offset_limit) or q.pass_offset_m > offset_limit:
            v.refusals.append(f"{said} (at most {offset_limit:.1f} m, {limits.max_pass_offset:.0%} of the flying "
                              "height): the passes' poses disagree (altitude drift?)")
        else:
            v.warnings.append(f"{said}: " + _likely_cause("the passes' poses differ a little (drifting odometry?)",
                                                           poses_fit, causes))
    offset_limit = limits.max_pass_offset * abs(q.flying_height_m)
    if np.isfinite(q.pass_height_offset_z) and q.pass_height_offset_z > limits.pass_offset_margin and \
            np.isfinite(offset_limit) and q.pass_height_offset_m > offset_limit:
        v.refusals.append(f"two passes of the flight, each triangulating the landmarks both saw, put them "
                          f"{q.pass_height_offset_m:.1f} m apart in height ({q.pass_height_offset_z:.0f} standard "
                          f"errors; at most {offset_limit:.1f} m, {limits.max_pass_offset:.0%} of the flying "
                          "height): the passes' poses disagree in height (altitude drift, tilted or offset heights)")
    nadir_doubt = _nadir_ground_tilt(q)
    if nadir_doubt:
        v.warnings.append(nadir_doubt)
    elif np.isfinite(q.ground_tilt_deg) and q.ground_tilt_deg > limits.warn_ground_tilt_deg and \
            not (np.isfinite(q.block_tilt_deg) and q.block_tilt_deg > limits.max_block_tilt_deg):
        v.warnings.append(f"the ground tilts {q.ground_tilt_deg:.0f} deg under cameras tilted "
                          f"{q.view_tilt_deg:.0f} deg: a steep site, or GPS heights that drift along the flight")
    if np.isfinite(q.flying_height_m) and q.flying_height_m > limits.warn_flying_height_m:
        v.warnings.append(f"the cameras fly {q.flying_height_m:.0f} m above the ground they see (more than "
                          f"{limits.warn_flying_height_m:.0f} m, beyond any mapping flight): are the poses in "
                          "centimetres, millimetres or feet instead of metres?")
    if q.passes_without_landmarks:
        cause = _likely_cause("their poses may not fit their images, e.g. a wrong heading", poses_fit, causes)
        v.warnings.append(f"{q.passes_without_landmarks} of {q.passes} passes of the flight see no landmark at all "
                          f"({cause})")
    if np.isfinite(q.keyframes_with_landmarks) and q.keyframes_with_landmarks < limits.min_keyframes_with_landmarks:
        v.warnings.append(f"only {q.keyframes_with_landmarks:.0%} of the keyframes see a landmark")
    if np.isfinite(q.track_yield) and q.track_yield < limits.min_track_yield:
        cause = _likely_cause("poses or camera doubtful", poses_fit, causes)
        v.warnings.append(f"only {q.track_yield:.0%} of the long tracks triangulated ({cause})")
    return v
