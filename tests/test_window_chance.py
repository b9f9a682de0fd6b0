"""The chance model of window pairs and the windows derived from it (`plugin.association.window_chance`)."""

import dataclasses

import numpy as np
import pytest

from sosmatch.plugin.association import search
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.association.window_chance import (
    MAX_CHANCE_PER_TRANSFORM,
    area_factors,
    derived_windows,
    size_pass_fraction,
    window_chance,
)
from sosmatch.plugin.map_noise import (
    MapNoise,
    derived_association_params,
    derived_search_params,
    first_search_params,
)
from sosmatch.plugin.params import AssociationParams


def _largest_upright(res, params):
    return max((int(h.size) for h in res.hypotheses
                if h.transform is not None and h.tilt_deg <= params.max_gravity_angle_deg), default=0)


@pytest.mark.parametrize("density", [300.0, 3000.0])
def test_model_bounds_the_largest_chance_set_of_the_search(density):
    # two maps of different worlds: every consistent set the search finds between them is chance
    a = survey_map_pair(400, seed=3, density_per_km2=density)
    b = survey_map_pair(400, seed=11, density_per_km2=density)
    params = AssociationParams()
    chance = window_chance(a.points_a, a.sizes_a, b.points_b, b.sizes_b, params)
    assert chance.per_transform <= MAX_CHANCE_PER_TRANSFORM
    found = _largest_upright(search(a.points_a, a.sizes_a, b.points_b, b.sizes_b,
                                    dataclasses.replace(params, min_associations=2)), params)
    assert chance.largest - 3 <= found <= chance.largest


@pytest.mark.parametrize("density", [300.0, 3000.0])
def test_model_with_a_prior_bounds_the_largest_chance_set_of_the_search_with_it(density):
    # maps of different worlds laid over one ground in one frame: a search with a position prior looks at far
    # fewer transforms and window pairs, and finds chance sets no larger than the model under the prior says
    a = survey_map_pair(400, seed=4, density_per_km2=density)
    b = survey_map_pair(400, seed=12, density_per_km2=density)
    pb = b.points_b - b.points_b.mean(axis=0) + a.points_a.mean(axis=0)
    params = AssociationParams()
    everywhere = window_chance(a.points_a, a.sizes_a, pb, b.sizes_b, params)
    near = window_chance(a.points_a, a.sizes_a, pb, b.sizes_b, params, prior_m=50.0)
    assert near.trials < everywhere.trials / 10 and near.largest < everywhere.largest
    found = _largest_upright(search(a.points_a, a.sizes_a, pb, b.sizes_b,
                                    dataclasses.replace(params, min_associations=2, position_prior_m=50.0)), params)
    assert near.largest - 3 <= found <= near.largest
    # a map that lies farther away than the prior shares no window pair with the other: one trial cell left
    far = window_chance(a.points_a, a.sizes_a, pb + np.array([1e4, 0.0, 0.0]), b.sizes_b, params, prior_m=50.0)
    assert far.trials < near.trials / 10


def test_grown_windows_near_the_georeference_get_theta_s_from_the_prior():
    # the sparse pair of the wider-window test below: grown windows, theta_S over the configured one
    s = survey_map_pair(800, seed=3, density_per_km2=3000.0, missing_b=0.9, added_b=9.0, noise_m=0.4)
    arrays = (s.points_a, s.sizes_a, s.points_b @ s.rotation.T + s.translation, s.sizes_b)
    got = derived_windows(*arrays, AssociationParams())
    assert got.derived is not None and got.params.min_associations > AssociationParams().min_associations
    near = got.near_params
    assert near is not None and got.near.trials < got.derived.trials / 10
    assert (near.window_length, near.window_stride) == (got.params.window_length, got.params.window_stride)
    assert AssociationParams().min_associations <= near.min_associations == max(6, got.near.largest) \
        < got.params.min_associations
    assert got.to_dict()["near_georeference"]["min_associations"] == near.min_associations
    off = derived_windows(*arrays, AssociationParams(georeference_prior_m=0.0))
    assert off.near_params is None and off.to_dict()["near_georeference"] is None
    # windows that are not grown keep the configured theta_S near the georeference too
    dense = survey_map_pair(600, seed=5, density_per_km2=30000.0)
    kept = derived_windows(dense.points_a, dense.sizes_a, dense.points_b, dense.sizes_b, AssociationParams())
    assert kept.derived is None and kept.near_params is None


def test_chance_grows_with_the_window_and_the_tolerance():
    s = survey_map_pair(400, seed=3, density_per_km2=3000.0)
    params = AssociationParams()
    args = (s.points_a, s.sizes_a, s.points_b, s.sizes_b)
    short, long = window_chance(*args, params, 50), window_chance(*args, params, 200)
    assert long.per_transform > 2 * short.per_transform and long.largest > short.largest
    loose = window_chance(*args, dataclasses.replace(params, distance_tolerance_m=4.0), 50)
    assert loose.per_transform > 3 * short.per_transform and loose.largest > short.largest
    assert size_pass_fraction(s.sizes_a, s.sizes_b, 0.2) < size_pass_fraction(s.sizes_a, s.sizes_b, 0.4)
    assert size_pass_fraction(None, s.sizes_b, 0.2) == 1.0


