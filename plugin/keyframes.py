"""Keyframe selection by camera travel (SOS-Match step 1, `theta_T`)."""

from __future__ import annotations

from typing import NamedTuple

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
# as a random order of the same centres does, and capture times that interleave flights (two drones at once, a
# camera clock reset between batteries, both in one folder) step back and forth between them. Either order jumps
# (`order_jumps`): a step more than JUMP_STEPS of the flight's steps long (`flight_step`) that goes past the
# SCRAMBLED_NEXT_RANK frames nearest to the current one (its rank: how many frames are strictly nearer than the next
# one) to a frame JUMP_RATIO times nearer to one of the JUMP_LOOKBACK - 1 frames before the current one than to
# the current one: the order left a place and came back to it. A flight has no such steps, however often it passes
# over its ground: its steps are flight steps, and a turn onto a line far away goes to a new place. Before, the
# median rank alone judged an order (more than 8: no flight): a flight over its ground again has high ranks (the
# twins of this frame and the next are nearer, about 2 a pass), so a corridor flown out and back 3 times in its own
# order was "not in the order of one flight" (rev53 D4), and listed without times it was reordered along the path;
# and capture times that interleave two flights in runs of a few frames have a median rank of 1 (nu57 D3: BATT, a
# third of its steps jump). Measured on shuffled lists (50 shuffles each, least / median): 8 / 16 % of a 80-frame
# lawnmower's steps jump, 12 / 19 % of a 240-frame one's, 10 / 18 % of 200 uniform random points'; a dozen frames
# in a random order may read as a flight (a 12-frame line: 34 shuffles of 50; a 20-frame one: none). Earlier
# still, rules compared the median step with one scale of the whole set: with the nearest-frame distance, a flight
# that revisits its ground was "scrambled" at its 7 m steps (new-user sweep 22); with a random order's step (the
# site's scale), two blocks 2 km apart, each shuffled within, were kept as given (review 20).
SCRAMBLED_NEXT_RANK = 8
JUMP_STEPS = 2.0
JUMP_RATIO = 3.0
JUMP_LOOKBACK = 4  # the frame before and the 3 before it: up to 4 flights interleaved at one rate are told apart
# An order reads as one flight with at most this share of its steps jumps (and always with one: a GPS fix gone
# astray for a frame and back is one), so a flight's odd outliers do not make it "no flight".
JUMP_SHARE_MAX = 0.05


