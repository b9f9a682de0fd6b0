"""evaluate reports an answer's error over B's landmarks, not only at its pairs' centroid."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.refinement import yaw_matrix
from sosmatch.workflows.evaluate import error_to_identity
from sosmatch.workflows.evaluate.report import format_table, row_of


def _turned_answer() -> tuple[Sim3, np.ndarray, np.ndarray]:
    """B spans 2000 m; the answer is turned 0.68 deg about its pairs' centroid near the middle (NAIP-like)."""
    rng = np.random.default_rng(0)
    pb = np.column_stack([rng.uniform(0, 2000, 200), rng.uniform(0, 800, 200), np.zeros(200)])
    paired = pb[(np.abs(pb[:, 0] - 1000) < 300)][:10]
    centre = paired.mean(axis=0)
    turn = yaw_matrix(np.radians(0.68))
    return Sim3(turn, centre - turn @ centre, 1.0), paired, pb


def test_error_over_b_sees_what_the_centroid_hides() -> None:
    t, paired, pb = _turned_answer()
    e = error_to_identity(t, paired, None, pb)
    assert e["horizontal_m"] < 0.01  # at the pairs' centroid the turn moves nothing
    assert e["map_max_m"] > 10.0 and e["map_median_m"] > 3.0
    assert "map_max_m" not in error_to_identity(t, paired)  # the old fields alone without B's landmarks


def test_evaluation_table_shows_the_error_over_b() -> None:
    t, paired, pb = _turned_answer()
    e = error_to_identity(t, paired, None, pb)
    summary = {"average_f1": 1.0, "recall_at_p99": 1.0, "f1_at_p99": 1.0, "f1_at_r99": 1.0, "recall_reached": 1.0}
    res = {"curve": SimpleNamespace(summary=summary), "search_seconds": 1.0, "map_bytes": [1000, 1000],
           "verification": {"clear_winner": True, "accepted": True, **e}, "accepted_truth": []}
    row = row_of("case", "sosmatch", res)
    assert row["accepted_max_error_m"] < 0.01  # kept as it was: benchmarks read it
    assert row["accepted_max_map_error_m"] == e["map_max_m"]
    table = format_table([row])
    assert f"{e['map_median_m']:.1f} / {e['map_max_m']:.1f}" in table


def test_median_and_max_of_the_worst_answer_come_from_one_answer() -> None:
    """Without a verification every accepted window hypothesis is an answer: the cell's median and max are those of
    the answer with the largest max, not each the largest over the answers (review 20: they could come from two)."""
    summary = {"average_f1": 1.0, "recall_at_p99": 1.0, "f1_at_p99": 1.0, "f1_at_r99": 1.0, "recall_reached": 1.0}
    answers = [{"error_m": 0.5, "map_median_m": 6.0, "map_max_m": 9.0},  # evenly off
               {"error_m": 0.2, "map_median_m": 1.0, "map_max_m": 20.0}]  # turned: small median, large max
    res = {"curve": SimpleNamespace(summary=summary), "search_seconds": 1.0, "map_bytes": [1000, 1000],
           "accepted_truth": answers}
    row = row_of("case", "windows only", res)
    assert (row["accepted_median_map_error_m"], row["accepted_max_map_error_m"]) == (1.0, 20.0)
    assert "1.0 / 20.0" in format_table([row])
