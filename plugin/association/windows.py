"""Windows over a map's landmark order (the method spec section 2, step 1) and the landmark pairs they share."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..params import AssociationParams


def make_windows(n: int, length: int, stride: int) -> np.ndarray:
    """[start, end) of windows of `length` ids with `stride`; one window if n <= length; the tail is covered."""
    if length < 1 or stride < 1:
        raise InputError(f"window length and stride must be >= 1, got {length} and {stride}")
    if n <= length:
        return np.array([[0, n]], dtype=np.int64)
    starts = list(range(0, n - length + 1, stride))
    if starts[-1] != n - length:
        starts.append(n - length)
    s = np.array(starts, dtype=np.int64)
    return np.column_stack([s, s + length])


def window_layouts(params: AssociationParams) -> tuple[tuple[int, int], tuple[int, int]]:
    """(length, stride) of A's windows and of B's: theta_WL and theta_SL times each map's window factor (1 and 1:
    the paper's windows; equal-area windows grow the denser map's, `window_chance.area_factors`)."""
    length, stride = params.window_length, params.window_stride
    fa, fb = params.window_factor_a, params.window_factor_b
    return (length * fa, stride * fa), (length * fb, stride * fb)


def map_windows(n_a: int, n_b: int, params: AssociationParams) -> tuple[np.ndarray, np.ndarray]:
    """The windows of maps of n_a and n_b landmarks (`make_windows` with each map's `window_layouts`)."""
    (la, sa), (lb, sb) = window_layouts(params)
    return make_windows(n_a, la, sa), make_windows(n_b, lb, sb)


def window_span(n: int, wins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every landmark id, the first and last index of the windows that contain it."""
    ids = np.arange(n)
    first = np.searchsorted(wins[:, 1], ids, side="right")  # first window with end > id
    last = np.searchsorted(wins[:, 0], ids, side="right") - 1  # last window with start <= id
    return first, last


def map_edges(points: np.ndarray, wins: np.ndarray, first: np.ndarray, last: np.ndarray,
               length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmark pairs i < k that share a window, and their distances."""
    n = len(points)
    ii, kk = [], []
    for off in range(1, min(length, n)):
        i = np.arange(n - off)
        k = i + off
        ok = first[k] <= last[i]
        ii.append(i[ok])
        kk.append(k[ok])
    i = np.concatenate(ii) if ii else np.zeros(0, np.int64)
    k = np.concatenate(kk) if kk else np.zeros(0, np.int64)
    d = points[i] - points[k]
    return i, k, np.sqrt(np.einsum("ij,ij->i", d, d))



def window_pair_counts(a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray, b_hi: np.ndarray, nwa: int,
                        nwb: int) -> np.ndarray:
    """(nwa, nwb) number of items whose window rectangle [a_lo, a_hi] x [b_lo, b_hi] covers each window pair."""
    diff = np.zeros((nwa + 1) * (nwb + 1), dtype=np.int64)
    for ra, rb, sign in ((a_lo, b_lo, 1), (a_hi + 1, b_lo, -1), (a_lo, b_hi + 1, -1), (a_hi + 1, b_hi + 1, 1)):
        diff += sign * np.bincount(ra * (nwb + 1) + rb, minlength=len(diff))
    return diff.reshape(nwa + 1, nwb + 1).cumsum(0).cumsum(1)[:nwa, :nwb]



HILBERT_BITS = 16  # a 65536 x 65536 grid over the map's extent: cells far below any landmark spacing


def hilbert_order(points: np.ndarray) -> np.ndarray:
    """Permutation sorting landmarks along a Hilbert curve of their horizontal positions (in their own frame).

    Consecutive landmarks of this order are close on the ground, so windows of this order are compact patches
    whatever path the flight took: the "spatial" windows. Ties (one grid cell) keep the id order; the order
    depends only on the map itself.
    """
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    if len(xy) == 0:
        return np.zeros(0, np.int64)
    lo = xy.min(axis=0)
    extent = float(np.max(xy.max(axis=0) - lo))
    side = 1 << HILBERT_BITS
    if extent <= 0:
        return np.arange(len(xy))
    g = np.minimum(((xy - lo) / extent * side).astype(np.int64), side - 1)
    x, y = g[:, 0].copy(), g[:, 1].copy()
    d = np.zeros(len(xy), np.int64)
    s = side >> 1
    while s > 0:  # the classic xy -> d conversion, one bit level at a time for all points
        rx = (x & s) > 0
        ry = (y & s) > 0
        d += s * s * ((3 * rx) ^ ry)
        # rotate the quadrant so the sub-curve is in standard orientation
        flip = ~ry
        swap_x = np.where(flip & rx, side - 1 - x, x)
        swap_y = np.where(flip & rx, side - 1 - y, y)
        x = np.where(flip, swap_y, swap_x)
        y = np.where(flip, swap_x, swap_y)
        s >>= 1
    return np.argsort(d, kind="stable")
