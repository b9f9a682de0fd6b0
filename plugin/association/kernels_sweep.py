"""The m^2 / 2 length tests of a set of associations against per-map distance tables, by blocks of rows (numba).

One function per question for the two callers: `kernels_graph.graph_from_tables` sweeps all rows in one thread
(a window pair of the search, or a small problem); `kernels_problem.problem_graph` gives each thread a block of
rows and joins the blocks in row order, so both produce the same edges in the same order.

An association pair (p, q), p < q, passes when |lena[ua[p], ua[q]] - lenb[ub[p], ub[q]]| <= eps (false for NaN
and inf: the diagonal of a table is inf, so a pair sharing a landmark never passes); c is that difference.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def grow(x: np.ndarray, cap: int) -> np.ndarray:
    """A copy of `x` with room for `cap` entries (the output buffers of the joins and graphs)."""
    y = np.empty(cap, x.dtype)
    y[: len(x)] = x
    return y


@njit(cache=True)
def sweep_rows(ua: np.ndarray, ub: np.ndarray, lena: np.ndarray, lenb: np.ndarray, eps: float, r0: int, r1: int,
               found: np.ndarray, ne: int, count: np.ndarray, lower: np.ndarray) -> tuple:
    """The tests of rows [r0, r1) against every later column: the columns that pass, row by row ascending, are
    written to `found` from position `ne` on and count[p] is set to row p's number. `found` grows (a copy) only
    when it has no room for the pairs of the next four rows. Returns (found, end position).

    lower (empty, or m entries): lower[q] counts the rows that found column q (q's lower neighbours: the CSR's
    row lengths), counted where each column is appended.

    ua, ub: each association's row in lena, lenb (unsigned: numba then skips the negative-index wraparound on
    every table read). The tests store one column each without a branch (few pass). Four rows at a time: each
    column's landmark ids are read once for the four, and the four independent stores keep the core busy
    (1.3-1.4x over one row at a time); each row's columns land in a buffer of their own and are appended.
    """
    m = len(ua)
    buf = np.empty((4, max(m, 1)), np.int32)
    b0, b1, b2, b3 = buf[0], buf[1], buf[2], buf[3]
    p = r0
    while p < r1:
        if ne + 4 * (m - p) > len(found):  # room for the pairs of four whole rows
            found = grow(found, 2 * len(found) + 4 * m)
        if p + 4 > r1:  # the last rows of the block, one at a time
            ra = lena[ua[p]]
            rb = lenb[ub[p]]
            n0 = 0
            for q in range(p + 1, m):
                found[ne + n0] = q
                n0 += abs(ra[ua[q]] - rb[ub[q]]) <= eps
            if len(lower):
                for k in range(ne, ne + n0):
                    lower[found[k]] += 1
            ne += n0
            count[p] = n0
            p += 1
            continue
        ra0, rb0 = lena[ua[p]], lenb[ub[p]]
        ra1, rb1 = lena[ua[p + 1]], lenb[ub[p + 1]]
        ra2, rb2 = lena[ua[p + 2]], lenb[ub[p + 2]]
        ra3, rb3 = lena[ua[p + 3]], lenb[ub[p + 3]]
        n0 = 0
        n1 = 0
        n2 = 0
        n3 = 0
        for q in range(p + 1, p + 4):  # the corner of the triangle: columns before the four-row sweep
            b0[n0] = q
            n0 += abs(ra0[ua[q]] - rb0[ub[q]]) <= eps
        for q in range(p + 2, p + 4):
            b1[n1] = q
            n1 += abs(ra1[ua[q]] - rb1[ub[q]]) <= eps
        b2[n2] = p + 3
        n2 += abs(ra2[ua[p + 3]] - rb2[ub[p + 3]]) <= eps
        for q in range(p + 4, m):
            x = ua[q]
            y = ub[q]
            b0[n0] = q
            n0 += abs(ra0[x] - rb0[y]) <= eps
            b1[n1] = q
            n1 += abs(ra1[x] - rb1[y]) <= eps
            b2[n2] = q
            n2 += abs(ra2[x] - rb2[y]) <= eps
            b3[n3] = q
            n3 += abs(ra3[x] - rb3[y]) <= eps
        nrow = (n0, n1, n2, n3)
        for r in range(4):  # the four rows' columns appended in row order
            row = buf[r]
            for k in range(nrow[r]):
                found[ne + k] = row[k]
            if len(lower):
                for k in range(nrow[r]):
                    lower[row[k]] += 1
            ne += nrow[r]
            count[p + r] = nrow[r]
        p += 4
    return found, ne


@njit(cache=True)
def expand_rows(ua: np.ndarray, ub: np.ndarray, lena: np.ndarray, lenb: np.ndarray, r0: int, r1: int,
                found: np.ndarray, src: int, dst: int, count: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                cs: np.ndarray) -> None:
    """The edges of rows [r0, r1) as `sweep_rows` left them in found[src:]: rows, cols and the mismatch c (the
    same expression as the test) written from position `dst` on."""
    for p in range(r0, r1):
        ra = lena[ua[p]]
        rb = lenb[ub[p]]
        for k in range(count[p]):
            q = found[src + k]
            rows[dst + k] = p
            cols[dst + k] = q
            cs[dst + k] = abs(ra[ua[q]] - rb[ub[q]])
        src += count[p]
        dst += count[p]
