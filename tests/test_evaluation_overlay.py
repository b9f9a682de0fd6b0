"""What evaluate's overlay.png draws of the match's associations."""

import numpy as np

from sosmatch.workflows.evaluate.report import association_layers, verification_refused


def _sos(verification):
    pa = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    pb = pa + np.array([0.5, 0.0, 0.0])
    pb[2] += 30.0  # one association far off: wrong
    pairs = np.array([[0, 0], [1, 1], [2, 2]])
    return {"positions": (pa, pb), "accepted": [(pairs, None)], "verification": verification}


def test_a_refused_match_s_associations_are_not_drawn_as_associated():
    """rev55 D6: with the verification refusing (F1 0, the match answers "no match"), the window hypotheses'
    associations were drawn as green "associated" rings, the figure's colour and word for a found match."""
    refused = _sos({"accepted": False, "support": 5, "associations": []})
    assert verification_refused(refused)
    layers = association_layers(refused)
    assert [len(a) for a, *_ in layers] == [2, 1]
    assert all("refused" in label and "window hypotheses, support 5" in label for *_, label in layers)
    assert "limegreen" not in [color for _, _, color, _ in layers]
    accepted = _sos({"accepted": True, "support": 2, "associations": [[0, 0], [1, 1]]})
    assert not verification_refused(accepted) and not verification_refused(_sos(None))
    (_, _, color, label), _ = association_layers(accepted)
    assert color == "limegreen" and label.startswith("associated (2; 1 accepted hypotheses + verified alignment of 2")
