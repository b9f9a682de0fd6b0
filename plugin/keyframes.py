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


# A flight's consecutive frames are about as far apart as each frame is from its nearest neighbour (along a
# line: one spacing; a hover: zero). Frames listed in another order (file names that do not follow the capture
# order: renamed files, counters that wrapped, two batteries' folders merged, a model exported by name) jump
# across the survey: their median consecutive step is many spacings.
SCRAMBLED_STEP_RATIO = 3.0


def flight_order(centers: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The order in which the frames were taken, and how it was found ("given", "capture time", "path").

    Capture times (every frame one, finite) decide when they exist (stable for equal times). Without them the
    given order stands unless it is evidently not a flight (the median step between consecutive frames more than
    SCRAMBLED_STEP_RATIO x the median distance to the nearest frame, horizontally); then the frames are chained
    from an end of the survey (the frame farthest from the centroid) to the nearest frame not yet taken, which
    retraces a survey's lines and turns.

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
    nearest = float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))
    if step <= SCRAMBLED_STEP_RATIO * nearest or step == 0.0:
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