def test_sparse_maps_get_longer_windows_dense_ones_keep_the_configured():
    params = AssociationParams()
    sparse = survey_map_pair(600, seed=5, density_per_km2=300.0)
    got = derived_windows(sparse.points_a, sparse.sizes_a, sparse.points_b, sparse.sizes_b, params)
    assert got.derived is not None and got.params.window_length > params.window_length
    assert got.derived.per_transform <= MAX_CHANCE_PER_TRANSFORM
    assert got.params.min_associations >= max(params.min_associations, got.derived.largest)
    assert got.params.window_stride == got.params.window_length // 2
    doc = got.to_dict()
    assert doc["derived"] and doc["derived_chance"]["length"] == got.params.window_length
    dense = survey_map_pair(600, seed=5, density_per_km2=30000.0)
    kept = derived_windows(dense.points_a, dense.sizes_a, dense.points_b, dense.sizes_b, params)
    assert kept.derived is None and kept.params == params
    assert kept.wider_params is None and kept.to_dict()["wider"] is None  # kept windows: no wider search
    assert kept.configured.per_transform > MAX_CHANCE_PER_TRANSFORM / 2


def test_derivation_is_recorded_and_needs_both_maps_noise():
    s = survey_map_pair(600, seed=5, density_per_km2=300.0)
    arrays = (s.points_a, s.sizes_a, s.points_b, s.sizes_b)
    base = AssociationParams(derive_from_maps=True)
    noise = MapNoise(0.2, 0.7, 0.06, 600)
    got = derived_search_params(base, noise, noise, *arrays)
    assert got.params.distance_tolerance_m == pytest.approx(3 * 0.7, abs=0.01)
    assert got.record["windows"]["window_length"] == got.params.window_length
    assert got.record["tolerances"]["distance_tolerance_m"] == got.params.distance_tolerance_m
    tolerances = derived_association_params(base, noise, noise)
    assert got.wider_try == derived_windows(*arrays, tolerances).wider_params  # the last search, recorded too
    assert got.record["windows"]["wider"] == derived_windows(*arrays, tolerances).to_dict()["wider"]
    for off in (derived_search_params(base, noise, None, *arrays),
                derived_search_params(dataclasses.replace(base, derive_from_maps=False), noise, noise, *arrays)):
        assert off.params.window_length == base.window_length and off.record["windows"] == "configured"
        assert off.first_try is None and off.wider_try is None  # nothing derived: one search
    assert np.isfinite(got.record["windows"]["configured_chance"]["per_transform"])


def test_first_search_keeps_the_configured_windows():
    # the derived longer windows are searched only when the configured ones are refused (as looser tolerances)
    s = survey_map_pair(600, seed=5, density_per_km2=300.0)
    base = AssociationParams(derive_from_maps=True)
    noise = MapNoise(0.2, 0.5, 0.05, 600)
    derivation = derived_search_params(base, noise, noise, s.points_a, s.sizes_a, s.points_b, s.sizes_b)
    got = derivation.params
    assert got.window_length > base.window_length
    first = first_search_params(base, got)
    assert derivation.first_try == first  # the one first search every consumer runs
    assert (first.window_length, first.window_stride, first.min_associations) == (
        base.window_length, base.window_stride, base.min_associations)
    assert first.distance_tolerance_m == min(base.distance_tolerance_m, got.distance_tolerance_m)


def test_size_gate_fraction_is_the_mean_of_the_gate_over_all_pairs():
    """The compiled count gives the fraction of `gates.size_ratio` over the sampled pairs exactly, unknown (NaN),
    zero and infinite sizes included."""
    from sosmatch.plugin.association.gates import size_ratio

    rng = np.random.default_rng(0)
    for n_a, n_b in ((7, 900), (1000, 300)):
        a, b = rng.uniform(0, 5, n_a), rng.uniform(0, 5, n_b)
        a[::11], b[::13], a[::17], b[::19] = np.nan, 0.0, np.inf, np.inf

        def sample(h):
            return h if len(h) <= 800 else h[np.linspace(0, len(h) - 1, 800).astype(np.int64)]

        for theta in (0.0, 0.2, 0.45):
            expected = float(np.mean(size_ratio(sample(a)[:, None], sample(b)[None, :]) <= theta))
            assert size_pass_fraction(a, b, theta) == expected


def _winter_like(seed):
    """A dense summer-like map A and a map B of a third of its density of which a third is common (a winter map:
    most summer objects lost, as many segmented of its own)."""
    return survey_map_pair(600, seed=seed, density_per_km2=10000.0, missing_b=0.9, added_b=2.0, noise_m=0.3)


