"""Batch stage 3's choice of session pairs: every pair, or with --nearest K the pairs of nearby sessions plus each
flight's neighbours in time (see `choose_pairs`)."""

from __future__ import annotations

import logging
import statistics
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.multisession import nearest_pairs

log = logging.getLogger(__name__)


def flight_time(images: Path | None) -> float | None:
    """When a flight was flown: the median EXIF DateTimeOriginal (seconds since 1970, camera clock) of its first,
    middle and last image by name, or None when none of them carries one (or there are no images: an adopted
    mapped session). Three reads, not all: a flight's time only orders flights flown hours or days apart, and a
    batch re-run reads it again."""
    from ...database.exif import read_image_metadata
    from ...database.images import image_files
    from ...plugin.errors import InputError

    if images is None:
        return None
    files = sorted(image_files(images))
    stamps = []
    for path in {files[0], files[len(files) // 2], files[-1]} if files else ():
        try:
            if (t := read_image_metadata(path).capture_time_s) is not None:
                stamps.append(t)
        except InputError:  # the map stage reports an image it cannot read
            continue
    return statistics.median(stamps) if stamps else None


def _footprint(session: str) -> tuple[float, float, float, float] | None:
    """The ground box (x0, y0, x1, y1) of a mapped session's landmarks, or None when it cannot be read."""
    from ...database.landmark_map import read_landmark_map
    from ...plugin.errors import InputError

    try:
        xy = read_landmark_map(Path(session) / "landmarks.sosmap").positions[:, :2]
    except (InputError, OSError, ValueError):
        return None
    if not len(xy):
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _overlap(a: tuple[float, ...] | None, b: tuple[float, ...] | None) -> bool:
    return a is not None and b is not None and min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1])


def time_neighbour_pairs(names: list[str], times: dict[str, float | None],
                         footprints: dict[str, tuple[float, float, float, float] | None]) -> list[tuple[str, str]]:
    """For each flight with a capture time, the pair with the flight flown last before it and the one flown first
    after it among those whose landmarks' ground boxes overlap its own: at most 2 pairs per flight, the pairs of
    consecutive surveys of one site ("what changed since the last flight"). Pairs (a, b) in the order of `names`."""
    order = sorted((n for n in names if times.get(n) is not None), key=lambda n: (times[n], n))
    rank = {n: k for k, n in enumerate(names)}
    chosen = set()
    for k, n in enumerate(order):
        before = next((m for m in reversed(order[:k]) if _overlap(footprints.get(n), footprints.get(m))), None)
        after = next((m for m in order[k + 1:] if _overlap(footprints.get(n), footprints.get(m))), None)
        for m in (before, after):
            if m is not None:
                chosen.add(tuple(sorted((n, m), key=rank.__getitem__)))
    return sorted(chosen, key=lambda p: (rank[p[0]], rank[p[1]]))


def choose_pairs(names: list[str], sessions: dict[str, dict[str, Any]], nearest: int | None,
                 times: dict[str, float | None] | None = None) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """(the session pairs to match, those of them added for their capture times). Every pair, or with `nearest`
    the pairs where one session is among the k nearest of the other by mean camera position, plus each flight's
    neighbours in time (`time_neighbour_pairs`; `times`: each flight's capture time, `flight_time`): the flights
    of one site all overlap, so the nearest by position are arbitrary among them (nu40, 6 flights, --nearest 2:
    1-2..1-6, 2-6, 3-5, 3-6, 4-6 kept and 2-3, 3-4, 4-5, the consecutive surveys, dropped)."""
    all_pairs = list(combinations(names, 2))
    if nearest is None:
        return all_pairs, []
    centres = [sessions[n].get("center") for n in names]
    epsgs = {sessions[n].get("epsg") for n in names}
    if any(c is None for c in centres) or len(epsgs) > 1:
        log.warning("--nearest needs every session's position in one frame; matching all %d pairs", len(all_pairs))
        return all_pairs, []
    chosen = [(names[i], names[j]) for i, j in nearest_pairs(np.asarray(centres), nearest)]
    timed = [n for n in names if (times or {}).get(n) is not None]
    if len(timed) < 2:
        return chosen, []
    footprints = {n: _footprint(sessions[n]["session"]) for n in timed if sessions[n].get("session")}
    added = [p for p in time_neighbour_pairs(names, times or {}, footprints) if p not in set(chosen)]
    if added:
        log.info("--nearest %d: %d pair(s) of flights consecutive in capture time (EXIF DateTimeOriginal) among "
                 "overlapping ones matched too: %s", nearest, len(added), ", ".join(f"{a}-{b}" for a, b in added))
    rank = {p: k for k, p in enumerate(all_pairs)}
    return sorted(chosen + added, key=rank.__getitem__), added
