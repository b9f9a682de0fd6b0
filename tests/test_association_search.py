"""Windowed search: same hypotheses as the straightforward computation, the transform recovered, gravity check,
degenerate maps."""

import dataclasses

import numpy as np
import pytest

from sosmatch.plugin.association import make_windows, putative_pairs, search, search_reference, size_ratio, size_score
from sosmatch.plugin.association.reference import differences
from sosmatch.plugin.association.rigid import rotation_angle_deg, rotation_from_rpy_deg
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import AssociationParams, preset_params

P = preset_params("paper").association  # the paper's method; tests of the other modes: test_association_modes


def _assert_same(fast, ref):
    assert differences(fast, ref) == []


@pytest.mark.parametrize("seed,n,params", [
    (1, 180, P),
    (1, 180, AssociationParams()),
    (2, 150, dataclasses.replace(P, window_length=30, window_stride=7, min_associations=4)),
    (4, 120, dataclasses.replace(P, min_associations=2)),
    (2, 150, dataclasses.replace(P, window_length=25, window_stride=5, window_factor_b=3)),
])
def test_fast_search_equals_reference(seed, n, params):
    s = survey_map_pair(n, seed=seed)
    fast = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params, workers=1)
    ref = search_reference(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params)
    assert len(ref.accepted) > 0
    _assert_same(fast, ref)


def test_fast_search_equals_reference_without_sizes_and_with_two_workers():
    s = survey_map_pair(100, seed=7)
    params = dataclasses.replace(P, window_length=25, window_stride=8)
    fast = search(s.points_a, None, s.points_b, None, params, workers=2)
    ref = search_reference(s.points_a, None, s.points_b, None, params)
    _assert_same(fast, ref)


def test_transform_recovered_and_associations_correct():
    s = survey_map_pair(400, seed=11)
    res = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, P)
    assert res.consensus is not None and res.best is not None
    c = res.consensus
    assert rotation_angle_deg(c.transform.rotation, s.rotation) < 0.5
    assert np.linalg.norm(c.transform.translation - s.translation) < 2.0
    truth = set(map(tuple, s.truth.tolist()))
    found = set(map(tuple, c.associations.tolist()))
    assert len(found - truth) <= 0.02 * len(found)
    assert len(found & truth) >= 0.5 * len(truth)
    for k in res.accepted:  # every accepted window pair agrees with the truth
        h = res.hypotheses[k]
        assert rotation_angle_deg(h.transform.rotation, s.rotation) < 22.5


def test_gravity_check_rejects_tilted_transforms():
    for tilt, accepted in ((10.0, True), (35.0, False)):
        s = survey_map_pair(150, seed=5, tilt_deg=tilt)
        res = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, P)
        big = [h for h in res.hypotheses if h.size > P.min_associations and h.transform is not None]
        assert big, "the solver should still find the consistent sets"
        if accepted:
            assert res.best is not None
        else:
            assert res.best is None and not res.accepted
            assert all(h.tilt_deg > P.max_gravity_angle_deg for h in big)
            assert all(abs(h.tilt_deg - tilt) < 10.0 for h in big)


def test_rotated_and_permuted_maps_same_result():
    s = survey_map_pair(150, seed=8)
    res = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, P)
    # rotating and shifting map B changes only the transform
    r = rotation_from_rpy_deg(0.0, 0.0, 77.0)
    pb2 = s.points_b @ r.T + [1000.0, -300.0, 5.0]
    res2 = search(s.points_a, s.sizes_a, pb2, s.sizes_b, P)
    assert [h.associations.tolist() for h in res.hypotheses] == [h.associations.tolist() for h in res2.hypotheses]
    assert rotation_angle_deg(res2.consensus.transform.rotation, res.consensus.transform.rotation @ r.T) < 1e-6


def test_windows_and_size_gate():
    assert make_windows(120, 50, 10).tolist()[-1] == [70, 120]
    assert make_windows(125, 50, 10).tolist()[-2:] == [[70, 120], [75, 125]]
    assert make_windows(30, 50, 10).tolist() == [[0, 30]]
    r = size_ratio(np.array([1.0, 2.0, np.nan]), np.array([1.1, 3.0, 4.0]))
    assert r[0] == pytest.approx(2 * 0.1 / 2.1) and r[2] == 0.0
    assert size_score(np.array([0.0, 0.1, 0.2, 0.3]), 0.2).tolist() == pytest.approx([2.0, 1.0, 0.0, 0.0])
    pairs, w = putative_pairs(np.array([1.0, 5.0]), np.array([1.05, 9.0, 5.2]), np.arange(2), np.arange(3), 0.2)
    assert pairs.tolist() == [[0, 0], [1, 2]] and np.all(w > 1.5)


