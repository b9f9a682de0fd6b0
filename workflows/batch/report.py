"""Batch report: OUT/report.json, report.md, sessions.csv, pairs.csv and the session graph plot."""

from __future__ import annotations

import csv
import io
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...database.atomic import write_text_atomic

log = logging.getLogger(__name__)


@dataclass
class BatchReport:
    """Everything the batch did; also written as OUT/report.json (and .md)."""

    out_dir: Path
    sessions: list[dict[str, Any]] = field(default_factory=list)
    pairs: list[dict[str, Any]] = field(default_factory=list)
    groups: list[dict[str, Any]] = field(default_factory=list)
    executor: str = ""
    seconds: float = 0.0

    @property
    def failures(self) -> list[str]:
        items = [("session", s["name"], s) for s in self.sessions] + [("pair", p["pair"], p) for p in self.pairs]
        items += [("group", g["reference"], g) for g in self.groups]
        return [f"{kind} {name}: {x.get('error', '')}" for kind, name, x in items if x["status"] == "failed"]

    @property
    def ok(self) -> bool:
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "sosmatch batch report v1",
            "ok": self.ok,
            "failures": self.failures,
            "executor": self.executor,
            "seconds": round(self.seconds, 3),
            "sessions": self.sessions,
            "pairs": self.pairs,
            "groups": self.groups,
        }


def _table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return "" if v is None else str(v).replace("|", "/")

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def _pair_rows(report: BatchReport) -> list[dict[str, Any]]:
    rows = []
    for p in report.pairs:
        row = dict(p)
        t = p.get("transform")
        if t:
            rot = np.asarray(t["rotation"])
            row["yaw_deg"] = round(float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))), 3)
            row["shift_m"] = round(float(np.linalg.norm(t["translation"])), 3)
            row["scale"] = round(float(t["scale"]), 5)
        rows.append(row)
    return rows


SESSION_COLUMNS = ["name", "kind", "status", "images", "points3D", "landmarks", "seconds", "error"]
PAIR_COLUMNS = ["pair", "status", "accepted", "in_graph", "num_associations", "yaw_deg", "shift_m", "scale", "seconds",
                "error"]
GROUP_COLUMNS = ["reference", "members", "status", "images", "points3D", "landmarks", "fused", "merged", "error"]


def write_report(report: BatchReport) -> None:
    """OUT/report.json, OUT/report.md, OUT/sessions.csv, OUT/pairs.csv and OUT/session_graph.png."""
    out = report.out_dir
    write_text_atomic(out / "report.json", json.dumps(report.to_dict(), indent=2) + "\n")
    pair_rows = _pair_rows(report)
    groups = [{**g, "members": " ".join(g["members"])} for g in report.groups]
    status = "ok" if report.ok else f"{len(report.failures)} failure(s)"
    md = [
        "# sosmatch batch report", "",
        f"{len(report.sessions)} sessions, {len(report.pairs)} pairs, {len(report.groups)} groups; {status}; "
        f"executor: {report.executor}; {report.seconds:.1f} s", "",
        "## Sessions", "", _table(report.sessions, SESSION_COLUMNS), "",
        "## Pairs", "", "(transform a_from_b: yaw about z, length of the translation, scale)", "",
        _table(pair_rows, PAIR_COLUMNS), "",
        "## Groups (merged models)", "", _table(groups, GROUP_COLUMNS), "",
        "![session graph](session_graph.png)", "",
    ]
    write_text_atomic(out / "report.md", "\n".join(md))
    tables = (("sessions.csv", report.sessions, SESSION_COLUMNS), ("pairs.csv", pair_rows, PAIR_COLUMNS))
    for name, rows, cols in tables:
        buf = io.StringIO()
        w = csv.DictWriter(buf, cols, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out / name, buf.getvalue())
    plot_session_graph(report, out / "session_graph.png")


def plot_session_graph(report: BatchReport, path: Path) -> None:
    """Sessions at their mean camera position (or on a circle), accepted pairs as solid lines labelled |S|,
    rejected pairs dashed, failed pairs dotted red; colour = merged group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ...database.atomic import atomic_path

    names = [s["name"] for s in report.sessions]
    n = len(names)
    centres = [s.get("center") for s in report.sessions]
    same_frame = len({s.get("epsg") for s in report.sessions}) == 1
    if n and same_frame and all(c is not None for c in centres):
        xy = np.asarray(centres)[:, :2]
        if n > 1 and np.ptp(xy, axis=0).max() < 1e-6:
            xy = None
    else:
        xy = None
    if xy is None:
        ang = 2 * np.pi * np.arange(n) / max(n, 1)
        xy = np.stack([np.cos(ang), np.sin(ang)], 1)
    pos = {nm: xy[i] for i, nm in enumerate(names)}
    group_of = {m: k for k, g in enumerate(report.groups) for m in g["members"]}
    fig, ax = plt.subplots(figsize=(6, 5))
    for p in report.pairs:
        if p["a"] not in pos or p["b"] not in pos:
            continue
        (x0, y0), (x1, y1) = pos[p["a"]], pos[p["b"]]
        if p["status"] == "done" and p.get("accepted") and p.get("in_graph") is False:
            ax.plot([x0, x1], [y0, y1], "-.", color="tab:orange", lw=1.5, zorder=1)
        elif p["status"] == "done" and p.get("accepted"):
            ax.plot([x0, x1], [y0, y1], "-", color="tab:green", lw=2, zorder=1)
            ax.annotate(str(p.get("num_associations", "")), ((x0 + x1) / 2, (y0 + y1) / 2), fontsize=8,
                        ha="center", color="tab:green")
        elif p["status"] == "done":
            ax.plot([x0, x1], [y0, y1], "--", color="0.6", lw=1, zorder=0)
        else:
            ax.plot([x0, x1], [y0, y1], ":", color="tab:red", lw=1, zorder=0)
    cmap = plt.get_cmap("tab10")
    for s in report.sessions:
        x, y = pos[s["name"]]
        color = "tab:red" if s["status"] != "done" else cmap(group_of.get(s["name"], 0) % 10)
        ax.scatter([x], [y], s=200, color=color, zorder=2, edgecolors="k")
        ax.annotate(s["name"], (x, y), textcoords="offset points", xytext=(8, 8), fontsize=9)
    ax.set_title("session graph: accepted (solid, |S|), contradicted (orange), rejected (dashed), failed (dotted)",
                 fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.margins(0.2)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
