"""A session that sees the site unlike the other (another sensor, low contrast): what it neither maps nor
segments is no evidence that the object went (plugin.changes.evidence.visible_share)."""

import numpy as np

from sosmatch.plugin.changes.evidence import absence_log_ratio, visible_share
from sosmatch.plugin.params import ChangeParams
from sosmatch.tools.toy_sessions import change_session, lawnmower, make_spaced_world, yaw_transform


def _unchanged_pair(b_sees: float):
    """One unchanged 260-object world flown twice; B (in a frame of its own) maps and segments only a random
    share `b_sees` of the objects, as a thermal camera shows only those warmer than the grass."""
    w = make_spaced_world(260, 240.0, (1.0, 4.0), 3)
    rng = np.random.default_rng(11)
    present = np.ones(len(w.positions), dtype=bool)
    frame_b = yaw_transform(35.0, (12.0, -7.0, 2.0))
    a, _ = change_session(w.positions, w.sizes, present, lawnmower(30, 150, 30, 150, 70, 30, 8), 1)
    b, _ = change_session(w.positions, w.sizes, rng.random(len(present)) < b_sees,
                          lawnmower(60, 180, 40, 160, 70, 30, 8), 2, session_from_world=frame_b)
    return a, b, frame_b.inverse()


def test_a_session_that_sees_few_objects_claims_no_absence():
    """B sees a fifth of the objects and nothing changed: none of A's objects is gone (before: dozens at > 0.99),
    and the order of the sessions does not matter (B's claims against A are A's, relabelled)."""
    from sosmatch.plugin.changes import detect_changes

    a, b, a_from_b = _unchanged_pair(0.2)
    res = detect_changes(a, b, a_from_b, ChangeParams(), 2.0)
    assert res.counts()["gone"] == 0 and res.counts()["new"] == 0
    back = detect_changes(b, a, a_from_b.inverse(), ChangeParams(), 2.0)
    assert back.counts()["gone"] == 0 and back.counts()["new"] == 0
    assert max(np.max(res.a.confidence), np.max(back.b.confidence)) < ChangeParams().min_confidence


def test_sessions_that_see_alike_keep_full_weight():
    """Two sessions that see every object: the share is 1 whatever their share of changes, so absence of hits
    counts fully; a session that sees a fifth of them leaves little weight."""
    rng = np.random.default_rng(0)
    h = rng.uniform(1.0, 4.0, 100)
    matched = rng.random(100) < 0.6
    alike = visible_share(h, (h, matched, matched | (rng.random(100) < 0.9)),
                          (h, matched, matched | (rng.random(100) < 0.9)), 0.3)
    assert np.all(alike > 0.8)  # sampling noise of the two shares only
    few = np.arange(100) < 15
    thin = visible_share(h, (h, few, few | (np.arange(100) < 20)), (h[:20], np.ones(20, bool), np.ones(20, bool)), 0.3)
    assert np.all(thin < 0.15)
    # a share of 0 makes the segments say nothing; 1 is the binomial ratio of before
    llr = absence_log_ratio(np.array([0, 0]), np.array([30, 30]), np.array([0.01, 0.01]), np.array([0.6, 0.6]),
                            2.0, np.array([0.0, 1.0]))
    assert abs(llr[0]) < 1e-9 and llr[1] > 10


def test_a_session_that_sees_few_objects_is_named_in_a_warning():
    """The thin session is named with its counts; sessions that see alike raise no such warning."""
    from sosmatch.plugin.changes import detect_changes
    from sosmatch.workflows.changes import sensing_notes

    a, b, a_from_b = _unchanged_pair(0.2)
    res = detect_changes(a, b, a_from_b, ChangeParams(), 2.0)
    notes = sensing_notes(res, "mapA", "mapB")
    assert len(notes) == 1 and notes[0].startswith("mapB (session B): its map holds")
    assert "do not see alike" in notes[0] and "absent from it are weak" in notes[0]
    assert res.sensing_a.visible < 0.5 <= res.sensing_b.visible
    a, b, a_from_b = _unchanged_pair(1.0)
    assert sensing_notes(detect_changes(a, b, a_from_b, ChangeParams(), 2.0), "mapA", "mapB") == []
