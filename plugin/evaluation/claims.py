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

Everything here is pure numpy/scipy on indices; reading match.json and landmarks.csv lives in the workflow.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class Hypothesis:
    """One window-pair hypothesis: associations (M, 2) landmark indices (A, B), score |S|, gravity-check flag."""

    associations: np.ndarray
    score: float
    valid: bool = True


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
    hypotheses: Sequence[Hypothesis], observers_a: sp.csr_matrix, observers_b: sp.csr_matrix
) -> np.ndarray:
    """(K_a, K_b) claim-score matrix: max |S| over valid hypotheses claiming the pair, NaN where none does.

    Per hypothesis, the claimed pairs are the non-zeros of O_A[a]^T O_B[b] summed over its associations
    (one sparse product, no Python loop over associations).
    """
    ka, kb = observers_a.shape[1], observers_b.shape[1]
    scores = np.full((ka, kb), -np.inf)
    oa_t = observers_a.T.tocsr()
    for hyp in hypotheses:
        assoc = np.asarray(hyp.associations, dtype=np.int64).reshape(-1, 2)
        if not hyp.valid or len(assoc) == 0:
            continue
        if assoc[:, 0].max() >= observers_a.shape[0] or assoc[:, 1].max() >= observers_b.shape[0]:
            raise ValueError("association refers to a landmark index beyond the map")
        # (K_a x M) @ (M x K_b): sum over associations of outer products of observer indicators.
        pairs = (oa_t[:, assoc[:, 0]] @ observers_b[assoc[:, 1]]).tocoo()
        if pairs.nnz:
            cur = scores[pairs.row, pairs.col]
            scores[pairs.row, pairs.col] = np.maximum(cur, hyp.score)
    scores[np.isinf(scores)] = np.nan
    return scores
