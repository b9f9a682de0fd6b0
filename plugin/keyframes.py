"""Keyframe selection by camera travel (SOS-Match step 1, `theta_T`)."""

from __future__ import annotations

import numpy as np


def select_keyframes(centers: np.ndarray, interval_m: float) -> np.ndarray:
    """Indices of the keyframes of a sequence of camera centres.

    The first frame is always a keyframe; after that a frame becomes a keyframe as soon as its straight-line
    distance from the position of the last keyframe reaches `interval_m` (`theta_T`, 2.0 m in the paper).
    Distance from the last keyframe, not path length, so hovering or jitter in place never adds keyframes.

    Args:
        centers: (N, 3) camera centres in metres, in acquisition order.
        interval_m: travel between keyframes; <= 0 makes every frame a keyframe.

    Returns:
        (K,) int64 sorted indices into `centers`.
    """
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"centers must be (N, 3), got {centers.shape}")
    n = len(centers)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.all(np.isfinite(centers)):
        raise ValueError("centers contain NaN or inf")
    if interval_m <= 0:
        return np.arange(n, dtype=np.int64)
    keys = [0]
    last = 0
    # One vectorised distance scan per keyframe: the selection is sequential by nature (each keyframe depends
    # on the previous one), but the search for the next one is not.
    while last < n - 1:
        dist = np.linalg.norm(centers[last + 1 :] - centers[last], axis=1)
        far = np.flatnonzero(dist >= interval_m)
        if len(far) == 0:
            break
        last = last + 1 + int(far[0])
        keys.append(last)
    return np.asarray(keys, dtype=np.int64)


# A flight steps about its frame spacing; frames listed in another order (file names that do not follow the capture
# order: renamed files, counters that wrapped, a model exported by name) step across the survey, as a random
# order of the same centres does. The listed order is judged scrambled when its median step is more than
# SCRAMBLED_RANDOM_FRACTION of a random order's (a random pair's median distance: the site's scale) AND more than
# SCRAMBLED_STEP_RATIO x the median distance to the nearest frame. The second condition alone was the first rule;
# it fails on a flight that revisits its ground (a double grid, an out-and-back corridor, a second battery over
# the same lines), where every frame has a twin 0-1.5 m away: its 7 m steps were "scrambled" and the passes were
# interleaved by the path (new-user sweep 22). It stays as a necessary condition for short flights, whose few
# frames give a random order steps of one or two spacings too (a line of 4 frames in order).
SCRAMBLED_RANDOM_FRACTION = 0.5
SCRAMBLED_STEP_RATIO = 3.0
# All pairs up to this many frames (exact, 0.5 M distances); beyond, this many seeded random pairs.
_RANDOM_PAIRS_EXACT_MAX = 1000
_RANDOM_PAIRS_SAMPLED = 500_000


def random_order_step(xy: np.ndarray) -> float:
    """The median step of a random order of these points: the median distance between two distinct frames.

    Args:
        xy: (N, 2) horizontal camera centres in metres, N >= 2.

    Returns:
        The median over all pairs (N <= 1000), else over a fixed seeded sample of pairs (deterministic).
    """
    n = len(xy)
    if n <= _RANDOM_PAIRS_EXACT_MAX:
        from scipy.spatial.distance import pdist

        return float(np.median(pdist(xy)))
    rng = np.random.default_rng(0)
    i = rng.integers(0, n, _RANDOM_PAIRS_SAMPLED)
    j = (i + rng.integers(1, n, _RANDOM_PAIRS_SAMPLED)) % n  # never i itself
    return float(np.median(np.linalg.norm(xy[i] - xy[j], axis=1)))


def flight_order(centers: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The order in which the frames were taken, and how it was found ("given", "capture time", "path").

    Capture times (every frame one, finite) decide when they exist (stable for equal times). Without them the
    given order stands unless it is evidently not a flight (horizontally, the median step between consecutive
    frames is more than SCRAMBLED_RANDOM_FRACTION x a random order's, `random_order_step`, and more than
    SCRAMBLED_STEP_RATIO x the median distance to the nearest frame); then the frames are chained from an end of
    the survey (the frame farthest from the centroid) to the nearest frame not yet taken, which retraces a
    survey's lines and turns. A flight that passes over its ground again stays as given: its steps are about its
    spacing, a small fraction of a random order's.

    Args:
        centers: (N, 3) camera centres in metres, in the given order.
        times: (N,) capture times in seconds, or None.

    Returns:
        ((N,) int64 permutation into the given order, how).
    """
    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    identity = np.arange(n, dtype=np.int64)
    if times is not None and len(times) == n and n > 1 and np.all(np.isfinite(times)):
        order = np.argsort(np.asarray(times, dtype=np.float64), kind="stable").astype(np.int64)
        return order, ("given" if np.array_equal(order, identity) else "capture time")
    if n < 3 or not np.all(np.isfinite(centers)):
        return identity, "given"
    from scipy.spatial import cKDTree

    xy = centers[:, :2]
    step = float(np.median(np.linalg.norm(np.diff(xy, axis=0), axis=1)))
    if step == 0.0 or step <= SCRAMBLED_RANDOM_FRACTION * random_order_step(xy):
        return identity, "given"
    nearest = float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))
    if step <= SCRAMBLED_STEP_RATIO * nearest:
        return identity, "given"
    current = int(np.argmax(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))
    taken = np.zeros(n, dtype=bool)
    order = [current]
    taken[current] = True
    for _ in range(n - 1):  # O(N^2) in all, one row at a time (memory O(N))
        row = np.where(taken, np.inf, np.linalg.norm(xy - xy[current], axis=1))
        current = int(np.argmin(row))  # ties: the lowest index (deterministic)
        order.append(current)
        taken[current] = True
    return np.asarray(order, dtype=np.int64), "path"
