"""Precision-recall of keyframe-pair claims against footprint-IoU ground truth (the method spec section 3).

A pair with IoU > `tp_iou` (0.333) should be claimed; a claim on a pair with IoU < `fp_iou` (0.01) is a false
positive; pairs in between count neither way. A method gives every keyframe pair a score (NaN = never
claimed); sweeping a threshold t (claim if score >= t) traces the curve.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TP_IOU = 0.333
FP_IOU = 0.01
TARGET = 0.99


@dataclass
class PRCurve:
    """One point per distinct score threshold, in decreasing threshold order (recall non-decreasing).

    `thresholds[k]`: claims are the pairs with score >= thresholds[k]; `tp`, `fp`: counted claims;
    `positives`: pairs with IoU > tp_iou (claimed or not).
    """

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    positives: int
    summary: dict = field(default_factory=dict)


def _f1(p: np.ndarray, r: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(p + r > 0, 2 * p * r / (p + r), 0.0)


def pr_curve(scores: np.ndarray, iou: np.ndarray, tp_iou: float = TP_IOU, fp_iou: float = FP_IOU) -> PRCurve:
    """The precision-recall curve of a score matrix against an IoU matrix of the same shape.

    Precision is TP / (TP + FP), taken as 1 when nothing counted is claimed; recall is TP / positives (0 when
    there are no positives). Vectorised: one sort of the claimed scores and two cumulative sums.
    """
    scores = np.asarray(scores, dtype=np.float64).ravel()
    iou = np.asarray(iou, dtype=np.float64).ravel()
    if scores.shape != iou.shape:
        raise ValueError(f"scores {scores.shape} and iou {iou.shape} differ in size")
    positives = int(np.count_nonzero(iou > tp_iou))
    claimed = np.isfinite(scores)
    s, lab = scores[claimed], iou[claimed]
    order = np.argsort(-s, kind="stable")
    s, lab = s[order], lab[order]
    tp = np.cumsum(lab > tp_iou)
    fp = np.cumsum(lab < fp_iou)
    # The curve point of threshold t includes every claim with score >= t: the last index of each score run.
    last = np.flatnonzero(np.r_[s[1:] != s[:-1], True]) if len(s) else np.zeros(0, dtype=int)
    tp, fp, thr = tp[last], fp[last], s[last]
    with np.errstate(divide="ignore", invalid="ignore"):
        precision = np.where(tp + fp > 0, tp / np.maximum(tp + fp, 1), 1.0)
    recall = tp / positives if positives else np.zeros(len(tp))
    curve = PRCurve(thr, precision.astype(float), recall.astype(float), tp, fp, positives)
    curve.summary = summarize(curve)
    return curve


def summarize(curve: PRCurve, target: float = TARGET) -> dict:
    """The paper's operating points of a curve.

    - `recall_at_p99`: highest recall among thresholds with precision >= target (0 if none);
    - `f1_at_p99`: the F1 at that threshold;
    - `f1_at_r99`: the F1 at the highest threshold whose recall >= target, or, if recall never reaches target,
      at the highest threshold reaching the highest recall (the most precise way to get it);
    - `average_f1`: mean of the two F1 values (the paper's "average F1").
    """
    p, r, thr = curve.precision, curve.recall, curve.thresholds
    out = {"positives": curve.positives, "recall_at_p99": 0.0, "threshold_at_p99": None, "f1_at_p99": 0.0,
           "f1_at_r99": 0.0, "threshold_at_r99": None, "recall_reached": 0.0, "average_f1": 0.0}
    if len(p) == 0:
        return out
    f1 = _f1(p, r)
    ok = np.flatnonzero(p >= target)
    if len(ok):
        k = ok[np.argmax(r[ok])]  # first index of the max: the highest threshold giving that recall
        out.update(recall_at_p99=float(r[k]), threshold_at_p99=float(thr[k]), f1_at_p99=float(f1[k]))
    reach = np.flatnonzero(r >= target)
    k = int(reach[0]) if len(reach) else int(np.argmax(r))
    out.update(f1_at_r99=float(f1[k]), threshold_at_r99=float(thr[k]), recall_reached=float(r[k]))
    out["average_f1"] = 0.5 * (out["f1_at_p99"] + out["f1_at_r99"])
    return out


def operating_point(curve: PRCurve, min_score: float) -> dict:
    """Precision, recall and F1 of the claims with score >= `min_score` (a method's own decision threshold:
    for SOS-Match |S| > theta_S, i.e. min_score = theta_S + 1 on integer |S|); nothing claimed gives P = 1,
    R = 0."""
    ok = np.flatnonzero(curve.thresholds >= min_score)
    if len(ok) == 0:
        return {"min_score": float(min_score), "precision": 1.0, "recall": 0.0, "f1": 0.0, "tp": 0, "fp": 0}
    k = int(ok[-1])  # thresholds decrease: the last one still >= min_score claims the most
    p, r = float(curve.precision[k]), float(curve.recall[k])
    return {"min_score": float(min_score), "precision": p, "recall": r, "f1": float(_f1(np.array(p), np.array(r))),
            "tp": int(curve.tp[k]), "fp": int(curve.fp[k])}
