"""Segment tracking across keyframes (SOS-Match method spec 1.5): gates, pair score, one-to-one assignment.

For each keyframe t, the candidate tracks are those whose latest observation (mask i at keyframe s) is at most
`theta_t` keyframes old. A (track, mask j of keyframe t) pair is feasible only if every gate holds:

- **Epipolar** (`theta_a`): the centroid pair lies within `epipolar_margin_px` of each other's epipolar line.
  Fundamental matrix from the two fixed poses and K; the distance is the larger of the two point-to-line distances
  (in image s and image t), so the gate means "within theta_a px in both images". With a (near) zero baseline the
  epipolar geometry is undefined and the transfer distance through the rotation homography K R K^-1 is used.
- **Cheirality** *(ours, `cheirality_check`)*: the position of m_j along the epipolar line must correspond to a
  point in front of camera s, up to `epipolar_margin_px` of slack around the vanishing point of the ray (zero
  parallax). The paper's motion gate only compares magnitudes, so it accepts both the true partner and its mirror
  image on the other side of the ray's vanishing point; this removes the mirror at no cost.
- **Motion** (`theta_v`): `| |m_i - m_j| - mu | / sigma < theta_v`. For a gap of g = t - s keyframes, mu is the
  sum of the g consecutive `mu_p` (survey legs are straight, so displacements add up) and sigma combines the g
  `sigma_p` and the centroid noise of both masks in quadrature:
  `sigma = sqrt(sum sigma_p^2 + 2 centroid_sigma_px^2)` *(ours)*. Without the centroid term a pure translation
  over flat ground gives sigma_p ~ 0.1 px and the gate would reject every segment whose centroid jitters by 1 px.
- **Point transfer** *(ours, `point_transfer_gate`)*: once a track's observation rays meet at
  `point_gate_min_ray_angle_deg` or more (smallest eigenvalue of sum(I - d d^T) >= 1 - cos of that angle), its
  least-squares point is projected into keyframe t and the candidate must lie within `epipolar_margin_px` of it;
  this replaces the epipolar, cheirality and motion gates for that track. The epipolar line admits every segment
  along it (Seneca: 54 of 338 three-view tracks were consistent; 113 of 213 with this gate), and across flight
  lines the summed image motion of the motion gate is meaningless.
- **Ground band** *(ours, `ground_band_sigmas`, `plugin.ground_band`; on by default, off in the paper preset)*: a
  track without a point yet must reappear within `epipolar_margin_px` of the stretch of its epipolar line between
  the lowest and highest height of the local ground (median +- that many robust sigmas of the heights of the
  candidate tracks' points confirmed by a third observation). With fixed poses this predicts the image motion from
  the poses and the ground, where the image-only estimate fails (Seneca: 72 of 165 steps without a measured
  motion), and removes the wrong partners that the epipolar line admits hundreds of metres above or below the
  ground.
- **Score** (`theta_q`): `q = sqrt(q_s q_f) >= min_score`, with the size score
  `q_s = 1 + cos(pi r / theta_h)` if `r = 2|h_i - h_j| / (h_i + h_j) < theta_h` else 0 (in [0, 2] as in the
  paper) and the feature score q_f, the Dice fraction of mutual ratio-test matches between the two masks' SIFT
  sets (both scores: `plugin.mask_scores`). The epipolar distances and the cheirality test: `plugin.epipolar`.

Feasible pairs are assigned one-to-one by the Hungarian algorithm maximising the sum of q over all candidate tracks
(of every age) at once; unmatched masks start new tracks. Only pairs that pass the cheap matrix gates get SIFT
matching, batched as one padded matrix product per chunk of pairs. Deterministic: no randomness anywhere.

Defaults *(ours)*, chosen on two 100-frame synthetic sessions with the classical front end (BENCHMARKS.md,
"Tracking parameters"; `tools/benchmarks/bench_tracking.py` regenerates the table): `theta_a = 12 px` is the
smallest margin at which EKF-noisy poses (0.3 deg attitude, f = 502 px) track as well as exact ones; it is ~1.5x
the 95th percentile of the epipolar distance of true links (8-12 px with EKF poses, 4-8 px exact) and wider
margins only add impurity. `theta_t = 3` keyframes bridges segmentation misses (+17-22 % mean track length
over theta_t = 1); 5 adds little and lowers purity. For other cameras scale theta_a with f x attitude error.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from .epipolar import behind_camera, epipolar_distances
from .geometry import Camera, Poses, pixel_rays, project
from .ground_band import band_distances, band_segments, local_ground
from .mask_features import MaskFeatures
from .mask_scores import desc_index, feature_scores, size_scores
from .params import TrackingParams
from .truncation import (
    TruncatedViews,
    cut_masks,
    joined_shifts,
    truncated_pairs,
    truncated_size_scores,
    truncation_state,
)

logger = logging.getLogger(__name__)

_GROUND_MIN_OBSERVATIONS = 3  # tracks whose points describe the ground for the ground band gate


@dataclass
class TrackingResult:
    """Track id of every mask of every keyframe.

    `track_ids[t][k]` is the track of mask k of keyframe t. Ids start at 0 and increase with first sighting
    (keyframe, then mask index). Every mask has a track; a track holds at most one mask per keyframe.
    `shifts[t]` (K, 2), with `TrackingParams.truncation_aware`: the outward box each mask of keyframe t was gated
    with when it joined its track (0 for a mask not cut by the border; `truncation.joined_shifts`), for the
    database's check of the links (`colmap_db.verify_associations`); None without.
    """

    track_ids: list[np.ndarray]
    num_tracks: int
    shifts: list[np.ndarray] | None = None
    _obs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def _index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(order-by-track keyframe idx, mask idx, start offset per track, count per track), cached."""
        if self._obs is None:
            tid = np.concatenate([np.asarray(t, np.int64) for t in self.track_ids] + [np.zeros(0, np.int64)])
            kf = np.concatenate([np.full(len(t), i, np.int64) for i, t in enumerate(self.track_ids)]
                                + [np.zeros(0, np.int64)])
            mk = np.concatenate([np.arange(len(t), dtype=np.int64) for t in self.track_ids]
                                + [np.zeros(0, np.int64)])
            order = np.argsort(tid, kind="stable")  # stable: observations stay in keyframe order
            counts = np.bincount(tid, minlength=self.num_tracks).astype(np.int64)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
            self._obs = (kf[order], mk[order], starts, counts)
        return self._obs

    def observations(self, track_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(keyframe indices, mask indices) of one track, in keyframe order."""
        kf, mk, starts, counts = self._index()
        if not 0 <= track_id < self.num_tracks:
            raise IndexError(f"track {track_id} out of range [0, {self.num_tracks})")
        sl = slice(starts[track_id], starts[track_id] + counts[track_id])
        return kf[sl], mk[sl]

    def track_lengths(self) -> np.ndarray:
        """(num_tracks,) number of observations of every track."""
        return self._index()[3].copy()

    def tracks_longer_than(self, n: int) -> np.ndarray:
        """Ids of the tracks with MORE than n observations (theta_n semantics), ascending."""
        return np.flatnonzero(self._index()[3] > n).astype(np.int64)


def pair_scores(
    feat_s: MaskFeatures, masks_s: np.ndarray, feat_t: MaskFeatures, camera: Camera, poses: Poses, s: int, t: int,
    mu: float, sigma: float, params: TrackingParams,
    desc_s: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    desc_t: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    predicted_xy: np.ndarray | None = None,
    band: tuple[float, float] | None = None,
    truncated: TruncatedViews | None = None,
) -> np.ndarray:
    """(n, m) score q of masks `masks_s` of keyframe s against all masks of keyframe t; 0 where infeasible.

    `mu`, `sigma` are the expected centroid displacement and its standard deviation for this keyframe gap (the
    centroid-noise term is already included by the caller). `predicted_xy` (n, 2), optional: where the row's
    track point projects in keyframe t (NaN: no point yet); such rows are gated by the distance to it (point
    transfer gate, module docstring) instead of the motion, epipolar and cheirality gates. `band`, optional:
    the (lowest, highest) height of the local ground (`plugin.ground_band`); rows without a point must then lie
    within `epipolar_margin_px` of the stretch of the epipolar line between those heights. `truncated`, optional
    (`TrackingParams.truncation_aware`): which views are cut by the image border; the size gate is then one-sided
    against each row's reference size and a pair with a cut view passes the position gates anywhere in the box
    its truncation could have shifted the centroid by (`plugin.truncation`).
    """
    n, m = len(masks_s), len(feat_t)
    q = np.zeros((n, m))
    if n == 0 or m == 0:
        return q
    xy_s = np.asarray(feat_s.centroids, np.float64)[masks_s]
    xy_t = np.asarray(feat_t.centroids, np.float64)
    if truncated is None:
        qs = size_scores(np.asarray(feat_s.sizes)[masks_s], feat_t.sizes, params.size_tolerance)
    else:
        qs = truncated_size_scores(truncated.ref_sizes, truncated.ref_whole, feat_t.sizes, truncated.cut_t,
                                   params.size_tolerance)
    has_point = (np.isfinite(predicted_xy[:, 0]) if predicted_xy is not None else np.zeros(n, bool))[:, None]
    ok = qs > 0
    if has_point.any():
        transfer = np.linalg.norm(np.where(has_point, predicted_xy, 0.0)[:, None, :] - xy_t[None, :, :], axis=2)
        ok &= ~has_point | (transfer <= params.epipolar_margin_px)
    disp = np.linalg.norm(xy_s[:, None, :] - xy_t[None, :, :], axis=2)
    if np.isfinite(mu) and np.isfinite(sigma):  # unknown image motion (NaN from a caller): no motion gate
        ok &= has_point | (np.abs(disp - mu) < params.motion_gate_sigmas * max(sigma, 1e-9))
    if not ok.any() and truncated is None:
        return q
    ok &= has_point | (epipolar_distances(camera, poses, s, t, xy_s, xy_t) <= params.epipolar_margin_px)
    if params.cheirality_check and ok.any():
        ok &= has_point | ~behind_camera(camera, poses, s, t, xy_s, xy_t, params.epipolar_margin_px)
    if band is not None and ok.any():
        rows = np.flatnonzero(ok.any(axis=1) & ~has_point[:, 0])
        if len(rows):
            dist = band_distances(band_segments(camera, poses, s, t, xy_s[rows], band), xy_t)
            ok[rows] &= ~(dist > params.epipolar_margin_px)  # NaN (no prediction for that ray): no band gate
    if truncated is not None:
        ok |= truncated_pairs(feat_s, masks_s, feat_t, camera, poses, s, t, mu, sigma, params, qs > 0, ok,
                               predicted_xy, band, truncated)
    ii, jj = np.nonzero(ok)
    if len(ii) == 0:
        return q
    desc_s = desc_s if desc_s is not None else desc_index(feat_s)
    desc_t = desc_t if desc_t is not None else desc_index(feat_t)
    qf = feature_scores(desc_s, desc_t, np.asarray(masks_s)[ii], jj, params.sift_ratio)
    qq = np.sqrt(qs[ii, jj] * qf)
    keep = qq >= params.min_score
    q[ii[keep], jj[keep]] = qq[keep]
    return q


def gap_motion(
    motion_stats: Sequence[tuple[float, float]], s: int, t: int, centroid_sigma_px: float
) -> tuple[float, float]:
    """Expected centroid displacement and its sigma between keyframes s < t (module docstring, motion gate)."""
    stats = np.asarray([motion_stats[k] for k in range(s + 1, t + 1)], np.float64).reshape(-1, 2)
    mu = float(np.sum(stats[:, 0]))
    sigma = float(np.sqrt(np.sum(stats[:, 1] ** 2) + 2.0 * centroid_sigma_px**2))
    return mu, sigma


def _predict_track_points(
    ray_a: np.ndarray, ray_b: np.ndarray, origin: np.ndarray, camera: Camera, poses: Poses, t: int, min_eig: float
) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) projection into keyframe t of each track's least-squares ray intersection, and (n, 3) that point;
    NaN where the rays are too close to parallel (smallest eigenvalue of sum(I - d d^T) below `min_eig`), and
    for the projection also where the point is not in front of camera t."""
    out = np.full((len(ray_a), 2), np.nan)
    points = np.full((len(ray_a), 3), np.nan)
    if not len(ray_a):
        return out, points
    eig_min = np.linalg.eigvalsh(ray_a)[:, 0]
    good = np.flatnonzero(eig_min >= min_eig)
    if not len(good):
        return out, points
    x = np.linalg.solve(ray_a[good], ray_b[good][:, :, None])[:, :, 0] + origin
    points[good] = x
    uv, depth = project(camera, poses.rotations[t], poses.centers[t], x)
    front = depth > 1e-9
    out[good[front]] = uv[front]
    return out, points


def _check_finite(features: Sequence[MaskFeatures], keyframe_poses: Poses) -> None:
    """ValueError naming the first keyframe with a NaN or infinite pose, mask centroid or size: one NaN centre made
    the track points' origin NaN and switched the point-transfer gate and ground band off for the whole flight
    (twice the tracks, no error), one NaN centroid failed deep in an eigen-solver (rev50 D5)."""
    finite = np.isfinite(keyframe_poses.centers).all(axis=1) & np.isfinite(keyframe_poses.rotations).all(axis=(1, 2))
    bad_pose = ~finite
    for t, feats in enumerate(features):
        if bad_pose[t]:
            raise ValueError(f"keyframe {t} ({keyframe_poses.names[t]}): NaN or infinite pose")
        if not (np.isfinite(feats.centroids).all() and np.isfinite(feats.sizes).all()):
            raise ValueError(f"keyframe {t} ({keyframe_poses.names[t]}): NaN or infinite mask centroid or size")


def track_masks(
    features: Sequence[MaskFeatures],
    camera: Camera,
    keyframe_poses: Poses,
    motion_stats: Sequence[tuple[float, float]],
    params: TrackingParams,
    descriptors: Callable[[int], np.ndarray] | None = None,
) -> TrackingResult:
    """Track the masks of a keyframe sequence (the method spec 1.5).

    Args:
        features: per keyframe, its mask description (centroids, sizes, SIFT sets).
        camera: intrinsics of every keyframe (pixels in COLMAP convention, as the centroids).
        keyframe_poses: pose of every keyframe, same order as `features`.
        motion_stats: motion_stats[t] = (mu_p, sigma_p) between keyframes t-1 and t (entry 0 unused), e.g. from
            `sosmatch.plugin.motion.image_motion_stats`; NaN where the motion is unknown: no motion gate
            for gaps spanning that step.
        params: tracking parameters.
        descriptors: descriptors(t) gives keyframe t's SIFT descriptors when `features` do not hold them (a
            flight's would not fit in memory: ~1 MB per keyframe); it is called for the keyframes of the last
            `max_track_age_keyframes` only, and only those are kept.

    Returns:
        TrackingResult with a track id for every mask.

    Raises:
        ValueError: the inputs' lengths differ, or a keyframe has a NaN or infinite pose, centroid or size.
    """
    n_kf = len(features)
    if len(keyframe_poses) != n_kf or len(motion_stats) != n_kf:
        raise ValueError(
            f"features ({n_kf}), keyframe_poses ({len(keyframe_poses)}) and motion_stats ({len(motion_stats)}) "
            "must have one entry per keyframe"
        )
    _check_finite(features, keyframe_poses)
    max_age = max(1, int(params.max_track_age_keyframes))
    point_gate = bool(params.point_transfer_gate)
    # Per track, the normal equations of the least-squares intersection of its observation rays,
    # sum (I - d d^T) X = sum (I - d d^T) C (centres relative to `origin` for precision): the track's point.
    origin = keyframe_poses.centers.mean(axis=0) if n_kf else np.zeros(3)
    ray_a = np.zeros((0, 3, 3))
    ray_b = np.zeros((0, 3))
    # Two rays at angle a give a smallest eigenvalue of exactly 1 - cos a; more rays raise it (n rays spread over
    # a: ~n a^2 / 12), so long tracks qualify at smaller spreads, as their points are pinned better too.
    min_eig = 1.0 - np.cos(np.radians(params.point_gate_min_ray_angle_deg))
    last_kf = np.zeros(0, np.int64)  # per track: keyframe of its latest observation
    last_mask = np.zeros(0, np.int64)  # per track: mask index of its latest observation
    n_rays = np.zeros(0, np.int64)  # per track: observations whose rays are in its point (all, or the whole ones)
    aware = bool(params.truncation_aware)
    # (truncation_aware) per track: the size of its latest whole view (or the largest cut one while it has none),
    # whether it has a whole view, whether its latest observation is cut and that observation's outward box; per
    # keyframe, every mask's box as it joined its track
    ref_size = np.zeros(0)
    ref_whole = np.zeros(0, bool)
    last_cut = np.zeros(0, bool)
    last_shift = np.zeros((0, 2))
    shifts: list[np.ndarray] = []
    track_ids: list[np.ndarray] = []
    desc_cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def descriptor_index(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return desc_index(features[k], None if descriptors is None else descriptors(k))

    n_matched = 0
    for t in range(n_kf):
        feat_t = features[t]
        m = len(feat_t)
        ids = np.full(m, -1, np.int64)
        cand = np.flatnonzero(last_kf >= t - max_age) if m else np.zeros(0, np.int64)
        cut_t = cut_masks(camera, feat_t) if aware else np.zeros(m, bool)
        predicted, band = None, None
        if point_gate and len(cand):
            predicted, points = _predict_track_points(ray_a[cand], ray_b[cand], origin, camera, keyframe_poses, t,
                                                      min_eig)
            # the ground under the recent keyframes: the points of the candidate tracks (seen within theta_t) that a
            # third ray confirmed (a wrong two-view link puts its point anywhere along the epipolar line; a cut view
            # adds no ray to the point, so it confirms nothing)
            band = local_ground(points[n_rays[cand] >= _GROUND_MIN_OBSERVATIONS, 2], params.ground_band_sigmas)
        if len(cand):
            desc_cache[t] = descriptor_index(t)
            q = np.zeros((len(cand), m))
            for s in np.unique(last_kf[cand]):
                rows = np.flatnonzero(last_kf[cand] == s)
                if s not in desc_cache:
                    desc_cache[s] = descriptor_index(int(s))
                mu, sigma = gap_motion(motion_stats, int(s), t, params.centroid_sigma_px)
                tracks = cand[rows]
                views = (TruncatedViews(ref_size[tracks], ref_whole[tracks], last_cut[tracks], cut_t,
                                        last_shift[tracks]) if aware else None)
                q[rows] = pair_scores(
                    features[s], last_mask[tracks], feat_t, camera, keyframe_poses, int(s), t, mu, sigma,
                    params, desc_cache[s], desc_cache[t], None if predicted is None else predicted[rows], band, views,
                )
            r_any = np.flatnonzero(q.max(axis=1) > 0)
            c_any = np.flatnonzero(q.max(axis=0) > 0)
            if len(r_any) and len(c_any):
                sub = q[np.ix_(r_any, c_any)]
                rr, cc = linear_sum_assignment(sub, maximize=True)
                good = sub[rr, cc] > 0  # infeasible pairs (0) fill the assignment but are not matches
                rows, cols = r_any[rr[good]], c_any[cc[good]]
                ids[cols] = cand[rows]
                n_matched += len(rows)
        new = np.flatnonzero(ids < 0)
        ids[new] = len(last_kf) + np.arange(len(new))
        last_kf = np.concatenate([last_kf, np.full(len(new), t, np.int64)])
        last_mask = np.concatenate([last_mask, np.zeros(len(new), np.int64)])
        n_rays = np.concatenate([n_rays, np.zeros(len(new), np.int64)])
        n_rays[ids[~cut_t]] += 1
        if aware:
            # each cut mask's box as it joins: from its track's reference before this keyframe (0: a new track)
            shift_t = joined_shifts(camera, feat_t, cut_t, np.concatenate([ref_size, np.zeros(len(new))])[ids])
            last_shift = np.concatenate([last_shift, np.zeros((len(new), 2))])
            last_shift[ids] = shift_t
            shifts.append(shift_t)
            ref_size, ref_whole, last_cut = truncation_state(ref_size, ref_whole, last_cut, len(new), ids, cut_t,
                                                              np.asarray(feat_t.sizes, np.float64))
        if point_gate and m:
            ray_a = np.concatenate([ray_a, np.zeros((len(new), 3, 3))])
            ray_b = np.concatenate([ray_b, np.zeros((len(new), 3))])
            # (truncation_aware) a cut view's centroid slides with the camera: the point is the whole views'
            seen = np.flatnonzero(~cut_t)
            d = pixel_rays(camera, feat_t.centroids[seen], keyframe_poses.rotations[t])
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
            np.add.at(ray_a, ids[seen], proj)
            np.add.at(ray_b, ids[seen], proj @ (keyframe_poses.centers[t] - origin))
        last_kf[ids] = t
        last_mask[ids] = np.arange(m)
        track_ids.append(ids)
        for old in [k for k in desc_cache if k < t - max_age]:  # descriptors older than theta_t are never needed
            del desc_cache[old]
    logger.info("tracked %d masks over %d keyframes into %d tracks (%d matches)",
                sum(len(x) for x in track_ids), n_kf, len(last_kf), n_matched)
    return TrackingResult(track_ids=track_ids, num_tracks=len(last_kf), shifts=shifts if aware else None)
