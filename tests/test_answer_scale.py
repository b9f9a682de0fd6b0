"""The answer's scale and heights (nu49): a map matched against a scaled or upside-down copy of itself.

A rigid answer between maps whose scales differ is flagged imprecise when the scale its pairs show moves B's far
landmarks beyond the gate (`answer_uncertainty.scale_check`); with `association.transform = "similarity"` the
verification fits the scale and every consumer reads it; heights that anti-correlate (one map's z axis pointing
down) are flagged (`answer_uncertainty.height_flip`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.match_answer import match_maps
from sosmatch.plugin.params import Params
from sosmatch.plugin.refinement import yaw_matrix

TURN = yaw_matrix(np.radians(20.0))
SHIFT = np.array([30.0, 40.0, 0.0])


@pytest.fixture(scope="module")
def map_a() -> tuple[np.ndarray, np.ndarray]:
    """A survey-like map of ~300 landmarks over ~320 m (nu49's world 7 map: 274 over 300 m)."""
    s = survey_map_pair(274, seed=21, density_per_km2=3000.0)
    return s.points_a, s.sizes_a


def _copy(points: np.ndarray, scale: float = 1.0, flip: bool = False) -> np.ndarray:
    """The map re-observed (0.4 m noise), turned 20 deg, moved (30, 40) and scaled; heights upside down if asked."""
    noisy = points + np.random.default_rng(3).normal(0.0, 0.4, points.shape)
    b = scale * noisy @ TURN.T + SHIFT
    if flip:
        b[:, 2] = 300.0 - b[:, 2]
    return b


def _params(transform: str = "rigid") -> Params:
    p = Params()
    return dataclasses.replace(p, association=dataclasses.replace(p.association, transform=transform))


def _error_at_b(answer, pb: np.ndarray, scale: float) -> float:
    truth = (pb - SHIFT) @ TURN / scale
    return float(np.linalg.norm(answer.transform.apply(pb) - truth, axis=1).max())


def test_a_copy_at_the_same_scale_is_not_flagged(map_a) -> None:
    pa, sa = map_a
    ans = match_maps(pa, sa, _copy(pa), sa, _params())
    u = ans.uncertainty
    assert ans.accepted and not u.imprecise and u.reason == "" and not u.height_flip
    assert u.scale_error_max_m == 0.0 and abs(u.scale_ratio - 1.0) < 3 * u.scale_sd + 1e-3


def test_a_rigid_answer_between_maps_of_other_scales_is_imprecise(map_a) -> None:
    """B scaled by 1.02: verified, its far landmarks metres off (beyond the gate) while the noise alone predicts
    well within it; the scale its pairs show is measured, significant, and its error makes the answer imprecise,
    with a warning that names the ratio and the similarity transform."""
    pa, sa = map_a
    pb = _copy(pa, 1.02)
    ans = match_maps(pa, sa, pb, sa * 1.02, _params())
    u = ans.uncertainty
    assert ans.accepted and ans.transform.scale == 1.0
    gate = u.gate_m
    assert _error_at_b(ans, pb, 1.02) > gate  # the answer does misplace B beyond its gate
    assert u.imprecise and u.scale_p < 1e-6 and abs(u.scale_ratio - 1 / 1.02) < 0.01
    assert u.predicted_max_m > gate and u.scale_error_max_m > 0.5 * gate
    assert "scales disagree" in u.warning() and "association.transform=similarity" in u.warning()
    assert u.to_dict()["imprecise"] is True


def test_similarity_verification_keeps_and_states_the_scale(map_a, tmp_path) -> None:
    """B scaled by 1.10 with transform=similarity: the verified answer is the similarity (scale 1/1.10, B placed
    within a metre), not a rigid refit of it; its scale's uncertainty is stated; merge/changes/batch read it."""
    from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
    from sosmatch.database.match_io import read_match
    from sosmatch.workflows import match

    pa, sa = map_a
    pb = _copy(pa, 1.10)
    ans = match_maps(pa, sa, pb, sa * 1.10, _params("similarity"))
    assert ans.accepted and ans.source == "verified"
    assert abs(ans.transform.scale - 1 / 1.10) < 0.002
    assert _error_at_b(ans, pb, 1.10) < 1.0
    u = ans.uncertainty
    assert not u.imprecise and 0.0 < u.scale_sd < 0.002 and abs(u.scale - ans.transform.scale) < 1e-12
    # what merge, changes and batch read (`read_match`) is that scale
    write_landmark_map(tmp_path / "a.sosmap", LandmarkMap(pa, sa, pa.mean(0).round()))
    write_landmark_map(tmp_path / "b.sosmap", LandmarkMap(pb, sa * 1.10, pb.mean(0).round()))
    res = match.run(_params("similarity"), tmp_path / "a.sosmap", tmp_path / "b.sosmap", tmp_path / "m", plot=False)
    assert res.accepted
    read = read_match(tmp_path / "m" / "match.json")
    assert read.transform_kind == "similarity" and abs(read.transform.scale - 1 / 1.10) < 0.002


def test_upside_down_heights_are_flagged(map_a) -> None:
    """B's z axis pointing down (z -> 300 - z): horizontally right and verified, but its heights anti-correlate
    with A's: imprecise, said as heights, and the consumers' note says why."""
    from sosmatch.database.match_io import MatchSummary
    from sosmatch.database.match_notes import imprecise_note

    pa, sa = map_a
    ans = match_maps(pa, sa, _copy(pa, flip=True), sa, _params())
    u = ans.uncertainty
    assert ans.accepted and u.height_flip and u.height_r < -0.9 and u.imprecise
    assert "upside down" in u.warning() and "heights anti-correlate" in u.warning()
    note = imprecise_note(MatchSummary(True, None, np.zeros((0, 2), np.int64), imprecise=True,
                                       predicted_max_m=u.predicted_max_m, gate_m=u.gate_m, imprecise_reason=u.reason))
    assert note is not None and "upside down" in note


def test_a_refinement_keeps_a_scale_only_where_it_explains_more_pairs(map_a) -> None:
    """`refine_alignment` with a scale (dof 5): on maps of one scale the scale-free fit pairs no more landmarks
    than the rigid one, and the rigid answer (scale exactly 1) is kept; on B scaled by 1.05 the scale is."""
    from sosmatch.plugin.multisession import Sim3
    from sosmatch.plugin.refinement import refine_alignment

    pa, sa = map_a
    start = Sim3(TURN.T, -TURN.T @ SHIFT, 1.0)  # the true turn and shift, scale 1
    same = refine_alignment(pa, sa, _copy(pa), sa, start, 2.8, 0.4, dof=5)
    assert same.transform.scale == 1.0 and len(same.associations) > 250
    scaled = refine_alignment(pa, sa, _copy(pa, 1.05), sa * 1.05, Sim3(TURN.T, -TURN.T @ SHIFT / 1.05, 1 / 1.05),
                              2.8, 0.4, dof=5)
    assert abs(scaled.transform.scale - 1 / 1.05) < 0.002 and len(scaled.associations) > 250


def test_one_odd_pair_on_flat_ground_is_no_flip() -> None:
    """rev37: on flat ground (heights within their noise) one pair with A on a 15 m crown and B on a wrong track
    8 m below the ground gave Pearson r -0.95 (p 1e-31) over 60 pairs: a true answer called upside down. By rank it
    weighs as one pair; a real flip (every height mirrored) stays near -1."""
    from sosmatch.plugin.answer_uncertainty import HEIGHT_FALSE_ALARM, height_flip

    rng = np.random.default_rng(3)
    za, zb = rng.normal(0.0, 0.3, 60), rng.normal(0.0, 0.3, 60)
    za[0], zb[0] = 15.0, -8.0
    r, p = height_flip(zb, za)
    assert p > HEIGHT_FALSE_ALARM and r > -0.3
    terrain = rng.uniform(0.0, 20.0, 60)
    r, p = height_flip(300.0 - (terrain + rng.normal(0.0, 0.3, 60)), terrain)
    assert p <= HEIGHT_FALSE_ALARM and r < -0.9


def _best_rigid_candidate(scale: float, n: int = 13) -> tuple[np.ndarray, np.ndarray, object, np.ndarray]:
    """nu54's refused candidate: 13 pairs over ~100 m of two maps whose landmark layers differ by `scale` (two
    domed SfM blocks), 0.3 m noise, placed by the best yaw + translation (what a rigid verification fits)."""
    from sosmatch.plugin.refinement import fit_yaw_translation

    rng = np.random.default_rng(5)
    pa = np.c_[rng.uniform(-50.0, 50.0, (n, 2)), rng.normal(0.0, 1.0, n)]
    pb = scale * (pa + rng.normal(0.0, 0.3, pa.shape)) @ TURN.T + SHIFT
    pairs = np.c_[np.arange(n), np.arange(n)]
    return pa, pb, fit_yaw_translation(pb, pa), pairs


def test_a_refusal_that_a_scale_explains_says_so() -> None:
    """nu54 M14: two SfM maps 4 % apart in scale were refused (13 pairs against 11) with no word of the scale; the
    candidate's own pairs show it (p 6e-10 there), so the refusal names it and the similarity."""
    from sosmatch.plugin.answer_uncertainty import refused_scale_note

    pa, pb, transform, pairs = _best_rigid_candidate(1.04)
    note = refused_scale_note(pa, pb, transform, pairs)
    assert note is not None and "association.transform=similarity" in note
    ratio = float(note.split("13 pairs fit x ")[1].split()[0])
    assert abs(ratio - 1 / 1.04) < 0.01
    pa, pb, transform, pairs = _best_rigid_candidate(1.0)
    assert refused_scale_note(pa, pb, transform, pairs) is None
    assert refused_scale_note(pa, pb, transform, pairs[:0]) is None
