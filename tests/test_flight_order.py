"""The order the frames were taken in, from capture times or the camera path (plugin.keyframes.flight_order)."""

import numpy as np

from sosmatch.plugin.keyframes import _step_ranks, flight_order
from sosmatch.tools.toy_sessions import lawnmower


def _lawnmower(lines=4, per_line=20, spacing=7.0, line_gap=30.0):
    """`lines` back-and-forth lines of `per_line` frames at 100 m (toy_sessions.lawnmower)."""
    return lawnmower(0.0, (per_line - 1) * spacing, 0.0, (lines - 1) * line_gap, 100.0, line_gap, spacing)


def test_a_flight_in_order_stays_as_given_and_hovering_is_no_jump():
    c = _lawnmower()
    assert flight_order(c)[1] == "given"
    hover = np.repeat(c, 3, axis=0)  # three frames at every place: the nearest frame is at 0 m
    assert flight_order(hover)[1] == "given"



def test_a_long_hover_or_gps_stall_before_a_line_is_no_scrambled_order():
    # 20 frames at one recorded position (a hover, or a stalled GPS repeating one fix), then a 15-frame line:
    # a step that stays put has no frame strictly nearer (rank 0); counting the coincident frames as nearer
    # judged this flight scrambled and reversed it (rev50 D2)
    line = np.c_[np.zeros(15), np.arange(1, 16) * 7.0, np.full(15, 100.0)]
    c = np.r_[np.tile([0.0, 0.0, 100.0], (20, 1)), line]
    assert _step_ranks(c[:, :2], np.arange(19)).tolist() == [0] * 19  # the rank order_jumps reads
    order, how = flight_order(c)
    assert how == "given" and np.array_equal(order, np.arange(len(c)))
    assert flight_order(np.tile([0.0, 0.0, 100.0], (30, 1)))[1] == "given"  # a hover alone

def test_a_shuffled_lawnmower_is_chained_back_along_its_lines():
    c = _lawnmower()
    perm = np.random.default_rng(0).permutation(len(c))
    order, how = flight_order(c[perm])
    assert how == "path" and sorted(order.tolist()) == list(range(len(c)))
    walked = perm[order]  # indices of the true flight, in the recovered order
    steps = np.linalg.norm(np.diff(c[walked][:, :2], axis=0), axis=1)
    assert np.all(steps <= 30.0 + 1e-9)  # one spacing along a line, one line gap at a turn, never across
    assert np.sum(steps > 7.0 + 1e-9) <= 3


def test_capture_times_decide_when_every_frame_has_one():
    c = _lawnmower(lines=2, per_line=5)
    times = np.arange(len(c), dtype=float)[::-1]  # listed last-taken first
    order, how = flight_order(c, times)
    assert how == "capture time" and order.tolist() == list(range(len(c)))[::-1]
    assert flight_order(c, np.arange(len(c), dtype=float))[1] == "given"
    with_missing = np.arange(len(c), dtype=float)
    with_missing[3] = np.nan  # one frame without a time: the path rule decides (in order here)
    assert flight_order(c, with_missing)[1] == "given"


def test_a_flight_that_revisits_its_ground_stays_as_given():
    """New-user sweep 22: a lawnmower flown again backwards over the same lines (out-and-back corridor, second
    battery), exactly or 1.5 m aside, and a crosshatch (the grid again at right angles). Every frame has a twin
    0-1.5 m away, so the nearest-frame distance says nothing of the spacing; before, the listed order (7 m steps)
    was judged scrambled against it and chained through the centres, interleaving the passes: refused ("a heading
    180 deg off"), or half the frames lost as keyframes."""
    c = _lawnmower()
    for again in (c[::-1], c[::-1] + [1.5, 1.0, 0.0]):
        revisit = np.concatenate([c, again])
        order, how = flight_order(revisit)
        assert how == "given" and order.tolist() == list(range(len(revisit)))
    crosshatch = np.concatenate([c, c[:, [1, 0, 2]]])
    assert flight_order(crosshatch)[1] == "given"


def test_shuffled_revisits_and_small_flights_are_judged_against_a_random_order():
    """A shuffled list of a revisiting flight still steps across the site (as a random order of its centres does)
    and is chained; a short line in order (too few frames to tell its steps from a random order's) stays."""
    c = _lawnmower()
    revisit = np.concatenate([c, c[::-1] + [1.5, 1.0, 0.0]])
    perm = np.random.default_rng(1).permutation(len(revisit))
    assert flight_order(revisit[perm])[1] == "path"
    for n in (3, 4, 5, 8):
        line = np.column_stack([np.arange(n) * 7.0, np.zeros(n), np.full(n, 100.0)])
        assert flight_order(line)[1] == "given", n


