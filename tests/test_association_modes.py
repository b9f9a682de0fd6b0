"""Search modes beside the paper's (gravity consistency with yaw slices, spatial windows, a position prior, the
bounded solver): each gives exactly the straightforward per-window-pair reference's hypotheses, and each does
what it is for."""

import dataclasses

import numpy as np
import pytest

from sosmatch.plugin.association import search, search_reference
from sosmatch.plugin.association.consistency import pair_consistency, size_gate
from sosmatch.plugin.association.hypotheses import SearchMode
from sosmatch.plugin.association.kernels_graph import association_graph
from sosmatch.plugin.association.reference import differences
from sosmatch.plugin.association.rigid import rotation_angle_deg
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.association.windows import hilbert_order
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import AssociationParams, preset_params

P = preset_params("paper").association
GRAVITY = AssociationParams()  # the default: gravity consistency, yaw slices, bounded solver


@pytest.mark.parametrize("name,params,kw", [
    ("gravity, yaw slices", GRAVITY, {}),
    ("gravity, no slices", dataclasses.replace(GRAVITY, yaw_slice_deg=0.0), {}),
    ("gravity, clipper solver, wide slices", dataclasses.replace(GRAVITY, solver="clipper", yaw_slice_deg=20.0,
                                                                 gravity_tilt_deg=1.0), {}),
    ("distance, bounded solver", dataclasses.replace(P, solver="bounded"), {}),
    ("spatial windows", dataclasses.replace(GRAVITY, windows="spatial"), {}),
    ("spatial windows, paper test", dataclasses.replace(P, windows="spatial", window_length=30, window_stride=7), {}),
    ("position prior", dataclasses.replace(GRAVITY, position_prior_m=60.0), {"same_frame": True}),
    ("no sizes", dataclasses.replace(GRAVITY, window_length=25, window_stride=8), {"no_sizes": True}),
    ("dense maps", GRAVITY, {"dense": True}),
    # equal-area windows: each map its own window length and stride (the denser map's grown)
    ("A's windows 4 x B's", dataclasses.replace(GRAVITY, window_length=20, window_stride=5, window_factor_a=4), {}),
    ("B's windows 2 x A's, spatial", dataclasses.replace(GRAVITY, windows="spatial", window_length=30,
                                                          window_stride=7, window_factor_b=2), {}),
])
def test_mode_equals_reference(name, params, kw):
    if kw.get("dense"):
        s = survey_map_pair(160, seed=3, density_per_km2=10000, strip_width_m=30)
    else:
        s = survey_map_pair(150, seed=2, yaw_deg=0.0 if kw.get("same_frame") else None, tilt_deg=1.0)
    pb = s.points_b
    if kw.get("same_frame"):  # B expressed in A's frame, as two georeferenced maps are (up to a few metres)
        pb = s.points_b @ s.rotation.T + s.translation + [3.0, -2.0, 0.5]
    ha, hb = (None, None) if kw.get("no_sizes") else (s.sizes_a, s.sizes_b)
    fast = search(s.points_a, ha, pb, hb, params)
    ref = search_reference(s.points_a, ha, pb, hb, params)
    assert len(ref.accepted) > 0, name
    assert differences(fast, ref) == [], name


def test_gravity_mode_recovers_the_transform():
    s = survey_map_pair(400, seed=11, tilt_deg=1.5)
    res = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, GRAVITY)
    c = res.consensus
    assert c is not None
    assert rotation_angle_deg(c.transform.rotation, s.rotation) < 0.5
    truth = set(map(tuple, s.truth.tolist()))
    found = set(map(tuple, c.associations.tolist()))
    assert len(found - truth) <= 0.02 * len(found) and len(found & truth) >= 0.5 * len(truth)
    assert all(h.yaw_slice is not None for h in res.hypotheses)


