"""P(absent | the other session's segments) of a landmark without a counterpart (`absence_probability`): the
binomial likelihood ratio of its hits at the local chance rate against the presence rate of objects like it."""

from __future__ import annotations

import numpy as np

from ..params import ChangeParams
from ..sampling import evenly_spaced
from .evidence import (
    absence_log_ratio,
    dispersion,
    landmark_presence_rate,
    presence_rate,
    segment_hits,
    view_correlation,
)
from .observations import SessionObservations

REFERENCE_LIMIT = 400  # reference landmarks for the presence rate (evenly spaced): bounded cost on large maps


def absence_probability(sizes: np.ndarray, ref_positions: np.ndarray, ref_sizes: np.ndarray, hits: np.ndarray,
                        views: np.ndarray, chance: np.ndarray, other: SessionObservations, gate_m: float,
                        params: ChangeParams, own: SessionObservations | None = None,
                        positions: np.ndarray | None = None, log_ratio: np.ndarray | float = 0.0,
                        visible: np.ndarray | float = 1.0) -> np.ndarray:
    """P(absent | the other session's segments) for objects of the given sizes, from their segment hits in the
    other session's keyframes: binomial with the local chance rate if the object is absent, with the presence rate
    of objects of its size if present (`presence_rate`, measured on the reference landmarks of its map, those with
    a counterpart), the log-likelihood ratio divided by the dispersion of a count of that many views (`dispersion`,
    with the views' correlation measured on the references: neighbouring keyframes are not independent looks),
    prior odds 1. With `own` (the landmarks' own session, with its segments) and their `positions`, the presence
    rate is each landmark's own (`landmark_presence_rate`): scaled by how often its own session shows it.
    `log_ratio`: further evidence of absence (a log-likelihood ratio: the surface heights',
    `surface.height_log_ratio`), added to the segments'. `visible`: the share of present objects without a
    counterpart that the other session sees at all (`evidence.visible_share`; 1: every one)."""
    rate, spread = presence(sizes, views, ref_positions, ref_sizes, other, gate_m, params, own, positions)
    return probability(hits, views, chance, rate, spread, log_ratio, visible)


def probability(hits: np.ndarray, views: np.ndarray, chance: np.ndarray, rate: np.ndarray, spread: np.ndarray,
                log_ratio: np.ndarray | float, visible: np.ndarray | float) -> np.ndarray:
    """`absence_probability` from its parts: hits, views, chance rate, presence rate, dispersion (`presence`),
    further log-likelihood ratio of absence and the share of present objects the other session sees."""
    llr = absence_log_ratio(hits, views, chance, rate, spread, visible) + log_ratio
    return 1.0 / (1.0 + np.exp(-np.clip(llr, -30.0, 30.0)))  # below 1: --min-confidence 1 reports nothing


def presence(sizes: np.ndarray, views: np.ndarray, ref_positions: np.ndarray, ref_sizes: np.ndarray,
             other: SessionObservations, gate_m: float, params: ChangeParams,
             own: SessionObservations | None = None,
             positions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`absence_probability`'s presence rate per landmark and the dispersion of its count of `views`."""
    ref = np.asarray(evenly_spaced(len(ref_positions), REFERENCE_LIMIT), dtype=np.int64)
    ref_h = ref_sizes[ref]
    ref_hits, ref_views = segment_hits(ref_positions[ref], ref_h, other.poses, other.cameras, other.segments,
                                       gate_m, params.max_size_difference, other.smallest_mask_px)
    bw = params.presence_bandwidth
    if own is not None and own.segments is not None and positions is not None:
        # the presence rate of each landmark from how often its own session shows it (the references' too)
        ref_own = segment_hits(ref_positions[ref], ref_h, own.poses, own.cameras, own.segments, gate_m,
                               params.max_size_difference, own.smallest_mask_px)
        mine = segment_hits(positions, sizes, own.poses, own.cameras, own.segments, gate_m,
                            params.max_size_difference, own.smallest_mask_px)
        ref_rate = landmark_presence_rate(ref_h, *ref_own, ref_h, ref_hits, ref_views, *ref_own, bw)
        rate = landmark_presence_rate(sizes, *mine, ref_h, ref_hits, ref_views, *ref_own, bw)
    else:
        ref_rate = presence_rate(ref_h, ref_h, ref_hits, ref_views, bw)
        rate = presence_rate(sizes, ref_h, ref_hits, ref_views, bw)
    rho = view_correlation(ref_hits, ref_views, ref_rate)
    return rate, dispersion(views, rho)
