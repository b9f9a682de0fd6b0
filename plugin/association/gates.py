"""The size gate of putative associations (the method spec section 2, step 2): one definition for every consumer.

r(h_i, h_j) = 2 |h_i - h_j| / (h_i + h_j) <= theta_r (`association.max_size_difference`) admits a landmark pair as
a putative association, weighted by q_s = 1 + cos(pi r / theta_r). An unknown size (NaN) opens the gate (r = 0).
The windowed search, the reference, the full-map verification (`plugin.verification`) and the evaluation all use
these functions, so the gate means the same everywhere.
"""

from __future__ import annotations

import numpy as np


def size_ratio(h_a: np.ndarray, h_b: np.ndarray) -> np.ndarray:
    """r = 2 |h_a - h_b| / (h_a + h_b); 0 where either size is unknown (the gate is then off)."""
    h_a = np.asarray(h_a, dtype=np.float64)
    h_b = np.asarray(h_b, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = 2.0 * np.abs(h_a - h_b) / (h_a + h_b)
    r = np.where(np.isnan(h_a) | np.isnan(h_b), 0.0, r)
    return np.where(np.isnan(r), 0.0, r)  # both sizes 0


def size_score(r: np.ndarray, theta_h: float) -> np.ndarray:
    """q_s = 1 + cos(pi r / theta_h) for r < theta_h, else 0 (in [0, 2])."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < theta_h, 1.0 + np.cos(np.pi * r / theta_h), 0.0)


def putative_pairs(sizes_a: np.ndarray, sizes_b: np.ndarray, ids_a: np.ndarray, ids_b: np.ndarray,
                   theta_r: float) -> tuple[np.ndarray, np.ndarray]:
    """Size-gated associations between landmark ids `ids_a` x `ids_b`, ordered by (i, j), and their weights q_s."""
    ia, ib = np.meshgrid(np.asarray(ids_a), np.asarray(ids_b), indexing="ij")
    ia, ib = ia.ravel(), ib.ravel()
    r = size_ratio(sizes_a[ia], sizes_b[ib])
    ok = r <= theta_r
    return np.column_stack([ia[ok], ib[ok]]), size_score(r[ok], theta_r)