def test_degenerate_maps():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 100, (40, 3))
    with pytest.raises(InputError, match="at least 3"):
        search(pts[:2], None, pts, None, P)
    bad = pts.copy()
    bad[5, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        search(pts, None, bad, None, P)
    with pytest.raises(InputError, match="negative"):
        search(pts, -np.ones(40), pts, None, P)
    # colinear landmarks: consistent sets exist but no transform is determined, nothing is accepted
    line = np.outer(np.arange(40.0), [3.0, 1.0, 0.0])
    res = search(line, None, line + 5.0, None, P)
    assert res.best is None and all(h.transform is None for h in res.hypotheses)
    assert any(h.size > P.min_associations for h in res.hypotheses)
    # duplicated landmarks: no crash, the copy is recovered
    dup = np.vstack([pts, pts[:10]])
    res = search(dup, None, dup + [10.0, 0, 0], None, P)
    assert res.best is not None
    assert np.allclose(res.consensus.transform.translation, [-10.0, 0, 0], atol=1e-6)
    # nothing in common: an empty result, not an error
    far = rng.uniform(0, 5000, (60, 3))
    res = search(pts, np.full(40, 2.0), far, np.full(60, 7.0), P)
    assert res.best is None and res.hypotheses == []


def test_dense_maps_take_the_direct_path_with_the_same_result():
    # landmarks far denser than the window span: the shared join prunes little, window pairs are computed directly
    s = survey_map_pair(150, seed=3, density_per_km2=10000, strip_width_m=30)
    fast = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, P, workers=1)
    assert fast.timings.get("direct_blocks", 0) >= 1
    ref = search_reference(s.points_a, s.sizes_a, s.points_b, s.sizes_b, P)
    assert len(ref.accepted) > 0
    _assert_same(fast, ref)


def test_dense_window_pairs_in_threads_give_the_same_hypotheses(monkeypatch):
    """Where cores are idle the direct window pairs run in one share of the tasks per thread
    (`windowed_search._direct_in_threads`); the joined results are those of one thread, bit for bit."""
    from sosmatch.plugin.association import windowed_search

    s = survey_map_pair(300, seed=3, density_per_km2=10000, strip_width_m=30)
    params = dataclasses.replace(AssociationParams(), max_size_difference=0.4, distance_tolerance_m=3.0)
    monkeypatch.setattr(windowed_search, "core_free", lambda threads: False)
    one = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params)
    calls = []
    monkeypatch.setattr(windowed_search, "core_free", lambda threads: calls.append(threads) or True)
    monkeypatch.setattr(windowed_search, "thread_count", lambda: 3)
    monkeypatch.setattr(windowed_search, "DIRECT_THREAD_MIN", 4)
    threaded = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params)
    assert calls and max(calls) == 3 and one.timings["direct_blocks"] >= 1
    assert len(one.hypotheses) > 20
    _assert_same(threaded, one)


@pytest.mark.parametrize("space_extra,k", [(0, 2), (0, 3), (0, 6), (-600, 1), (2_000_000_000, 3)])
def test_peel_on_association_ids_equals_compact_then_peel(space_extra, k):
    """`peeled_ids` (degrees on the ids, only survivors renumbered; or the sort path for a huge id space) leaves
    the pairs `compact_ids` + `peel_pairs` leave, with the ids of their associations in the same order."""
    from sosmatch.plugin.association.kernels_peel import compact_ids, peel_pairs, peeled_ids

    rng = np.random.default_rng(k)
    # a dense core (survives) in a sparse cloud (peeled), and a tail hanging off the core listed from the core
    # outwards: at k = 2 each pass removes one edge of it (more passes than the table path makes: its fallback)
    core = rng.choice(5000, 40, replace=False)
    v1 = [core[rng.integers(0, 40, 600)]]
    v2 = [core[rng.integers(0, 40, 600)]]
    v1.append(rng.integers(0, 5000, 3000))
    v2.append(rng.integers(0, 5000, 3000))
    chain = np.concatenate([[core[0]], np.arange(5000, 5400)])
    v1.append(chain[:-1])
    v2.append(chain[1:])
    v1, v2 = np.concatenate(v1), np.concatenate(v2)
    keep = v1 != v2
    v1, v2 = v1[keep].astype(np.int64), v2[keep].astype(np.int64)
    space = 6000 + space_extra
    ids, e1, e2 = compact_ids(v1, v2, space)
    want = np.flatnonzero(peel_pairs(len(ids), e1, e2, k))
    got_ids, f1, f2, sel = peeled_ids(v1, v2, space, k)
    assert np.array_equal(sel, want) and len(sel) > 0
    assert np.array_equal(got_ids, np.unique(np.concatenate([v1[want], v2[want]])))
    assert np.array_equal(got_ids[f1], v1[sel]) and np.array_equal(got_ids[f2], v2[sel])


