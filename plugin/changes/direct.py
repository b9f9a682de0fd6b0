"""What the other session shows of one map's landmarks directly, before any containment link (`direct_evidence`):
how often it should have seen them, their counterpart landmarks, its segments at their places and, with both
sessions' images, the surface heights there and whether an object stands at all. `verdict` judges each landmark on
it (`detect_changes`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..evaluation.footprints import HeightField
from ..params import ChangeParams
from .absence import presence, probability
from .evidence import binomial_tail, counterparts, segment_evidence
from .objectness import (
    beside_kept_objects,
    evenly,
    flat_landmarks,
    ground_noise_known,
    ground_noise_loose,
    other_footprint_stands,
    ring_heights,
    surface_heights,
    with_ground_places,
)
from .observations import SessionObservations, in_view
from .surface import REFERENCE_LIMIT as SURFACE_REFERENCES
from .surface import height_limit, height_log_ratio, shows_relief, stands_above_ground


@dataclass(frozen=True)
class DirectEvidence:
    """What the other session shows of one map's landmarks directly, before any containment link: how often it
    should have seen them, their counterpart landmarks, and its segments at their places (for the compared ones
    without a counterpart). `established`: present in both sessions by direct evidence (a counterpart, or the
    other session's segments); only such landmarks may vouch for others through a nested or part link."""

    views: np.ndarray
    compared: np.ndarray
    index: np.ndarray  # counterpart in the other map (-1 none or not compared)
    hits: np.ndarray  # segment hits / views / local chance rate; computed where `tested`
    trials: np.ndarray
    chance: np.ndarray
    absent: np.ndarray  # P(absent | segment hits), `absence_probability`
    tested: np.ndarray
    by_segments: np.ndarray  # the other session's segments show it significantly more often than chance
    surface: np.ndarray  # the surface heights' log-likelihood ratio of absence (0 without both sessions' images)
    # the surface heights say absent more strongly than a counterpart would say present: no link vouches for it
    doubted: np.ndarray
    # the reference places' surface heights above the ground (own session, other session), None: not measured
    surface_references: tuple[np.ndarray, np.ndarray] | None = None
    # swept places whose surface in their own session stands no higher than the ground (`stands_above_ground`):
    # no object of theirs to have gone (all False where nothing was swept; None: the test did not run)
    flat: np.ndarray | None = None
    # whether the own session's images show relief at its references (`shows_relief`); None: not measured here
    relief: bool | None = None
    # False: the sweep's ground noise could not be measured (no place at ground level even with the bare
    # places added), so the objectness test let every place stand; None: measured, or not measured here
    ground_noise: bool | None = None
    # what `reweigh` needs: per landmark the segments' presence rate and dispersion (where tested) and whether
    # its hits are significantly above chance; and how the other session sees this map (`visible_share`'s
    # sizes, matched, shown of the compared landmarks)
    rate: np.ndarray | None = None
    spread: np.ndarray | None = None
    above: np.ndarray | None = None
    seen: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def reweigh(self, visible: np.ndarray) -> DirectEvidence:
        """The same evidence with the absence probability of the tested landmarks at `visible` (per landmark, the
        share of present objects without a counterpart that the other session sees; `visible_share`)."""
        if self.rate is None or not np.any(self.tested):
            return self
        idx = np.flatnonzero(self.tested)
        absent = self.absent.copy()
        absent[idx] = probability(self.hits[idx], self.trials[idx], self.chance[idx], self.rate[idx],
                                   self.spread[idx], self.surface[idx], visible[idx])
        by_segments = self.by_segments.copy()
        by_segments[idx] = self.above[idx] & (absent[idx] < 0.5)
        return replace(self, absent=absent, by_segments=by_segments)

    @property
    def established(self) -> np.ndarray:
        """Per landmark: the other session shows it directly (compared, and a counterpart landmark or its own
        segments): what a link may rest on."""
        return self.compared & ((self.index >= 0) | self.by_segments)


def direct_evidence(own_pos: np.ndarray, own_h: np.ndarray, other: SessionObservations, other_pos: np.ndarray,
            other_h: np.ndarray, gate_m: float, params: ChangeParams,
            references: tuple[np.ndarray, np.ndarray] | None = None,
            deep: np.ndarray | None = None, own: SessionObservations | None = None,
            ground: HeightField | None = None,
            surface_references: tuple[np.ndarray, np.ndarray] | None = None,
            counterpart_log_ratio: float = 0.0,
            visible: Callable[[np.ndarray], np.ndarray] | None = None) -> DirectEvidence:
    """`references`: positions and sizes of the own map's landmarks with a counterpart (for the presence rate);
    None: those among own_pos. `deep`: landmarks below the ground (`below_the_ground`), compared with nothing.
    `own`: the session these landmarks belong to (its segments give each one's own presence rate). With the
    `ground` and both sessions' images, each tested landmark's surface heights are evidence too (`surface_heights`),
    calibrated on `surface_references` (None: measured here on the landmarks with a counterpart); with
    `params.surface_overrules_links`, every compared landmark's, and a counterpart they contradict more than
    it supports presence (`counterpart_log_ratio`: log P(counterpart | absent) / P(counterpart | present))
    is none. `visible`: per size, the share of present objects without a counterpart that the other session sees
    (`visible_share`); None: every one (the pair's landmarks are `reweigh`ed once both directions are measured)."""
    n = len(own_pos)
    seen, _, _ = in_view(own_pos, own_h, other.poses, other.cameras, min_area_px=other.smallest_mask_px,
                         size_tolerance=params.max_size_difference)
    views = seen.sum(0)
    compared = views >= other.views_needed(params.min_views)
    if deep is not None:
        compared &= ~deep
    index, _ = counterparts(own_pos, own_h, other_pos, other_h, gate_m, params.max_size_difference,
                            params.z_weight)
    index = np.where(compared, index, -1)
    hits, trials = np.zeros(n, np.int64), np.zeros(n, np.int64)
    chance, absent = np.full(n, np.nan), np.zeros(n)
    rate, spread, above = np.full(n, np.nan), np.ones(n), np.zeros(n, dtype=bool)
    by_segments = np.zeros(n, dtype=bool)
    surface, doubted, flat = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    relief, ground_noise = None, None
    swept = None  # (landmarks, own place heights, own ring heights) where the objectness test swept them
    kept = references
    if references is None:
        references = (own_pos[compared & (index >= 0)], own_h[compared & (index >= 0)])
    asked = compared & ((index < 0) & (other.segments is not None) | params.surface_overrules_links)
    if (params.surface_evidence and ground is not None and own is not None and own.images is not None
            and other.images is not None and np.any(asked)):
        measured_here = surface_references is None
        if surface_references is None:
            ref = evenly(np.flatnonzero(compared & (index >= 0)), SURFACE_REFERENCES)
            surface_references = surface_heights(own_pos[ref], own, other, ground, params)
            if params.object_height_p < 1.0 and ground_noise_loose(surface_references):
                # few reference places at ground level to measure the sweep's ground noise on (a small or
                # cross-season pair keeps few counterparts, most of them objects): the objectness test's limit
                # widens with so thin a fit, and without any it lets every place stand. Bare places beside the
                # compared landmarks add ground
                surface_references = with_ground_places(surface_references, own_pos[compared], own_h[compared],
                                                         own, other, ground, gate_m, params)
        idx = np.flatnonzero(asked)
        own_heights, other_heights = surface_heights(own_pos[idx], own, other, ground, params)
        surface[idx] = height_log_ratio(own_heights, other_heights, *surface_references)
        if params.object_height_p < 1.0:  # the objectness test is on
            shown = shows_relief(surface_references[0], params.object_height_p)
            if shown:
                flat[idx], pick, place_h, own_ring, wide = flat_landmarks(own_pos[idx], own_h[idx], own_heights,
                                                                          own, ground, surface_references[0], params)
                swept = (idx, own_heights, own_ring)
                # a landmark whose object stands beside its place (on its ring) is judged where it stands: the
                # other session's surface is swept at the same places, and the heights' evidence is read at the
                # place that stands
                there = other_heights.copy()
                moved = np.flatnonzero(pick >= 0)
                if len(moved):
                    around = ring_heights(own_pos[idx[moved]], own_h[idx[moved]], other, ground, params)
                    there[moved] = around[np.arange(len(moved)), pick[moved]]
                    surface[idx[moved]] = height_log_ratio(place_h[moved], there[moved], *surface_references)
                # what stands in both sessions' images did not go (nor come), such as the crown beside a shadow
                # that moved: no change of the surface, no change of an object. Tested where the own session
                # stands, and, for a landmark judged on its ring, anywhere on it as the own session was (the
                # highest of the same places at their joint level). Only where the other session's own ground
                # noise is measured (otherwise every place would "stand")
                if np.isfinite(height_limit(surface_references[1], params.object_height_p)):
                    flat[idx] |= stands_above_ground(there, surface_references[1], params.object_height_p)
                    if len(moved):
                        flat[idx[moved]] |= stands_above_ground(np.column_stack([other_heights[moved], around]),
                                                                surface_references[1], params.object_height_p,
                                                                1 + params.object_height_ring)
                    if np.any(wide):  # standing by its footprint's mean: the other's same places must not
                        flat[idx[wide]] |= other_footprint_stands(own_pos[idx[wide]], own_h[idx[wide]],
                                                                  other_heights[wide], own_heights, own_ring,
                                                                  other, ground, surface_references[1], params)
            relief = shown if measured_here else None
            if measured_here and not ground_noise_known(surface_references):
                ground_noise = False  # the test could not be made: every place stands (said by the caller)
        if params.surface_overrules_links:
            # a counterpart is a landmark of compatible size within the gate, which a ground patch where the
            # object stood is as often as chance allows (`alignment_support`'s displaced rate): where the
            # surface says absent more strongly than the counterpart says there, it is no evidence of presence
            # (nor is a containment link, a compatible landmark nearby too: `_judge`)
            doubted = asked & (surface + counterpart_log_ratio > 0)
            index = np.where(doubted, -1, index)
    if swept is not None:
        # a landmark that stands only within reach of an object both sessions have (a kept landmark standing in
        # both sessions' images)
        # is that object's neighbourhood, such as a cast shadow whose patch catches the crown's edge: no object of
        # its own to have gone or come, whatever the other session's images make of that edge
        if kept is None:
            kept = (own_pos[compared & (index >= 0)], own_h[compared & (index >= 0)])
        at, place_heights, ring_heights_own = swept
        flat[at] |= beside_kept_objects(own_pos[at], own_h[at], place_heights, ring_heights_own, *kept, own,
                                        other, ground, surface_references, params)
    tested = compared & (index < 0) & (other.segments is not None)
    if np.any(tested):
        idx = np.flatnonzero(tested)
        hits[idx], trials[idx], chance[idx] = segment_evidence(
            own_pos[idx], own_h[idx], other.poses, other.cameras, other.segments, gate_m,
            params.max_size_difference, params.probe_count, params.probe_radius_factor, other.smallest_mask_px)
        rate[idx], spread[idx] = presence(own_h[idx], trials[idx], *references, other, gate_m, params, own,
                                           own_pos[idx])
        absent[idx] = probability(hits[idx], trials[idx], chance[idx], rate[idx], spread[idx], surface[idx],
                                   1.0 if visible is None else visible(own_h[idx]))
        # shown: more hits than chance would give, and more like an object that is there than like its absence
        above[idx] = binomial_tail(hits[idx], trials[idx], chance[idx]) < params.segment_evidence_p
        by_segments[idx] = above[idx] & (absent[idx] < 0.5)
    matched = (index >= 0)[compared]
    seen = (own_h[compared], matched, matched | above[compared])
    return DirectEvidence(views, compared, index, hits, trials, chance, absent, tested, by_segments, surface, doubted,
                   surface_references, None if swept is None else flat, relief, ground_noise, rate, spread, above,
                   seen)
