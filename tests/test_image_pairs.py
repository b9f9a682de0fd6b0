"""Which image pairs structure from motion matches (plugin.image_pairs): the footprint cap and the flight plan."""

from __future__ import annotations

import numpy as np

from sosmatch.plugin.flight_lines import flight_lines
from sosmatch.plugin.image_pairs import line_spacing_m, overlap_cap_m, select_pairs


def _lawnmower(lines: int = 3, per_line: int = 15, step_m: float = 7.0, spacing_m: float = 30.0) -> np.ndarray:
    rows = []
    for k in range(lines):
        xs = np.arange(per_line) * step_m
        rows.extend((x, k * spacing_m) for x in (xs if k % 2 == 0 else xs[::-1]))
    return np.array(rows, dtype=np.float64)


def _cross_line_pairs(xy: np.ndarray, pairs: np.ndarray) -> int:
    return int(np.sum(np.abs(xy[pairs[:, 0], 1] - xy[pairs[:, 1], 1]) > 1.0))


def test_the_line_spacing_of_a_lawnmower_flight():
    xy = _lawnmower()
    assert line_spacing_m(xy, flight_lines(xy)) == np.float64(30.0)
    assert line_spacing_m(xy[:15], flight_lines(xy[:15])) is None  # one line: no spacing


def test_a_footprint_narrower_than_the_line_spacing_is_no_cap():
    """nu28: a take-off 90 m above the surveyed ground left RelativeAltitude ~10 m, a 24 m footprint cap and no
    pair across lines 30 m apart (the block held together only by luck). A survey's neighbouring lines overlap,
    so such a footprint is a wrong height: no cap."""
    xy = _lawnmower()
    spacing = line_spacing_m(xy, flight_lines(xy))
    capped, _ = select_pairs(xy, 10, 2, 24.0, 40, 10)
    assert _cross_line_pairs(xy, capped) <= 6  # only the capture-order successors at the 2 turns cross
    cap = overlap_cap_m(24.0, spacing)
    assert cap is None
    free, _ = select_pairs(xy, 10, 2, cap, 40, 10)
    assert _cross_line_pairs(xy, free) > 20
    assert overlap_cap_m(150.0, spacing) == 150.0  # a plausible footprint keeps its cap
    assert overlap_cap_m(24.0, None) == 24.0 and overlap_cap_m(None, spacing) is None
