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


# A flight steps to one of the frames nearest to where it is; frames listed in another order (file names that do not
# follow the capture order: renamed files, counters that wrapped, a model exported by name) step across the survey,
# as a random order of the same centres does. The listed order is judged scrambled when, for most steps, the next
# frame is not among the SCRAMBLED_NEXT_RANK frames nearest to the current one (its rank: how many frames are
# strictly nearer than it). The rank is local and scale-free. Two earlier rules compared the median step with one
# scale of the whole set: with the nearest-frame distance, a flight that revisits its ground (every frame with a
# twin 0-1.5 m away) was "scrambled" at its 7 m steps (new-user sweep 22); with a random order's step (the site's
# scale), two blocks 2 km apart, each shuffled within, were kept as given (119 m steps against 1850 m; review 20).
# A flight over its ground again P times has ranks up to about 2P (the twins of this frame and the next): 8 keeps
# four passes; a shuffled block of M frames has ranks about M/2, so a list of up to ~2 x 8 frames is never judged
# scrambled (a line of 4 frames in order stays).
SCRAMBLED_NEXT_RANK = 8
# The ranks of at most this many steps (evenly spaced, deterministic): each costs up to one pass over the frames.
_RANK_STEPS_MAX = 1000


def next_frame_ranks(xy: np.ndarray) -> np.ndarray:
    """For steps i -> i+1 of the listed order: how many frames are strictly nearer to frame i than frame i+1 is.

    Args:
        xy: (N, 2) horizontal camera centres in metres, in the listed order, N >= 2.

    Returns:
        (S,) int64 ranks, for every step (N - 1 <= _RANK_STEPS_MAX), else for that many evenly spaced ones.
    """
    from scipy.spatial import cKDTree

    steps = np.arange(len(xy) - 1)
    if len(steps) > _RANK_STEPS_MAX:
        steps = np.unique(np.linspace(0, len(xy) - 2, _RANK_STEPS_MAX).astype(np.int64))
    dist = np.linalg.norm(xy[steps + 1] - xy[steps], axis=1)
    tree = cKDTree(xy)
    # frames within the step, the frame itself included (a ball's edge is closed: frames at exactly the step's
    # distance are not nearer, so the radius is shrunk by a rounding margin)
    inside = tree.query_ball_point(xy[steps], np.maximum(dist * (1.0 - 1e-9) - 1e-9, 0.0), return_length=True)
    return np.maximum(np.asarray(inside, dtype=np.int64) - 1, 0)


def flight_order(centers: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The order in which the frames were taken, and how it was found ("given", "capture time", "path").

    Capture times (every frame one, finite) decide when they exist (stable for equal times). Without them the
    given order stands unless it is evidently not a flight (horizontally, the median `next_frame_ranks` is more
    than SCRAMBLED_NEXT_RANK: most steps go past the frames nearest to the current one); then the frames are
    chained from an end of the survey (the frame farthest from the centroid) to the nearest frame not yet taken,
    which retraces a survey's lines and turns. A flight that passes over its ground again stays as given: its
    next frame is among the few nearest (its twins are the others).

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
    xy = centers[:, :2]
    if np.median(next_frame_ranks(xy)) <= SCRAMBLED_NEXT_RANK:
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
