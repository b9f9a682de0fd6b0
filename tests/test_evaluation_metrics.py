"""PR curve, recall at P >= 0.99 and average F1 against a brute-force reference written independently."""

import numpy as np
import pytest

from sosmatch.plugin.evaluation.metrics import pr_curve


def _brute(scores, iou, tp_iou=0.333, fp_iou=0.01):
    """Threshold-by-threshold reference: loops, no cumulative sums."""
    s, u = scores.ravel(), iou.ravel()
    pos = sum(1 for v in u if v > tp_iou)
    pts = []
    for t in sorted({v for v in s if not np.isnan(v)}, reverse=True):
        tp = sum(1 for a, v in zip(s, u) if not np.isnan(a) and a >= t and v > tp_iou)
        fp = sum(1 for a, v in zip(s, u) if not np.isnan(a) and a >= t and v < fp_iou)
        p = tp / (tp + fp) if tp + fp else 1.0
        r = tp / pos if pos else 0.0
        pts.append((t, p, r))
    return pts


def test_hand_made_curve():
    # Labels: positives (0.5), false (0.0) and "between" (0.1, counts neither way).
    iou = np.array([0.5, 0.5, 0.1, 0.0, 0.5, 0.0, 0.5])
    scores = np.array([9.0, 8.0, 7.0, 7.0, 5.0, np.nan, np.nan])
    c = pr_curve(scores, iou)
    assert c.positives == 4
    assert np.allclose(c.thresholds, [9, 8, 7, 5])
    assert np.allclose(c.precision, [1, 1, 2 / 3, 3 / 4])
    assert np.allclose(c.recall, [0.25, 0.5, 0.5, 0.75])
    s = c.summary
    assert s["recall_at_p99"] == 0.5 and s["threshold_at_p99"] == 8
    f1_p = 2 * 1 * 0.5 / 1.5
    f1_r = 2 * 0.75 * 0.75 / 1.5  # recall never reaches 0.99: F1 at the highest reachable recall (0.75)
    assert s["f1_at_p99"] == pytest.approx(f1_p) and s["f1_at_r99"] == pytest.approx(f1_r)
    assert s["average_f1"] == pytest.approx((f1_p + f1_r) / 2)


def test_perfect_method_scores_one():
    iou = np.array([[0.9, 0.0], [0.0, 0.6]])
    c = pr_curve(np.array([[3.0, np.nan], [np.nan, 2.0]]), iou)
    assert c.summary["average_f1"] == pytest.approx(1.0) and c.summary["recall_at_p99"] == 1.0


def test_no_precise_threshold_gives_zero_at_p99():
    c = pr_curve(np.array([5.0, 4.0]), np.array([0.0, 0.9]))
    assert c.summary["recall_at_p99"] == 0.0 and c.summary["f1_at_p99"] == 0.0
    assert c.summary["recall_reached"] == 1.0 and c.summary["f1_at_r99"] == pytest.approx(2 * 0.5 / 1.5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_sets_agree_with_brute_force(seed):
    rng = np.random.default_rng(seed)
    iou = rng.choice([0.0, 0.005, 0.2, 0.4, 0.9], size=(9, 11))
    scores = rng.integers(0, 12, size=iou.shape).astype(float)
    scores[rng.random(iou.shape) < 0.3] = np.nan
    scores += (iou > 0.333) * rng.integers(0, 4, size=iou.shape)  # informative, not perfect
    c = pr_curve(scores, iou)
    ref = _brute(scores, iou)
    assert len(ref) == len(c.thresholds)
    for k, (t, p, r) in enumerate(ref):
        assert c.thresholds[k] == t and c.precision[k] == pytest.approx(p) and c.recall[k] == pytest.approx(r)
