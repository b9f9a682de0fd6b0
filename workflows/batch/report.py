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
from ...database.outputs import OutputDir

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
    stale_outputs: list[str] = field(default_factory=list)  # OUT's folders of no flight or group of this run
    # what the run warned of that is no one session's or pair's (--nearest: flights without a capture time)
    run_warnings: list[str] = field(default_factory=list)

    @property
    def failures(self) -> list[str]:
        items = [("session", s["name"], s) for s in self.sessions] + [("pair", p["pair"], p) for p in self.pairs]
        items += [("group", g["reference"], g) for g in self.groups]
        out = [f"{kind} {name}: {x.get('error', '')}" for kind, name, x in items if x["status"] == "failed"]
        return out + [f"changes {p['pair']}: {p.get('changes_error', '')}" for p in self.pairs
                      if p.get("changes_status") == "failed"]

    @property
    def warnings(self) -> list[str]:
        """What the batch's results say of its inputs without failing: the run's own (`run_warnings`), then each
        named by its session or pair (`session_warnings`, `pair_warnings`), sessions first."""
        return (list(self.run_warnings) + [w for s in self.sessions for w in session_warnings(s)]
                + [w for p in self.pairs for w in pair_warnings(p)])

    @property
    def status(self) -> str:
        """One line: "ok" only without failures and warnings (a result with warnings is no plain success)."""
        said = [f"{len(self.failures)} failure(s)"] if self.failures else []
        said += [f"{len(self.warnings)} warning(s)"] if self.warnings else []
        return ", ".join(said) or "ok"

    @property
    def ok(self) -> bool:
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "sosmatch batch report v1",
            "ok": self.ok,  # no failure (the exit code); `status` also counts the warnings
            "status": self.status,
            "failures": self.failures,
            "warnings": self.warnings,
            "executor": self.executor,
            "seconds": round(self.seconds, 3),
            "sessions": self.sessions,
            "pairs": self.pairs,
            "groups": self.groups,
            "stale_outputs": self.stale_outputs,
        }

    def changes_line(self) -> str:
        """What the pairs' change detection found, for a one-line summary: the counts of the pairs it ran on,
        and which it did not (a pair without changes is no pair where nothing changed)."""
        from ...plugin.changes import COUNT_KEYS, counts_summary

        ran = [p for p in self.pairs if p.get("changes_status") == "done"]
        failed = sum(p.get("changes_status") == "failed" for p in self.pairs)
        if not ran and not failed:
            return "no changes detected (off, or no accepted pair)"
        # `sosmatch changes`'s count and words (nu60 D1: "15 objects gone" added landmarks, often two of one tree,
        # and objects never mapped), summed over the pairs whose record holds them (`workflow._changes_record`)
        counted = [p for p in ran if all(k in p for k in COUNT_KEYS)]
        total = {k: sum(int(p[k]) for p in counted) for k in COUNT_KEYS}
        said = [f"summed over {len(counted)} pair(s): {counts_summary(total)}"] if counted else []
        said += [f"{len(ran) - len(counted)} pair(s) without counts"] if len(counted) < len(ran) else []
        said += [f"change detection failed on {failed} pair(s)"] if failed else []
        return "changes " + "; ".join(said)


def session_warnings(session: dict[str, Any]) -> list[str]:
    """What a session's map warned of (its record's `warnings`, from its run.json verdict), named by it."""
    return [f"session {session['name']}: {w}" for w in session.get("warnings", ())]


def pair_warnings(pair: dict[str, Any]) -> list[str]:
    """What a pair's record says of its inputs without failing, named by it: what its match warned of
    (`match_warnings`, its match.json), that its maps' georeferences disagree (`georeference_warning`, match's
    warning repeated with what batch did), that the session graph left it out (`left_out`: it contradicts the
    other pairs, or it is an imprecise answer nothing corroborates), that merge's alignment control refused its
    accepted answer (`refused`,
    `refused_by` "control": left out of the session graph; a match's own "no match" is its table row's, not a
    warning), and what its change detection warned of (`changes_warnings`, from its changes.json)."""
    key = pair["pair"]
    said = [f"pair {key} match: {w}" for w in pair.get("match_warnings", ())]
    said += [f"pair {key}: {pair['georeference_warning']}"] if pair.get("georeference_warning") else []
    said += [f"pair {key}: {pair['left_out']}"] if pair.get("left_out") else []
    if pair.get("refused") and pair.get("refused_by", "control") == "control":
        said.append(f"pair {key} refused: {pair['refused']}")
    return said + [f"pair {key} changes: {w}" for w in pair.get("changes_warnings", ())]