def test_blocks_far_apart_each_shuffled_within_are_chained():
    """Review 20: two 240-frame blocks 2 km apart, each shuffled within, listed one after the other. Their median
    step (119 m) is small against a random order's over the whole site (1850 m: the site's scale, not the frame
    spacing), so the rule of a random order kept them as given; the next frame is still no near one (its rank
    among the current frame's neighbours is about half a block). Chained, every step is back along a line, at a
    turn or the one jump between the blocks."""
    c = _lawnmower(lines=6, per_line=40)
    far = c + [2000.0, 0.0, 0.0]
    rng = np.random.default_rng(0)
    listed = np.concatenate([c[rng.permutation(len(c))], far[rng.permutation(len(far))]])
    order, how = flight_order(listed)
    assert how == "path" and sorted(order.tolist()) == list(range(len(listed)))
    steps = np.linalg.norm(np.diff(listed[order][:, :2], axis=0), axis=1)
    assert np.sum(steps > 30.0 + 1e-9) == 1  # the jump between the blocks, once
    # the same blocks each in order stay as given
    assert flight_order(np.concatenate([c, far]))[1] == "given"


def _walked_steps(c, listed_perm, order):
    """Horizontal steps of the true flight `c` as recovered: `listed_perm` listed it, `order` reorders the list."""
    return np.linalg.norm(np.diff(c[listed_perm[order]][:, :2], axis=0), axis=1)


def test_one_capture_time_on_every_frame_orders_nothing():
    """The nu25 sweep: every DateTimeOriginal rewritten to one instant, names shuffled. A stable sort on equal times
    returned the shuffled names' order as "given": mapped across the survey (696 matches against 1189, 64
    landmarks of 75), exit 0, no word. One time orders nothing: as without times, the path decides."""
    c = _lawnmower()
    perm = np.random.default_rng(2).permutation(len(c))
    same = np.full(len(c), 1.717e9)
    order, how = flight_order(c[perm], same)
    assert how == "path" and sorted(order.tolist()) == list(range(len(c)))
    assert np.all(_walked_steps(c, perm, order) <= 30.0 + 1e-9)
    assert flight_order(c, same)[1] == "given"  # listed in flight order: it stays


def test_frames_sharing_a_clock_second_are_ordered_along_the_path_within_it():
    """Bursts of 3 frames a second stamped in whole seconds (no SubSecTimeOriginal), names shuffled: the seconds
    order the bursts, and within each the listed (random) order stood. Within a time the frames now follow the
    path from the frame before; listed in flight order, they keep it."""
    c = _lawnmower()
    t = np.floor(np.arange(len(c)) * 0.34)  # 3 frames in most seconds
    perm = np.random.default_rng(3).permutation(len(c))
    order, how = flight_order(c[perm], t[perm])
    assert how == "capture time + path"
    assert np.array_equal(perm[order], np.arange(len(c)))  # the flight exactly (every step one spacing or a turn)
    assert np.all(np.diff(t[perm[order]]) >= 0)  # the times still rule between seconds
    order, how = flight_order(c, t)
    assert how == "given" and np.array_equal(order, np.arange(len(c)))
    # the first second too, which has no frame before it: it ends next to the following second's frames
    first = np.array([2, 0, 1] + list(range(3, len(c))))
    order, how = flight_order(c[first], t[first])
    assert how == "capture time + path" and np.array_equal(first[order], np.arange(len(c)))


def test_a_real_time_order_stays_authoritative_over_the_path():
    """Times that differ decide, however far the frames between them lie (a flight that revisits its ground, or
    one whose order the path would take otherwise): only frames of one time are reordered."""
    c = _lawnmower()
    revisit = np.concatenate([c, c[::-1] + [1.5, 1.0, 0.0]])
    t = np.arange(len(revisit), dtype=float) * 2.0
    perm = np.random.default_rng(4).permutation(len(revisit))
    order, how = flight_order(revisit[perm], t[perm])
    assert how == "capture time" and np.array_equal(perm[order], np.arange(len(revisit)))
    # a pair of frames of one second in a turn, listed in flight order: the given order is no longer, it stays
    turn = np.array([[0.0, 0.0, 100.0], [7.0, 0.0, 100.0], [7.0, 7.0, 100.0], [0.0, 7.0, 100.0], [-7.0, 7.0, 100.0]])
    assert flight_order(turn, np.array([0.0, 1.0, 1.0, 2.0, 3.0]))[1] == "given"


def test_the_order_is_told_in_the_log():
    from sosmatch.plugin.keyframes import flight_order_message

    assert flight_order_message("given", None) is None
    assert flight_order_message("capture time", np.arange(3.0))[0] is False
    warn, text = flight_order_message("capture time + path", np.array([0.0, 0.0, 0.0, 1.0, 2.0, 2.0]))
    assert warn and text.startswith("5 of 6 frames share their capture time")
    warn, text = flight_order_message("path", np.zeros(4))
    assert warn and "not listed in flight order" in text and "all 4 images carry one capture time" in text
    assert "not every image carries a capture time" in flight_order_message("path", None)[1]


