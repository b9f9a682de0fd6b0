"""Turning map-association hypotheses into scored claims about keyframe pairs.

The protocol scores keyframe pairs, but SOS-Match associates landmarks. Our rule *(ours; the paper does not
spell it out)*:

- A window-pair hypothesis with a consistent set S of landmark associations claims, for every association
  (a, b) in S, every pair (k_a, k_b) of a keyframe of session A that observed landmark a and a keyframe of
  session B that observed landmark b: the two images show the same ground object, so they overlap.
- A claim's score is |S| of the best hypothesis supporting it (the maximum over hypotheses); thresholding
  the score at theta_S + 1 reproduces accepting hypotheses with |S| > theta_S, so sweeping the threshold
  draws the precision-recall curve of theta_S.
- Hypotheses rejected for a reason other than |S| (the gravity check) claim nothing.
- `max_observers` optionally keeps, per landmark, only the observers whose camera centre is horizontally
  nearest the landmark: a long track's first and last observers see the landmark at the image border and
  may overlap little with the other session's observers.
- With `ObserverGeometry` (the default of the evaluation) a pair is claimed only when the association places
  the two cameras close enough that their images must overlap: each observer's horizontal offset from its
  landmark, in its own map's frame (its own poses, B's turned by the hypothesis' rotation), gives the two cameras'
  separation; it must be at most `max_separation` x the lower camera height above the landmark (0.8 x the
  image's shorter side on the ground: two nadir footprints that close overlap with IoU >= 0.08 at any heading,
  while every pair with IoU > 1/3 is closer than 0.5 x). A landmark seen at two images' opposite edges says
  nothing about overlap; with one landmark per object over all its passes such pairs are common (a correct
  free-form alignment: 1.5 % of its claims had IoU < 0.01, enough to keep precision below 0.99).

Everything here is pure numpy/scipy on indices; reading match.json and landmarks.csv lives in the workflow.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

SEPARATION_OF_SHORTER_SIDE = 0.8  # the claimed cameras' largest separation, in image shorter sides on the ground


@dataclass(frozen=True)
class Hypothesis:
    """One window-pair hypothesis: associations (M, 2) landmark indices (A, B), score |S|, gravity-check flag,
    and its rotation A_from_B (None: identity) for `ObserverGeometry`."""

    associations: np.ndarray
    score: float
    valid: bool = True
    rotation: np.ndarray | None = None


@dataclass(frozen=True)
class ObserverGeometry:
    """Where one map's observers were: per landmark, the (n, 2) horizontal offset camera - landmark and the (n,)
    camera height above the landmark of each observer, in the order of its `observer_matrix` row (ascending
    keyframe), in the map's own frame."""

    offsets: list[np.ndarray]
    heights: list[np.ndarray]


def observer_geometry(observers: sp.csr_matrix, landmarks: np.ndarray, keyframe_centers: np.ndarray
                      ) -> ObserverGeometry:
    """`ObserverGeometry` of a map: landmark positions (L, 3) and each keyframe's camera centre (K, 3), both in
    the map's frame (the poses the map was built on)."""
    offsets, heights = [], []
    for i in range(observers.shape[0]):
        kf = observers.indices[observers.indptr[i]:observers.indptr[i + 1]]
        kf = np.sort(kf)
        d = np.asarray(keyframe_centers, np.float64)[kf] - np.asarray(landmarks, np.float64)[i]
        offsets.append(d[:, :2])
        heights.append(d[:, 2])
    return ObserverGeometry(offsets, heights)


def separation_ratio(width_px: int, height_px: int, focal_px: float) -> float:
    """`max_separation` of `claim_scores`: SEPARATION_OF_SHORTER_SIDE x the image's shorter side, per metre of
    camera height (for a nadir camera, its shorter side on the ground)."""
    return SEPARATION_OF_SHORTER_SIDE * min(width_px, height_px) / focal_px


def observer_matrix(
    observers: Sequence[Sequence[int]], n_keyframes: int, landmark_xy: np.ndarray | None = None,
    keyframe_xy: np.ndarray | None = None, max_observers: int | None = None,
) -> sp.csr_matrix:
    """(n_landmarks, n_keyframes) boolean CSR matrix: landmark i was observed in keyframe k.

    Args:
        observers: per landmark, the keyframe indices that observed it (out-of-range indices are an error).
        n_keyframes: number of keyframes of the session.
        landmark_xy, keyframe_xy: (L, 2) and (K, 2) horizontal positions, needed with `max_observers`.
        max_observers: keep only this many observers per landmark, nearest first (None: all).
    """
    rows, cols = [], []
    for i, obs in enumerate(observers):
        obs = np.unique(np.asarray(obs, dtype=np.int64))
        if len(obs) and (obs.min() < 0 or obs.max() >= n_keyframes):
            raise ValueError(f"landmark {i}: observer index out of range [0, {n_keyframes})")
        if max_observers is not None and len(obs) > max_observers:
            if landmark_xy is None or keyframe_xy is None:
                raise ValueError("max_observers needs landmark_xy and keyframe_xy")
            dist = np.linalg.norm(np.asarray(keyframe_xy)[obs] - np.asarray(landmark_xy)[i], axis=1)
            obs = obs[np.argsort(dist, kind="stable")[:max_observers]]
        rows.append(np.full(len(obs), i, dtype=np.int64))
        cols.append(obs)
    r = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
    return sp.csr_matrix((np.ones(len(r), dtype=np.float32), (r, c)), shape=(len(observers), n_keyframes))


