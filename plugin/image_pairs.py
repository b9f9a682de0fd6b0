"""Which image pairs structure from motion matches (pure numpy): never all pairs of a large flight.

Feature matching costs the same for every pair, and on 2 CPU cores all pairs of a 167-image flight (13,861) take
longer than the rest of the pipeline together; only images whose ground footprints overlap can match. So:
- with GPS: each image with its `neighbours` nearest images (horizontal GPS distance), within `max_distance`
  when the footprint size is known (centres further apart than a footprint's diagonal cannot overlap), plus
  its `sequential` predecessors and successors in capture order, which survive one wrong GPS fix;
- without GPS (or for images lacking a fix): every pair when there are at most `exhaustive_up_to` images,
  else the `sequential_without_gps` neighbours in capture order (a flight line's consecutive frames).
"""

from __future__ import annotations

import numpy as np


def select_pairs(
    positions: np.ndarray,
    neighbours: int = 10,
    sequential: int = 2,
    max_distance: float | None = None,
    exhaustive_up_to: int = 40,
    sequential_without_gps: int = 10,
) -> tuple[np.ndarray, str]:
    """Pairs (M,2) of image indices (i < j, sorted) for images in capture order with horizontal `positions`
    (N,2) (NaN rows: no fix), and how they were chosen."""
    xy = np.asarray(positions, dtype=np.float64).reshape(len(positions), -1)[:, :2]
    n = len(xy)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64), "fewer than 2 images"
    has = np.all(np.isfinite(xy), axis=1)
    pairs: set[tuple[int, int]] = set()

    def add(i: int, j: int) -> None:
        if i != j:
            pairs.add((min(i, j), max(i, j)))

    if n <= exhaustive_up_to and not has.all():  # a small folder without GPS: all pairs are cheap
        return np.array([(i, j) for i in range(n) for j in range(i + 1, n)], dtype=np.int64), \
            f"all {n * (n - 1) // 2} pairs (at most {exhaustive_up_to} images, not all with GPS)"
    how = []
    idx = np.flatnonzero(has)
    if len(idx) >= 2:
        d = np.linalg.norm(xy[idx, None, :] - xy[None, idx, :], axis=2)
        np.fill_diagonal(d, np.inf)
        k = min(neighbours, len(idx) - 1)
        nearest = np.argsort(d, axis=1, kind="stable")[:, :k]
        for a, row in enumerate(nearest):
            for b in row:
                if max_distance is None or d[a, b] <= max_distance:
                    add(int(idx[a]), int(idx[b]))
        how.append(f"{k} GPS neighbours" + (f" within {max_distance:.0f} m" if max_distance else ""))
    window = sequential if has.all() else sequential_without_gps
    for i in range(n):
        for j in range(i + 1, min(n, i + window + 1)):
            add(i, j)
    how.append(f"{window} successors in capture order")
    out = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    return out, " + ".join(how)


def line_spacing_m(positions: np.ndarray, lines: np.ndarray) -> float | None:
    """The median horizontal distance from an image to the nearest image of another flight line (`positions`
    (N,2+) in capture order, NaN rows without a fix; `lines` the line id per image, -1 for none, as
    `flight_lines.flight_lines` gives them): how far apart neighbouring lines are flown. None with fewer than
    two lines."""
    xy = np.asarray(positions, dtype=np.float64).reshape(len(positions), -1)[:, :2]
    ok = np.all(np.isfinite(xy), axis=1) & (np.asarray(lines) >= 0)
    ids = np.asarray(lines)[ok]
    if len(np.unique(ids)) < 2:
        return None
    pts = xy[ok]
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2)
    d[ids[:, None] == ids[None, :]] = np.inf
    return float(np.median(d.min(axis=1)))


def overlap_cap_m(footprint_diagonal_m: float | None, spacing_m: float | None) -> float | None:
    """The distance cap of `select_pairs` from a footprint diagonal, or None (no cap) when that footprint would
    not reach the neighbouring flight line (`line_spacing_m`): a survey is flown so that neighbouring lines
    overlap, so a footprint narrower than their spacing says the height it came from is wrong (DJI's
    RelativeAltitude is above the take-off point: a take-off on a ridge 90 m above the survey gave 24 m
    footprints for lines 30 m apart, and no pair across lines)."""
    if footprint_diagonal_m is None or spacing_m is None or footprint_diagonal_m > spacing_m:
        return footprint_diagonal_m
    return None

