"""Which ground-truth object each landmark is, and how many landmarks two maps have in common (ours).

The paper scores a match only by keyframe-pair claims; that cannot say whether a poor recall comes from the front
end (the two maps share few landmarks, or their sizes disagree) or from the search (the common landmarks are
there, the search does not find them). With a synthetic world's truth the common landmarks can be counted:

- object of a landmark: the object id under each observed mask centroid (the session's label image; 0 = ground
  cover), majority vote (`majority_objects`);
- eligible objects of a pair of sessions: present in both and seen in more than theta_n keyframes of each
  (`frames.json` visibility): the landmarks a perfect front end could have in common;
- segmented objects of a map: the object under a segment centroid (every mask of every keyframe, as the map's
  database holds them) in more than theta_n keyframes (`segmented_objects`); an eligible object segmented in both
  maps but not common was lost by tracking or triangulation, one not segmented by the segmenter;
- common landmarks: objects that are the majority object of a landmark in both maps; for each, the pair of
  landmarks (one per map) closest in space stands for it (`common_landmarks`);
- their size agreement: the ratio h_B / h_A and the relative difference r (the search's size gate,
  `association.size_ratio`) of each common pair;
- the oracle: one hypothesis holding every common pair (or only those passing the size gate), scored like the
  search's (`plugin.evaluation.claims`): the recall that an ideal search on these two maps would reach.

Pure numpy; the label images are read by the caller (`workflows.evaluate`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass
class LandmarkObjects:
    """Majority ground-truth object of every landmark of one map."""

    object_ids: np.ndarray  # (L,) int64 majority object id of the observations (0 = ground cover)
    purity: np.ndarray  # (L,) float share of the observations on that id


def majority_objects(observed: Sequence[np.ndarray]) -> LandmarkObjects:
    """Majority object id (ties: the smallest id) and its share, from each landmark's observed ids."""
    ids = np.zeros(len(observed), np.int64)
    purity = np.zeros(len(observed), np.float64)
    for i, obs in enumerate(observed):
        obs = np.asarray(obs, dtype=np.int64).ravel()
        if len(obs) == 0:
            continue
        values, counts = np.unique(obs, return_counts=True)
        k = int(np.argmax(counts))
        ids[i], purity[i] = values[k], counts[k] / len(obs)
    return LandmarkObjects(ids, purity)


