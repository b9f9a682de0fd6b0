"""The order the frames were taken in, from capture times or the camera path (plugin.keyframes.flight_order)."""

import numpy as np

from sosmatch.plugin.keyframes import flight_order, next_frame_ranks
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
    assert next_frame_ranks(c[:, :2])[:19].tolist() == [0] * 19
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


def test_capture_times_of_two_flights_flown_at_once_are_no_flight_and_do_not_lower_theta_n(caplog):
    """nu57 D3: two batteries whose clocks overlap (a clock reset, or two drones at once) in one folder were
    ordered by capture time alone, alternating between flights 40 m apart: tracks broke at every jump and the
    pass length measured on those steps lowered theta_n 5 -> 2, with an INFO line. The capture-time order gets
    the flight test a listed order gets, and its warning names the overlap; the map keeps theta_n for
    keyframes in no flight's order. A single flight by its times is unchanged."""
    import logging

    from sosmatch.plugin.keyframes import flight_order_message
    from sosmatch.plugin.params import Params, for_flight
    from sosmatch.workflows.map.workflow import flown_params

    one = _lawnmower(lines=2, per_line=15)
    two = one + [15.0, 40.0, 0.0]
    both = np.concatenate([one, two])
    t = np.r_[np.arange(len(one)) * 2.0, np.arange(len(two)) * 2.0 + 1.0]  # interleaved, every time distinct
    order, how = flight_order(both, t)
    assert how == "capture time, not a flight" and np.array_equal(order, np.argsort(t))
    warn, text = flight_order_message(how, t)
    assert warn and "capture times overlap" in text and "map each flight separately" in text
    assert flight_order(both[order], t[order])[1] == "given"  # ordered already: said once, where it was ordered
    # one flight in time order, and the two flights one after the other: as before
    assert flight_order(one[::-1], np.arange(len(one))[::-1] * 2.0)[1] == "capture time"
    assert flight_order(both, np.r_[t[: len(one)], t[len(one):] + 1000.0])[1] == "given"
    params = Params()
    assert for_flight(params, 3.3) is not params  # the 3.3 views of the interleaved order would lower it
    with caplog.at_level(logging.WARNING):
        assert flown_params(params, 3.3, both[order]) is params
    assert "not in the order of one flight: theta_n stays 5 (not lowered to 2" in caplog.text
    caplog.clear()
    lowered = flown_params(params, 3.3, one)  # one flight's keyframes: lowered as before, without a warning
    assert lowered.triangulation.min_observations == 2 and not caplog.text
