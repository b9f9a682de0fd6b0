"""Scoring change detection against a synthetic world's truth (tools.benchmarks.change_truth) and naming why it
failed (tools.benchmarks.change_failures), on the small world of test_changes with verdicts set by hand."""

from dataclasses import replace

import numpy as np
import pytest
import shapely

from sosmatch.plugin.changes import BY_LANDMARK, GONE, KEPT, NEW, detect_changes, in_view
from sosmatch.plugin.params import ChangeParams
from sosmatch.tools.benchmarks.change_failures import FALSE, MISSED, NO_OBJECT, classify_failures
from sosmatch.tools.benchmarks.change_truth import ObjectTruth, score_pair
from sosmatch.tools.toy_sessions import CHANGE_CAMERA as CAM
from sosmatch.tools.toy_sessions import toy_change_pair


@pytest.fixture(scope="module")
def scored():
    positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b = toy_change_pair()
    res = detect_changes(a, b, a_from_b, ChangeParams(min_confidence=0.0), 2.0)
    b_in_a = b.transformed(a_from_b)
    views_a = in_view(positions, sizes, a.poses, [CAM] * len(a.poses))[0].sum(0)
    views_b = in_view(positions, sizes, b_in_a.poses, [CAM] * len(b.poses))[0].sum(0)
    # object ids 1..n (0 = the ground); footprint radius 2 h, so every object >= 2 m is in the bar's size scope
    truth = ObjectTruth(np.arange(1, len(positions) + 1), np.full(len(positions), "tree"), 2.0 * sizes,
                        present_a, present_b, views_a, views_b)
    area = shapely.box(-1e4, -1e4, 1e4, 1e4)
    return res, truth, ids_a + 1, ids_b + 1, area


def _force(verdict, i, **fields):
    arrays = {k: np.array(getattr(verdict, k), copy=True) for k in fields}
    for k, v in fields.items():
        arrays[k][i] = v
    return replace(verdict, **arrays)


def test_a_claim_on_no_object_counts_against_the_precision_with_ground_only(scored):
    res, truth, oa, ob, area = scored
    before = score_pair(res, truth, oa, ob, area, area, min_confidence=0.5)
    kept = np.flatnonzero((res.a.label == KEPT) & (res.sizes_a >= 1.0))[0]
    oa2 = oa.copy()
    oa2[kept] = 0  # a ground patch (or a shadow) that A mapped and B did not
    res2 = replace(res, a=_force(res.a, kept, label=GONE, confidence=0.99))
    after = score_pair(res2, truth, oa2, ob, area, area, min_confidence=0.5)
    assert after.scope_counts(GONE) == before.scope_counts(GONE)  # the bar's: objects only
    good, claims, _, _ = after.scope_counts(GONE, with_ground=True)
    assert (good, claims) == (before.scope_counts(GONE)[0], before.scope_counts(GONE)[1] + 1)
    assert after.false_landmarks == before.false_landmarks + 1
    assert sum(after.ground_claimed.values()) == sum(before.ground_claimed.values()) + 1


def test_every_failure_gets_its_mechanism(scored):
    res, truth, oa, ob, area = scored
    where = truth.index()
    removed = truth.present_a & ~truth.present_b
    # a removed object kept by a counterpart that lies on the ground: a coincidence of place and size
    lost = next(i for i in np.flatnonzero(res.a.label == GONE) if removed[where[int(oa[i])]])
    ob2 = ob.copy()
    ob2[0] = 0
    res2 = replace(res, a=_force(res.a, lost, label=KEPT, evidence=BY_LANDMARK, counterpart=0))
    # a kept object claimed gone although B's landmark of it lies just beyond the gate (a position error)
    both = truth.present_a & truth.present_b
    kept = next(i for i in np.flatnonzero(res.a.label == KEPT)
                if both[where[int(oa[i])]] and np.count_nonzero(ob2 == oa[i]) == 1
                and np.count_nonzero(oa == oa[i]) == 1)
    shift = np.zeros_like(res.positions_a)
    j = int(np.flatnonzero(ob2 == oa[kept])[0])
    d = res.positions_a[kept] - res.positions_b[j]
    shift[kept] = 1.5 * res.tolerance_m * np.r_[d[:2] / max(np.linalg.norm(d[:2]), 1e-9), 0.0] - np.r_[d[:2], 0.0]
    res2 = replace(res2, positions_a=res.positions_a + shift,
                   a=_force(res2.a, kept, label=GONE, confidence=0.99))
    # a claim of a new object on the ground
    ground = np.flatnonzero((res.b.label == KEPT) & (res.sizes_b >= 1.0))
    ground = ground[(ground != 0) & (ground != j)][0]
    ob2[ground] = 0
    res2 = replace(res2, b=_force(res2.b, ground, label=NEW, confidence=0.99))
    found = classify_failures(res2, truth, oa, ob2, 0.5)
    by_object = {(f.change, f.what, f.object_id): f.mechanism for f in found}
    assert by_object[(GONE, MISSED, int(oa[lost]))] == "counterpart on the ground"
    assert by_object[(GONE, FALSE, int(oa[kept]))] == "counterpart beyond the gate"
    assert (NEW, NO_OBJECT, 0) in by_object and by_object[(NEW, NO_OBJECT, 0)] == "ground texture or shadow"
    # the counts agree with the score: every missed change and false claim of the scope is named once
    s = score_pair(res2, truth, oa, ob2, area, area, min_confidence=0.5)
    for change in (GONE, NEW):
        good, claims, hit, changed = s.scope_counts(change)
        assert sum(f.change == change and f.what == FALSE for f in found) == claims - good
        assert sum(f.change == change and f.what == MISSED for f in found) == changed - hit
