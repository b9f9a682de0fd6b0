"""The verdict per landmark (`detect_changes`): kept, gone, new or unseen, with its evidence and confidence, judged on
what the other session shows of each landmark directly (`direct.direct_evidence`) and the links between landmarks."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from ..evaluation.footprints import HeightField
from ..multisession import Sim3
from ..params import ChangeParams
from .absence import REFERENCE_LIMIT, absence_probability, presence, probability  # noqa: F401
from .confidence import held_out_logistic, reobservation_features
from .direct import DirectEvidence, direct_evidence
from .evidence import (
    Sensing,
    counterparts,
    holder_pairs,
    inside_larger,
    sensing,
    visible_share,
)
from .objectness import (
    session_heights,
)
from .observations import (
    SessionObservations,
    above_the_surface,
    below_the_ground,
    ground_height_field,
    observed_area,
)
from .support import AlignmentSupport, alignment_support, counterpart_gate
from .surface import (
    ground_sweep_noise,
)
from .unmapped import UnmappedObjects, no_unmapped_objects, unmapped_objects

KEPT, GONE, NEW, UNSEEN = "kept", "gone", "new", "unseen"
CLASSES = (KEPT, GONE, NEW, UNSEEN)
# evidence behind a class
BY_LANDMARK, BY_NESTING, BY_PART, BY_SEGMENTS, NO_EVIDENCE, TOO_FEW_VIEWS, LOW_CONFIDENCE, BELOW_GROUND, FLAT = (
    "landmark", "nested", "part", "segments", "none", "views", "confidence", "height", "flat")
EVIDENCE = (BY_LANDMARK, BY_NESTING, BY_PART, BY_SEGMENTS, NO_EVIDENCE, TOO_FEW_VIEWS, LOW_CONFIDENCE, BELOW_GROUND,
            FLAT)


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
        """How many landmarks have class `label` (kept, gone, new, unseen)."""
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
    # objects each session saw but never mapped (`unmapped`; B's in A's frame) and their verdicts
    unmapped_a: UnmappedObjects = field(default_factory=no_unmapped_objects)
    unmapped_b: UnmappedObjects = field(default_factory=no_unmapped_objects)
    tracks_a: LandmarkChanges | None = None
    tracks_b: LandmarkChanges | None = None
    # sessions ("A", "B") whose images show no relief: their claims were made without the objectness test
    without_relief: tuple[str, ...] = ()
    # sessions whose sweep's ground noise could not be measured: their claims were made without that test too
    without_ground_noise: tuple[str, ...] = ()
    # how B sees A's landmarks and A sees B's (`evidence.sensing`); None: not measured (no segments)
    sensing_a: Sensing | None = None
    sensing_b: Sensing | None = None

    @property
    def common_area(self) -> object:
        """The ground both sessions observed (shapely geometry in A's frame): the intersection of their areas."""
        import shapely

        return shapely.intersection(self.observed_a, self.observed_b)

    def counts(self) -> dict[str, int]:
        """Landmarks per class: kept (of A and of B), gone (A), new (B), unseen (of both maps; flat: those unseen
        because no object stands there, evidence `flat`); objects never
        mapped (of A and of B) and how many of them are gone (A) / new (B)."""
        return {"kept_a": self.a.count(KEPT), "kept_b": self.b.count(KEPT), "gone": self.a.count(GONE),
                "new": self.b.count(NEW), "unseen_a": self.a.count(UNSEEN), "unseen_b": self.b.count(UNSEEN),
                "flat_a": int(np.count_nonzero(self.a.evidence == FLAT)),
                "flat_b": int(np.count_nonzero(self.b.evidence == FLAT)),
                "unmapped_a": len(self.unmapped_a), "unmapped_b": len(self.unmapped_b),
                "gone_unmapped": self.tracks_a.count(GONE) if self.tracks_a is not None else 0,
                "new_unmapped": self.tracks_b.count(NEW) if self.tracks_b is not None else 0}

    def summary(self) -> str:
        """One line: counts per class and the common area (`counts_summary`)."""
        return counts_summary(self.counts(), float(self.common_area.area) / 1e4)


# the keys of `ChangeResult.counts()`, each a count that adds up over pairs (batch sums them: `counts_summary`)
COUNT_KEYS = ("kept_a", "kept_b", "gone", "new", "unseen_a", "unseen_b", "flat_a", "flat_b", "unmapped_a",
              "unmapped_b", "gone_unmapped", "new_unmapped")


def counts_summary(c: dict[str, int], area_ha: float | None = None) -> str:
    """The one line `sosmatch changes` prints of `ChangeResult.counts()` `c`, and batch of their sums over its pairs
    (nu60 D1: batch added landmarks and objects never mapped into "objects gone", where one tree is often two
    landmarks): landmarks and objects never mapped counted apart, as what they are. `area_ha`: the ground seen by
    both (None: not said; a sum over pairs of overlapping ground is no area)."""
    flat = (f" ({c['flat_a']} + {c['flat_b']} of them flat: a change of looks, no object standing there)"
            if c["flat_a"] + c["flat_b"] else "")
    return (f"{c['gone']} gone, {c['new']} new, {c['kept_a']} + {c['kept_b']} kept, {c['unseen_a']} + "
            f"{c['unseen_b']} unseen landmarks (A + B){flat}; {c['gone_unmapped']} gone, {c['new_unmapped']} new "
            f"of {c['unmapped_a']} + {c['unmapped_b']} objects never mapped"
            + ("" if area_ha is None else f"; {area_ha:.1f} ha seen by both"))



def _judge(own: SessionObservations, own_pos: np.ndarray, own_h: np.ndarray, other: SessionObservations,
           other_pos: np.ndarray, other_h: np.ndarray, heights: np.ndarray, change_label: str, gate_m: float,
           params: ChangeParams, mine: DirectEvidence, theirs: DirectEvidence) -> LandmarkChanges:
    """Classify one map's landmarks against the other session (both already in one frame); `mine` is the direct
    evidence of this map's landmarks in the other session, `theirs` that of the other map's in this one."""
    n = len(own_pos)
    views, compared, index = mine.views, mine.compared, mine.index
    holder = np.full(n, -1, dtype=np.int64)
    if params.nest_max_ratio >= 1:
        # the holder must itself be established in this session (a counterpart here, or this session's
        # segments show it): a ground patch that the other session sees where this map's object stood is no
        # whole of that object
        holder = np.where(compared & (index < 0) & ~mine.doubted,
                          inside_larger(own_pos, own_h, other_pos, other_h, params.nest_max_ratio,
                                        theirs.established), -1)
    label = np.full(n, UNSEEN, dtype=object)
    evidence = np.full(n, TOO_FEW_VIEWS, dtype=object)
    evidence[(views >= other.views_needed(params.min_views)) & ~compared] = BELOW_GROUND
    direct = compared & ((index >= 0) | (holder >= 0))
    label[direct] = KEPT
    evidence[index >= 0] = BY_LANDMARK
    evidence[(index < 0) & (holder >= 0)] = BY_NESTING
    # one object, several landmarks of this map: a part inside the footprint of a larger landmark (at most
    # part_max_ratio times its size) that the other session shows directly is kept with it; a whole kept only
    # through a link of its own vouches for nothing (chained links let ground regions hold what really went)
    link = np.full(n, -1, dtype=np.int64)
    if params.part_max_ratio >= 1:
        part, whole = holder_pairs(own_pos, own_h, own_pos, own_h, params.part_max_ratio, same_map=True)
        hit = compared[part] & ~direct[part] & ~mine.doubted[part] & (mine.established | direct)[whole]
        hp, hw = part[hit], whole[hit]  # sorted by part, then distance: the nearest whole first
        first = np.r_[True, hp[1:] != hp[:-1]] if len(hp) else np.zeros(0, bool)
        link[hp[first]] = hw[first]
    by_part = link >= 0
    label[by_part] = KEPT
    evidence[by_part] = BY_PART
    open_ = compared & ~direct & ~by_part
    if params.part_max_ratio >= 1 and np.any(open_):
        # the same link the other way round: the other session mapped this object as parts, smaller landmarks
        # (down to 1 / part_max_ratio of its size) inside its footprint that have a counterpart in this map (a
        # crown whole here, its halves there; a removed object leaves no matched parts, only ground patches)
        matched_other, _ = counterparts(other_pos, other_h, own_pos, own_h, gate_m, params.max_size_difference,
                                        params.z_weight)
        j, i = holder_pairs(other_pos, other_h, own_pos, own_h, params.part_max_ratio)
        ok = open_[i] & ~mine.doubted[i] & (matched_other[j] >= 0)
        i, j = i[ok], j[ok]
        order = np.lexsort((j, i))
        first = np.r_[True, i[order][1:] != i[order][:-1]] if len(order) else np.zeros(0, bool)
        whole = i[order][first]
        holder[whole] = j[order][first]  # reported as the counterpart
        label[whole] = KEPT
        evidence[whole] = BY_PART
        open_[whole] = False
    confidence = np.zeros(n)
    if other.segments is not None and np.any(open_):
        idx = np.flatnonzero(open_)  # all tested: compared, no counterpart
        confidence[idx] = mine.absent[idx]
        present = idx[mine.by_segments[idx]]
        label[present] = KEPT
        evidence[present] = BY_SEGMENTS
        open_[present] = False
    elif other.segments is None and np.any(open_):
        # no segments of the other session: the only sign that the object went is that its map lacks it. How often
        # that map holds a landmark like this one (`reobserved`: a logistic on the pair's compared landmarks, each
        # scored by a fit it took no part in) gives the probability of absence at prior odds 1, as the segments'
        # confidence does: a present object goes unmapped with 1 - p, an absent one always, so 1 / (2 - p). Kept
        # landmarks keep confidence 0 (rev44 D3: they had p, and the open ones, negatives of the fit that scored
        # them, a p pulled low)
        idx = np.flatnonzero(compared)
        feats = reobservation_features(own_h[idx], views[idx], heights[idx],
                                       None if own.support is None else own.support[idx])
        reobserved = held_out_logistic(feats, label[idx] == KEPT)
        scored = open_[idx]
        confidence[idx[scored]] = 1.0 / (2.0 - reobserved[scored])
    if mine.flat is None:  # not tested for an object standing there: most such claims are changes of looks
        confidence[open_] *= params.untested_object_rate
    label[open_] = change_label
    evidence[open_] = NO_EVIDENCE
    if mine.flat is not None:
        # no height of its own where it stands: a change of looks (a shadow, ground texture), not of an object
        flat = open_ & mine.flat
        label[flat] = UNSEEN
        evidence[flat] = FLAT
        open_ &= ~flat
    weak = open_ & (confidence < params.min_confidence)
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
    gate = counterpart_gate(params, association_tolerance_m)
    all_pts = np.vstack([a.positions, b_in_a.positions])
    ground = ground_height_field(all_pts)
    heights_a, heights_b = _above(ground, a.positions), _above(ground, b_in_a.positions)
    deep_a, deep_b = (below_the_ground(h, h, params.max_depth_sigmas) for h in (heights_a, heights_b))
    support = alignment_support(a, b_in_a, gate, params)
    cp = support.counterpart_log_ratio()
    direct_a = direct_evidence(a.positions, a.sizes, b_in_a, b_in_a.positions, b_in_a.sizes, gate, params, deep=deep_a,
                       own=a, ground=ground, counterpart_log_ratio=cp)
    direct_b = direct_evidence(b_in_a.positions, b_in_a.sizes, a, a.positions, a.sizes, gate, params, deep=deep_b,
                       own=b_in_a, ground=ground, counterpart_log_ratio=cp)
    # a present object the other session does not see looks there as a removed one: the absence of hits counts
    # only as far as that session sees such objects, measured on the pair both ways (the same for either order)
    bw = params.presence_bandwidth
    sees_a = partial(visible_share, mine=direct_a.seen, theirs=direct_b.seen, bandwidth=bw)  # B sees A's objects
    sees_b = partial(visible_share, mine=direct_b.seen, theirs=direct_a.seen, bandwidth=bw)
    direct_a, direct_b = direct_a.reweigh(sees_a(a.sizes)), direct_b.reweigh(sees_b(b_in_a.sizes))
    res_a = _judge(a, a.positions, a.sizes, b_in_a, b_in_a.positions, b_in_a.sizes, heights_a, GONE, gate, params,
                   direct_a, direct_b)
    res_b = _judge(b_in_a, b_in_a.positions, b_in_a.sizes, a, a.positions, a.sizes, heights_b, NEW, gate, params,
                   direct_b, direct_a)
    unmapped_a, tracks_a = _unmapped(a, b_in_a, direct_a, direct_b, ground, heights_a, GONE, gate, params, cp, sees_a)
    unmapped_b, tracks_b = _unmapped(b_in_a, a, direct_b, direct_a, ground, heights_b, NEW, gate, params, cp, sees_b)
    return ChangeResult(
        a=res_a, b=res_b, positions_a=a.positions, positions_b=b_in_a.positions, sizes_a=a.sizes,
        sizes_b=b_in_a.sizes, tolerance_m=gate, ground=ground,
        observed_a=observed_area(a.poses, a.cameras, ground, _median(a.sizes), a.smallest_mask_px,
                                 params.max_size_difference),
        observed_b=observed_area(b_in_a.poses, b_in_a.cameras, ground, _median(b_in_a.sizes),
                                 b_in_a.smallest_mask_px, params.max_size_difference),
        params=params,
        support=support, unmapped_a=unmapped_a, unmapped_b=unmapped_b,
        tracks_a=tracks_a, tracks_b=tracks_b,
        without_relief=tuple(name for name, d in (("A", direct_a), ("B", direct_b)) if d.relief is False),
        without_ground_noise=tuple(name for name, d in (("A", direct_a), ("B", direct_b))
                                   if d.ground_noise is False),
        sensing_a=sensing(direct_a.seen, direct_b.seen, bw) if b.segments is not None else None,
        sensing_b=sensing(direct_b.seen, direct_a.seen, bw) if a.segments is not None else None,
    )


def _unmapped(own: SessionObservations, other: SessionObservations, mine: DirectEvidence, theirs: DirectEvidence,
              ground: HeightField, own_heights: np.ndarray, change_label: str, gate_m: float, params: ChangeParams,
              counterpart_log_ratio: float = 0.0, visible: Callable[[np.ndarray], np.ndarray] | None = None,
              ) -> tuple[UnmappedObjects, LandmarkChanges | None]:
    """The objects `own` saw but never mapped (`unmapped.unmapped_objects`) and their verdicts against `other`,
    judged as landmarks are but by direct evidence alone: a counterpart landmark, a holder of the other map that
    this session shows, the other session's segments, else a change with the absence probability (presence rates
    from this map's landmarks with a counterpart). No part links: a piece of track is no whole of anything, and it
    vouches for nothing. None without the tracks or either session's segments (nothing to judge them by)."""
    if not params.unmapped_objects or own.tracks is None or own.segments is None or other.segments is None:
        return no_unmapped_objects(), None
    objs = unmapped_objects(own.tracks, own.poses, own.cameras, own.segments, own.positions, own.sizes, gate_m,
                            params.max_size_difference, params.z_weight, params.part_max_ratio,
                            params.unmapped_max_error_px, params.unmapped_pixel_sigma_px)
    # below the ground its session looked at (by the scale of its map's landmarks): a wrong triangulation
    heights = _above(ground, objs.positions)
    keep = np.flatnonzero(~below_the_ground(heights, own_heights, params.max_depth_sigmas))
    objs, heights = objs.subset(keep), heights[keep]
    if params.surface_evidence and own.images is not None and mine.surface_references is not None and len(objs):
        # far above the surface its session's images show at its place (nu29: 9 m above a conifer's tip, new at
        # 0.999 beside the tree's kept landmarks): a wrong triangulation too
        surface = session_heights(objs.positions, own, ground, params)
        noise = ground_sweep_noise(mine.surface_references[0])
        keep = np.flatnonzero(~above_the_surface(heights, surface, own_heights, params.max_depth_sigmas, noise))
        objs, heights = objs.subset(keep), heights[keep]
    # its own segments must show it, as the other session's must show a landmark to keep it (the same test, with
    # this session's landmarks as the references of presence): a piece of track alone is no object
    nothing = np.zeros((0, 3))
    shown = direct_evidence(objs.positions, objs.sizes, own, nothing, nothing[:, 0], gate_m, params,
                    (own.positions, own.sizes))
    keep = np.flatnonzero(shown.by_segments & (shown.hits >= own.views_needed(params.min_views)))
    objs, heights = objs.subset(keep), heights[keep]
    reference = mine.compared & (mine.index >= 0)
    direct = direct_evidence(objs.positions, objs.sizes, other, other.positions, other.sizes, gate_m, params,
                     (own.positions[reference], own.sizes[reference]), own=own, ground=ground,
                     surface_references=mine.surface_references, counterpart_log_ratio=counterpart_log_ratio,
                     visible=visible)
    return objs, _judge(own, objs.positions, objs.sizes, other, other.positions, other.sizes, heights, change_label,
                        gate_m, replace(params, part_max_ratio=0.0), direct, theirs)


def _above(ground: HeightField, points: np.ndarray) -> np.ndarray:
    """Heights of `points` above the ground height field."""
    return points[:, 2] - ground(points[:, 0], points[:, 1])


def _median(sizes: np.ndarray) -> float:
    """The median of the known sizes (the session's typical landmark, for its footprints' reach); NaN if none."""
    known = np.asarray(sizes, dtype=np.float64)
    known = known[np.isfinite(known)]
    return float(np.median(known)) if len(known) else float("nan")