def claim_scores(
    hypotheses: Sequence[Hypothesis], observers_a: sp.csr_matrix, observers_b: sp.csr_matrix,
    geometry: tuple[ObserverGeometry, ObserverGeometry, float] | None = None,
) -> np.ndarray:
    """(K_a, K_b) claim-score matrix: max |S| over valid hypotheses claiming the pair, NaN where none does.

    Per hypothesis, the claimed pairs are the non-zeros of O_A[a]^T O_B[b] summed over its associations
    (one sparse product, no Python loop over associations). With `geometry` = (A's, B's, max_separation), only
    the observer pairs the association places within max_separation x camera height of each other (module doc).
    """
    ka, kb = observers_a.shape[1], observers_b.shape[1]
    scores = np.full((ka, kb), -np.inf)
    if geometry is not None:
        return _geometric_claims(hypotheses, observers_a, observers_b, geometry, scores)
    oa_t = observers_a.T.tocsr()
    for hyp in hypotheses:
        assoc = _associations(hyp, observers_a, observers_b)
        if assoc is None:
            continue
        # (K_a x M) @ (M x K_b): sum over associations of outer products of observer indicators.
        pairs = (oa_t[:, assoc[:, 0]] @ observers_b[assoc[:, 1]]).tocoo()
        if pairs.nnz:
            cur = scores[pairs.row, pairs.col]
            scores[pairs.row, pairs.col] = np.maximum(cur, hyp.score)
    scores[np.isinf(scores)] = np.nan
    return scores


def _associations(hyp: Hypothesis, observers_a: sp.csr_matrix, observers_b: sp.csr_matrix) -> np.ndarray | None:
    """A hypothesis' (K, 2) associations checked against the maps' landmark counts; None when it claims nothing
    (invalid or empty)."""
    assoc = np.asarray(hyp.associations, dtype=np.int64).reshape(-1, 2)
    if not hyp.valid or len(assoc) == 0:
        return None
    if assoc[:, 0].max() >= observers_a.shape[0] or assoc[:, 1].max() >= observers_b.shape[0]:
        raise ValueError("association refers to a landmark index beyond the map")
    return assoc


def _geometric_claims(hypotheses: Sequence[Hypothesis], observers_a: sp.csr_matrix, observers_b: sp.csr_matrix,
                      geometry: tuple[ObserverGeometry, ObserverGeometry, float], scores: np.ndarray) -> np.ndarray:
    """`claim_scores` with the separation test: per distinct association, its best hypothesis' score and
    rotation, then its observer pairs within the separation."""
    geo_a, geo_b, ratio = geometry
    best: dict[tuple[int, int], tuple[float, np.ndarray | None]] = {}
    for hyp in hypotheses:
        assoc = _associations(hyp, observers_a, observers_b)
        if assoc is None:
            continue
        for a, b in assoc.tolist():
            if (a, b) not in best or hyp.score > best[(a, b)][0]:
                best[(a, b)] = (hyp.score, hyp.rotation)
    for (a, b), (score, rot) in best.items():
        kfa = np.sort(observers_a.indices[observers_a.indptr[a]:observers_a.indptr[a + 1]])
        kfb = np.sort(observers_b.indices[observers_b.indptr[b]:observers_b.indptr[b + 1]])
        if not len(kfa) or not len(kfb):
            continue
        off_b = geo_b.offsets[b] if rot is None else geo_b.offsets[b] @ np.asarray(rot)[:2, :2].T
        sep = np.linalg.norm(geo_a.offsets[a][:, None, :] - off_b[None, :, :], axis=2)
        limit = ratio * np.minimum(geo_a.heights[a][:, None], geo_b.heights[b][None, :])
        i, j = np.nonzero(sep <= limit)
        cur = scores[kfa[i], kfb[j]]
        scores[kfa[i], kfb[j]] = np.maximum(cur, score)
    scores[np.isinf(scores)] = np.nan
    return scores
