"""The evaluation's report: its table rows, the markdown table, the precision-recall plot and the overlay of the
two maps with the verified answer's associations (`workflow` computes, this module draws and formats).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...database.atomic import atomic_path
from ...plugin.evaluation.metrics import PRCurve

if TYPE_CHECKING:
    from .ground_truth import GroundTruthSession

WRONG_ASSOCIATION_M = 5.0  # an association whose landmarks are farther apart (world frame) is drawn as wrong
LABELS = {"sosmatch": "SOS-Match (ours)", "sosmatch_windows": "SOS-Match, windows only", "orb_ransac": "ORB+RANSAC",
          "sift_ransac": "SIFT+RANSAC"}


def row_of(case: str, method: str, res: dict) -> dict:
    """One row of the evaluation table (`format_table`) for `method`'s results `res` on `case`."""
    s = res["curve"].summary
    row = {"case": case, "method": LABELS.get(method, method), "search_s": res["search_seconds"],
           "map_mb": float(np.mean(res["map_bytes"])) / 1e6, "average_f1": s["average_f1"],
           "recall_at_p99": s["recall_at_p99"], "f1_at_p99": s["f1_at_p99"], "f1_at_r99": s["f1_at_r99"],
           "recall_reached": s["recall_reached"]}
    op = res.get("operating_point")
    if op is not None:
        row.update(f1_at_operating=op["f1"], recall_at_operating=op["recall"], precision_at_operating=op["precision"],
                   operating_theta_S=res.get("operating_theta_S"))
    truth = res.get("landmark_truth")
    if truth is not None:
        row.update(common_landmarks=truth["common"], eligible_objects=truth["eligible_objects"],
                   oracle_recall=truth["oracle_size_gated"]["recall"], limited_by=limiting_stage(row, truth))
    # The worst accepted transform. With the verification the matcher accepts one transform, the verified one:
    # the window hypotheses that agree with it lend it their associations (the claims), not their transforms,
    # which are fitted on their own 7-10 associations and can be metres off (5.8-7.2 m on held-out worlds).
    # Without a verification (the windows-only row, the paper's protocol, or `--no-verify`) every accepted window
    # hypothesis is an answer of its own; with a refused verification the matcher accepted nothing.
    # `accepted_max_error_m` is each answer's error at its pairs' centroid (kept: benchmarks read it);
    # `accepted_max_map_error_m` / `_median_` its horizontal error over all of B's landmarks (`error_to_identity`
    # map_max_m / map_median_m), where merge and changes use the transform: evaluation.md's "worst accepted error"
    ver = res.get("verification") or {}
    verified = bool(ver.get("clear_winner"))
    if res.get("verification") is not None and not verified:
        answers = []
    elif verified:
        answers = [ver] if ver.get("accepted") and np.isfinite(ver.get("error_m", np.nan)) else []
        windows = [h["error_m"] for h in res.get("accepted_truth", [])
                   if np.isfinite(h["error_m"]) and h.get("agrees_with_verified")]
        row["agreeing_windows_max_error_m"] = max(windows) if windows else None
    else:
        answers = [h for h in res.get("accepted_truth", []) if np.isfinite(h["error_m"])]
    if "accepted_truth" in res:
        errors = [a["error_m"] for a in answers]
        row["accepted_max_error_m"] = max(errors) if errors else None
        over_map = [a for a in answers if np.isfinite(a.get("map_max_m", np.nan))]
        # both of one answer, the worst (largest max): the largest median of another answer paired with it
        # described no answer that was given
        worst = max(over_map, key=lambda a: a["map_max_m"]) if over_map else None
        row["accepted_max_map_error_m"] = worst["map_max_m"] if worst else None
        row["accepted_median_map_error_m"] = worst["map_median_m"] if worst else None
    return row


def limiting_stage(row: dict, truth: dict, target: float = 0.95) -> str:
    """Which stage limits the recall at the operating point: "none" (it reaches `target`), "search" (the
    common landmarks that pass the size gate could vouch for a tenth more than the search found) or
    "front end" (the search finds about what the common landmarks allow)."""
    recall, oracle = row.get("recall_at_operating", 0.0), truth["oracle_size_gated"]["recall"]
    if recall >= target:
        return "none"
    return "search" if recall < 0.9 * oracle else "front end"


def _cell(row: dict, key: str, fmt: str = ".3f") -> str:
    value = row.get(key)
    return "-" if value is None else format(value, fmt)


