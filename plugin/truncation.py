"""Masks cut by the image border as truncated views (ours; `TrackingParams.truncation_aware`).

A mask whose extent reaches past the image border (`landmark_size.border_sides`: its 2-sigma extent, tested in the
real image: `mask_features.border_of`) shows only the part of its object inside the frame: its size is a lower
bound of the object's, and its centroid lies inward of the object's, by at most the object's half-extent less the
visible part's along each axis where it is cut (`outward_shifts`, towards the sides of the real border that cut
it). The tracker's gates read a cut view that way:

- **size** (`truncated_size_scores`): one-sided against the track's latest whole view: a cut candidate may be
  smaller than it, not larger by more than theta_h; a track seen only cut gives a lower bound; two cut views
  carry no size evidence.
- **position** (`relaxed_position_gates`): the point-transfer, epipolar, cheirality, motion and ground-band gates
  accept the centroid anywhere in the outward box the truncation could have shifted it by: they are evaluated at
  the box's centre with the margin widened by its half-diagonal (the disc around the centre that holds the box).
  A cut view's box is fixed when it joins its track (`box_object_sizes`: the larger of the track's reference
  size then and its own); the tracker keeps it (`TrackingResult.shifts`) for the view's later links and the
  database's verification of the links uses the same boxes, so the check cannot drop a link the tracker made for
  want of box.
- **the ground band** (in `tracking.track_masks`): a track's point describes the ground once three whole views
  meet in it (a cut view adds no ray to the point, so it confirms nothing).
- **the track's point** (in `tracking.track_masks`): from whole views only, as a landmark is located
  (`triangulation.located_from_whole_masks`).

Why: on world 229's and 331's summer maps (BENCHMARKS.md, "one crown, one segment?") a third to a half of the
whole-to-whole links of one crown fail, 63-80 % of the size failures and 51-64 % of the epipolar ones at the frame
edge: the tracks break at every pass's edge and the crowns never reach theta_n observations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .epipolar import behind_camera, epipolar_distances
from .geometry import Camera, Poses
from .ground_band import band_distances, band_segments
from .mask_features import MaskFeatures, border_of
from .mask_scores import size_scores
from .params import TrackingParams

_EXTENT_SIGMAS = 2.0  # a disc of radius R has sigma R / 2 and h = sqrt(lambda_max) = R / 2: extent = 2 sigma


def cut_masks(camera: Camera, feat: MaskFeatures) -> np.ndarray:
    """(K,) True for the masks of one keyframe cut by the real image's border (`mask_features.border_of`)."""
    if not len(feat):
        return np.zeros(0, bool)
    return border_of(feat, camera).any(axis=(1, 2))


def outward_shifts(border: np.ndarray, covariances: np.ndarray, object_sizes: np.ndarray) -> np.ndarray:
    """(n, 2) the outward corner of the box the truncation could have shifted each centroid by (0 for a mask not
    cut): along each axis where the mask's extent passes the border (`border` (n, 2, 2), the sides that cut it in
    the real image: `mask_features.border_of`), towards that border, by the object's half-extent (2 x
    `object_sizes`, the sizes h of whole views) less the visible part's (2 sigma of `covariances` on that axis);
    nothing on an axis cut on both sides (the object spans the frame: no direction)."""
    sig = np.sqrt(np.maximum(np.diagonal(np.asarray(covariances, np.float64).reshape(-1, 2, 2), axis1=1, axis2=2),
                             0.0))
    ext = _EXTENT_SIGMAS * sig
    sides = np.asarray(border, bool).reshape(-1, 2, 2)
    direction = sides[:, :, 1].astype(np.float64) - sides[:, :, 0].astype(np.float64)  # both sides cut: 0
    reach = np.maximum(_EXTENT_SIGMAS * np.asarray(object_sizes, np.float64).reshape(-1, 1) - ext, 0.0)
    return direction * reach


def box_object_sizes(reference: np.ndarray, own: np.ndarray) -> np.ndarray:
    """The object size h behind a cut view's outward box (`outward_shifts`): the larger of its track's reference
    size when the view joins it (`TruncatedViews.ref_sizes`; 0 for a view that starts a track) and the view's
    own size (the size gate lets a cut view exceed a whole reference by up to theta_h). The one rule for the
    tracker's gates and the database's check of its links (module docstring)."""
    return np.maximum(np.asarray(reference, np.float64), np.asarray(own, np.float64))


