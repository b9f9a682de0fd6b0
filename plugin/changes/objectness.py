"""Does an object stand at a landmark: each session's surface height above the pair's ground, swept from its own
images at the landmark's place and on a ring inside its footprint (`surface`), and the sweep's ground noise that
scales the test, measured on the pair's reference places or, where too few lie at ground level, on bare places
beside the compared landmarks. Used by `verdict.detect_changes` (the objectness test of a gone / new claim)."""

from __future__ import annotations

import numpy as np

from ..evaluation.footprints import HeightField
from ..params import ChangeParams
from ..sampling import evenly_spaced
from .observations import SessionObservations
from .surface import (
    PATCH_HALF_M,
    SWEEP_STEP_M,
    footprint_places,
    ground_noise_fit,
    ground_noise_limit,
    ground_sweep_noise,
    height_limit,
    heights_above_ground,
    stands_above_ground,
)
from .surface import REFERENCE_LIMIT as SURFACE_REFERENCES


def flat_landmarks(points: np.ndarray, sizes: np.ndarray, heights: np.ndarray, own: SessionObservations,
          ground: HeightField, ref_heights: np.ndarray,
          params: ChangeParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which landmarks have no object standing in their footprint in their own session: neither at their place
    (`heights`, already swept) nor at any of `params.object_height_ring` places around it
    (`surface.footprint_places`, swept here only for those whose place does not stand), the highest tested at the
    limit for all those places (`surface.stands_above_ground`). Also, per landmark, where its object stands: -1
    its own place, k the k-th place of its ring (the highest, where only the ring stands), the own session's
    height there, the (N, ring) own session's heights on the ring (NaN where not swept), and whether it stands
    only by its footprint's mean sweep (`changes.object_height_mean`: `footprint_mean_limit`)."""
    places = 1 + params.object_height_ring
    by_mean = params.object_height_mean and params.object_height_ring > 0
    # two tests of one place (its highest and its mean sweep): each at half the level (Bonferroni), so bare ground
    # passes either as rarely as it passed the one
    p = params.object_height_p / 2.0 if by_mean else params.object_height_p
    flat = ~stands_above_ground(heights, ref_heights, p, places)
    pick = np.full(len(flat), -1, dtype=np.int64)
    high = np.asarray(heights, dtype=np.float64).copy()
    ring = np.full((len(flat), params.object_height_ring), np.nan)
    wide = np.zeros(len(flat), dtype=bool)
    low = np.flatnonzero(flat & (np.asarray(sizes) > 0))
    if params.object_height_ring and len(low):
        around = ring_heights(points[low], sizes[low], own, ground, params)
        ring[low] = around
        both = np.column_stack([heights[low], around])
        flat[low] = ~stands_above_ground(both, ref_heights, p, places)
        stands = ~flat[low]
        best = np.argmax(np.where(np.isfinite(around), around, -np.inf), axis=1)
        pick[low[stands]] = best[stands]
        high[low[stands]] = around[stands, best[stands]]
        if by_mean:
            means = footprint_means(both)
            over = np.isfinite(means) & (means > footprint_mean_limit(means, p, places)) & flat[low]
            wide[low[over]] = True
            flat[low[over]] = False
    return flat, pick, high, ring, wide


def footprint_means(heights: np.ndarray) -> np.ndarray:
    """(N,) the mean of each row of (N, K) sweeps of one landmark's footprint (its place and its ring), NaN where
    fewer than half of them have a height."""
    h = np.asarray(heights, dtype=np.float64)
    known = np.isfinite(h)
    count = known.sum(axis=1)
    total = np.where(known, h, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(2 * count >= h.shape[1], total / np.maximum(count, 1), np.nan)


def footprint_mean_limit(means: np.ndarray, p: float, places: int) -> float:
    """The mean footprint height (`footprint_means` of `places` sweeps) that bare ground exceeds at one-sided p:
    the noise of such means measured on the same means, those at or below the ground (objects only add height,
    so the means that do not are ground alone; `surface.ground_noise_fit` on the grid of a mean of `places`
    levels), a Student-t quantile with the fit's degrees of freedom, and at least one sweep step. A low bush's
    flat top fills most of its footprint: one 2 m patch reads it against the ground noise of one patch, the
    mean of its footprint's places against the noise of a mean, which the overlap of the patches and the ground
    under a shadow's ring leave to be measured, not assumed. NaN without any mean at ground level."""
    return ground_noise_limit(means, p, SWEEP_STEP_M / max(int(places), 1))


def beside_kept_objects(points: np.ndarray, sizes: np.ndarray, heights: np.ndarray, ring: np.ndarray,
                        kept_points: np.ndarray, kept_sizes: np.ndarray, own: SessionObservations,
                        other: SessionObservations, ground: HeightField,
                        references: tuple[np.ndarray, np.ndarray], params: ChangeParams) -> np.ndarray:
    """Which landmarks stand in their own session only where an object present in both sessions stands: every
    place of theirs that stands (their own place where it does, else the places of their ring that do; `heights`
    and `ring` as `flat_landmarks` swept them) lies within the swept patch's reach (`surface.PATCH_HALF_M`) of
    the footprint (radius 2 h) of a kept landmark (`kept_points`, `kept_sizes`: those with a counterpart), outside
    which the landmark lies and whose
    surface stands in both sessions (`references`: the own and the other session's reference heights): a
    counterpart alone can be a chance pairing (a new crown's landmark with a ground patch of the other map), and
    a kept patch of ground texture explains no height. Such a landmark is that object's neighbourhood, not an
    object of its own: a cast shadow beside a crown whose 2 x 2 m patch catches the crown's edge stands in the
    noon images and not in the overcast ones, where the same edge, without the shadow's contrast, sweeps to the
    ground. False where nothing stands (those are flat anyway) or where any standing place lies beyond every kept
    object's reach."""
    n = len(points)
    out = np.zeros(n, dtype=bool)
    kept_points = np.asarray(kept_points, dtype=np.float64).reshape(-1, 3)
    if not n or not len(kept_points):
        return out
    places = 1 + params.object_height_ring
    limit = height_limit(references[0], params.object_height_p, places)
    if not (np.isfinite(limit) and np.isfinite(height_limit(references[1], params.object_height_p))):
        return out
    h = np.asarray(heights, dtype=np.float64)
    own_stands = np.isfinite(h) & (h > limit)
    ring_xyz = footprint_places(points, sizes, params.object_height_ring)
    ring_stands = ~own_stands[:, None] & np.isfinite(ring) & (ring > limit)
    # the standing places: (landmark, x, y)
    who = np.concatenate([np.flatnonzero(own_stands), np.nonzero(ring_stands)[0]])
    xy = np.vstack([np.asarray(points, dtype=np.float64)[own_stands, :2], ring_xyz[ring_stands][:, :2]])
    if not len(who):
        return out
    footprint = 2.0 * np.nan_to_num(np.asarray(kept_sizes, dtype=np.float64), nan=0.0)
    near = np.linalg.norm(xy[:, None, :] - kept_points[None, :, :2], axis=2) <= footprint[None, :] + PATCH_HALF_M
    # beside, not inside: a landmark within a kept one's footprint may be an object on or in it (a new bush in a
    # kept field), which the nesting and part links judge; only one outside it can be its edge's neighbourhood
    centre = np.asarray(points, dtype=np.float64)[who, :2]
    near &= np.linalg.norm(centre[:, None, :] - kept_points[None, :, :2], axis=2) > footprint[None, :]
    # the kept objects within reach must stand in both sessions' images: an object that is there in both
    asked = np.flatnonzero(near.any(axis=0))
    if not len(asked):
        return out
    standing = np.zeros(len(kept_points), dtype=bool)
    mine, theirs = surface_heights(kept_points[asked], own, other, ground, params)
    standing[asked] = (stands_above_ground(mine, references[0], params.object_height_p)
                       & stands_above_ground(theirs, references[1], params.object_height_p))
    explained = (near & standing[None, :]).any(axis=1)
    unexplained = np.bincount(who[~explained], minlength=n)
    return (np.bincount(who, minlength=n) > 0) & (unexplained == 0)


def evenly(indices: np.ndarray, limit: int) -> np.ndarray:
    """At most `limit` of `indices`, evenly spaced over them (bounded cost on large maps)."""
    return indices[np.asarray(evenly_spaced(len(indices), limit), dtype=np.int64)]


def ground_noise_known(references: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether both sessions' reference heights hold a place at ground level to measure the sweep's ground noise
    on (`surface.ground_noise_limit`), the scale of the objectness test: with any, the test is made, its limit
    widened by how little the places tell."""
    return all(ground_noise_fit(r)[2] > 0 for r in references)


def ground_noise_loose(references: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether either session's reference heights hold fewer places at ground level than `ground_sweep_noise`
    asks of a scale: worth sweeping bare places beside the compared landmarks (`with_ground_places`) to narrow
    the objectness test's limit, which a thin fit widens."""
    return not all(np.isfinite(ground_sweep_noise(r)) for r in references)


def with_ground_places(references: tuple[np.ndarray, np.ndarray], points: np.ndarray, sizes: np.ndarray,
                        own: SessionObservations, other: SessionObservations, ground: HeightField, gate_m: float,
                        params: ChangeParams) -> tuple[np.ndarray, np.ndarray]:
    """`references` (own, other heights) with the surface heights at one bare place beside each of `points` (up
    to `SURFACE_REFERENCES` of them, evenly spaced) appended: where the segment evidence takes its chance rate,
    `probe_radius_factor` x the gate + 2 h away, at a golden-angle turn per landmark (deterministic). Objects only
    add height, so the places at or below the ground measure the sweep's ground noise whatever stands on the
    others (`surface.ground_sweep_noise`); the pairs also join the calibration as places that did not change."""
    keep = evenly(np.arange(len(points)), SURFACE_REFERENCES)
    pts, sizes = np.asarray(points, dtype=np.float64).reshape(-1, 3)[keep], np.asarray(sizes)[keep]
    if not len(pts):
        return references
    angle = np.arange(len(pts)) * np.pi * (3.0 - np.sqrt(5.0))
    radius = params.probe_radius_factor * gate_m + 2.0 * np.nan_to_num(np.asarray(sizes, np.float64), nan=0.0)
    places = pts.copy()
    places[:, 0] += radius * np.cos(angle)
    places[:, 1] += radius * np.sin(angle)
    more = surface_heights(places, own, other, ground, params)
    return np.concatenate([references[0], more[0]]), np.concatenate([references[1], more[1]])


def surface_heights(points: np.ndarray, own: SessionObservations, other: SessionObservations, ground: HeightField,
             params: ChangeParams) -> tuple[np.ndarray, np.ndarray]:
    """The surface height above the ground at each point in its own session and in the other, each from that
    session's own images (`surface.heights_above_ground`; both in one frame)."""
    return session_heights(points, own, ground, params), session_heights(points, other, ground, params)


def session_heights(points: np.ndarray, session: SessionObservations, ground: HeightField,
             params: ChangeParams) -> np.ndarray:
    """The surface height above the pair's ground at each (N, 3) point, from one session's own images."""
    return heights_above_ground(points, ground(points[:, 0], points[:, 1]), session.images, session.poses,
                                session.cameras, params.surface_views)


def ring_heights(points: np.ndarray, sizes: np.ndarray, session: SessionObservations, ground: HeightField,
                  params: ChangeParams) -> np.ndarray:
    """(N, object_height_ring) heights (`session_heights`) of one session at each landmark's `surface.footprint_places`:
    the same places in either session."""
    ring = footprint_places(points, sizes, params.object_height_ring)
    return session_heights(ring.reshape(-1, 3), session, ground, params).reshape(len(ring), -1)


def other_footprint_stands(points: np.ndarray, sizes: np.ndarray, other_place: np.ndarray, own_place: np.ndarray,
                           own_ring: np.ndarray, other: SessionObservations, ground: HeightField,
                           other_references: np.ndarray, params: ChangeParams) -> np.ndarray:
    """For landmarks that stand by their footprint's mean in their own session (`flat_landmarks`' `wide`):
    whether the other session's surface stands on the same places too, by the highest (the limit for all of
    them) or by their mean (`footprint_mean_limit` of the own session's swept footprints, `own_place` and
    `own_ring` of every landmark swept there): something stands in both, no change of an object."""
    places = 1 + params.object_height_ring
    p = params.object_height_p / 2.0
    around = ring_heights(points, sizes, other, ground, params)
    theirs = np.column_stack([other_place, around])
    swept = np.isfinite(own_ring).any(axis=1)
    limit = footprint_mean_limit(footprint_means(np.column_stack([own_place, own_ring])[swept]), p, places)
    means = footprint_means(theirs)
    return (stands_above_ground(theirs, other_references, p, places)
            | (np.isfinite(means) & (means > limit)))
