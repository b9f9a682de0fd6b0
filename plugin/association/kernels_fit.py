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


@njit(cache=True)
def agreeing_groups(rot: np.ndarray, tr: np.ndarray, pure: np.ndarray, off: np.ndarray, pts: np.ndarray, eps: float,
                    max_turn_deg: float) -> np.ndarray:
    """Groups of agreeing transforms, in order (`hypotheses.consensus_transform`): each transform joins the first
    group whose first member (head) it agrees with, else it starts a group. y agrees with head x when it maps x's
    points pts[off[x]:off[x + 1]] within eps of where x maps them (x_A = rot x_B + tr; rot holds the scale) and
    their rotations `pure` differ by less than max_turn_deg. Returns each transform's group number. (The sums run
    in loops, not numpy's einsum / matmul: a decision exactly at eps or at the turn limit may differ from an array
    statement's in the last bit, which the array statements themselves did between `@` and einsum.)

    One pass over the pairs (head, transform not yet grouped) with the cheap test first: over a map of two places
    every chance hypothesis is its own group, and the pairs number half the square of the hypotheses (52 689
    hypotheses took 562 s as array operations per head, BENCHMARKS.md "Refusals of season maps").
    """
    n = len(tr)
    group = np.full(n, -1, np.int64)
    ng = 0
    cos_turn = np.cos(np.radians(max_turn_deg))
    for x in range(n):
        if group[x] >= 0:
            continue
        group[x] = ng
        m = off[x + 1] - off[x]
        mine = np.empty((m, 3))
        for p in range(m):
            for i in range(3):
                mine[p, i] = (rot[x, i, 0] * pts[off[x] + p, 0] + rot[x, i, 1] * pts[off[x] + p, 1]
                              + rot[x, i, 2] * pts[off[x] + p, 2] + tr[x, i])
        for y in range(x + 1, n):
            if group[y] >= 0:
                continue
            trace = 0.0
            for i in range(3):
                for j in range(3):
                    trace += pure[x, i, j] * pure[y, i, j]
            c = min(max((trace - 1.0) / 2.0, -1.0), 1.0)
            if c < cos_turn - 1e-9:  # clearly turned by more (the exact angle is computed only near the limit)
                continue
            if c <= cos_turn + 1e-9 and not np.degrees(np.arccos(c)) < max_turn_deg:
                continue
            near = True
            for p in range(m):
                d2 = 0.0
                for i in range(3):
                    d = (rot[y, i, 0] * pts[off[x] + p, 0] + rot[y, i, 1] * pts[off[x] + p, 1]
                         + rot[y, i, 2] * pts[off[x] + p, 2] + tr[y, i]) - mine[p, i]
                    d2 += d * d
                if not np.sqrt(d2) <= eps:
                    near = False
                    break
            if near:
                group[y] = ng
        ng += 1
    return group