def _table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return "" if v is None else str(v).replace("|", "/")

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def _landmark_positions(session_dir: str | Path | None) -> np.ndarray | None:
    """A session's landmark positions (landmarks.sosmap), None when it cannot be read."""
    from ...database.landmark_map import read_landmark_map
    from ...plugin.errors import InputError

    if session_dir is None:
        return None
    try:
        return read_landmark_map(Path(session_dir) / "landmarks.sosmap").positions
    except (InputError, OSError):
        return None


def _pair_rows(report: BatchReport) -> list[dict[str, Any]]:
    """Each pair's record with its transform a_from_b summarised: yaw about z, scale, and how far it moves B's
    landmarks (median and max of |T(p) - p| over them, `Sim3.displacement`: the translation alone is the move of
    the origin, which a small turn far from the data makes large)."""
    from ...plugin.multisession import Sim3

    where = {s["name"]: s.get("session") for s in report.sessions}
    positions: dict[str, np.ndarray | None] = {}
    rows = []
    for p in report.pairs:
        row = dict(p)
        t = p.get("transform")
        if t:
            rot = np.asarray(t["rotation"])
            row["yaw_deg"] = round(float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))), 3)
            row["scale"] = round(float(t["scale"]), 5)
            b = p.get("b")
            if b not in positions:
                positions[b] = _landmark_positions(where.get(b))
            if positions[b] is not None and len(positions[b]):
                moved = Sim3.from_dict(t).displacement(positions[b])
                row["moved_median_m"] = round(float(np.median(moved)), 3)
                row["moved_max_m"] = round(float(moved.max()), 3)
        rows.append(row)
    return rows


SESSION_COLUMNS = ["name", "kind", "status", "warnings", "images", "points3D", "landmarks", "seconds", "error"]
PAIR_COLUMNS = ["pair", "status", "warnings", "accepted", "in_graph", "num_associations", "refused_support", "refused",
                "yaw_deg", "moved_median_m", "moved_max_m", "scale", "changes_status", "gone", "new",
                "kept_a", "kept_b", "unseen_a", "unseen_b", "gone_unmapped", "new_unmapped",
                "seconds", "error"]
GROUP_COLUMNS = ["reference", "members", "status", "images", "points3D", "landmarks", "fused", "merged", "error"]


# the files a batch writes at the top of its folder, its report.json (the record) last: a user's file at one of
# their names is refused when the folder is taken, before the batch
REPORT_FILES = ("report.md", "sessions.csv", "pairs.csv", "session_graph.png", "report.json")


def write_report(report: BatchReport, out: OutputDir) -> None:
    """OUT/report.json, OUT/report.md, OUT/sessions.csv, OUT/pairs.csv and OUT/session_graph.png, into the batch's
    taken folder `out` (through its staging area and `publish`: each recorded as the batch's)."""
    write_text_atomic(out.staged("report.json"), json.dumps(report.to_dict(), indent=2) + "\n")
    # each row's number of warnings (the texts: report.md's Warnings, report.json's records)
    pair_rows = [{**p, "warnings": len(pair_warnings(p))} for p in _pair_rows(report)]
    session_rows = [{**s, "warnings": len(session_warnings(s))} for s in report.sessions]
    groups = [{**g, "members": " ".join(g["members"])} for g in report.groups]
    status = report.status
    md = [
        "# sosmatch batch report", "",
        f"{len(report.sessions)} sessions, {len(report.pairs)} pairs, {len(report.groups)} groups; {status}; "
        f"executor: {report.executor}; {report.seconds:.1f} s", "",
        *(["## Warnings", "", *[f"- {w}" for w in report.warnings], ""] if report.warnings else []),
        "## Sessions", "", _table(session_rows, SESSION_COLUMNS), "",
        "## Pairs", "", "(transform a_from_b: yaw about z, how far it moves B's landmarks (median, max m), scale; "
        "the counts of `sosmatch changes` (pairs/A__B/changes/changes.json `counts`): landmarks gone from A and new "
        "in B, landmarks of A and of B kept and unseen by the other session, objects never mapped gone from A and new "
        "in B)", "",
        _table(pair_rows, PAIR_COLUMNS), "",
        "## Groups (merged models)", "", _table(groups, GROUP_COLUMNS), "",
        "![session graph](session_graph.png)", "",
    ]
    if report.stale_outputs:
        md += ["## Outputs of no flight or group of this run (left in place, not read)", "",
               *[f"- {name}" for name in report.stale_outputs], ""]
    write_text_atomic(out.staged("report.md"), "\n".join(md))
    tables = (("sessions.csv", session_rows, SESSION_COLUMNS), ("pairs.csv", pair_rows, PAIR_COLUMNS))
    for name, rows, cols in tables:
        buf = io.StringIO()
        w = csv.DictWriter(buf, cols, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out.staged(name), buf.getvalue())
    plot_session_graph(report, out.staged("session_graph.png"))
    out.publish(REPORT_FILES[:-1], last=REPORT_FILES[-1])


