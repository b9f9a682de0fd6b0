"""Compiled least-squares fits of many hypotheses at once (numba): Arun / Umeyama, as `rigid.fit_transform`."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def fit_many(pa: np.ndarray, pb: np.ndarray, off: np.ndarray, sel_a: np.ndarray, sel_b: np.ndarray,
             similarity: bool) -> tuple:
    """A_from_B of every hypothesis h (associations sel_a/sel_b[off[h]:off[h + 1]]): x_A = s R x_B + t.

    Degenerate (ok False): fewer than 3 associations, or the landmarks of either side (nearly) on one line or one
    point (second eigenvalue of the scatter below 1e-12 of the first), where the rotation is not determined.
    Returns R (H, 3, 3), t (H, 3), s (H,), ok (H,).
    """
    nh = len(off) - 1
    rot = np.zeros((nh, 3, 3))
    tr = np.zeros((nh, 3))
    sc = np.ones(nh)
    ok = np.zeros(nh, np.bool_)
    for h in range(nh):
        m = off[h + 1] - off[h]
        if m < 3:
            continue
        src = np.empty((m, 3))
        dst = np.empty((m, 3))
        for x in range(m):
            src[x] = pb[sel_b[off[h] + x]]
            dst[x] = pa[sel_a[off[h] + x]]
        mu_s = np.zeros(3)
        mu_d = np.zeros(3)
        for x in range(m):
            mu_s += src[x]
            mu_d += dst[x]
        mu_s /= m
        mu_d /= m
        xs = src - mu_s
        xd = dst - mu_d
        degenerate = False
        for arr in (xs, xd):
            ev = np.linalg.eigvalsh(arr.T @ arr)
            if ev[2] <= 0.0 or ev[1] < 1e-12 * ev[2]:
                degenerate = True
        if degenerate:
            continue
        cov = xd.T @ xs / m
        u, s, vt = np.linalg.svd(cov)
        sign = np.sign(np.linalg.det(u @ vt))
        if sign == 0.0:
            sign = 1.0
        fix = np.eye(3)
        fix[2, 2] = sign
        r = u @ fix @ vt
        scale = 1.0
        if similarity:
            var_s = 0.0
            for x in range(m):
                var_s += xs[x, 0] * xs[x, 0] + xs[x, 1] * xs[x, 1] + xs[x, 2] * xs[x, 2]
            var_s /= m
            scale = (s[0] + s[1] + s[2] * sign) / var_s
        rot[h] = r
        tr[h] = mu_d - scale * (r @ mu_s)
        sc[h] = scale
        ok[h] = True
    return rot, tr, sc, ok
