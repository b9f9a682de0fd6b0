"""A map's own noise figures and the association tolerances derived from them."""

import dataclasses
import json

import numpy as np
import pytest

from sosmatch.database.map_loading import load_map, read_map_noise
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, project
from sosmatch.plugin.map_noise import (
    MapNoise,
    derived_association_params,
    first_search_params,
    measure_map_noise,
    replaced_settings,
)
from sosmatch.plugin.params import AssociationParams

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
NADIR = np.diag([1.0, -1.0, -1.0])


def noisy_map(pixel_sigma, size_sigma, seed=0, n_landmarks=60, views=10):
    rng = np.random.default_rng(seed)
    centers = np.stack([np.zeros(40), np.arange(40) * 3.0, np.full(40, 100.0)], 1)
    rots = np.repeat(NADIR[None], len(centers), 0)
    points = np.stack([rng.uniform(-20, 20, n_landmarks), rng.uniform(20, 100, n_landmarks), np.zeros(n_landmarks)], 1)
    obs, pix, cov = [], [], []
    for p in points:
        kf = np.flatnonzero(np.abs(centers[:, 1] - p[1]) < 30)[:views]
        uv = np.concatenate([project(CAM, NADIR, centers[k], p[None])[0] for k in kf])
        obs.append(kf)
        pix.append(uv + rng.normal(0, pixel_sigma, uv.shape))
        h = 10.0 * np.exp(rng.normal(0, size_sigma, len(kf)))  # 10 px: 2 m at 100 m
        cov.append(np.eye(2)[None] * (h**2)[:, None, None])
    return measure_map_noise(CAM, rots, centers, points, obs, pix, cov)


def test_measured_noise_follows_pixel_and_size_noise():
    quiet, loud = noisy_map(1.0, 0.05), noisy_map(4.0, 0.2)
    assert quiet.ground_resolution_m == pytest.approx(0.2, rel=0.01)  # 100 m / 500 px
    # median of |2-D normal| = sigma sqrt(2 ln 2) = 1.18 sigma px, x 0.2 m/px
    assert quiet.residual_m == pytest.approx(1.18 * 0.2, rel=0.15)
    assert loud.residual_m == pytest.approx(4 * quiet.residual_m, rel=0.2)
    assert quiet.size_log_std == pytest.approx(0.05, rel=0.25) and loud.size_log_std == pytest.approx(0.2, rel=0.25)
    assert MapNoise.from_dict(json.loads(json.dumps(loud.to_dict()))) == loud


def test_derived_tolerances_and_when_they_apply():
    base = AssociationParams(derive_from_maps=True)
    a = MapNoise(0.2, 0.9, 0.08, 300)
    b = MapNoise(0.2, 1.1, 0.09, 200)
    got = derived_association_params(base, a, b)
    assert got.affinity_sigma_m == pytest.approx(1.65) and got.distance_tolerance_m == pytest.approx(3.3)
    assert got.max_size_difference == pytest.approx(3.0 * np.hypot(0.08, 0.09), abs=1e-3)
    assert (got.window_length, got.min_associations) == (base.window_length, base.min_associations)
    # figures a map file may hold but the search's parameters do not allow: the widest tolerances it accepts
    # (they were refused by the parameter check, naming no file; a built AssociationParams passed that check)
    wild = derived_association_params(base, MapNoise(2.0, 600.0, 2.0, 10), b)
    assert (wild.distance_tolerance_m, wild.max_size_difference) == (1000.0, 1.0)
    tiny = MapNoise(0.01, 0.002, 1e-5, 10)  # sigma rounded to 0 cm (refused by the search), theta_r 0
    tight = derived_association_params(base, tiny, tiny)
    assert (tight.affinity_sigma_m, tight.distance_tolerance_m, tight.max_size_difference) == (0.01, 0.02, 0.01)
    # off, or a map without figures (a .sosmap file, an empty map): the configured values
    off = dataclasses.replace(base, derive_from_maps=False)
    assert derived_association_params(off, a, b) == off
    assert derived_association_params(base, a, None) == base
    assert derived_association_params(base, a, MapNoise(float("nan"), float("nan"), float("nan"), 0)) == base


def test_session_noise_is_read_from_run_json(tmp_path):
    from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map

    write_landmark_map(tmp_path / "landmarks.sosmap", LandmarkMap(np.zeros((3, 3)), np.ones(3, np.float32)))
    assert read_map_noise(tmp_path) is None and load_map(tmp_path).noise is None
    noise = MapNoise(0.2, 0.9, 0.08, 3)
    (tmp_path / "run.json").write_text(json.dumps({"noise": noise.to_dict()}))
    assert load_map(tmp_path).noise == noise
    # the session's own map file is the session (the ninth sweep: given as a file, its noise was unknown and the
    # configured tolerances found nothing where the session matched); a copy elsewhere has none
    assert load_map(tmp_path / "landmarks.sosmap").noise == noise and load_map(tmp_path / "landmarks.sosmap").kind \
        == "session"
    (tmp_path / "copy").mkdir()
    (tmp_path / "copy" / "m.sosmap").write_bytes((tmp_path / "landmarks.sosmap").read_bytes())
    assert load_map(tmp_path / "copy" / "m.sosmap").noise is None  # a map file written before they travelled
    # figures no map can have (an older version's, or edited by hand): unknown, said with the file's name
    (tmp_path / "run.json").write_text(json.dumps({"noise": MapNoise(0.2, 1e6, 0.08, 3).to_dict()}))
    assert load_map(tmp_path).noise is None
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(InputError, match="run.json"):
        load_map(tmp_path)