def session_outline(session_dir: str | Path) -> tuple[np.ndarray, Any] | None:
    """(camera centres (K, 3), union of the keyframes' ground footprints) of a mapped session in its own frame,
    the ground taken flat at the median landmark height; None when the session cannot be read."""
    import shapely

    from ...database.colmap_model import read_colmap_model_poses
    from ...database.landmark_map import read_landmark_map
    from ...plugin.errors import InputError
    from ...plugin.evaluation.footprints import FlatGround, footprint_polygons

    try:
        poses, cameras, camera_of = read_colmap_model_poses(Path(session_dir) / "sparse")
        lmap = read_landmark_map(Path(session_dir) / "landmarks.sosmap")
    except InputError:
        return None
    if not len(poses):
        return None
    ground = FlatGround(float(np.median(lmap.positions[:, 2])) if len(lmap) else 0.0)
    polys = []
    for cid in sorted(set(camera_of.values())):
        idx = [k for k, n in enumerate(poses.names) if camera_of[n] == cid]
        polys.extend(footprint_polygons(cameras[cid], poses.rotations[idx], poses.centers[idx], ground, per_side=4))
    return poses.centers, shapely.union_all(polys)


def _placement(report: BatchReport) -> tuple[dict[str, Any], str]:
    """How to put the mapped sessions into one map: {name: reference_from_session Sim3} and a caption. Sessions
    that all lie in one frame (`pairs.frame_of`: one EPSG code, or one shared local frame) stay where they are;
    otherwise the largest merged group is drawn in its reference session's frame, with the sessions outside it
    that share that frame, and the others are left out (the figure names them: `plot_session_graph`). rev58 D3:
    only a shared EPSG code counted here, so sessions of one local frame outside the group were left off unsaid."""
    from ...plugin.multisession import Sim3
    from .pairs import frame_of

    done = [s for s in report.sessions if s["status"] == "done"]
    frames = {frame_of(s) for s in done}
    if len(frames) == 1 and None not in frames:
        code = frames.pop()
        return {s["name"]: Sim3.identity() for s in done}, f"EPSG:{code}" if code else "one shared local frame"
    groups = sorted(report.groups, key=lambda g: -len(g.get("members", [])))
    if groups and len(groups[0]["members"]) > 1:
        g = groups[0]
        placed = {n: Sim3.from_dict(t) for n, t in g["reference_from_session"].items()}
        ref = next((frame_of(s) for s in done if s["name"] == g["reference"]), None)
        if ref is not None:  # in the reference's frame as they are
            placed.update({s["name"]: Sim3.identity() for s in done
                           if s["name"] not in placed and frame_of(s) == ref})
        return placed, f"frame of {g['reference']} (its merged group)"
    return {s["name"]: Sim3.identity() for s in done}, "each session's own frame"


