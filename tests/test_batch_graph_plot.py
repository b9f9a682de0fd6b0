"""The session graph's pair labels (`batch.report.plot_session_graph`) stay readable however many sessions."""

from itertools import combinations, product

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
