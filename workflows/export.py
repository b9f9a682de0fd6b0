"""`sosmatch export`: a landmark map (or a mapped session) as GeoJSON (WGS84), PLY or CSV for other tools.

- GeoJSON: see `sosmatch.database.geojson` (points or size circles, lon/lat/height, the map's CRS in the
  properties); needs a georeferenced map (EPSG != 0) or `epsg=`.
- PLY: binary little-endian vertices with double x, y, z in the map's world frame (UTM-sized coordinates keep
  millimetres, unlike float32) and a float size; the CRS is in a header comment.
- CSV: index,x,y,z,size_m (+ lon,lat when georeferenced).
A session directory is read through its landmarks.sosmap; its landmarks.csv, when present, adds the
observation counts to the GeoJSON properties.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..database.geojson import check_projected_crs, check_within_crs_area, geojson_text, to_wgs84
from ..database.landmark_map import LandmarkMap, landmark_map_fingerprint, read_landmark_map
from ..database.output_files import OutputFiles
from ..database.output_markers import check_input_finished, fingerprint
from ..database.session_io import check_map_of_record, check_session_usable, map_record_of, read_landmark_table
from ..plugin.errors import InputError

log = logging.getLogger(__name__)


def load_map(source: str | Path) -> tuple[LandmarkMap, dict[str, np.ndarray]]:
    """The landmark map of a .sosmap file or a session directory, and per-landmark extras from landmarks.csv."""
    source = Path(source)
    if source.is_dir():
        record = map_record_of(source)  # run.json read once for both checks
        check_session_usable(source, record)
        lmap = read_landmark_map(source / "landmarks.sosmap")
        check_map_of_record(source, lmap, record)
        extras: dict[str, np.ndarray] = {}
        table_path = source / "landmarks.csv"
        if table_path.exists():
            table = read_landmark_table(table_path)
            if len(table.positions) == len(lmap) and table.num_observations is not None:
                extras["num_observations"] = table.num_observations
        return lmap, extras
    if not source.exists():
        raise InputError("landmark map or session directory not found", source)
    if source.name == "landmarks.sosmap" and (source.parent / "run.json").is_file():
        return load_map(source.parent)  # a session's own map file is that session (its checks), as `match` reads it
    check_input_finished(source)  # a killed `merge --overwrite` leaves its new map file beside the old
    return read_landmark_map(source), {}


def ply_bytes(lmap: LandmarkMap, epsg: int) -> bytes:
    """Binary PLY of the landmarks: double x, y, z (world frame) and float size_m."""
    # no "comment origin" line: a session's own landmarks.ply stores float32 offsets and says "world = vertex +
    # origin"; these vertices are world coordinates already, and an origin line read the same way doubled them
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"comment sosmatch landmarks in world coordinates (no origin to add), "
              f"crs {'EPSG:' + str(epsg) if epsg else 'local'}\n"
              f"element vertex {len(lmap)}\nproperty double x\nproperty double y\nproperty double z\n"
              "property float size_m\nend_header\n").encode("ascii")
    rec = np.zeros(len(lmap), dtype=[("xyz", "<f8", (3,)), ("size", "<f4")])
    rec["xyz"] = lmap.positions
    rec["size"] = lmap.sizes
    return header + rec.tobytes()


def csv_text(lmap: LandmarkMap, epsg: int) -> str:
    """CSV of the landmarks: index, x, y, z (world frame, 0.1 mm) and size_m, with lon and lat (WGS84, from `epsg`)
    when the map is georeferenced."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    lonlat = to_wgs84(lmap.positions[:, :2], epsg) if epsg and len(lmap) else None
    w.writerow(["index", "x", "y", "z", "size_m"] + (["lon", "lat"] if lonlat is not None else []))
    for i, (p, s) in enumerate(zip(lmap.positions, lmap.sizes)):
        row = [i, f"{p[0]:.4f}", f"{p[1]:.4f}", f"{p[2]:.4f}", "nan" if not np.isfinite(s) else f"{float(s):.3f}"]
        if lonlat is not None:
            row += [f"{lonlat[i, 0]:.9f}", f"{lonlat[i, 1]:.9f}"]
        w.writerow(row)
    return buf.getvalue()


def run(
    source: str | Path,
    geojson: str | Path | None = None,
    ply: str | Path | None = None,
    csv_out: str | Path | None = None,
    epsg: int | None = None,
    geometry: str = "point",
    overwrite: bool = False,
) -> dict[str, Any]:
    """Export the landmarks of `source` (a .sosmap or a session directory) to the requested files (atomic).

    `epsg` gives the CRS code of maps saved with 0 whose frame is in fact that CRS (another code than the one a
    map records is an InputError: a relabelling, not a reprojection); a code must be a projected CRS (the map's
    coordinates are metres). Output files go through
    `sosmatch.database.output_files.OutputFiles`: a file that exists is replaced only when this command wrote it
    (and `overwrite` when it came from another map or options). Returns {"landmarks": N, "epsg": code,
    "written": [paths]}.
    """
    if geojson is None and ply is None and csv_out is None:
        raise InputError("nothing to export: give --geojson, --ply and/or --csv")
    if geometry not in ("point", "circle"):
        raise InputError(f"geometry must be 'point' or 'circle', got {geometry!r}")
    if geometry == "circle" and geojson is None:  # PLY and CSV hold points: it was ignored there, and recorded
        raise InputError("--circles draws GeoJSON polygons: give it with --geojson (PLY and CSV hold points)")
    targets = {name: Path(p) for name, p in (("geojson", geojson), ("ply", ply), ("csv", csv_out)) if p is not None}
    lmap, extras = load_map(source)
    if epsg and lmap.epsg and int(epsg) != int(lmap.epsg):
        # --epsg relabels the coordinates, it does not reproject them: every landmark would land elsewhere
        # (the ninth sweep: 500 km west, exit 0)
        raise InputError(f"the map records its frame as EPSG:{lmap.epsg}; --epsg {epsg} would relabel its "
                         "coordinates, not reproject them (every landmark placed elsewhere): omit --epsg", source)
    code = int(epsg or lmap.epsg)
    if code:
        check_projected_crs(code, source if not epsg else None)
        # a CRS given here is a claim every format records (PLY in its header): a local map stamped with one is
        # refused for all (rev58 D2: --ply wrote "crs EPSG:32632" for coordinates of a few hundred metres, --csv
        # refused); the map's own CRS is checked where it is converted to lon/lat, and a PLY copies it as it is
        if epsg or "geojson" in targets or "csv" in targets:
            check_within_crs_area(code, lmap.positions[:, :2], source)
    elif "geojson" in targets:  # said here, where the map's name is known
        raise InputError("the landmark map has no geographic reference (EPSG 0, a local frame): give --epsg CODE "
                         "of its world frame if it has one", source)
    identity = fingerprint({"map": landmark_map_fingerprint(lmap), "epsg": code, "geometry": geometry,
                            "formats": sorted(targets), "extras": sorted(extras)})
    files = OutputFiles(targets.values(), "export", identity, inputs=[source], overwrite=overwrite)
    texts: dict[str, bytes | str] = {}
    if "geojson" in targets:
        texts["geojson"] = geojson_text(lmap, code, geometry, extras)
    if "ply" in targets:
        texts["ply"] = ply_bytes(lmap, code)
    if "csv" in targets:
        texts["csv"] = csv_text(lmap, code)
    for name, data in texts.items():
        files.write(targets[name], data)
    written = [str(targets[name]) for name in texts]
    log.info("exported %d landmarks to %s", len(lmap), ", ".join(written))
    return {"landmarks": len(lmap), "epsg": code, "written": written}