def _two_flights_at_once(whole_seconds=False, line_gap=14.0):
    """Two 30-frame lawnmowers (2 lines, 7 m steps) 43 m apart (the second shifted 15, 40 m), flown at once:
    frames 2 s apart each, the second's 1 s after the first's (or both stamped in whole seconds, 1.4 s apart, the
    second's from 0.3 s)."""
    one = _lawnmower(lines=2, per_line=15, line_gap=line_gap)
    two = one + [15.0, 40.0, 0.0]
    if whole_seconds:  # nu57's BATT: 1.4 s between frames, several frames of both flights in one second
        t = np.r_[np.floor(np.arange(len(one)) * 1.4), np.floor(np.arange(len(two)) * 1.4 + 0.3)]
    else:
        t = np.r_[np.arange(len(one)) * 2.0, np.arange(len(two)) * 2.0 + 1.0]
    return one, two, np.concatenate([one, two]), t


def test_capture_times_of_two_flights_flown_at_once_are_ordered_per_flight(caplog):
    """nu57 D3: two batteries whose clocks overlap (a clock reset, or two drones at once) in one folder were
    ordered by capture time alone, alternating between flights 43 m apart: tracks broke at every jump (-24 %
    landmarks) and the pass length measured on those steps lowered theta_n 5 -> 2. fix135 warned and kept theta_n
    but kept the interleaved order. Now the frames are split into the flights the times interleave, each in time
    order, one after the other, with one warning that says so; from any listing, the same order (deterministic,
    and given again it stays: the map orders its inputs twice); the map's keyframes read as one flight and theta_n
    follows their views as for the flights one after the other."""
    import logging

    from sosmatch.plugin.keyframes import flight_order_message, ordered_flight, reads_as_flight
    from sosmatch.plugin.params import Params, for_flight
    from sosmatch.workflows.map.workflow import flown_params

    for whole_seconds in (False, True):
        one, two, both, t = _two_flights_at_once(whole_seconds)
        per_flight = np.arange(len(both))  # the first flight in time order, then the second
        assert not reads_as_flight(both[np.argsort(t, kind="stable"), :2])  # the times' order jumps
        for seed in range(5):
            listed = np.random.default_rng(seed).permutation(len(both))
            order, how = flight_order(both[listed], t[listed])
            assert how == "capture time, per flight", whole_seconds
            assert np.array_equal(listed[order], per_flight), whole_seconds
            assert flight_order(both, t)[1] == "given"  # given again, it stays
        _, how, split = ordered_flight(both[listed], t[listed])
        warn, text = flight_order_message(how, t[listed], split)
        assert warn and "capture times interleave flights far apart" in text
        assert "ordered per flight along the camera path, each path by capture time" in text
        assert "jump between them; split into 2 paths" in text
    # turns onto the next line 30 m away (no frame in the turn) are as long as the jumps between the flights: each
    # line is a path, the paths one after the other as they started; no step jumps back any more
    _, _, both, t = _two_flights_at_once(line_gap=30.0)
    orders = set()
    for seed in range(5):
        listed = np.random.default_rng(seed).permutation(len(both))
        order, how = flight_order(both[listed], t[listed])
        assert how == "capture time, per flight" and reads_as_flight(both[listed[order], :2])
        orders.add(tuple(listed[order]))
        assert flight_order(both[listed[order]], t[listed[order]])[1] == "given"
    assert len(orders) == 1
    # one flight in time order, and the two flights one after the other: as before
    assert flight_order(one[::-1], np.arange(len(one))[::-1] * 2.0)[1] == "capture time"
    assert flight_order(both, np.r_[t[: len(one)], t[len(one):] + 1000.0])[1] == "given"
    params = Params()
    assert for_flight(params, 3.3) is not params  # lowers theta_n to 2 from 3.3 views a pass
    with caplog.at_level(logging.WARNING):
        lowered = flown_params(params, 3.3, both)  # keyframes per flight: lowered as for one flight, no word
    assert lowered.triangulation.min_observations == 2 and not caplog.text
    # keyframes that still jump back and forth (a listed order, no times): theta_n kept, said with the count
    with caplog.at_level(logging.WARNING):
        assert flown_params(params, 3.3, both[np.argsort(t)]) is params
    assert "of the 59 steps between keyframes jump back and forth" in caplog.text
    assert "theta_n stays 5 (not lowered to 2" in caplog.text


