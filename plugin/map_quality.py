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

The ground's plane and the shared tilt are `plugin.ground_plane`'s; the flight's passes and their disagreement
`plugin.pass_heights`'. `plugin.map_verdict.judge` turns the figures into refusals (the map is unusable) and
warnings, with limits in `QualityParams`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from .ground_plane import UP, robust_plane_normal, shared_tilt_deg
from .landmark_filters import neighbour_height_residuals
from .pass_heights import PassOffset, flight_passes, pass_disagreement, pass_height_offset


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
    # the pass disagreement the pairs prove (`PassDisagreement.ratio_low`): what `map_verdict.judge` weighs
    pass_disagreement_low: float = float("nan")
    # what the poses' vertical rests on and its sigma, from their `sosmatch poses` record (poses.json's
    # `vertical_source`, `vertical_sigma_deg`; "" / NaN: not known). The tilts above are measured against that
    # vertical, so none of them can see its error; with the nadir assumption alone (`georegistration.NADIR_SOURCE`),
    # `map_verdict.judge` weighs the ground's tilt against the sigma (nu58 D1)
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
    mean_axis = mean_axis / np.linalg.norm(mean_axis) if np.linalg.norm(mean_axis) > 0 else -UP
    camera_up = -mean_axis
    view_tilt = float(np.degrees(np.arccos(np.clip(camera_up @ UP, -1.0, 1.0))))
    if n_l >= 3:
        normal = robust_plane_normal(p)
        ground_tilt = float(np.degrees(np.arccos(np.clip(normal @ UP, -1.0, 1.0))))
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