def objects_under(labels: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Object id of the label image `labels` (rows x cols, 0 = ground cover) under each pixel point `xy` (n, 2),
    COLMAP convention (pixel i spans [i, i + 1)); points off the image take the nearest border pixel."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    col = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, labels.shape[1] - 1)
    row = np.clip(np.floor(xy[:, 1]).astype(np.int64), 0, labels.shape[0] - 1)
    return np.asarray(labels[row, col], np.int64)


def segmented_objects(ids_per_keyframe: Sequence[np.ndarray], min_keyframes: int) -> np.ndarray:
    """Object ids (> 0) under a segment centroid in at least `min_keyframes` keyframes (an object split into
    several segments counts once per keyframe), from `objects_under` of each keyframe's segment centroids."""
    counts: dict[int, int] = {}
    for ids in ids_per_keyframe:
        for oid in np.unique(np.asarray(ids, np.int64)):
            if oid > 0:
                counts[int(oid)] = counts.get(int(oid), 0) + 1
    return np.asarray(sorted(o for o, n in counts.items() if n >= min_keyframes), np.int64)


@dataclass
class CommonLandmarks:
    """The landmarks two maps share, counted against the ground-truth objects (see the module doc)."""

    eligible: np.ndarray  # object ids present in both sessions and seen in > theta_n keyframes of each
    mapped_a: np.ndarray  # eligible object ids with a landmark in A
    mapped_b: np.ndarray  # ... in B
    objects: np.ndarray  # (K,) object ids with a landmark in both maps (the common landmarks)
    pairs: np.ndarray  # (K, 2) landmark indices (A, B) standing for each common object
    sizes: np.ndarray  # (K, 2) their metric sizes
    offsets_m: np.ndarray  # (K,) distance between the two landmarks of a pair
    kinds: list[str] = field(default_factory=list)  # (K,) object kind of each common object

    @property
    def ratio(self) -> np.ndarray:
        """h_B / h_A of every common pair."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.sizes[:, 1] / self.sizes[:, 0]

    def summary(self, theta_r: float) -> dict:
        """Counts, the size-ratio quartiles and the share inside the size gate theta_r (JSON-friendly)."""
        from ..association.gates import size_ratio

        r = size_ratio(self.sizes[:, 0], self.sizes[:, 1]) if len(self.pairs) else np.zeros(0)
        ratio = self.ratio[np.isfinite(self.ratio)]
        q = np.percentile(ratio, [25, 50, 75]).tolist() if len(ratio) else [float("nan")] * 3
        return {"eligible_objects": int(len(self.eligible)), "mapped_a": int(len(self.mapped_a)),
                "mapped_b": int(len(self.mapped_b)), "common": int(len(self.objects)),
                "size_ratio_quartiles": q, "size_ratio_median": q[1],
                "within_size_gate": float(np.mean(r <= theta_r)) if len(r) else 0.0,
                "relative_size_difference_quartiles": (np.percentile(r, [25, 50, 75]).tolist() if len(r)
                                                       else [float("nan")] * 3),
                "median_offset_m": float(np.median(self.offsets_m)) if len(self.offsets_m) else float("nan"),
                "common_by_kind": count_by(self.kinds)}


def count_by(values: Sequence[str]) -> dict[str, int]:
    """How often each value occurs, sorted by value."""
    out: dict[str, int] = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return dict(sorted(out.items()))


def common_landmarks(objects_a: LandmarkObjects, objects_b: LandmarkObjects, positions_a: np.ndarray,
                     positions_b: np.ndarray, sizes_a: np.ndarray, sizes_b: np.ndarray, eligible: np.ndarray,
                     kind_of: dict[int, str] | None = None) -> CommonLandmarks:
    """The common landmarks of two maps of one world (positions in one frame; the synthetic truth is identity).

    Args:
        objects_a, objects_b: `majority_objects` of each map's landmarks.
        positions_a, positions_b: (L, 3) landmark positions; sizes_a, sizes_b: (L,) metric sizes.
        eligible: object ids a perfect front end could have in both maps (present in both sessions and seen in
            more than theta_n keyframes of each).
        kind_of: object id -> kind, for the per-kind counts.
    """
    eligible = np.unique(np.asarray(eligible, dtype=np.int64))
    ids_a, ids_b = objects_a.object_ids, objects_b.object_ids
    mapped_a = np.intersect1d(eligible, ids_a[ids_a > 0])
    mapped_b = np.intersect1d(eligible, ids_b[ids_b > 0])
    both = np.intersect1d(ids_a[ids_a > 0], ids_b[ids_b > 0])
    pairs, offsets = [], []
    for oid in both:
        ia, ib = np.flatnonzero(ids_a == oid), np.flatnonzero(ids_b == oid)
        d = np.linalg.norm(positions_a[ia, None, :] - positions_b[None, ib, :], axis=2)
        k = np.unravel_index(int(np.argmin(d)), d.shape)
        pairs.append((ia[k[0]], ib[k[1]]))
        offsets.append(float(d[k]))
    pairs_arr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    sizes = np.column_stack([np.asarray(sizes_a, np.float64)[pairs_arr[:, 0]],
                             np.asarray(sizes_b, np.float64)[pairs_arr[:, 1]]]) if len(pairs) else np.zeros((0, 2))
    kinds = [kind_of.get(int(o), "?") for o in both] if kind_of else []
    return CommonLandmarks(eligible, mapped_a, mapped_b, both.astype(np.int64), pairs_arr, sizes,
                           np.asarray(offsets, np.float64), kinds)


def eligible_objects(present_a: np.ndarray, present_b: np.ndarray, seen_a: dict[int, int], seen_b: dict[int, int],
                     min_keyframes_a: int, min_keyframes_b: int | None = None) -> np.ndarray:
    """Object ids present in both sessions and seen in at least `min_keyframes_a` keyframes of A and
    `min_keyframes_b` (None: the same) of B (each map's theta_n + 1: the flights may allow different ones).

    `present_*`: ids present in the session; `seen_*`: id -> number of keyframes showing it."""
    least_b = min_keyframes_a if min_keyframes_b is None else min_keyframes_b
    both = np.intersect1d(np.asarray(present_a, np.int64), np.asarray(present_b, np.int64))
    ok = [int(o) for o in both if seen_a.get(int(o), 0) >= min_keyframes_a and seen_b.get(int(o), 0) >= least_b]
    return np.asarray(ok, dtype=np.int64)


def oracle_recall(pairs: np.ndarray, observers_a: object, observers_b: object, iou: np.ndarray,
                  geometry: tuple | None = None) -> dict:
    """Precision and recall of one hypothesis holding `pairs` (all of them right), scored like the search's.

    The ceiling the search can reach on these maps: every keyframe pair the common landmarks can vouch for
    (`geometry`: the same overlap test as the search's claims, `claims.claim_scores`)."""
    from .claims import Hypothesis, claim_scores
    from .metrics import pr_curve

    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return {"associations": 0, "recall": 0.0, "precision": 1.0}
    scores = claim_scores([Hypothesis(pairs, float(len(pairs)))], observers_a, observers_b, geometry)
    curve = pr_curve(scores, iou)
    return {"associations": int(len(pairs)), "recall": float(curve.recall[-1]) if len(curve.recall) else 0.0,
            "precision": float(curve.precision[-1]) if len(curve.precision) else 1.0}
