"""Keyframe selection by camera travel (SOS-Match step 1, `theta_T`)."""

from __future__ import annotations

import numpy as np

from .geometry import SAME_POSITION


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
    ranks = np.maximum(np.asarray(inside, dtype=np.int64) - 1, 0)
    # A step that stays at its recorded position (a hover, a stalled GPS repeating one fix) has no frame strictly
    # nearer; the radius-0 ball above still holds every frame at that position, which ranked a hover of M frames
    # at M - 1 and had a stalled flight judged scrambled and reordered (rev50 D2).
    return np.where(dist <= SAME_POSITION, 0, ranks)


def flight_order(centers: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The order in which the frames were taken, and how it was found (`FLIGHT_ORDER_HOWS`).

    Capture times (every frame one, finite) decide where they differ. Frames that share a time (a clock in whole
    seconds under bursts of several frames a second, a tool that rewrote the dates) are in no order by it: within
    each such time they keep their given order unless a path through their camera centres is shorter
    (`_paths_within_equal_times`; "capture time + path"). Times that are all one carry no order at all and count
    as none. A capture-time order that is not a flight (`reads_as_flight`: times of two flights that overlap)
    is kept, as "capture time, not a flight", for the caller to warn of. Without times the given order stands
    unless it is evidently not a flight (horizontally, the median
    `next_frame_ranks` is more than SCRAMBLED_NEXT_RANK: most steps go past the frames nearest to the current
    one); then the frames are chained from an end of the survey (the frame farthest from the centroid) to the
    nearest frame not yet taken, which retraces a survey's lines and turns ("path"). A flight that passes over
    its ground again stays as given: its next frame is among the few nearest (its twins are the others).

    Args:
        centers: (N, 3) camera centres in metres, in the given order (only the horizontal ones are used; frames
            of one time keep their given order when any centre is not finite).
        times: (N,) capture times in seconds, or None.

    Returns:
        ((N,) int64 permutation into the given order, how).
    """
    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    identity = np.arange(n, dtype=np.int64)
    if times is not None and len(times) == n and n > 1 and np.all(np.isfinite(times)):
        t = np.asarray(times, dtype=np.float64)
        if np.ptp(t) > 0:
            order = np.argsort(t, kind="stable").astype(np.int64)
            order, path_within = _paths_within_equal_times(centers[:, :2], t, order)
            # capture times that interleave frames far apart (two flights at once in one folder, a camera clock
            # reset between batteries) are no flight either (nu57: -24 % landmarks, blamed on whole seconds)
            # (as listed already: said where it was put so; the map calls this again on its ordered inputs)
            if n >= 3 and np.all(np.isfinite(centers)) and not reads_as_flight(centers[order, :2]):
                return order, ("given" if np.array_equal(order, identity) else "capture time, not a flight")
            if path_within:
                return order, "capture time + path"
            return order, ("given" if np.array_equal(order, identity) else "capture time")
        # one time on every frame (the nu25 sweep: mapped in the shuffled names' order, 64 landmarks of 75, no
        # word): no order in it, as without times
    if n < 3 or not np.all(np.isfinite(centers)):
        return identity, "given"
    xy = centers[:, :2]
    if reads_as_flight(xy):
        return identity, "given"
    current = int(np.argmax(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))
    return np.asarray(_chain(xy, np.arange(n), current), dtype=np.int64), "path"


# How `flight_order` found the order: as listed, by capture time, by capture time with the frames of one time along
# the path through their centres, along that path alone, or by capture times that are no flight's order.
FLIGHT_ORDER_HOWS = ("given", "capture time", "capture time + path", "path", "capture time, not a flight")


def reads_as_flight(xy: np.ndarray) -> bool:
    """Whether frames in this order (horizontal centres (N, 2), finite) read as one flight: the median
    `next_frame_ranks` is at most SCRAMBLED_NEXT_RANK (most steps go to one of the frames nearest the current
    one). Fewer than 3 frames always do. The test `flight_order` applies to a listed order and a capture-time
    order, and the map applies to its keyframes before it takes a pass length from them (`workflows.map`)."""
    xy = np.asarray(xy, dtype=np.float64)
    return len(xy) < 3 or bool(np.median(next_frame_ranks(xy)) <= SCRAMBLED_NEXT_RANK)


def _chain(xy: np.ndarray, members: np.ndarray, start: int) -> list[int]:
    """`members` (indices into `xy`) chained from `start` (one of them) to the nearest one not yet taken, each in
    turn (ties: the first listed; deterministic). O(M^2) in all, one row at a time (memory O(M))."""
    pts = xy[members]
    taken = np.zeros(len(members), dtype=bool)
    k = int(np.flatnonzero(members == start)[0])
    out = [int(members[k])]
    taken[k] = True
    for _ in range(len(members) - 1):
        k = int(np.argmin(np.where(taken, np.inf, np.linalg.norm(pts - pts[k], axis=1))))
        out.append(int(members[k]))
        taken[k] = True
    return out


def _travel(xy: np.ndarray, seq: np.ndarray, before: np.ndarray | None, after: np.ndarray | None) -> float:
    """Horizontal distance flown through `seq` (indices into `xy`), from the point `before` and on to the
    nearest of the points `after` (either None: no such leg)."""
    pts = xy[seq]
    d = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    if before is not None:
        d += float(np.linalg.norm(pts[0] - before))
    if after is not None:
        d += float(np.min(np.linalg.norm(after - pts[-1], axis=1)))
    return d


def _paths_within_equal_times(xy: np.ndarray, t: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, bool]:
    """`order` (stable by capture time) with the frames of each shared time reordered along a path through their
    centres where that path is shorter than their given order (and whether any was).

    Frames taken within one clock tick are in no order by it. Among the orders of such a run, the flight is a
    short one: the aircraft went from the frame before the run through the run and on to the frames of the next
    time. The path candidate starts at the run's frame nearest the frame before and steps to the nearest frame
    left (the first run, with no frame before, is chained from its frame nearest the next time's frames and
    reversed). It replaces the given order only when it flies less, counting the legs from the frame before and
    to the next time: frames listed in flight order keep it (a line: equal; a run in a turn or over its ground
    again: the given order is the shorter or equal one), shuffled names do not."""
    if not np.all(np.isfinite(xy)):
        return order, False
    ts = t[order]
    starts = np.flatnonzero(np.r_[True, ts[1:] != ts[:-1]])
    bounds = np.r_[starts, len(order)]
    out = order.copy()
    changed = False
    for g in range(len(starts)):
        a, b = int(bounds[g]), int(bounds[g + 1])
        if b - a < 2:
            continue
        given = out[a:b].copy()
        before = xy[out[a - 1]] if a > 0 else None
        after = xy[order[b:int(bounds[g + 2])]] if g + 1 < len(starts) else None
        if before is not None:
            path = _chain(xy, given, int(given[np.argmin(np.linalg.norm(xy[given] - before, axis=1))]))
        else:  # the first time: end at the next time's frames (there is one: the times differ)
            near = [np.min(np.linalg.norm(after - xy[i], axis=1)) for i in given]
            path = _chain(xy, given, int(given[int(np.argmin(near))]))[::-1]
        path_arr = np.asarray(path, dtype=np.int64)
        shorter = _travel(xy, path_arr, before, after) < _travel(xy, given, before, after) * (1 - 1e-9) - 1e-9
        if shorter:
            out[a:b] = path_arr
            changed = True
    return out, changed


def flight_order_message(how: str, times: np.ndarray | None) -> tuple[bool, str] | None:
    """What the log says of `flight_order`'s `how` (None: nothing, the order is as listed), and whether it is a
    warning (an order found along the camera path is a guess). `times`: the capture times it was given."""
    if how == "given":
        return None
    if how == "capture time":
        return False, "the frames are ordered by their capture times (EXIF DateTimeOriginal), not as listed"
    if how == "capture time + path":
        t = np.asarray(times, dtype=np.float64)
        _, inverse, counts = np.unique(t, return_inverse=True, return_counts=True)
        shared = int(np.sum(counts[inverse] > 1))
        return True, (f"{shared} of {len(t)} frames share their capture time with others (EXIF DateTimeOriginal "
                      "in whole seconds without SubSecTimeOriginal, or dates rewritten by a tool?) and are not "
                      "listed in flight order within it: they are ordered by capture time, and the frames of one "
                      "time along a path through their camera centres")
    if how == "capture time, not a flight":
        return True, ("the frames' capture times interleave frames far apart (consecutive times jump across the "
                      "survey): two flights in one folder whose capture times overlap (two drones at once, or a "
                      "camera clock reset between batteries?); they are ordered by capture time, which breaks "
                      "tracks at every jump: map each flight separately")
    if times is not None and len(times) > 0 and bool(np.all(np.isfinite(times))):
        why = f"and all {len(times)} images carry one capture time, which orders nothing"
    else:
        why = "and not every image carries a capture time"
    return True, (f"the frames are not listed in flight order (consecutive frames lie far apart, {why}): they are "
                  "ordered along a path through their camera centres")
