"""The session graph's pair labels (`batch.report.plot_session_graph`) stay readable however many sessions."""

from itertools import combinations, product

import numpy as np
import pytest
from matplotlib.figure import Figure

from sosmatch.workflows.batch import BatchReport, plot_session_graph


def _labels_drawn(tmp_path, monkeypatch, n):
    """The window boxes of the pair labels of a graph of `n` sessions, every pair accepted; and the figure's texts."""
    report = BatchReport(tmp_path)
    names = [f"f{i + 1}" for i in range(n)]
    report.sessions = [{"name": nm, "status": "done"} for nm in names]
    report.pairs = [{"pair": f"{a}__{b}", "a": a, "b": b, "status": "done", "accepted": True, "in_graph": True,
                     "num_associations": 100 + i, "gone": i % 5, "new": i % 3}
                    for i, (a, b) in enumerate(combinations(names, 2))]
    report.groups = [{"reference": "f1", "members": names, "status": "done", "reference_from_session": {}}]
    seen = {}
    save = Figure.savefig

    def spy(fig, *args, **kwargs):
        renderer = fig.canvas.get_renderer()
        texts = [t for ax in fig.axes for t in ax.texts]
        seen["boxes"] = [t.get_window_extent(renderer) for t in texts if t.get_text().startswith("|S|")]
        seen["texts"] = [t.get_text() for t in texts]
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    plot_session_graph(report, tmp_path / "g.png")
    return seen["boxes"], seen["texts"]


@pytest.mark.parametrize("n", [4, 6, 8])
def test_pair_labels_do_not_cover_each_other(tmp_path, monkeypatch, n):
    """nu40: 6 sessions on a circle, the three diameters' labels at the centre on top of each other."""
    boxes, _ = _labels_drawn(tmp_path, monkeypatch, n)
    assert len(boxes) == n * (n - 1) // 2  # every label drawn
    for a, b in combinations(boxes, 2):
        w = max(0.0, min(a.x1, b.x1) - max(a.x0, b.x0))
        h = max(0.0, min(a.y1, b.y1) - max(a.y0, b.y0))
        assert w * h <= 0.1 * min(a.width * a.height, b.width * b.height)


def test_labels_without_room_are_left_off_and_said(tmp_path, monkeypatch):
    boxes, texts = _labels_drawn(tmp_path, monkeypatch, 16)  # 120 pairs: not all fit
    left = [t for t in texts if "pair labels left off" in t]
    assert len(left) == 1 and len(boxes) < 120 and left[0].startswith(f"{120 - len(boxes)} of 120")
    assert not any(a != b and (a.x0, a.y0) == (b.x0, b.y0) for a, b in product(boxes, boxes))


def test_the_map_draws_sessions_of_one_local_frame_and_names_those_it_leaves_out(tmp_path):
    """rev58 D3: the map took only one shared EPSG code for a shared frame; sessions of one local frame (a synth
    world) outside the largest merged group were left off, nothing said. The frame is read as `--nearest` reads it
    (`pairs.frame_of`), and a mapped session not drawn is named with why."""
    from sosmatch.plugin.multisession import Sim3
    from sosmatch.workflows.batch.report import _not_drawn_note, _placement

    shift = Sim3(np.eye(3), np.array([5.0, 0.0, 0.0])).to_dict()
    report = BatchReport(tmp_path)
    report.sessions = [{"name": n, "kind": "synth", "status": "done", "epsg": 0} for n in "ABC"]
    report.groups = [{"reference": "A", "members": ["A", "B"], "status": "done",
                      "reference_from_session": {"A": Sim3.identity().to_dict(), "B": shift}}]
    placed, caption = _placement(report)
    assert sorted(placed) == ["A", "B", "C"] and caption == "one shared local frame"
    # D: poses by structure from motion, a local frame of its own: the group's frame, D and nothing else left out
    report.sessions.append({"name": "D", "kind": "images", "status": "done", "epsg": 0})
    report.sessions.append({"name": "E", "kind": "images", "status": "failed"})
    placed, caption = _placement(report)
    assert sorted(placed) == ["A", "B", "C"] and caption == "frame of A (its merged group)"
    assert np.allclose(placed["B"].apply(np.zeros((1, 3))), [[5, 0, 0]])
    note = _not_drawn_note(report, {"A", "B"}, placed)
    assert "D (in no frame shared with those drawn)" in note and "C (its session does not read)" in note
    assert "E" not in note and _not_drawn_note(report, {"A", "B", "C", "D"}, placed) == ""
