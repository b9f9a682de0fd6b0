"""Why change detection failed on a synthetic pair: every false claim and every missed change of the bar's scope
(objects of radius >= 2 m both sessions saw >= 6 times), and every claim on no object, given one mechanism
each (used by `bench_changes --failures`).

The mechanism is read off the verdicts (`plugin.changes.LandmarkChanges`) and the world's truth (which object
each landmark lies on, `bench_map.landmark_objects`); the size and view limits below only name the failure, the
detector never sees them.

Missed change (the object changed; none of its landmarks or tracks is claimed), the first that holds:
- `never mapped`: its session has no landmark and no track on it;
- `below min-confidence`: claimed, but with too little confidence;
- `counterpart on the ground` / `counterpart on another object`: kept by a counterpart landmark of the other map
  within the gate, which lies on the ground or on a neighbour (a coincidence of place and size);
- `held by a larger landmark`: kept because a larger landmark of the other map holds it (`nested`);
- `part link`: kept as a part of a larger landmark of its own map; `other's segments`: kept because the other
  session's segments show something there; `flat`: compared, but its own session's surface stood no higher than
  the ground there (`changes.object_height_p`); `not compared`: too few views of the other session, or below
  ground.

False claim (the object is in both sessions), for its most confident claimed landmark:
- `claimed from a track`: only a track of it (never mapped) is claimed;
- `fragment of a kept object`: the landmark is less than half the object's size and another landmark of the
  object in its map is kept;
- `merged with neighbours`: the landmark is more than twice the object's size (one segment over several);
- `counterpart failed the size gate` / `counterpart beyond the gate`: the other map has a landmark of the object
  within the gate but of another size / of a compatible size but up to twice the gate away (position error);
- `other map has it elsewhere`: the other map's landmarks of the object are farther;
- `not mapped by the other, seen <= 10 times` / `... > 10 times`: the other map has no landmark of it (the
  other session's own segments said absent), split by how often it should have seen it.

Claim on no object: a claimed landmark or track of radius (2 h) >= 2 m whose observations lie on the ground
(`ground texture or shadow`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...plugin.association.gates import size_ratio
from ...plugin.changes import (
    BELOW_GROUND,
    BY_LANDMARK,
    BY_NESTING,
    BY_PART,
    BY_SEGMENTS,
    FLAT,
    FOOTPRINT_MARGIN,
    GONE,
    LOW_CONFIDENCE,
    NEW,
    ChangeResult,
)
from .change_truth import ObjectTruth

FALSE, MISSED, NO_OBJECT = "false claim", "missed", "claim on no object"
FEW_VIEWS = 10  # names the failure only


@dataclass(frozen=True)
class Failure:
    change: str  # gone / new
    what: str  # FALSE, MISSED or NO_OBJECT
    object_id: int  # 0 for a claim on no object
    kind: str
    radius_m: float
    mechanism: str


def classify_failures(result: ChangeResult, truth: ObjectTruth, objects_a: np.ndarray, objects_b: np.ndarray,
                      min_confidence: float, unmapped_objects_a: np.ndarray | None = None,
                      unmapped_objects_b: np.ndarray | None = None, min_views: int = 6,
                      min_radius: float = 2.0) -> list[Failure]:
    """Every failure of one pair's ChangeResult (see the module docstring), claims at `min_confidence`."""
    where = truth.index()
    in_scope = (truth.views_a >= min_views) & (truth.views_b >= min_views) & (truth.radius >= min_radius)
    out: list[Failure] = []
    scale = np.array([1.0, 1.0, result.params.z_weight])
    for change in (GONE, NEW):
        mine, other = (result.a, result.b) if change == GONE else (result.b, result.a)
        objs, other_objs = (objects_a, objects_b) if change == GONE else (objects_b, objects_a)
        pos, other_pos = ((result.positions_a, result.positions_b) if change == GONE
                          else (result.positions_b, result.positions_a))
        sizes, other_sizes = (result.sizes_a, result.sizes_b) if change == GONE else (result.sizes_b, result.sizes_a)
        tracks = result.tracks_a if change == GONE else result.tracks_b
        unmapped = result.unmapped_a if change == GONE else result.unmapped_b
        track_objs = unmapped_objects_a if change == GONE else unmapped_objects_b
        if tracks is None or track_objs is None:
            tracks, track_objs = None, np.zeros(0, np.int64)
        changed = (truth.present_a & ~truth.present_b) if change == GONE else (~truth.present_a & truth.present_b)
        claim = (mine.label == change) & (mine.confidence >= min_confidence)
        track_claim = ((tracks.label == change) & (tracks.confidence >= min_confidence) if tracks is not None
                       else np.zeros(0, bool))
        for i in np.flatnonzero(claim):
            if int(objs[i]) not in where and FOOTPRINT_MARGIN * sizes[i] >= min_radius:
                out.append(Failure(change, NO_OBJECT, 0, "ground", float(FOOTPRINT_MARGIN * sizes[i]),
                                   "ground texture or shadow"))
        for q in np.flatnonzero(track_claim):
            if int(track_objs[q]) not in where and FOOTPRINT_MARGIN * unmapped.sizes[q] >= min_radius:
                out.append(Failure(change, NO_OBJECT, 0, "ground", float(FOOTPRINT_MARGIN * unmapped.sizes[q]),
                                   "ground texture or shadow"))
        claimed = {where[int(o)] for o in objs[claim] if int(o) in where}
        claimed |= {where[int(o)] for o in track_objs[track_claim] if int(o) in where}
        for k in np.flatnonzero(in_scope):
            if bool(changed[k]) == (k in claimed):
                continue
            oid = int(truth.ids[k])
            lms = np.flatnonzero(objs == oid)
            if changed[k]:
                ev = {str(e) for e in mine.evidence[lms]}
                own_tracks = np.flatnonzero(track_objs == oid)
                if tracks is not None:
                    ev |= {str(e) for e in tracks.evidence[own_tracks]}
                below = np.any(mine.label[lms] == change) or (
                    tracks is not None and np.any(tracks.label[own_tracks] == change))
                if not len(lms) and not len(own_tracks):
                    why = "never mapped"
                elif below or LOW_CONFIDENCE in ev:
                    why = "below min-confidence"
                elif BY_LANDMARK in ev:
                    cps = mine.counterpart[lms[mine.evidence[lms] == BY_LANDMARK]]
                    on_ground = [int(other_objs[j]) not in where for j in cps]
                    why = "counterpart on the ground" if any(on_ground) else "counterpart on another object"
                elif BY_NESTING in ev:
                    why = "held by a larger landmark"
                elif BY_PART in ev:
                    why = "part link"
                elif BY_SEGMENTS in ev:
                    why = "other's segments"
                elif FLAT in ev:
                    why = "flat"
                else:
                    why = "not compared" + (" (below ground)" if BELOW_GROUND in ev else "")
                out.append(Failure(change, MISSED, oid, str(truth.kind[k]), float(truth.radius[k]), why))
                continue
            mine_claims = lms[claim[lms]]
            if not len(mine_claims):
                out.append(Failure(change, FALSE, oid, str(truth.kind[k]), float(truth.radius[k]),
                                   "claimed from a track"))
                continue
            i = mine_claims[np.argmax(mine.confidence[mine_claims])]
            h_object = truth.radius[k] / FOOTPRINT_MARGIN
            theirs = np.flatnonzero(other_objs == oid)
            if sizes[i] < 0.5 * h_object and np.any(mine.label[lms] == "kept"):
                why = "fragment of a kept object"
            elif sizes[i] > 2.0 * h_object:
                why = "merged with neighbours"
            elif len(theirs):
                d = np.linalg.norm((other_pos[theirs] - pos[i]) * scale, axis=1)
                j = int(np.argmin(d))
                compatible = size_ratio(sizes[i], other_sizes[theirs[j]]) <= result.params.max_size_difference
                if d[j] <= result.tolerance_m and not compatible:
                    why = "counterpart failed the size gate"
                elif d[j] <= 2.0 * result.tolerance_m and compatible:
                    why = "counterpart beyond the gate"
                else:
                    why = "other map has it elsewhere"
            else:
                why = f"not mapped by the other, seen {'<=' if mine.views[i] <= FEW_VIEWS else '>'} {FEW_VIEWS} times"
            out.append(Failure(change, FALSE, oid, str(truth.kind[k]), float(truth.radius[k]), why))
    return out


def failure_table(failures: list[Failure]) -> str:
    """Markdown table: mechanism x (gone / new, false claim / missed / claim on no object), counts."""
    counts = Counter((f.mechanism, f.change, f.what) for f in failures)
    cols = [(GONE, FALSE), (GONE, MISSED), (NEW, FALSE), (NEW, MISSED), (GONE, NO_OBJECT), (NEW, NO_OBJECT)]
    lines = ["| mechanism | " + " | ".join(f"{c} {w}" for c, w in cols) + " |", "|---|" + "---|" * len(cols)]
    for mech in sorted({m for m, _, _ in counts}, key=lambda m: -sum(v for (mm, _, _), v in counts.items()
                                                                        if mm == m)):
        lines.append(f"| {mech} | " + " | ".join(str(counts.get((mech, c, w), 0)) for c, w in cols) + " |")
    lines.append("| **all** | " + " | ".join(str(sum(v for (_, c2, w2), v in counts.items() if (c2, w2) == (c, w)))
                                            for c, w in cols) + " |")
    return "\n".join(lines)