def joined_shifts(camera: Camera, feat: MaskFeatures, cut: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(K, 2) the outward box of each mask of one keyframe as it joins its track (0 for a whole mask): the object
    size by `box_object_sizes` from `reference` (K,), its track's reference size before this keyframe (0 for a
    new track)."""
    out = np.zeros((len(feat), 2))
    sel = np.flatnonzero(np.asarray(cut, bool))
    if len(sel):
        obj = box_object_sizes(np.asarray(reference, np.float64)[sel], np.asarray(feat.sizes, np.float64)[sel])
        out[sel] = outward_shifts(border_of(feat, camera)[sel], feat.covariances[sel], obj)
    return out


def truncated_size_scores(ref_sizes: np.ndarray, ref_whole: np.ndarray, sizes_t: np.ndarray, cut_t: np.ndarray,
                          theta_h: float) -> np.ndarray:
    """(n, m) q_s (`mask_scores.size_scores`) with cut views as lower bounds: r counts only the difference that a cut
    view cannot explain (a cut candidate smaller than a whole reference, a whole candidate larger than a cut one);
    between two cut views r = 0."""
    hi = np.asarray(ref_sizes, np.float64)[:, None]
    hj = np.asarray(sizes_t, np.float64)[None, :]
    whole_i = np.asarray(ref_whole, bool)[:, None]
    cut_j = np.asarray(cut_t, bool)[None, :]
    explained = (whole_i & cut_j & (hj <= hi)) | (~whole_i & ~cut_j & (hj >= hi)) | (~whole_i & cut_j)
    return np.where(explained, 2.0, size_scores(ref_sizes, sizes_t, theta_h))  # r = 0: the full score


def relaxed_position_gates(
    camera: Camera, poses: Poses, s: int, t: int, xy_s: np.ndarray, shift_s: np.ndarray, xy_t: np.ndarray,
    shift_t: np.ndarray, predicted: np.ndarray | None, mu: float, sigma: float, band: tuple[float, float] | None,
    margin_px: float, motion_sigmas: float, cheirality: bool,
) -> np.ndarray:
    """(m,) whether one track's last observation (`xy_s` (2,), its outward shift `shift_s` (2,)) may be the
    candidates `xy_t` (m, 2) with shifts `shift_t` (m, 2) under the tracker's position gates (module docstring).

    `predicted` (2,): where the track's point (from whole views) projects in keyframe t, NaN or None without one:
    then only the point-transfer gate applies, as in `tracking.pair_scores`."""
    ct = np.asarray(xy_t, np.float64).reshape(-1, 2) + 0.5 * shift_t
    rho_t = 0.5 * np.linalg.norm(shift_t, axis=1)
    if predicted is not None and np.all(np.isfinite(predicted)):
        return np.linalg.norm(ct - predicted[None, :], axis=1) <= margin_px + rho_t
    cs = (np.asarray(xy_s, np.float64) + 0.5 * shift_s).reshape(1, 2)
    slack = 0.5 * float(np.linalg.norm(shift_s)) + rho_t
    ok = np.ones(len(ct), bool)
    if np.isfinite(mu) and np.isfinite(sigma):
        disp = np.linalg.norm(cs - ct, axis=1)
        ok &= np.abs(disp - mu) < motion_sigmas * max(sigma, 1e-9) + slack
    ok &= epipolar_distances(camera, poses, s, t, cs, ct)[0] <= margin_px + slack
    if cheirality and ok.any():
        ok &= ~behind_camera(camera, poses, s, t, cs, ct, margin_px + slack)[0]
    if band is not None and ok.any():
        dist = band_distances(band_segments(camera, poses, s, t, cs, band), ct)[0]
        ok &= ~(dist > margin_px + slack)  # NaN (no prediction for that ray): no band gate
    return ok


@dataclass(frozen=True)
class TruncatedViews:
    """What `pair_scores` needs to read views cut by the image border as truncated (`plugin.truncation`).

    `ref_sizes` (n,): per row, the size of its track's latest whole view, or the largest of its cut views when it
    has none (`ref_whole` False: a lower bound); `cut_s` (n,): whether the row's last observation is cut; `cut_t`
    (m,): whether each mask of keyframe t is cut; `shift_s` (n, 2): the outward box of the row's last observation,
    fixed when it joined the track (`joined_shifts`; 0 for a whole one)."""

    ref_sizes: np.ndarray
    ref_whole: np.ndarray
    cut_s: np.ndarray
    cut_t: np.ndarray
    shift_s: np.ndarray


def truncated_pairs(
    feat_s: MaskFeatures, masks_s: np.ndarray, feat_t: MaskFeatures, camera: Camera, poses: Poses, s: int, t: int,
    mu: float, sigma: float, params: TrackingParams, size_ok: np.ndarray, ok: np.ndarray,
    predicted_xy: np.ndarray | None, band: tuple[float, float] | None, truncated: TruncatedViews,
) -> np.ndarray:
    """(n, m) the pairs with a cut view that pass the size gate and the position gates relaxed by the truncation
    (`truncation.relaxed_position_gates`), beyond those `ok` already holds. A cut candidate's box: the object
    size by `box_object_sizes` from the row's reference; the row's own (cut) last view: the box it joined with
    (`TruncatedViews.shift_s`)."""
    n, m = size_ok.shape
    out = np.zeros((n, m), bool)
    has_point = np.isfinite(predicted_xy[:, 0]) if predicted_xy is not None else np.zeros(n, bool)
    # a row with a point is gated by the projection of its point (whole views): only a cut candidate can relax it
    row_cut = truncated.cut_s & ~has_point
    todo = size_ok & ~ok & (row_cut[:, None] | truncated.cut_t[None, :])
    xy_s = np.asarray(feat_s.centroids, np.float64)[masks_s]
    row_shift = np.where(row_cut[:, None], np.asarray(truncated.shift_s, np.float64), 0.0)
    if todo.any():
        todo &= _within_reach(feat_t, camera, poses, s, t, mu, sigma, params, xy_s, row_shift, has_point,
                              predicted_xy, truncated)
    border_t = border_of(feat_t, camera)
    for i in np.flatnonzero(todo.any(axis=1)):
        cols = np.flatnonzero(todo[i])
        obj = box_object_sizes(truncated.ref_sizes[i], np.asarray(feat_t.sizes, np.float64)[cols])
        shift_t = outward_shifts(border_t[cols], feat_t.covariances[cols], obj)
        out[i, cols] = relaxed_position_gates(
            camera, poses, s, t, xy_s[i], row_shift[i], feat_t.centroids[cols], shift_t,
            None if not has_point[i] else predicted_xy[i], mu, sigma, band if not has_point[i] else None,
            params.epipolar_margin_px, params.motion_gate_sigmas, params.cheirality_check)
    return out


def _within_reach(
    feat_t: MaskFeatures, camera: Camera, poses: Poses, s: int, t: int, mu: float, sigma: float,
    params: TrackingParams, xy_s: np.ndarray, row_shift: np.ndarray, has_point: np.ndarray,
    predicted_xy: np.ndarray | None, truncated: TruncatedViews,
) -> np.ndarray:
    """(n, m) the pairs that the relaxed gates could pass at all, from the observed centroids and the whole shifts
    (S = |shift_s| + |shift_t|, twice the slack the relaxed gates grant): only those are tested one row at a time
    (`relaxed_position_gates`; a cut mask is a candidate of every row, and testing them all cost 100x the
    tracking's time). Exact for the point-transfer and motion gates (the box centres lie within S / 2 of the
    centroids); for the epipolar gate, which moves with both points, 2 S."""
    n, m = len(xy_s), len(feat_t)
    ref = np.asarray(truncated.ref_sizes, np.float64)
    reach = np.zeros((n, m)) + np.linalg.norm(row_shift, axis=1)[:, None]
    cols = np.flatnonzero(truncated.cut_t)
    if len(cols):
        obj = box_object_sizes(ref[:, None], np.asarray(feat_t.sizes, np.float64)[None, cols])
        sides = np.broadcast_to(border_of(feat_t, camera)[cols][None], (n, len(cols), 2, 2)).reshape(-1, 2, 2)
        cov = np.broadcast_to(feat_t.covariances[cols][None], (n, len(cols), 2, 2)).reshape(-1, 2, 2)
        reach[:, cols] += np.linalg.norm(outward_shifts(sides, cov, obj.ravel()), axis=1).reshape(n, len(cols))
    xy_t = np.asarray(feat_t.centroids, np.float64)
    margin = params.epipolar_margin_px
    point = has_point[:, None]
    ok = np.ones((n, m), bool)
    if has_point.any():
        transfer = np.linalg.norm(np.where(point, predicted_xy, 0.0)[:, None, :] - xy_t[None, :, :], axis=2)
        ok &= ~point | (transfer <= margin + reach)
    if np.isfinite(mu) and np.isfinite(sigma):
        disp = np.linalg.norm(xy_s[:, None, :] - xy_t[None, :, :], axis=2)
        ok &= point | (np.abs(disp - mu) < params.motion_gate_sigmas * max(sigma, 1e-9) + reach)
    if (ok & ~point).any():
        ok &= point | (epipolar_distances(camera, poses, s, t, xy_s, xy_t) <= margin + 2.0 * reach)
    return ok


def truncation_state(ref_size: np.ndarray, ref_whole: np.ndarray, last_cut: np.ndarray, n_new: int,
                      ids: np.ndarray, cut_t: np.ndarray, sizes_t: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tracks' (reference size, has a whole view, latest view cut) after keyframe t's masks joined tracks
    `ids` (`n_new` of them new): a whole view sets the reference; a cut one raises it while the track has no whole
    view (the largest lower bound) and leaves it otherwise."""
    ref_size = np.concatenate([ref_size, np.zeros(n_new)])
    ref_whole = np.concatenate([ref_whole, np.zeros(n_new, bool)])
    last_cut = np.concatenate([last_cut, np.zeros(n_new, bool)])
    whole = ~cut_t
    ref_size[ids[whole]] = sizes_t[whole]
    ref_whole[ids[whole]] = True
    lower = cut_t & ~ref_whole[ids]
    ref_size[ids[lower]] = np.maximum(ref_size[ids[lower]], sizes_t[lower])
    last_cut[ids] = cut_t
    return ref_size, ref_whole, last_cut