def test_a_consensus_that_holds_no_more_than_theta_s_is_no_answer():
    """Two accepted window hypotheses of 8 associations each whose transforms agree (within theta_eps on the larger
    one's landmarks) but whose associations, refitted together, leave fewer than theta_S within theta_eps: the
    seventh new-user sweep's `match --no-verify` of two different worlds answered such a consensus of 5 (theta_S
    7) as a match. The consensus must hold more than theta_S itself (spec 2.6, |S| > theta_S), the bar each
    hypothesis met: exactly theta_S was accepted until rev42."""
    from sosmatch.plugin.association.hypotheses import WindowHypothesis, consensus_transform
    from sosmatch.plugin.association.rigid import Transform

    rng = np.random.default_rng(3)
    params = dataclasses.replace(P, min_associations=7, distance_tolerance_m=2.0)
    pa = rng.uniform(0, 100, (16, 3))
    identity = Transform(np.eye(3), np.zeros(3), 1.0)
    pairs = [np.column_stack([np.arange(k, k + 8)] * 2) for k in (0, 8)]

    def hyp(assoc):
        return WindowHypothesis((0, 16), (0, 16), 8, 8, assoc, 8.0, identity, 0.0, 0.0, 0.0, True)

    def b_with(fitting: int) -> np.ndarray:  # B: the first `fitting` landmarks on A's, the others 3-6 m off
        pb = pa.copy()
        pb[fitting:] += rng.choice([-1, 1], (16 - fitting, 3)) * rng.uniform(3.0, 6.0, (16 - fitting, 3))
        return pb

    kept = consensus_transform(pa, b_with(8), [hyp(pairs[0]), hyp(pairs[1])], [0, 1], params)
    assert kept is not None and len(kept.associations) == 8 and kept.accepted
    few = consensus_transform(pa, b_with(5), [hyp(pairs[0]), hyp(pairs[1])], [0, 1], params)
    assert few is not None and len(few.associations) == 5 and not few.accepted
    exact = consensus_transform(pa, b_with(7), [hyp(pairs[0]), hyp(pairs[1])], [0, 1], params)
    assert exact is not None and len(exact.associations) == 7 and not exact.accepted


def groups_by_definition(points_b, hyps, ranked, eps, max_turn_deg):
    """The consensus' groups as `consensus_transform` defines them, one head at a time with array operations: each
    hypothesis (in rank order) joins the first group whose head maps the head's B landmarks within eps of where
    the head maps them, with rotations less than max_turn_deg apart."""
    rot = np.stack([hyps[k].transform.scale * hyps[k].transform.rotation for k in ranked])
    tr = np.stack([hyps[k].transform.translation for k in ranked])
    pure = np.stack([hyps[k].transform.rotation for k in ranked])
    group_of = np.full(len(ranked), -1)
    ng = 0
    for x in range(len(ranked)):
        if group_of[x] >= 0:
            continue
        group_of[x] = ng
        rest = np.flatnonzero(group_of < 0)
        rest = rest[rest > x]
        if len(rest):
            xb = points_b[hyps[ranked[x]].associations[:, 1]]
            mine = xb @ rot[x].T + tr[x]
            theirs = np.einsum("kij,nj->kni", rot[rest], xb) + tr[rest][:, None, :]
            near = np.max(np.linalg.norm(theirs - mine[None], axis=2), axis=1) <= eps
            turn = np.atleast_1d(rotation_angle_deg(np.broadcast_to(pure[x], pure[rest].shape), pure[rest]))
            group_of[rest[near & (turn < max_turn_deg)]] = ng
        ng += 1
    return group_of.tolist()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_consensus_groups_equal_their_definition(seed):
    """The compiled grouping (`kernels_fit.agreeing_groups`, one pass with the cheap test first) forms the groups
    the per-head statement forms, on hypotheses of true, nearby and chance transforms."""
    from sosmatch.plugin.association.hypotheses import WindowHypothesis
    from sosmatch.plugin.association.kernels_fit import agreeing_groups
    from sosmatch.plugin.association.rigid import Transform

    rng = np.random.default_rng(seed)
    pb = rng.uniform(0, 300, (400, 3)) * [1, 1, 0.1]
    hyps = []
    for _ in range(300):
        kind = rng.integers(3)  # the truth, a transform a little off it, or anywhere at any yaw
        yaw = {0: 0.0, 1: rng.normal(0, 10), 2: rng.uniform(-180, 180)}[kind]
        t = {0: np.zeros(3), 1: rng.normal(0, 2, 3), 2: rng.uniform(-300, 300, 3)}[kind]
        rot = rotation_from_rpy_deg(rng.normal(0, 1), rng.normal(0, 1), yaw)
        scale = 1.0 if seed % 2 == 0 else float(rng.uniform(0.95, 1.05))
        b = np.sort(rng.choice(len(pb), rng.integers(3, 12), replace=False))
        assoc = np.column_stack([b, b])
        hyps.append(WindowHypothesis((0, 1), (0, 1), 0, 0, assoc, float(len(b)), Transform(rot, t, scale), 0.0, 0.0,
                                     0.0, True))
    ranked = list(range(len(hyps)))
    eps, turn = 3.0, 22.5
    want = groups_by_definition(pb, hyps, ranked, eps, turn)
    off = np.concatenate([[0], np.cumsum([h.size for h in hyps])]).astype(np.int64)
    got = agreeing_groups(np.stack([h.transform.scale * h.transform.rotation for h in hyps]),
                          np.stack([h.transform.translation for h in hyps]),
                          np.stack([h.transform.rotation for h in hyps]), off,
                          pb[np.concatenate([h.associations[:, 1] for h in hyps])], eps, turn)
    assert got.tolist() == want
    assert 1 < max(want) + 1 < len(hyps)  # some groups hold several hypotheses, not all one