def format_table(rows: Sequence[dict]) -> str:
    """Markdown table: case, method, search time, map size, average F1, recall at P >= 0.99, F1 and recall at
    the method's own operating point (theta_S), and the common landmarks of the two maps against the eligible
    ground-truth objects with the oracle recall (synthetic sessions only)."""
    # the worst accepted alignment's error from the truth beside the scores: a map built with a wrong focal length
    # scored better than the right one while its answer was 28 m off (the thirteenth sweep), and only
    # evaluation.json said so
    lines = ["| case | method | search time (s) | map size (MB) | average F1 | recall at P >= 0.99 "
             "| F1 at theta_S | recall at theta_S | worst accepted error over B, median / max (m) "
             "| common / eligible objects "
             "| oracle recall | limited by |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        t = "n/a" if r["search_s"] is None else f"{r['search_s']:.3g}"
        common = f"{r['common_landmarks']} / {r['eligible_objects']}" if "common_landmarks" in r else "-"
        lines.append(f"| {r['case']} | {r['method']} | {t} | {r['map_mb']:.4g} | {r['average_f1']:.3f} "
                     f"| {r['recall_at_p99']:.3f} | {_cell(r, 'f1_at_operating')} | {_cell(r, 'recall_at_operating')} "
                     f"| {_worst_cell(r)} "
                     f"| {common} | {_cell(r, 'oracle_recall')} | {r.get('limited_by', '-')} |")
    return "\n".join(lines) + "\n"


def _worst_cell(row: dict) -> str:
    """'8.8 / 23.0': the worst accepted answer's horizontal error over B's landmarks, median / max; rows without
    it (an evaluation.json of an older sosmatch): the error at the pairs' centroid as before."""
    if row.get("accepted_max_map_error_m") is None:
        return _cell(row, "accepted_max_error_m", ".1f")
    return f"{row['accepted_median_map_error_m']:.1f} / {row['accepted_max_map_error_m']:.1f}"


def plot_pr(curves: dict[str, PRCurve], path: Path, title: str) -> None:
    """Precision-recall curves of every method into a PNG (written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2), dpi=110)
    for method, c in curves.items():
        if len(c.recall):
            ax.step(np.r_[0.0, c.recall], np.r_[1.0, c.precision], where="pre", label=LABELS.get(method, method))
        else:
            ax.plot([], [], label=f"{LABELS.get(method, method)} (no claims)")
    ax.axhline(0.99, color="grey", lw=0.6, ls=":")
    ax.set(xlabel="recall", ylabel="precision", xlim=(0, 1.02), ylim=(0, 1.02), title=title)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def verification_refused(sos: dict) -> bool:
    """Whether the full-map verification ran and refused the match (`sosmatch match` answers "no match")."""
    ver = sos.get("verification") or {}
    return bool(ver) and not ver.get("accepted")


def association_layers(sos: dict) -> list[tuple[np.ndarray, np.ndarray, str, str]]:
    """The overlay's association rings: (A positions, B positions, colour, legend label) per group. Green: the
    accepted window hypotheses' and the verified alignment's associations; red: those more than
    WRONG_ASSOCIATION_M apart in the world frame; grey: the window hypotheses' when the verification refused
    them (a refused match drawn green read as a found one)."""
    pa, pb = sos["positions"]
    assoc = [a for a, _ in sos.get("accepted", [])]
    ver = sos.get("verification") or {}
    if ver.get("accepted"):
        assoc.append(np.asarray(ver["associations"], dtype=int).reshape(-1, 2))
    if not assoc:
        return []
    pairs = np.unique(np.concatenate(assoc).reshape(-1, 2), axis=0)
    far = np.linalg.norm(pa[pairs[:, 0]] - pb[pairs[:, 1]], axis=1) > WRONG_ASSOCIATION_M
    n_hyp = len(sos.get("accepted", []))
    if verification_refused(sos):
        groups = [(~far, "0.55", "refused by the verification"), (far, "red", "refused, wrong")]
        what = f"{n_hyp} window hypotheses, support {ver.get('support')}"
    else:
        groups = [(~far, "limegreen", "associated"), (far, "red", "associated, wrong")]
        what = f"{n_hyp} accepted hypotheses" + (f" + verified alignment of {ver['support']}"
                                                 if ver.get("accepted") else "")
    return [(pa[pairs[sel, 0]], pb[pairs[sel, 1]], color, f"{label} ({int(sel.sum())}; {what})")
            for sel, color, label in groups if sel.any()]


def plot_overlay(gt_a: GroundTruthSession, gt_b: GroundTruthSession, sos: dict | None, path: Path, title: str) -> None:
    """Both flights' keyframe footprints and paths, both landmark maps, and the best hypothesis' associations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import shapely

    fig, ax = plt.subplots(figsize=(9.5, 6), dpi=110)
    for gt, color, label in ((gt_a, "tab:blue", "A"), (gt_b, "tab:orange", "B")):
        step = max(1, len(gt.footprints) // 40)
        for poly in gt.footprints[::step]:
            if not poly.is_empty and isinstance(poly, shapely.Polygon):
                x, y = poly.exterior.xy
                ax.plot(x, y, color=color, lw=0.3, alpha=0.35)
        ax.plot(gt.centers[:, 0], gt.centers[:, 1], color=color, lw=1.2, label=f"session {label} keyframes")
    if sos is not None:
        pa, pb = sos["positions"]
        ax.scatter(pa[:, 0], pa[:, 1], s=6, color="tab:blue", marker="o", label=f"landmarks A ({len(pa)})")
        ax.scatter(pb[:, 0], pb[:, 1], s=6, color="tab:orange", marker="x", label=f"landmarks B ({len(pb)})")
        truth = sos.get("landmark_truth")
        if truth and truth.get("common_pairs"):
            common = np.asarray([c[1] for c in truth["common_pairs"]], dtype=int)
            ax.scatter(pa[common, 0], pa[common, 1], s=70, facecolors="none", edgecolors="0.35", marker="s", lw=0.8,
                       label=f"common landmarks (truth: {len(common)})")
        # Associations of the accepted hypotheses, drawn as rings (a right one joins two landmarks ~1 m apart,
        # invisible as a segment on a plot hundreds of metres wide)
        for a, b, color, label in association_layers(sos):
            ax.scatter(a[:, 0], a[:, 1], s=40, facecolors="none", edgecolors=color, lw=1.6, label=label)
            for u, v in zip(a, b):
                ax.plot([u[0], v[0]], [u[1], v[1]], color=color, lw=1.6)
        if verification_refused(sos):
            title = f"{title} (verification refused: no match)"
        best = sos.get("best")
        if best:
            ab = np.asarray(best["associations"], dtype=int).reshape(-1, 2)
            ax.scatter(pa[ab[:, 0], 0], pa[ab[:, 0], 1], s=12, color="darkgreen", marker="D",
                       label=f"the match's answer ({best.get('answer', 'best hypothesis')}): {len(ab)} associations")
    ax.set_aspect("equal")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7)  # beside the map, not on it
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