def test_equal_area_factors_grow_only_the_denser_map():
    s = _winter_like(4)
    params = AssociationParams()
    got = derived_windows(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params).params
    fa, fb = got.window_factor_a, got.window_factor_b
    assert fa >= 2 and fb == 1
    # the denser map's window spans no more ground than the sparser map's, and twice it would
    xa, xb = s.points_a[:, :2], s.points_b[:, :2]
    assert area_factors(xa, xb, 50) == (fa, fb) and area_factors(xb, xa, 50) == (fb, fa)  # either map order
    chance = window_chance(s.points_a, s.sizes_a, s.points_b, s.sizes_b, got)
    assert chance.lengths == (50 * fa, 50) and chance.window_area_m2[0] <= chance.window_area_m2[1]
    assert window_chance(s.points_a, s.sizes_a, s.points_b, s.sizes_b,
                         dataclasses.replace(got, window_factor_a=2 * fa)).window_area_m2[0] > chance.window_area_m2[1]
    # maps of one density keep the paper's windows; so does the rule switched off (the configured factors stay)
    same = survey_map_pair(600, seed=4, density_per_km2=10000.0)
    assert area_factors(same.points_a[:, :2], same.points_b[:, :2], 50) == (1, 1)
    off = dataclasses.replace(params, equal_area_windows=False, window_factor_b=3)
    kept = derived_windows(s.points_a, s.sizes_a, s.points_b, s.sizes_b, off).params
    assert (kept.window_factor_a, kept.window_factor_b) == (1, 3)
    doc = derived_windows(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params).to_dict()
    assert doc["window_factors"] == [fa, fb] and doc["configured_chance"]["lengths"] == [50 * fa, 50]


@pytest.mark.parametrize("seed", [4, 5])
def test_equal_area_windows_hold_the_true_set_that_equal_length_windows_cannot(seed):
    # B has a third of A's density: a 50-landmark window of A covers a third of B's, so no window pair of equal
    # length holds more than theta_S of the common objects (nothing true is accepted, with or without the longer
    # windows the chance rule derives); equal-area windows hold them and find the true transform
    s = _winter_like(seed)
    truth = set(map(tuple, s.truth.tolist()))

    def true_accepted(res):
        return [h for h in (res.hypotheses[i] for i in res.accepted)
                if sum(tuple(x) in truth for x in h.associations.tolist()) > len(h.associations) / 2]

    for equal_area in (False, True):
        params = derived_windows(s.points_a, s.sizes_a, s.points_b, s.sizes_b,
                                 AssociationParams(equal_area_windows=equal_area)).params
        res = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params)
        if not equal_area:
            assert params.window_factor_a == params.window_factor_b == 1 and true_accepted(res) == []
        else:
            assert params.window_factor_a > 1 and len(true_accepted(res)) >= 3
            best = res.hypotheses[res.best]
            assert best in true_accepted(res)
            # the window's transform (9-13 associations, 0.3 m noise) horizontally where the truth puts B
            assert np.linalg.norm((best.transform.translation - s.translation)[:2]) < 2.0


def test_first_search_keeps_the_equal_area_factors():
    s = _winter_like(4)
    base = AssociationParams(derive_from_maps=True)
    noise = MapNoise(0.2, 0.5, 0.05, 600)
    got = derived_search_params(base, noise, noise, s.points_a, s.sizes_a, s.points_b, s.sizes_b)
    assert got.params.window_factor_a > 1
    first = got.first_try if got.first_try is not None else got.params
    assert (first.window_factor_a, first.window_factor_b) == (got.params.window_factor_a, 1)
    assert got.record["windows"]["window_factors"] == [got.params.window_factor_a, 1]


def test_a_refused_search_at_grown_windows_searches_once_more_at_the_next_doubled_window():
    # a map pair sparse for its tolerance (lambda ~0.7 at 100 landmarks) whose landmarks rarely repeat (B keeps a
    # tenth of A's objects and segments nine times as many of its own): the grown windows hold no true set over
    # their theta_S, the next doubled window does (window_chance module doc, "Wider windows")
    from sosmatch.plugin.match_answer import match_maps
    from sosmatch.plugin.params import Params

    s = survey_map_pair(800, seed=3, density_per_km2=3000.0, missing_b=0.9, added_b=9.0, noise_m=0.4)
    arrays = (s.points_a, s.sizes_a, s.points_b, s.sizes_b)
    got = derived_windows(*arrays, AssociationParams())
    assert got.derived is not None and got.derived.per_transform <= MAX_CHANCE_PER_TRANSFORM
    wider = got.wider_params
    assert wider.window_length == 2 * got.params.window_length and wider.window_stride == wider.window_length // 2
    assert got.wider.per_transform > MAX_CHANCE_PER_TRANSFORM  # the grown window was the longest under the bound
    assert wider.min_associations >= max(got.params.min_associations, got.wider.largest)
    assert got.to_dict()["wider"]["window_length"] == wider.window_length
    params = dataclasses.replace(Params(), association=got.params)
    assert not match_maps(*arrays, params).accepted
    ans = match_maps(*arrays, params, wider_try=wider)
    assert ans.accepted and ans.tolerances == "wider" and ans.searched.window_length == wider.window_length
    c = s.points_b.mean(axis=0)
    t = ans.transform
    assert np.linalg.norm((s.rotation @ c + s.translation) - (t.scale * t.rotation @ c + t.translation)) < 2.0