def _step_ranks(xy: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """For the steps `steps` (indices i of steps i -> i+1) of the order of horizontal centres `xy` (N, 2): how many
    frames are strictly nearer to frame i than frame i+1 is (int64)."""
    from scipy.spatial import cKDTree

    if len(steps) == 0:
        return np.zeros(0, dtype=np.int64)
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


def _lookback(xy: np.ndarray, first_lag: int) -> np.ndarray:
    """Per frame j >= 1 of the order (entry j - 1): the distance to the nearest of the frames j - first_lag ..
    j - JUMP_LOOKBACK before it (inf where there is none)."""
    n = len(xy)
    near = np.full(max(n - 1, 0), np.inf)
    for lag in range(first_lag, JUMP_LOOKBACK + 1):
        j = np.arange(lag, n)
        near[j - 1] = np.minimum(near[j - 1], np.linalg.norm(xy[j] - xy[j - lag], axis=1))
    return near


def flight_step(xy: np.ndarray) -> float:
    """The step of the flight (m) whose frames are in this order (horizontal centres (N, 2), finite): the median
    distance of a frame to the nearest of the JUMP_LOOKBACK frames before it (the frame before, in a flight;
    its own flight's previous frame, where up to that many flights are interleaved); frames at the position of
    one of them (a hover) count not. 0 when nothing moves."""
    near = _lookback(np.asarray(xy, dtype=np.float64), 1)
    moving = near[np.isfinite(near) & (near > SAME_POSITION)]
    return float(np.median(moving)) if len(moving) else 0.0


def order_jumps(xy: np.ndarray) -> np.ndarray:
    """Which steps i -> i+1 of the order jump: the step is more than JUMP_STEPS flight steps long (`flight_step`),
    its next frame is not among the SCRAMBLED_NEXT_RANK nearest to frame i (`_step_ranks`), and it lies more
    than JUMP_RATIO times nearer to one of the frames before frame i (up to JUMP_LOOKBACK back) than to frame i:
    the order left a place and came back to it. A flight's own steps are none of these: a turn onto a line far
    away goes to a new place, a step back over the ground just flown (a corridor's out-and-back turn) is one
    flight step long.

    Args:
        xy: (N, 2) horizontal camera centres in metres, finite, in the order to judge.

    Returns:
        (N - 1,) bool.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 3:
        return np.zeros(max(len(xy) - 1, 0), dtype=bool)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    # step i -> i+1 against frame i+1's distance to frames i-1 .. (lag 2 and more from frame i+1)
    back = _lookback(xy, 2)
    candidate = np.flatnonzero((step > JUMP_RATIO * back) & (step > JUMP_STEPS * flight_step(xy)))
    jumps = np.zeros(len(step), dtype=bool)
    # ranks of the candidates only: a flight has few, so the test stays O(N) where it passes
    jumps[candidate] = _step_ranks(xy, candidate) > SCRAMBLED_NEXT_RANK
    return jumps


def flight_order(centers: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The order in which the frames were taken, and how it was found (`FLIGHT_ORDER_HOWS`).

    Capture times (every frame one, finite) decide where they differ. Frames that share a time (a clock in whole
    seconds under bursts of several frames a second, a tool that rewrote the dates) are in no order by it: within
    each such time they keep their given order unless a path through their camera centres is shorter
    (`_paths_within_equal_times`; "capture time + path"). Times that are all one carry no order at all and count
    as none. A capture-time order that is no flight (`reads_as_flight`: the times interleave flights whose times
    overlap, and the order jumps back and forth between them) is split into the paths the times interleave
    (`flights_in_time_order`), each kept in time order, one after the other ("capture time, per flight"). Without
    times the given order stands unless it is no flight either (`reads_as_flight`); then the frames are chained
    from an end of the survey (the frame farthest from the centroid) to the nearest frame not yet taken, which
    retraces a survey's lines and turns ("path"). A flight that passes over its ground again stays as given: its
    next frame is the one nearest to where it just was.

    Args:
        centers: (N, 3) camera centres in metres, in the given order (only the horizontal ones are used; frames
            of one time keep their given order, and overlapping times their time order, when any centre is not
            finite).
        times: (N,) capture times in seconds, or None.

    Returns:
        ((N,) int64 permutation into the given order, how).
    """
    order, how, _ = ordered_flight(centers, times)
    return order, how


class FlightSplit(NamedTuple):
    """How `flight_order` split a capture-time order that is no flight ("capture time, per flight"): `jumps` of its
    `steps` jump (`order_jumps`), and `paths`, the flights it was split into (`flights_in_time_order`)."""

    jumps: int
    steps: int
    paths: int


def ordered_flight(centers: np.ndarray,
                   times: np.ndarray | None = None) -> tuple[np.ndarray, str, FlightSplit | None]:
    """`flight_order`, and for "capture time, per flight" the split it made (`FlightSplit`; None otherwise): what
    `flight_order_message` counts, found once."""
    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    identity = np.arange(n, dtype=np.int64)
    if times is not None and len(times) == n and n > 1 and np.all(np.isfinite(times)):
        t = np.asarray(times, dtype=np.float64)
        if np.ptp(t) > 0:
            order = np.argsort(t, kind="stable").astype(np.int64)
            order, path_within = _paths_within_equal_times(centers[:, :2], t, order)
            # capture times that interleave flights far apart (two drones at once in one folder, a camera clock
            # reset between batteries) jump back and forth: tracks broke at every jump (nu57 D3: -24 % landmarks)
            # (as listed already: said where it was put so; the map calls this again on its ordered inputs)
            jumps = int(np.count_nonzero(order_jumps(centers[order, :2]))) \
                if n >= 3 and np.all(np.isfinite(centers)) else 0
            if not _few_jumps(jumps, n):
                order, paths = flights_in_time_order(centers[:, :2], t)
                if np.array_equal(order, identity):
                    return order, "given", None
                return order, "capture time, per flight", FlightSplit(jumps, n - 1, paths)
            if path_within:
                return order, "capture time + path", None
            return order, ("given" if np.array_equal(order, identity) else "capture time"), None
        # one time on every frame (the nu25 sweep: mapped in the shuffled names' order, 64 landmarks of 75, no
        # word): no order in it, as without times
    if n < 3 or not np.all(np.isfinite(centers)):
        return identity, "given", None
    xy = centers[:, :2]
    if reads_as_flight(xy):
        return identity, "given", None
    current = int(np.argmax(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))
    return np.asarray(_chain(xy, np.arange(n), current), dtype=np.int64), "path", None


# How `flight_order` found the order: as listed, by capture time, by capture time with the frames of one time along
# the path through their centres, along that path alone, or by capture time per flight where the times interleave
# flights.
FLIGHT_ORDER_HOWS = ("given", "capture time", "capture time + path", "path", "capture time, per flight")


def reads_as_flight(xy: np.ndarray) -> bool:
    """Whether frames in this order (horizontal centres (N, 2), finite) read as one flight: at most one of its
    steps, or JUMP_SHARE_MAX of them, jump (`order_jumps`: go back to a place the order left a few frames before,
    past the frames nearest). The one test of an order: `flight_order` applies it to a listed order and a
    capture-time order, and the map to its keyframes before it takes a pass length from them (`workflows.map`)."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 3:
        return True
    return _few_jumps(int(np.count_nonzero(order_jumps(xy))), len(xy))


def _few_jumps(jumps: int, n: int) -> bool:
    """Whether an order of n frames with `jumps` jumping steps reads as one flight (`reads_as_flight`)."""
    return jumps <= max(1.0, JUMP_SHARE_MAX * (n - 1))


def flights_in_time_order(xy: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, int]:
    """The frames split into the flights their capture times interleave, each flight in time order (the frames of
    one time along the path where their given order is not: `_paths_within_equal_times`), one flight after the
    other in the order they started; and how many flights that makes.

    Consecutive frames of one flight are near each other in space and time. In time order, each frame continues
    the path whose latest frame is nearest to it, unless every path's latest frame is more than JUMP_RATIO
    flight steps (`flight_step` of the time order) away: then it starts a path (the first frame of a flight whose
    times overlap another's, or of a part of a flight after a turn or a jump as long). Paths that continue one
    another are then joined into one flight (`_join_continuations`). Deterministic; the split depends on
    the frames' centres and times, not on how they are listed, but for the order of frames of one time, so that
    the result given again comes back as it is.

    Args:
        xy: (N, 2) horizontal camera centres in metres, finite, in the given order.
        t: (N,) capture times in seconds, finite.

    Returns:
        ((N,) int64 permutation into the given order, the number of flights: paths after joining).
    """
    xy = np.asarray(xy, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    n = len(xy)
    if n == 0:
        return np.zeros(0, dtype=np.int64), 0
    timed = np.argsort(t, kind="stable").astype(np.int64)
    timed, _ = _paths_within_equal_times(xy, t, timed)
    gate = JUMP_RATIO * flight_step(xy[timed])
    flight_of = np.zeros(n, dtype=np.int64)
    tails: list[int] = []  # per flight, its latest frame
    for f in timed.tolist():
        if tails:
            d = np.linalg.norm(xy[tails] - xy[f], axis=1)
            k = int(np.argmin(d))  # ties: the flight that started first
            if d[k] <= gate:
                flight_of[f] = k
                tails[k] = f
                continue
        flight_of[f] = len(tails)
        tails.append(f)
    out: list[np.ndarray] = []
    for k in range(len(tails)):
        members = np.flatnonzero(flight_of == k)  # in the given order: frames of one time keep it, as above
        own = members[np.argsort(t[members], kind="stable")]
        out.append(_paths_within_equal_times(xy, t, own)[0])
    # flights that start at one time (batteries whose clocks both restarted at one instant): the one whose first
    # frame lies west-most, then south-most, first, whatever the listing
    first = np.array([[t[o[0]], xy[o[0], 0], xy[o[0], 1]] for o in out])
    rank = np.lexsort((first[:, 2], first[:, 1], first[:, 0]))
    flights = _join_continuations(xy, t, [out[k] for k in rank])
    return np.concatenate(flights).astype(np.int64), len(flights)


def _join_continuations(xy: np.ndarray, t: np.ndarray, paths: list[np.ndarray]) -> list[np.ndarray]:
    """`paths` (each in time order, listed by start) joined where one continues another, as flights listed by
    their first path's start.

    A flight whose turn onto its next line is longer than the split's gate comes out of it in pieces, and listed
    by start the other flight's pieces fell between them (rev56 D4: A's first line, all of B, then A's other
    lines; tracks across A's turn broken). A path continues the one that holds the frame nearest to its first
    frame among all frames taken before it, when that path ended before it started (one aircraft is in one place
    at a time: paths whose times overlap are different flights), its last frame is no farther from that first
    frame than any other path's frame taken before, and no path continues it yet. Paths left unjoined keep their
    start order, as before."""
    if len(paths) < 2:
        return paths
    path_of = np.empty(len(t), dtype=np.int64)
    for k, p in enumerate(paths):
        path_of[p] = k
    starts = np.array([t[p[0]] for p in paths])
    ends = np.array([t[p[-1]] for p in paths])
    after: dict[int, int] = {}  # a path -> the path that continues it
    flight_of = np.arange(len(paths))  # a path -> the first path of its flight
    continued = set()
    for q in range(1, len(paths)):
        f = int(paths[q][0])
        earlier = np.flatnonzero(t < starts[q])
        if not len(earlier):  # starts with the first (frames of one time)
            continue
        d = np.linalg.norm(xy[earlier] - xy[f], axis=1)
        p = int(np.min(path_of[earlier[d == d.min()]]))  # ties: the path that started first, whatever the listing
        if ends[p] >= starts[q] or p in after:
            continue
        # from p's end, not only from its ground: a path that starts where p started, a line length from p's end,
        # after other flights' frames nearer, is no step of p's (Seneca's halves at once: a 265 m step); frames of
        # the paths p continues are p's flight's own
        others = flight_of[path_of[earlier]] != flight_of[p]
        reach = float(np.linalg.norm(xy[int(paths[p][-1])] - xy[f]))
        if not np.any(others) or reach <= float(np.min(d[others])):
            after[p] = q
            continued.add(q)
            flight_of[q] = flight_of[p]
    flights = []
    for k in range(len(paths)):
        if k in continued:
            continue
        chain = [paths[k]]
        while k in after:
            k = after[k]
            chain.append(paths[k])
        flights.append(np.concatenate(chain))
    return flights


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


def flight_order_message(how: str, times: np.ndarray | None,
                         split: FlightSplit | None = None) -> tuple[bool, str] | None:
    """What the log says of `flight_order`'s `how` (None: nothing, the order is as listed), and whether it is a
    warning (an order found along the camera path is a guess). `times`: the capture times it was given; `split`:
    the split it made of them (`ordered_flight`; with it, the warning counts the jumps and the paths)."""
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
    if how == "capture time, per flight":
        said = "" if split is None else (f" ({split.jumps} of the {split.steps} steps in capture-time order jump "
                                         f"between them; split into {split.paths} paths)")
        return True, ("the frames' capture times interleave flights far apart (two drones at once, or a camera clock "
                      "reset between batteries, in one folder?), which would break tracks at every jump: they are "
                      "ordered per flight along the camera path, each path by capture time, one after the other"
                      f"{said}; map each flight separately if they are separate surveys")
    if times is not None and len(times) > 0 and bool(np.all(np.isfinite(times))):
        why = f"and all {len(times)} images carry one capture time, which orders nothing"
    else:
        why = "and not every image carries a capture time"
    return True, (f"the frames are not listed in flight order (consecutive frames lie far apart, {why}): they are "
                  "ordered along a path through their camera centres")
