"""Evenly spread samples: bounded work on a large input that still sees all of it.

One answer for every stage that looks at a few of many items (a flight's images for its white level or capture
time, a map's keyframes for its images' digests, a map's landmarks for the change test's references), so they
agree on which items "spread over" means: the first and the last included, in order, none twice."""

from __future__ import annotations

import numpy as np


def evenly_spaced(count: int, limit: int) -> list[int]:
    """Indices of at most `limit` of `count` items, evenly spread over them: all of them when `limit` allows,
    else the first, the last and the nearest item to each of `limit` equal steps between (ascending, distinct)."""
    if count <= 0 or limit <= 0:
        return []
    if count <= limit:
        return list(range(count))
    return sorted({int(i) for i in np.linspace(0, count - 1, limit).round()})
