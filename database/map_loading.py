"""Load a landmark map for matching from whatever the user points at.

Accepted: a `.sosmap` file; a mapped session directory (holding `landmarks.sosmap`); a COLMAP sparse model
directory (cameras/images/points3D, .bin or .txt) or a directory whose `sparse/` (or `sparse/0/`) is one. A COLMAP
model has no sizes: its points become landmarks ordered by point3D id (roughly the order of triangulation), the
sizes are NaN and the size gate is off for them. Every problem raises InputError naming the path.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from .landmark_map import LandmarkMap, read_landmark_map


@dataclass(frozen=True)
class LoadedMap:
    lmap: LandmarkMap
    kind: str  # "sosmap", "session" or "colmap"
    path: Path  # the file or model directory actually read


def _model_dir(path: Path) -> Path | None:
    for d in (path, path / "sparse", path / "sparse" / "0"):
        if d.is_dir() and any((d / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
            return d
    return None


def read_colmap_points(model_dir: str | Path) -> LandmarkMap:
    """Points of a COLMAP model as a size-less landmark map (positions ordered by point3D id)."""
    import pycolmap

    model_dir = Path(model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError on malformed models
        raise InputError(f"cannot read COLMAP model: {exc}".splitlines()[0], model_dir) from None
    ids = sorted(rec.point3D_ids())
    if ids:
        xyz = np.array([rec.point3D(i).xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    else:
        xyz = np.zeros((0, 3))
    origin = xyz.mean(0) if len(xyz) else np.zeros(3)
    return LandmarkMap(xyz, np.full(len(xyz), np.nan, dtype=np.float32), origin, epsg=0)


def load_map(path: str | Path) -> LoadedMap:
    """Read a map to match from a .sosmap file, a session directory or a COLMAP model (see module docstring)."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file or directory", path)
    if path.is_file():
        if path.suffix == ".sosmap":
            return LoadedMap(read_landmark_map(path), "sosmap", path)
        if path.name.startswith("points3D."):
            return LoadedMap(read_colmap_points(path.parent), "colmap", path.parent)
        raise InputError("not a landmark map (.sosmap), session directory or COLMAP model", path)
    if (path / "landmarks.sosmap").is_file():
        return LoadedMap(read_landmark_map(path / "landmarks.sosmap"), "session", path / "landmarks.sosmap")
    model = _model_dir(path)
    if model is not None:
        return LoadedMap(read_colmap_points(model), "colmap", model)
    raise InputError("directory holds neither landmarks.sosmap nor a COLMAP model (points3D.bin/.txt)", path)
