"""The suite's BENCHMARKS.md section handling and bar checks (the heavy runs are not tests)."""

from sosmatch.tools.benchmarks.bench_evaluate import END_MARKER, MARKER, check_bars, replace_section, section_text


def _ev(case, ours_s, orb_s, ours_f1, orb_f1):
    rows = [
        {"case": case, "method": "SOS-Match (ours)", "search_s": ours_s, "map_mb": 0.01, "average_f1": ours_f1,
         "recall_at_p99": 0.5},
        {"case": case, "method": "ORB+RANSAC", "search_s": orb_s, "map_mb": 5.0, "average_f1": orb_f1,
         "recall_at_p99": 0.4},
        {"case": case, "method": "SIFT+RANSAC", "search_s": orb_s, "map_mb": 50.0, "average_f1": 0.1,
         "recall_at_p99": 0.1},
    ]
    return {"case": case, "rows": rows, "keyframes": [10, 12], "methods": {"sosmatch": {"search_seconds_runs": [1, 2]}},
            "protocol": {"positive_pairs": 5, "negative_pairs": 50, "tp_iou": 0.333, "fp_iou": 0.01}}


def test_bars_met_and_missed_with_numbers():
    notes = check_bars(_ev("summer-winter", 1.0, 5.0, 0.3, 0.6))
    assert "5x shorter" in notes[0] and "bar 10x MISSED" in notes[0] and "bar 100x met" in notes[0]
    assert "0.300 vs best baseline 0.600" in notes[1] and "MISSED" in notes[1]
    notes = check_bars(_ev("summer-20min", 0.1, 5.0, 0.3, 0.6))
    assert len(notes) == 1 and "bar 10x met" in notes[0]  # not a cross-season case: no F1 bar


def test_section_replaced_in_place_and_idempotent():
    text = "# Benchmarks\n\n<!-- section:match -->\n" + MARKER + "\n<!-- section:real-data -->\n"
    sec = section_text([_ev("summer-winter", 1.0, 50.0, 0.7, 0.6)], "machine", "cmd")
    once = replace_section(text, sec)
    assert once.count(MARKER) == 1 and once.count(END_MARKER) == 1
    assert once.index("<!-- section:match -->") < once.index(MARKER) < once.index("<!-- section:real-data -->")
    twice = replace_section(once, sec)
    assert twice == once
    assert "| summer-winter | SOS-Match (ours) | 1 | 0.01 | 0.700 | 0.500 |" in once
    assert "median of 2 runs of the match's answer" in once


def test_seasons_altitude_bar_on_same_season_pairs_only():
    from sosmatch.tools.benchmarks.bench_seasons import check_bars as season_bars

    def row(ratio):
        return {"size_ratio_median": ratio, "recall_at_p99": 0.9, "average_f1": 0.95}

    rows = {"summer-winter": row(0.95), "summer-winter-130m": row(0.90), "summer-130m": row(1.01),
            "winter-130m": row(0.96)}
    notes = [n for n in season_bars(7, rows) if "size ratio" in n]
    assert len(notes) == 3
    assert "w7 summer-130m" in notes[0] and "1.010" in notes[0] and notes[0].endswith("met")
    assert "w7 winter-130m" in notes[1] and "0.960" in notes[1] and notes[1].endswith("MISSED")
    # the cross-season pair is information, with its equal-altitude reference and the quotient, and no verdict
    assert "information" in notes[2] and "0.900" in notes[2] and "0.950" in notes[2] and "0.947" in notes[2]
    assert "met" not in notes[2] and "MISSED" not in notes[2]
