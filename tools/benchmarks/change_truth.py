"""Scoring change detection against the synthetic world's truth (used by bench_changes and the tests).

Truth of a pair (A, B) of one world: an object is *removed* when present in A and absent in B (objects.csv
`present`), *added* when absent in A and present in B. An object is scored when both sessions' keyframes saw its
place at least `min_views` times (its true position projected with the true poses, with its radius as margin,
`plugin.changes.in_view`), whether or not it was there; the bar's scope is those of radius >= 2 m (the size
bins). A landmark's object is the majority label of its observations (`bench_map.landmark_objects`).

Claims are scored per object: an object is claimed gone when any of its A landmarks is `gone` (new: any of its B
landmarks `new`), or any of the objects A never mapped whose track lies on it (`plugin.changes.unmapped`).
Precision = claimed objects truly removed / claimed objects; recall = removed objects that are claimed / removed
objects (`recall`), and the same over the removed objects that A mapped at all
(`recall_mapped`: what the comparison can reach; an object never mapped cannot be reported).
Claims on no object: a gone / new landmark (or track) whose observations lie on the ground (ground texture,
a shadow) is a claim of an object that does not exist; the bar's scope is set by the world's objects, so these
are counted apart (`ground_claimed`, by the claim's own radius 2 h): `scope_counts(..., with_ground=True)`
is the precision of what changes.csv says of things of radius >= 2 m, ground claims included (on the 21
same-season development pairs 571 such claims against 124 on objects in scope at the default confidence).
False changes: every gone / new landmark whose object did not change (ground texture included), per hectare
of the area both sessions observed (true footprints of frames.json). Outside: change claims on landmarks
that lie outside the other session's true observed area (must be 0). Every claimed landmark is also kept with its
confidence and whether its object truly changed (`landmark_claims`): the precision of what a user reads in
changes.csv, and the calibration of the confidence.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...plugin.changes import FOOTPRINT_MARGIN, GONE, NEW, ChangeResult, in_view

SIZE_BINS = ((0.0, 2.0, "r < 2 m"), (2.0, 3.0, "2-3 m"), (3.0, 5.0, "3-5 m"), (5.0, np.inf, ">= 5 m"))


@dataclass
class ObjectTruth:
    """Per world object of a pair: kind, radius, presence in A and B, views of its place by A and B."""

    ids: np.ndarray
    kind: np.ndarray
    radius: np.ndarray
    present_a: np.ndarray
    present_b: np.ndarray
    views_a: np.ndarray
    views_b: np.ndarray

    def index(self) -> dict[int, int]:
        return {int(o): k for k, o in enumerate(self.ids)}


def object_truth(synth_a: Any, synth_b: Any, keyframes_a: list[str], keyframes_b: list[str]) -> ObjectTruth:
    """The world's objects with their presence and how often each session's keyframes saw their place."""
    oa, ob = synth_a.objects, synth_b.objects
    if not np.array_equal(oa["id"], ob["id"]):
        raise ValueError("the two sessions are not of one world (object ids differ)")
    pos = np.column_stack([oa["x"], oa["y"], oa["z"]])
    half = oa["radius"] / 2.0  # in_view's margin is 2 h; an object's footprint radius is 2 h

    def views(synth: Any, names: list[str]) -> np.ndarray:
        idx = [synth.poses.names.index(n) for n in names]
        poses = synth.poses.subset(idx)
        seen, _, _ = in_view(pos, half, poses, [synth.camera] * len(poses))
        return seen.sum(0)

    return ObjectTruth(oa["id"].astype(np.int64), oa["kind"].astype(str), oa["radius"].astype(np.float64),
                       oa["present"].astype(bool), ob["present"].astype(bool), views(synth_a, keyframes_a),
                       views(synth_b, keyframes_b))


def observed_truth_area(synth: Any, keyframes: list[str]) -> object:
    """Union of the true ground footprints (frames.json) of the keyframes."""
    import shapely

    wanted = set(keyframes)
    return shapely.union_all([shapely.Polygon(f["footprint"]) for f in synth.frames if f["name"] in wanted])


@dataclass
class Score:
    """Counts of one or several pairs; `add` pools."""

    claimed: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    correct: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    truth: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    found: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    truth_mapped: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    found_mapped: dict[tuple[str, str, str], int] = field(default_factory=lambda: defaultdict(int))
    ground_claimed: dict[tuple[str, str], int] = field(default_factory=lambda: defaultdict(int))  # (change, size)
    false_landmarks: int = 0
    false_by_kind: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    outside: int = 0
    common_ha: float = 0.0
    pairs: int = 0
    # (confidence, the landmark's object truly changed this way) per gone / new landmark, any size or object
    landmark_claims: list[tuple[float, bool]] = field(default_factory=list)

    def add(self, other: Score) -> None:
        for name in ("claimed", "correct", "truth", "found", "truth_mapped", "found_mapped", "false_by_kind",
                     "ground_claimed"):
            mine, theirs = getattr(self, name), getattr(other, name)
            for k, v in theirs.items():
                mine[k] += v
        self.false_landmarks += other.false_landmarks
        self.outside += other.outside
        self.common_ha += other.common_ha
        self.pairs += other.pairs
        self.landmark_claims.extend(other.landmark_claims)

    def _sum(self, table: dict, change: str, kind: str | None, size: str | None) -> int:
        return sum(v for (c, k, s), v in table.items()
                   if c == change and (kind is None or k == kind) and (size is None or s == size))

    def precision(self, change: str, kind: str | None = None, size: str | None = None) -> tuple[float, int]:
        n = self._sum(self.claimed, change, kind, size)
        return (self._sum(self.correct, change, kind, size) / n if n else float("nan")), n

    def recall(self, change: str, kind: str | None = None, size: str | None = None,
               mapped: bool = False) -> tuple[float, int]:
        truth, found = (self.truth_mapped, self.found_mapped) if mapped else (self.truth, self.found)
        n = self._sum(truth, change, kind, size)
        return (self._sum(found, change, kind, size) / n if n else float("nan")), n

    def scope_counts(self, change: str, min_radius: float = 2.0, with_ground: bool = False,
                     ) -> tuple[int, int, int, int]:
        """(correct claims, claims, changed objects found, changed objects) over the size bins from min_radius;
        `with_ground`: the claims on no object (ground texture, shadows) of those sizes count as claims too."""
        names = {name for lo, _, name in SIZE_BINS if lo >= min_radius}
        counts = [self._sum_sizes(t, change, names) for t in (self.correct, self.claimed, self.found, self.truth)]
        if with_ground:
            counts[1] += sum(v for (c, size), v in self.ground_claimed.items() if c == change and size in names)
        return counts[0], counts[1], counts[2], counts[3]

    def _sum_sizes(self, table: dict, change: str, sizes: set[str]) -> int:
        return sum(v for (c, _, s), v in table.items() if c == change and s in sizes)

    def landmark_precision(self) -> tuple[float, int]:
        """Share of all gone / new landmarks whose object truly changed (ground texture and small objects
        included), and their number."""
        n = len(self.landmark_claims)
        return (sum(ok for _, ok in self.landmark_claims) / n if n else float("nan")), n

    def false_per_ha(self) -> float:
        return self.false_landmarks / self.common_ha if self.common_ha > 0 else float("nan")


def size_bin(radius: float) -> str:
    for lo, hi, name in SIZE_BINS:
        if lo <= radius < hi:
            return name
    return SIZE_BINS[-1][2]


def score_pair(result: ChangeResult, truth: ObjectTruth, objects_a: np.ndarray, objects_b: np.ndarray,
               truth_area_a: object, truth_area_b: object, min_views: int = 6,
               min_confidence: float = 0.0, unmapped_objects_a: np.ndarray | None = None,
               unmapped_objects_b: np.ndarray | None = None) -> Score:
    """Score one pair's ChangeResult (see the module docstring). objects_a/b: the object id of each landmark
    (0 = not on an object); unmapped_objects_a/b: the same for the objects each session never mapped
    (`result.unmapped_a/b`, whose claims count as the landmarks' do; None: not scored). Claims below
    `min_confidence` are not counted as claims (as `--min-confidence`)."""
    import shapely

    score = Score(pairs=1)
    where = truth.index()
    common = shapely.intersection(truth_area_a, truth_area_b)
    score.common_ha = float(common.area) / 1e4
    sides = ((GONE, result.a, objects_a, truth.present_a & ~truth.present_b, result.positions_a, truth_area_b,
              result.tracks_a, unmapped_objects_a, result.unmapped_a, result.sizes_a),
             (NEW, result.b, objects_b, ~truth.present_a & truth.present_b, result.positions_b, truth_area_a,
              result.tracks_b, unmapped_objects_b, result.unmapped_b, result.sizes_b))
    for change, verdict, objects, changed, positions, other_area, tracks, track_objects, unmapped, sizes in sides:
        mapped = {where[int(o)] for o in objects if int(o) in where}  # by a landmark
        labels, confidence = verdict.label, verdict.confidence
        if tracks is not None and track_objects is not None:
            labels, confidence = np.r_[labels, tracks.label], np.r_[confidence, tracks.confidence]
            objects, positions = np.r_[objects, track_objects], np.r_[positions.reshape(-1, 3), unmapped.positions]
            sizes = np.r_[sizes, unmapped.sizes]
        claims = (labels == change) & (confidence >= min_confidence)
        claimed_objects: set[int] = set()
        for i in np.flatnonzero(claims):
            o = int(objects[i])
            k = where.get(o)
            score.landmark_claims.append((float(confidence[i]), bool(k is not None and changed[k])))
            if k is None or not changed[k]:
                score.false_landmarks += 1
                score.false_by_kind[truth.kind[k] if k is not None else "ground"] += 1
            if k is None and np.isfinite(sizes[i]):  # on no object: a claim of something of its own size
                score.ground_claimed[(change, size_bin(FOOTPRINT_MARGIN * float(sizes[i])))] += 1
            if not shapely.contains_xy(other_area, positions[i, 0], positions[i, 1]):
                score.outside += 1
            if k is not None:
                claimed_objects.add(k)
        in_scope = (truth.views_a >= min_views) & (truth.views_b >= min_views)
        for k in np.flatnonzero(in_scope):
            key = (change, str(truth.kind[k]), size_bin(float(truth.radius[k])))
            if k in claimed_objects:
                score.claimed[key] += 1
                score.correct[key] += int(changed[k])
            if changed[k]:
                score.truth[key] += 1
                score.found[key] += int(k in claimed_objects)
                if k in mapped:
                    score.truth_mapped[key] += 1
                    score.found_mapped[key] += int(k in claimed_objects)
    return score
