"""changes.csv and changes.geojson (written by `sosmatch changes`): one row / feature per landmark of either map
and per object either session saw but never mapped.

changes.csv columns (CHANGE_COLUMNS): `class` (kept / gone / new / unseen), `session` (A or B), `index` (the
landmark's index in its own map), `x, y, z` (in A's frame), `size_m`, `confidence`, `counterpart` (index in the
other map of the landmark that matched it, -1 none), `counterpart_distance_m`, `size_change_m` (counterpart's
size minus this one's), `views` (keyframes of the other session that should have seen it), `evidence`
(landmark, nested, part, segments, none, views, confidence, height, flat: `sosmatch.plugin.changes.EVIDENCE`),
`height_above_ground_m` and `source` (`landmark`, or `track`: an object the session saw but never mapped, from its
track pieces, `sosmatch.plugin.changes.unmapped`; its `index` counts those objects of its session). Rows: A's
landmarks in order, then B's, then A's and B's objects never mapped. Empty cells are unknown values.
The reader applies the same validation the writer's rows satisfy.

changes.json (the run's record, written last by `sosmatch changes` and batch): `parse_changes_record` is its one
validation (the writer runs it on what it is about to write; `read_changes_record` reads one back), and its
`warnings` the run's warnings (a record written before they were kept has none: read as []).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..plugin.changes import CLASSES, EVIDENCE, ChangeResult, LandmarkChanges
from ..plugin.errors import InputError
from .geojson import HEIGHT_REFERENCE, to_wgs84
from .text_input import read_user_json, read_user_text

CHANGES_FORMAT = "sosmatch changes v1"

CHANGE_COLUMNS = ["class", "session", "index", "x", "y", "z", "size_m", "confidence", "counterpart",
                  "counterpart_distance_m", "size_change_m", "views", "evidence", "height_above_ground_m", "source"]
CHANGE_DTYPE = np.dtype([
    ("class", "U6"), ("session", "U1"), ("index", "<i8"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
    ("size_m", "<f8"), ("confidence", "<f8"), ("counterpart", "<i8"), ("counterpart_distance_m", "<f8"),
    ("size_change_m", "<f8"), ("views", "<i8"), ("evidence", "U10"), ("height_above_ground_m", "<f8"),
    ("source", "U8"),
])
SOURCES = ("landmark", "track")


def _fmt(value: float, digits: int) -> str:
    return "" if not math.isfinite(value) else f"{value:.{digits}f}"


def shown_confidence(value: float) -> float:
    """A confidence as changes.csv and changes.geojson show it: rounded DOWN to 3 decimals, so that a row shown at
    c passes `--min-confidence c` (rounded to nearest, 0.9996 showed as 1.000 yet `--min-confidence 1` dropped it)."""
    return math.floor(value * 1000.0 + 1e-9) / 1000.0 if math.isfinite(value) else value


def _parts(result: ChangeResult) -> list[tuple[str, str, LandmarkChanges, np.ndarray, np.ndarray]]:
    """(session, source, verdicts, positions, sizes) of every row group, in row order."""
    parts = [("A", "landmark", result.a, result.positions_a, result.sizes_a),
             ("B", "landmark", result.b, result.positions_b, result.sizes_b)]
    for session, verdict, objs in (("A", result.tracks_a, result.unmapped_a),
                                   ("B", result.tracks_b, result.unmapped_b)):
        if verdict is not None:
            parts.append((session, "track", verdict, objs.positions, objs.sizes))
    return parts


def change_rows(result: ChangeResult) -> list[list[str]]:
    """The rows of changes.csv (without the header)."""
    rows = []
    for session, source, verdict, pos, sizes in _parts(result):
        for i in range(len(pos)):
            shown = shown_confidence(float(verdict.confidence[i]))
            rows.append([str(verdict.label[i]), session, str(i), _fmt(pos[i, 0], 3), _fmt(pos[i, 1], 3),
                         _fmt(pos[i, 2], 3), _fmt(float(sizes[i]), 3), _fmt(shown, 3),
                         str(int(verdict.counterpart[i])), _fmt(float(verdict.distance_m[i]), 3),
                         _fmt(float(verdict.size_change_m[i]), 3), str(int(verdict.views[i])),
                         str(verdict.evidence[i]), _fmt(float(verdict.height_above_ground_m[i]), 2), source])
    return rows


def format_changes_csv(result: ChangeResult) -> str:
    """changes.csv of a comparison as text: the header `CHANGE_COLUMNS`, one row per landmark of A then of B, then
    one per object either session never mapped (`source` track); fixed decimals, so equal results give equal
    bytes (`read_changes_csv` reads it back)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CHANGE_COLUMNS)
    writer.writerows(change_rows(result))
    return buf.getvalue()