def _not_drawn_note(report: BatchReport, drawn: set[str], placed: dict[str, Any]) -> str:
    """The mapped sessions the map leaves out, named with why ("" when none is)."""
    import textwrap

    left = [s["name"] for s in report.sessions if s["status"] == "done" and s["name"] not in drawn]
    if not left:
        return ""
    parts = [f"{', '.join(names)} ({why})" for names, why in (
        ([n for n in left if n not in placed], "in no frame shared with those drawn"),
        ([n for n in left if n in placed], "its session does not read")) if names]
    return "\n" + textwrap.fill("not drawn: " + "; ".join(parts), 110)


def plot_session_graph(report: BatchReport, path: Path) -> None:
    """Two panels, readable however much the flights overlap. Left, the geography: every session's keyframe
    ground footprints (outline, light fill) and flight path in one frame (`_placement`), one colour per session,
    named in the legend. Right, the graph: sessions on a circle (names outside it), accepted pairs solid green
    labelled with |S| and the landmarks gone / new (objects never mapped), pairs left out of the graph (`left_out`)
    orange dash-dot, rejected dashed grey, failed dotted red; a node's outline colour is its merged group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import shapely

    from ...database.atomic import atomic_path

    names = [s["name"] for s in report.sessions]
    n = len(names)
    cmap = plt.get_cmap("tab20" if n > 10 else "tab10")
    colour = {nm: cmap(i % cmap.N) for i, nm in enumerate(names)}
    group_of = {m: k for k, g in enumerate(report.groups) for m in g["members"]}
    fig, (geo, graph) = plt.subplots(1, 2, figsize=(13, 6.2), gridspec_kw={"width_ratios": [1.15, 1.0]})

    placement, caption = _placement(report)
    drawn: set[str] = set()
    for s in report.sessions:
        t = placement.get(s["name"])
        outline = session_outline(s["session"]) if t is not None and s.get("session") else None
        if outline is None:
            continue
        centres, area = outline
        c = t.apply(centres)
        for poly in getattr(area, "geoms", [area]):
            if isinstance(poly, shapely.Polygon) and not poly.is_empty:
                ring = t.apply(np.column_stack([np.asarray(poly.exterior.coords), np.zeros(len(poly.exterior.coords))]))
                geo.fill(ring[:, 0], ring[:, 1], color=colour[s["name"]], alpha=0.12, lw=0)
                geo.plot(ring[:, 0], ring[:, 1], color=colour[s["name"]], lw=1.2)
        geo.plot(c[:, 0], c[:, 1], "-", color=colour[s["name"]], lw=0.8, alpha=0.8,
                 label=f"{s['name']} ({s.get('landmarks', '?')} landmarks)")
        geo.plot(c[:1, 0], c[:1, 1], "o", color=colour[s["name"]], ms=4)
        drawn.add(s["name"])
    geo.set_title(f"flights: keyframe footprints and paths ({caption})"
                  f"{_not_drawn_note(report, drawn, placement)}", fontsize=9)
    geo.set_aspect("equal", adjustable="datalim")
    geo.set_xlabel("x [m]")
    geo.set_ylabel("y [m]")
    if drawn:
        geo.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.1), ncol=3, frameon=False)

    ang = np.pi / 2 - 2 * np.pi * np.arange(n) / max(n, 1)
    pos = {nm: np.array([np.cos(a), np.sin(a)]) for nm, a in zip(names, ang)}
    labels: list[tuple[str, np.ndarray, np.ndarray]] = []  # accepted pairs' labels, placed after the layout
    for p in report.pairs:
        if p["a"] not in pos or p["b"] not in pos:
            continue
        (x0, y0), (x1, y1) = pos[p["a"]], pos[p["b"]]
        if p["status"] == "done" and p.get("accepted") and p.get("in_graph") is False:
            graph.plot([x0, x1], [y0, y1], "-.", color="tab:orange", lw=1.5, zorder=1)
        elif p["status"] == "done" and p.get("accepted"):
            graph.plot([x0, x1], [y0, y1], "-", color="tab:green", lw=2, zorder=1)
            text = f"|S| {p.get('num_associations', '')}"
            if p.get("gone") is not None:  # landmarks, then objects never mapped (nu60 D1: summed as "objects")
                text += f"\n-{p['gone']} +{p['new']}" + (f" (-{p['gone_unmapped']} +{p['new_unmapped']})"
                                                          if p.get("gone_unmapped") or p.get("new_unmapped") else "")
            labels.append((text, np.array([x0, y0]), np.array([x1, y1])))
        elif p["status"] == "done":
            graph.plot([x0, x1], [y0, y1], "--", color="0.7", lw=1, zorder=0)
        else:
            graph.plot([x0, x1], [y0, y1], ":", color="tab:red", lw=1, zorder=0)
    group_colours = plt.get_cmap("Dark2")
    for s in report.sessions:
        x, y = pos[s["name"]]
        edge = "tab:red" if s["status"] != "done" else group_colours(group_of.get(s["name"], 0) % 8)
        graph.scatter([x], [y], s=260, color=colour[s["name"]], zorder=2, edgecolors=[edge], linewidths=2.5)
        graph.annotate(s["name"], (1.22 * x, 1.22 * y), fontsize=9, ha="center", va="center")
    graph.set_title("session graph: accepted (|S|, landmarks gone / new (objects never mapped)),\n"
                    "left out (orange), rejected (dashed), failed (dotted red); node outline = merged group",
                    fontsize=8)
    graph.set_xlim(-1.5, 1.5)
    graph.set_ylim(-1.5, 1.5)
    graph.set_aspect("equal")
    graph.axis("off")
    fig.tight_layout()
    if left_off := _place_edge_labels(graph, labels, [pos[nm] for nm in names]):
        graph.text(0.5, 0.0, f"{left_off} of {len(labels)} pair labels left off (no room): see report.md",
                   transform=graph.transAxes, ha="center", va="top", fontsize=8, color="darkred")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


# where along its edge a label may sit (fraction from one end): the middle first, then either side of it, never
# on a node
LABEL_STOPS = (0.5, 0.4, 0.6, 0.3, 0.7, 0.22, 0.78, 0.16, 0.84)
LABEL_OVERLAP = 0.1  # the part of a label's box that others may cover and leave it readable


def _place_edge_labels(ax: Any, labels: list[tuple[str, np.ndarray, np.ndarray]], nodes: list[np.ndarray]) -> int:
    """Put each label on its edge where its box overlaps no label placed before it and no node: the first free
    stop of `LABEL_STOPS`. At the midpoints, the edges between opposite sessions of an even number on the circle
    all labelled the centre, one over the other (nu40: 2 of 15 labels of 6 flights unreadable). Short edges
    (neighbours on the circle, least room) are placed first. A label with no stop where it overlaps less than
    `LABEL_OVERLAP` of its box is left off, not drawn unreadable (every pair of 12 flights accepted: 66 labels);
    returns how many were (report.md has every pair's figures)."""
    renderer = ax.figure.canvas.get_renderer()
    taken = []
    for node in nodes:  # a node's disc (scatter s=260: ~16 pt across) is no place for a label
        cx, cy = ax.transData.transform(node)
        half = 10 * ax.figure.dpi / 72
        taken.append((cx - half, cy - half, cx + half, cy + half))

    def overlap(box: tuple[float, float, float, float]) -> float:
        return sum(max(0.0, min(box[2], t[2]) - max(box[0], t[0])) * max(0.0, min(box[3], t[3]) - max(box[1], t[1]))
                   for t in taken)

    left_off = 0
    for text, a, b in sorted(labels, key=lambda item: float(np.linalg.norm(item[2] - item[1]))):
        best = None
        for stop in LABEL_STOPS:
            artist = ax.annotate(text, tuple(a + stop * (b - a)), fontsize=7, ha="center", va="center",
                                 color="darkgreen", zorder=3,
                                 bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8})
            ext = artist.get_window_extent(renderer)
            box = (ext.x0, ext.y0, ext.x1, ext.y1)
            cost = overlap(box) / max((box[2] - box[0]) * (box[3] - box[1]), 1e-9)
            if best is None or cost < best[0]:
                if best is not None:
                    best[1].remove()
                best = (cost, artist, box)
            else:
                artist.remove()
            if cost == 0.0:
                break
        if best is not None and best[0] <= LABEL_OVERLAP:
            taken.append(best[2])
        elif best is not None:
            best[1].remove()
            left_off += 1
    return left_off
