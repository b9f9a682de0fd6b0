"""The predicted placement error of an accepted alignment (`plugin.answer_uncertainty`) and what consumers read."""

from __future__ import annotations

import numpy as np

from sosmatch.plugin.answer_uncertainty import answer_uncertainty, truncated_sigma
from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.refinement import fit_yaw_translation

IDENTITY = Sim3(np.eye(3), np.zeros(3), 1.0)


def _maps(extent: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, extent, n), rng.uniform(0, extent / 2, n), rng.normal(0, 1, n)])


def test_tight_pairs_over_the_map_are_precise() -> None:
    """Survey-like: 30 pairs with 0.7 m noise spread over a 200 m map, gate 2.8 m: well within the gate."""
    pa = _maps(200.0, 120, 1)
    rng = np.random.default_rng(2)
    pb = pa + np.column_stack([rng.normal(0, 0.7, (120, 2)), np.zeros(120)])
    pairs = np.column_stack([np.arange(0, 120, 4), np.arange(0, 120, 4)])
    fit = fit_yaw_translation(pb[pairs[:, 1]], pa[pairs[:, 0]])
    u = answer_uncertainty(pa, pb, fit, pairs, 2.8)
    assert u is not None and not u.imprecise
    assert u.predicted_max_m < 0.6 * 2.8


def test_a_few_wrong_pairs_that_tilt_the_fit_are_flagged() -> None:
    """NAIP-like: 10 pairs at an 8 m gate over a 1800 m map, 5 of them wrong by up to 16 m in the pattern of a
    turn. The fit turns B enough to bring every pair within the gate, which puts B's far landmarks beyond it: the
    residuals fill the gate, and propagated over the map the answer cannot keep B within its gate."""
    pa = _maps(1800.0, 200, 3)
    rng = np.random.default_rng(4)
    truth_b = pa + np.column_stack([rng.normal(0, 2.0, (200, 2)), np.zeros(200)])
    idx = np.linspace(0, 199, 10).astype(int)
    pb = truth_b.copy()
    # every other pair is wrong: its B landmark lies up to 16 m north of its A landmark at the east end and as far
    # south at the west end, the pattern a turn of B gives
    wrong = idx[1::2]
    pb[wrong, 1] += 16.0 * (pa[wrong, 0] - 900.0) / 900.0
    pairs = np.column_stack([idx, idx])
    fit = fit_yaw_translation(pb[idx], pa[idx])
    placed = fit.apply(truth_b)
    true_err = np.linalg.norm(placed[:, :2] - truth_b[:, :2], axis=1)  # the transform's own error
    assert np.max(true_err) > 8.0  # the fit does misplace B beyond the gate
    resid = np.linalg.norm(fit.apply(pb[idx])[:, :2] - pa[idx, :2], axis=1)
    assert resid.max() < 8.0  # and every associated pair passes the gate
    u = answer_uncertainty(pa, pb, fit, pairs, 8.0)
    assert u is not None and u.imprecise and u.predicted_max_m > 8.0
    assert u.to_dict()["imprecise"] is True and "imprecise" in u.warning()


def test_truncated_sigma_undoes_the_gate() -> None:
    """Residual distances of noise as large as the gate, kept within the gate, give a sigma near the true one (the
    plain rms is far smaller); residuals well within the gate give the plain estimate."""
    rng = np.random.default_rng(5)
    d = np.linalg.norm(rng.normal(0, 6.0, (20000, 2)), axis=1)
    kept = d[d <= 8.0]
    plain = np.sqrt(np.mean(kept**2) / 2.0)
    assert plain < 4.0
    assert abs(truncated_sigma(kept, 8.0) - 6.0) < 0.6
    small = np.linalg.norm(rng.normal(0, 0.5, (500, 2)), axis=1)
    assert abs(truncated_sigma(small, 8.0) - np.sqrt(np.mean(small**2) / 2.0)) < 0.01


def test_too_few_pairs_give_nothing() -> None:
    pa = _maps(100.0, 10, 6)
    assert answer_uncertainty(pa, pa, IDENTITY, np.array([[0, 0], [1, 1]]), 3.0) is None


def test_match_json_records_it_for_merge_and_changes(match_doc) -> None:
    """match.json "answer_uncertainty" reaches the consumers' reader: an imprecise answer gets a note, a precise one
    or a match.json without the field (an older sosmatch) none; a malformed field is refused."""
    import pytest

    from sosmatch.database.match_io import parse_match
    from sosmatch.database.match_notes import imprecise_note
    from sosmatch.plugin.errors import InputError

    doc = match_doc([[0, 1], [2, 3], [4, 5]], 3, 8.24)
    doc["hypotheses"][0]["tilt_deg"] = 0.5
    assert imprecise_note(parse_match(doc)) is None
    doc["answer_uncertainty"] = {"predicted_max_m": 34.85, "gate_m": 8.24, "imprecise": True}
    note = imprecise_note(parse_match(doc))
    assert note is not None and "34.9 m" in note and "8.24 m gate" in note
    doc["answer_uncertainty"]["imprecise"] = False
    assert imprecise_note(parse_match(doc)) is None
    doc["answer_uncertainty"] = [1]
    with pytest.raises(InputError, match="answer_uncertainty"):
        parse_match(doc)
    # imprecise without its predicted error: merge and changes crashed formatting None (review 20)
    doc["answer_uncertainty"] = {"imprecise": True}
    with pytest.raises(InputError, match="answer_uncertainty.predicted_max_m is missing"):
        parse_match(doc)