def read_changes_csv(path: str | Path) -> np.ndarray:
    """changes.csv -> structured array (CHANGE_DTYPE); InputError naming the file and line on any defect."""
    path = Path(path)
    text = read_user_text(path, "changes table")
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or [c.strip() for c in header] != CHANGE_COLUMNS:
        raise InputError(f"changes table must start with the header {','.join(CHANGE_COLUMNS)}", path, 1)
    out = []
    for lineno, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != len(CHANGE_COLUMNS):
            raise InputError(f"expected {len(CHANGE_COLUMNS)} fields, got {len(row)}", path, lineno)
        try:
            rec = tuple(_parse(v, CHANGE_DTYPE.fields[c][0]) for c, v in zip(CHANGE_COLUMNS, row))
        except ValueError:
            raise InputError("malformed value", path, lineno) from None
        if (rec[0] not in CLASSES or rec[1] not in ("A", "B") or rec[12] not in EVIDENCE or rec[2] < 0
                or rec[14] not in SOURCES):
            raise InputError("unknown class, session, evidence or source, or a negative index", path, lineno)
        out.append(rec)
    return np.array(out, dtype=CHANGE_DTYPE)


def _parse(value: str, dtype: np.dtype) -> object:
    value = value.strip()
    if dtype.kind == "f":
        return float(value) if value else float("nan")
    if dtype.kind == "i":
        return int(value)
    return value


def changes_feature_collection(result: ChangeResult, epsg: int) -> dict:
    """GeoJSON FeatureCollection (WGS84 points with height: z of A's frame, unconverted, see
    `geojson.HEIGHT_REFERENCE`) of every landmark of both maps, with class, session, index, size, confidence,
    evidence and the counterpart as properties; `epsg`: the CRS of A's frame."""
    features = []
    for session, source, verdict, pos, sizes in _parts(result):
        lonlat = to_wgs84(pos[:, :2], epsg) if len(pos) else np.zeros((0, 2))
        features.extend(_features(session, source, verdict, pos, sizes, lonlat))
    return {"type": "FeatureCollection",
            "properties": {"source_crs": f"EPSG:{epsg}", "height_reference": HEIGHT_REFERENCE,
                           "classes": list(CLASSES), **result.counts()},
            "features": features}


def _features(session: str, source: str, verdict: LandmarkChanges, pos: np.ndarray, sizes: np.ndarray,
              lonlat: np.ndarray) -> list[dict]:
    out = []
    for i in range(len(pos)):
        size = float(sizes[i])
        out.append({
            "type": "Feature", "id": f"{session}{i}" if source == "landmark" else f"{session}t{i}",
            "geometry": {"type": "Point", "coordinates": [round(float(lonlat[i, 0]), 8), round(float(lonlat[i, 1]), 8),
                                                          round(float(pos[i, 2]), 3)]},
            "properties": {"class": str(verdict.label[i]), "session": session, "index": i, "source": source,
                           "size_m": round(size, 3) if math.isfinite(size) else None,
                           "confidence": shown_confidence(float(verdict.confidence[i])),
                           "evidence": str(verdict.evidence[i]),
                           "counterpart": int(verdict.counterpart[i]), "x": round(float(pos[i, 0]), 3),
                           "y": round(float(pos[i, 1]), 3), "z": round(float(pos[i, 2]), 3)},
        })
    return out


def parse_changes_record(doc: object, path: str | Path = "<changes.json>") -> dict:
    """Validate a changes.json document (a JSON object of format CHANGES_FORMAT, `warnings` a list of strings when
    present) and return it with `warnings` always a list; InputError naming the file otherwise."""
    path = Path(path)
    if not isinstance(doc, dict):
        raise InputError("changes record must hold a JSON object", path)
    if doc.get("format") != CHANGES_FORMAT:
        raise InputError(f"not a record of `sosmatch changes` (format {str(doc.get('format'))[:40]!r}, this sosmatch "
                         f"reads {CHANGES_FORMAT!r})", path)
    warnings = doc.get("warnings", [])
    if not isinstance(warnings, list) or not all(isinstance(w, str) for w in warnings):
        raise InputError("changes record field warnings must be a list of strings", path)
    return {**doc, "warnings": list(warnings)}


def read_changes_record(path: str | Path) -> dict:
    """changes.json (or the folder holding it) -> its validated document (`parse_changes_record`)."""
    path = Path(path)
    if path.is_dir():
        path = path / "changes.json"
    return parse_changes_record(read_user_json(path, "changes record", redo="re-run `sosmatch changes`"), path)