def test_yaw_slices_never_form_a_mirror_image():
    # a flat map and its mirror image have every pairwise distance in common: the paper's test fills cores with
    # the mirrored set (rejected only after the solve, by the tilt), the yaw slices never form it
    rng = np.random.default_rng(4)
    pts = np.column_stack([rng.uniform(0, 300, 160), rng.uniform(0, 300, 160), rng.normal(0, 0.2, 160)])
    sizes = rng.uniform(1, 8, 160)
    mirrored = pts * [-1.0, 1.0, 1.0]
    paper = search(pts, sizes, mirrored, sizes, P)
    big = [h for h in paper.hypotheses if h.size > P.min_associations]
    assert big and not paper.accepted  # consistent mirrored sets, each rejected by the gravity check
    sliced = search(pts, sizes, mirrored, sizes, GRAVITY)
    assert not sliced.accepted
    assert max((h.size for h in sliced.hypotheses), default=0) < min(h.size for h in big)


def test_position_prior_keeps_only_nearby_candidates():
    s = survey_map_pair(200, seed=6, yaw_deg=0.0, tilt_deg=0.5)
    pb = s.points_b @ s.rotation.T + s.translation  # B in A's frame (georeferenced maps)
    near = search(s.points_a, s.sizes_a, pb + [4.0, 3.0, 0.0], s.sizes_b,
                  dataclasses.replace(GRAVITY, position_prior_m=30.0))
    assert near.best is not None
    assert np.linalg.norm(near.consensus.transform.translation[:2] - [-4.0, -3.0]) < 1.0
    # the frames disagree by more than the prior: no putative association survives, nothing is found
    far = search(s.points_a, s.sizes_a, pb + [200.0, 0.0, 0.0], s.sizes_b,
                 dataclasses.replace(GRAVITY, position_prior_m=30.0))
    assert far.best is None and far.hypotheses == []


def test_consistency_functions_match_the_graph_kernel():
    s = survey_map_pair(60, seed=9)
    rng = np.random.default_rng(0)
    pairs = np.column_stack([rng.integers(0, len(s.points_a), 80), rng.integers(0, len(s.points_b), 80)])
    pairs = np.unique(pairs, axis=0)
    for params in (P, GRAVITY):
        m = 1 if params.consistency == "gravity" else 0
        sm = SearchMode.of(params)
        rows, cols, c, s0, ns = association_graph(s.points_a, s.points_b, pairs[:, 0].copy(), pairs[:, 1].copy(), m,
                                                     sm.eps, sm.sigma, sm.tan_tilt, sm.eps_z, sm.sin_tilt, sm.nslices)
        iu, ju = np.triu_indices(len(pairs), 1)
        ok, mis, t0, tn = pair_consistency(s.points_a, s.points_b, pairs[iu], pairs[ju], params)
        assert set(zip(rows.tolist(), cols.tolist())) == set(zip(iu[ok].tolist(), ju[ok].tolist()))
        assert np.array_equal(np.sort(mis[ok]), np.sort(c))
        if m == 1:
            assert sorted(zip(t0[ok].tolist(), tn[ok].tolist())) == sorted(zip(s0.tolist(), ns.tolist()))
    assert size_gate(np.array([1.0, 1.0, np.nan]), np.array([1.1, 2.0, 3.0]), P).tolist() == [True, False, True]


def test_spatial_order_is_a_permutation_of_compact_patches():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1000, (2000, 3))
    order = hilbert_order(pts)
    assert sorted(order.tolist()) == list(range(2000))
    extent = [np.ptp(pts[order[s:s + 50], :2], axis=0).max() for s in range(0, 1950, 50)]
    assert np.median(extent) < 300  # a window of 50 of 2000 landmarks spread over 1 km x 1 km: a patch


def test_paper_preset_and_bad_modes():
    paper = preset_params("paper").association
    assert (paper.consistency, paper.windows, paper.position_prior_m, paper.solver) == ("distance", "id", 0.0,
                                                                                        "clipper")
    s = survey_map_pair(60, seed=1)
    for bad in ({"consistency": "angles"}, {"windows": "tiles"}, {"solver": "exact"}, {"yaw_slice_deg": -1.0}):
        with pytest.raises(InputError):
            search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, dataclasses.replace(P, **bad))
