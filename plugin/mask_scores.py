"""The scores of a (track, mask) pair in tracking (method spec 1.5; `tracking.pair_scores` gates the pairs and
combines them, q = sqrt(q_s q_f)): the size score q_s and the feature score q_f.

**q_f** *(ours, the paper says "fraction of SIFT features of A_i and A_j that survive Lowe's ratio test")*: match
A_i against A_j with the ratio test in both directions (nearest / second-nearest descriptor distance within the
other mask's set < `sift_ratio`; a set with a single descriptor has no second neighbour and passes the ratio test
trivially) and keep mutual nearest neighbours; every kept match makes one feature of A_i and one of A_j survive, so
`q_f = 2 |matches| / (|A_i| + |A_j|)` (a Dice coefficient, in [0, 1]; 0 when either mask has no SIFT feature).
Descriptors are L2-normalised first, so the ratio test is scale-free.

Only the pairs that pass the tracker's cheap gates get SIFT matching, batched as one padded matrix product per
chunk of pairs.
"""

from __future__ import annotations

import numpy as np

from .mask_features import MaskFeatures

_PAIR_CHUNK_ELEMS = 4_000_000  # padded pairs x rows x cols per batched descriptor product (~16 MB float32)


def desc_index(feat: MaskFeatures, descriptors: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit-norm descriptors sorted by owner mask, start offset per mask, count per mask). `descriptors`: the
    features' SIFT descriptors when they are not held in `feat` (read from the keyframe cache)."""
    k = len(feat)
    owner = np.asarray(feat.sift_mask, np.int64).reshape(-1)
    desc = np.asarray(feat.sift_desc if descriptors is None else descriptors, np.float32).reshape(-1, 128)
    ok = (owner >= 0) & (owner < k)
    owner, desc = owner[ok], desc[ok]
    order = np.argsort(owner, kind="stable")
    desc = desc[order]
    desc = desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    counts = np.bincount(owner, minlength=k).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return desc.astype(np.float32), starts, counts


def feature_scores(
    desc_a: tuple[np.ndarray, np.ndarray, np.ndarray],
    desc_b: tuple[np.ndarray, np.ndarray, np.ndarray],
    pairs_a: np.ndarray,
    pairs_b: np.ndarray,
    ratio: float,
) -> np.ndarray:
    """q_f of mask pairs (pairs_a[p] in set a, pairs_b[p] in set b): Dice fraction of mutual ratio-test matches.

    `desc_*` come from `desc_index`. All pairs are evaluated together as padded (P, n, m) distance tensors,
    chunked to bound memory.
    """
    da, sa, ca = desc_a
    db, sb, cb = desc_b
    n_a, n_b = ca[pairs_a], cb[pairs_b]
    out = np.zeros(len(pairs_a))
    live = np.flatnonzero((n_a > 0) & (n_b > 0))
    if len(live) == 0:
        return out
    # Chunk pairs of similar size together so padding stays small.
    live = live[np.argsort(n_a[live] * n_b[live], kind="stable")]
    i = 0
    while i < len(live):
        nmax, mmax = n_a[live[i]], n_b[live[i]]
        j = i + 1
        while j < len(live):
            nn, mm = max(nmax, n_a[live[j]]), max(mmax, n_b[live[j]])
            if (j - i + 1) * nn * mm > _PAIR_CHUNK_ELEMS:
                break
            nmax, mmax, j = nn, mm, j + 1
        chunk = live[i:j]
        out[chunk] = _feature_scores_padded(
            da, sa[pairs_a[chunk]], n_a[chunk], db, sb[pairs_b[chunk]], n_b[chunk], int(nmax), int(mmax), ratio
        )
        i = j
    return out


def _feature_scores_padded(
    da: np.ndarray, start_a: np.ndarray, n_a: np.ndarray, db: np.ndarray, start_b: np.ndarray, n_b: np.ndarray,
    nmax: int, mmax: int, ratio: float,
) -> np.ndarray:
    ra, rb = np.arange(nmax), np.arange(mmax)
    valid_a = ra[None, :] < n_a[:, None]  # (P, nmax)
    valid_b = rb[None, :] < n_b[:, None]
    ia = np.where(valid_a, start_a[:, None] + ra[None, :], 0)
    ib = np.where(valid_b, start_b[:, None] + rb[None, :], 0)
    a, b = da[ia], db[ib]  # (P, nmax, 128), (P, mmax, 128)
    # contiguous (P, 128, mmax): numpy's stacked matmul takes a slow non-BLAS loop on a transposed view (~40x)
    dot = np.matmul(a, np.ascontiguousarray(b.transpose(0, 2, 1)))
    dist = np.sqrt(np.maximum(2.0 - 2.0 * dot, 0.0))
    dist[~(valid_a[:, :, None] & valid_b[:, None, :])] = np.inf

    def nn_ratio(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest index along the last axis, and whether it passes the ratio test."""
        nn = np.argmin(d, axis=-1)
        if d.shape[-1] >= 2:
            two = np.partition(d, 1, axis=-1)
            d1, d2 = two[..., 0], two[..., 1]
        else:
            d1, d2 = d[..., 0], np.full(d.shape[:-1], np.inf)
        return nn, np.isfinite(d1) & ((d1 < ratio * d2) | ~np.isfinite(d2))

    nn_ab, ok_ab = nn_ratio(dist)  # (P, nmax): for each feature of A, its partner in B
    nn_ba, ok_ba = nn_ratio(dist.transpose(0, 2, 1))  # (P, mmax)
    back = np.take_along_axis(nn_ba, nn_ab, axis=1)  # partner's partner
    ok_back = np.take_along_axis(ok_ba, nn_ab, axis=1)
    mutual = ok_ab & ok_back & (back == ra[None, :]) & valid_a
    return 2.0 * mutual.sum(axis=1) / (n_a + n_b)


def size_scores(h_i: np.ndarray, h_j: np.ndarray, theta_h: float) -> np.ndarray:
    """(n, m) q_s = 1 + cos(pi r / theta_h) for r < theta_h else 0, r = 2|h_i - h_j| / (h_i + h_j)."""
    hi = np.asarray(h_i, np.float64)[:, None]
    hj = np.asarray(h_j, np.float64)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = 2.0 * np.abs(hi - hj) / (hi + hj)
    r = np.where(np.isfinite(r), r, np.inf)
    return np.where(r < theta_h, 1.0 + np.cos(np.pi * np.minimum(r, theta_h) / theta_h), 0.0)