def test_first_search_tolerances_are_the_tighter_ones():
    configured = AssociationParams(derive_from_maps=True)
    looser = derived_association_params(configured, MapNoise(0.2, 0.9, 0.08, 300), MapNoise(0.2, 1.1, 0.09, 200))
    first = first_search_params(configured, looser)
    assert first is not None
    assert (first.distance_tolerance_m, first.affinity_sigma_m, first.max_size_difference) == (
        configured.distance_tolerance_m, configured.affinity_sigma_m, configured.max_size_difference)
    # mixed: a tighter derived size gate is kept, a looser eps is not
    mixed = dataclasses.replace(looser, max_size_difference=0.1)
    assert first_search_params(configured, mixed).max_size_difference == 0.1
    # nowhere looser (derivation off, or quiet maps): one search
    assert first_search_params(configured, configured) is None
    quiet = dataclasses.replace(configured, distance_tolerance_m=1.0, affinity_sigma_m=0.5, max_size_difference=0.1)
    assert first_search_params(configured, quiet) is None


def _answer_in_two_steps(first_size_gate: float | None = None):
    from sosmatch.plugin.association.synthetic import survey_map_pair
    from sosmatch.plugin.match_answer import match_maps
    from sosmatch.plugin.params import Params

    s = survey_map_pair(300, seed=4, noise_m=0.3, size_noise=0.05, tilt_deg=1.0)
    loose = dataclasses.replace(Params().association, distance_tolerance_m=4.0, affinity_sigma_m=2.0,
                                max_size_difference=0.4)
    params = dataclasses.replace(Params(), association=loose)
    first = first_search_params(Params().association, loose)
    if first_size_gate is not None:
        first = dataclasses.replace(first, max_size_difference=first_size_gate)
    two = match_maps(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params, first_try=first)
    one = match_maps(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params)
    return s, two, one


def test_two_step_search_stops_at_the_first_when_it_is_verified():
    s, two, one = _answer_in_two_steps()
    assert (two.tolerances, one.tolerances) == ("first", "configured")
    assert two.accepted and one.accepted
    # the first search's tolerances make fewer pairs; the answer is verified with the derived gate, as one search's
    assert two.search.timings["consistent_pairs"] < one.search.timings["consistent_pairs"]
    assert two.verification.best.transform.rotation == pytest.approx(one.verification.best.transform.rotation,
                                                                     abs=1e-2)
    truth = set(map(tuple, s.truth.tolist()))
    got = set(map(tuple, two.associations.tolist()))
    assert len(got & truth) >= 0.9 * len(set(map(tuple, one.associations.tolist())) & truth)


def test_two_step_search_falls_back_to_the_derived_tolerances():
    # a first search that cannot find anything (a size gate no two landmarks pass): the derived search answers,
    # exactly as one search does
    _, two, one = _answer_in_two_steps(first_size_gate=0.0)
    assert two.tolerances == "derived" and one.accepted
    assert two.accepted and np.array_equal(two.associations, one.associations)
    assert two.search.timings["consistent_pairs"] == one.search.timings["consistent_pairs"]


def test_a_chosen_tolerance_the_derivation_replaces_is_named():
    """rev56 D8: a tolerance the user set and the maps' derivation replaced went without a word. Named (looser:
    not used; tighter: the first search only), unless not chosen, or the derivation itself was chosen."""
    used = dataclasses.replace(AssociationParams(), distance_tolerance_m=3.22, affinity_sigma_m=1.61)
    looser = dataclasses.replace(AssociationParams(), distance_tolerance_m=5.0)
    said = replaced_settings(looser, used, {"association.distance_tolerance_m"})
    assert said is not None and said.startswith("association.distance_tolerance_m=5 replaced by 3.22 derived")
    assert "affinity_sigma_m" not in said and said.endswith("set association.derive_from_maps=false to keep yours")
    tighter = dataclasses.replace(AssociationParams(), distance_tolerance_m=1.0)
    assert "=1 searched first, then 3.22" in replaced_settings(tighter, used, {"association.distance_tolerance_m"})
    assert replaced_settings(looser, used, {"association.seed"}) is None
    assert replaced_settings(looser, used, {"association.distance_tolerance_m", "association.derive_from_maps"}) is None
