"""When two associations are consistent, and when a landmark pair is a putative association: one definition.

A putative association (i, j) pairs landmark i of map A with landmark j of map B. It passes
  - the size gate: r(h_i, h_j) = 2 |h_i - h_j| / (h_i + h_j) <= theta_r (`association.max_size_difference`;
    an unknown size opens it), weighted q_s = 1 + cos(pi r / theta_r) (`gates.size_ratio`, `gates.size_score`);
  - with a position prior (`association.position_prior_m` > 0, maps in one world frame): the horizontal
    distance of the two landmarks is at most that radius.
Two associations p = (i, j) and q = (k, l), i != k and j != l, give the landmark-pair vectors a = A_k - A_i and
b = B_l - B_j (oriented from the lower A id, so every path computes the same numbers). With eps = theta_eps
(`association.distance_tolerance_m`):
  - "distance" (the paper): | ||a|| - ||b|| | <= eps; mismatch c = | ||a|| - ||b|| |;
  - "gravity" (both maps gravity-aligned to within `gravity_tilt_deg` = tau): the horizontal lengths agree,
    c_h = | ||a_xy|| - ||b_xy|| | <= eps, and the height differences agree up to the tilt,
    e_z = |a_z - b_z| - max(||a_xy||, ||b_xy||) tan(tau) <= eps; c = sqrt(c_h^2 + max(e_z, 0)^2).
    A pair of associations also implies a yaw, theta = atan2(a) - atan2(b) (horizontal directions), known to
    within asin((eps + max(|a_z|, |b_z|) sin(tau)) / min(||a_xy||, ||b_xy||)); a consistent set shares one yaw, so
    with `yaw_slice_deg` > 0 every window pair is solved per yaw slice of that width (a pair belongs to every
    slice its tolerance covers). Mirror images (a reflected map matches every distance) never share a yaw.
The affinity of a consistent pair is exp(-c^2 / 2 sigma^2) (`affinity_sigma_m`).

The compiled kernels (`kernels_graph.py`) implement these tests for the search and its reference; the
functions here evaluate them on arrays, for analysis and tests (e.g. how many true pairs pass across seasons).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..params import AssociationParams
from .gates import size_ratio
from .hypotheses import SearchMode
from .kernels_graph import pair_mismatch, pair_slices, vector_invariants


def size_gate(sizes_a: np.ndarray, sizes_b: np.ndarray, params: AssociationParams) -> np.ndarray:
    """Boolean mask: which landmark pairs (sizes_a[t], sizes_b[t]) pass r <= theta_r (NaN sizes pass)."""
    return size_ratio(sizes_a, sizes_b) <= params.max_size_difference


def pair_consistency(points_a: np.ndarray, points_b: np.ndarray, first: np.ndarray, second: np.ndarray,
                     params: AssociationParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pair test of `params.consistency` for pairs of associations.

    first, second: (E, 2) associations (index in A, index in B), pair t being {first[t], second[t]}.
    Returns (consistent, mismatch c (NaN where inconsistent), first yaw slice, number of yaw slices); slices are
    (0, 1) without yaw slicing. Associations sharing a landmark are inconsistent.
    """
    m = SearchMode.of(params)
    f = np.asarray(first, dtype=np.int64).reshape(-1, 2)
    s = np.asarray(second, dtype=np.int64).reshape(-1, 2)
    c, s0, ns = _pair_test(np.asarray(points_a, np.float64), np.asarray(points_b, np.float64), f[:, 0].copy(),
                           f[:, 1].copy(), s[:, 0].copy(), s[:, 1].copy(), m.consistency, m.eps, m.tan_tilt, m.eps_z,
                           m.sin_tilt, m.nslices)
    ok = c >= 0
    return ok, np.where(ok, c, np.nan), s0, ns


@njit(cache=True)
def _pair_test(pa: np.ndarray, pb: np.ndarray, i: np.ndarray, j: np.ndarray, k: np.ndarray, l_: np.ndarray,
               mode: int, eps: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    c = np.full(len(i), -1.0)
    s0 = np.zeros(len(i), np.int64)
    ns = np.ones(len(i), np.int64)
    for t in range(len(i)):
        if i[t] == k[t] or j[t] == l_[t]:
            continue
        a1, b1, a2, b2 = (i[t], j[t], k[t], l_[t]) if i[t] < k[t] else (k[t], l_[t], i[t], j[t])
        la, za, anga = vector_invariants(pa[a2, 0] - pa[a1, 0], pa[a2, 1] - pa[a1, 1], pa[a2, 2] - pa[a1, 2], mode)
        lb, zb, angb = vector_invariants(pb[b2, 0] - pb[b1, 0], pb[b2, 1] - pb[b1, 1], pb[b2, 2] - pb[b1, 2], mode)
        c[t] = pair_mismatch(la, za, lb, zb, mode, eps, tan_tilt, eps_z)
        if c[t] >= 0.0 and mode == 1:
            s0[t], ns[t] = pair_slices(anga, angb, la, lb, za, zb, eps, sin_tilt, nslices)
    return c, s0, ns