def test_a_corridor_flown_in_many_passes_is_one_flight(caplog):
    """rev53 D4: a corridor flown out and back up to 20 times in its own order (frames 10 m apart, 1 m GPS
    noise). Its median next-frame rank grows about 2 a pass (10 at 6 passes): the map warned its keyframes "are
    not in the order of one flight" and kept theta_n, and listed without capture times it was reordered along the
    path, interleaving the passes. A flight whose steps are all flight steps is one flight, however often it passes
    over its ground."""
    import logging

    from sosmatch.plugin.keyframes import order_jumps, reads_as_flight
    from sosmatch.plugin.params import Params
    from sosmatch.workflows.map.workflow import flown_params

    rng = np.random.default_rng(0)
    for passes in (6, 8, 20):
        x = np.concatenate([np.arange(0, 300, 10.0)[:: 1 if i % 2 == 0 else -1] for i in range(passes)])
        c = np.c_[x + rng.normal(0, 1, len(x)), rng.normal(0, 1.4, len(x)), np.full(len(x), 100.0)]
        assert np.median(_step_ranks(c[:, :2], np.arange(len(c) - 1))) > 8, passes  # what judged it before
        assert reads_as_flight(c[:, :2]) and not np.any(order_jumps(c[:, :2])), passes
        assert flight_order(c)[1] == "given", passes
        assert flight_order(c, np.arange(len(c)) * 2.0)[1] == "given", passes
        with caplog.at_level(logging.WARNING):
            assert flown_params(Params(), 3.3, c).triangulation.min_observations == 2
        assert not caplog.text, passes
        # the same corridor listed in a random order still jumps, and is chained along the path
        assert flight_order(c[rng.permutation(len(c))])[1] == "path", passes


def test_flights_one_after_another_and_turns_onto_far_lines_are_no_jumps():
    """Steps that go to a new place are no jumps: a lawnmower whose lines are 5 spacings apart (a turn without
    frames), two batteries one after the other with the second starting 40 m away, a GPS fix astray for one frame.
    Only steps back to a place left a few frames before are, and an order of up to one such step, or 5 % of its
    steps, is a flight."""
    from sosmatch.plugin.keyframes import order_jumps, reads_as_flight

    far_lines = _lawnmower(lines=6, per_line=6, line_gap=35.0)
    assert not np.any(order_jumps(far_lines[:, :2])) and flight_order(far_lines)[1] == "given"
    one, two, both, _ = _two_flights_at_once()
    assert not np.any(order_jumps(both[:, :2])) and reads_as_flight(both[:, :2])
    astray = _lawnmower().copy()
    astray[30, :2] += [60.0, 0.0]  # there and back: the step back is a jump
    assert np.count_nonzero(order_jumps(astray[:, :2])) == 1 and flight_order(astray)[1] == "given"


def test_a_flight_cut_at_its_turns_stays_together_between_the_other_flights_paths():
    """rev56 D4: two lawnmowers 150 m apart flown at once (capture times interleaved), lines 40 m apart with no
    frame in the turns: every turn is longer than the split's gate (3 flight steps), so each line came out as a
    path and the paths were listed by start, A0 B0 A1 B1 A2 B2: tracks broke at every line for no reason. Paths
    that continue one another (the next starts nearest the previous one's frames, after it ended, no other
    flight's frame nearer than its end) are one flight; from any listing, A's lines, then B's. Lines all flown
    one way (a frameless return leg along the line: the next line starts a line length from the last end) are
    joined the same way where no other flight's frame is nearer: A's are (B lies beyond their ends); B's return
    legs start nearer to A's line ends than to B's own and stay paths of their own, listed by start after A."""
    from sosmatch.plugin.keyframes import flight_order_message, flights_in_time_order, ordered_flight, reads_as_flight

    rng = np.random.default_rng(3)
    one = _lawnmower(lines=3, per_line=11, spacing=10.0, line_gap=40.0)
    racetrack = one.copy()
    racetrack[11:22, 0] = racetrack[11:22, 0][::-1]  # the middle line flown the way the others are
    for a, flights in ((one, 2), (racetrack, 4)):
        both = np.concatenate([a, a + [150.0, 0.0, 0.0]])
        both[:, :2] += rng.normal(0.0, 1.0, (len(both), 2))
        t = np.r_[np.arange(len(a)) * 2.0, np.arange(len(a)) * 2.0 + 0.5]
        for seed in range(4):
            listed = np.random.default_rng(seed).permutation(len(both))
            order, how = flight_order(both[listed], t[listed])
            assert how == "capture time, per flight"
            assert np.array_equal(listed[order], np.arange(len(both)))  # A in time order, then B
            assert reads_as_flight(both[listed[order], :2])
            assert flights_in_time_order(both[listed, :2], t[listed])[1] == flights
        _, how, split = ordered_flight(both[listed], t[listed])
        assert f"split into {flights} paths" in flight_order_message(how, t[listed], split)[1]
