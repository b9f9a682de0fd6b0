"""Load a landmark map for matching from whatever the user points at.

Accepted: a `.sosmap` file; a mapped session directory (holding `landmarks.sosmap`); a COLMAP sparse model
directory (cameras/images/points3D, .bin or .txt) or a directory whose `sparse/` (or `sparse/0/`) is one. A COLMAP
model's points become landmarks ordered by point3D id (roughly the order of triangulation); their sizes are
estimated from the tracks when a COLMAP database with affine keypoints (as `sosmatch map` writes) lies beside the
model, else they are NaN and the size gate is off for them. A model in Earth-centred coordinates (ECEF) is read
in its cameras' UTM zone. Every problem raises InputError naming the path.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plugin.errors import InputError
from ..plugin.map_noise import MapNoise
from .colmap_db import keypoint_sizes_px
from .landmark_map import POSE_SOURCE_SFM, LandmarkMap, read_landmark_map
from .output_markers import check_input_finished

if TYPE_CHECKING:
    import pycolmap

    from .session_io import MapRecord

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoadedMap:
    lmap: LandmarkMap
    kind: str  # "sosmap", "session" or "colmap"
    path: Path  # the file or model directory actually read
    noise: MapNoise | None = None  # the map's own noise figures (its file's, or its session's run.json), None: unknown
    # the settings that define its landmarks' metric sizes (`size_definition`), None: unknown (a bare map file)
    size_definition: dict[str, str] | None = None
    # its poses came from sosmatch's structure from motion (`recorded_sfm_poses`); False: given, or not known
    sfm_poses: bool = False


# mapping settings that change what a landmark's metric size measures, not only which landmarks there are: the
# size estimator ("mean" of h_px x depth / f, the paper's, reads 0.94 of "nadir" on common landmarks, 0.81 on
# conifers: sweep nu39) and the segmenter (where a mask's boundary lies). Maps that differ in them are compared with
# the search's size gate (theta_r, 20 % by default) all the same.
SIZE_SETTINGS = (("triangulation", "size_estimator"), ("segmentation", "backend"))


def size_definition(record: dict | None) -> dict[str, str] | None:
    """The size-defining settings (`SIZE_SETTINGS`) a map's run.json records in its params, as
    {"section.key": value}; None when the record or its params are missing (a map of an older version keeps the
    settings it had then, which `sosmatch config dump` does not know)."""
    params = record.get("params") if isinstance(record, dict) else None
    if not isinstance(params, dict):
        return None
    found = {f"{section}.{key}": str(params[section][key]) for section, key in SIZE_SETTINGS
             if isinstance(params.get(section), dict) and key in params[section]}
    return found or None


# the value of a size-defining setting in a merged map whose flights differ in it (`merged_size_definition`):
# "mixed (mean, nadir)"; such a map's sizes are of two definitions, unlike any other map's, its own kind included
MIXED = "mixed"


def _is_mixed(value: str) -> bool:
    return value.startswith(MIXED + " (")


def session_size_definition(session: str | Path, record: MapRecord | None = None) -> dict[str, str] | None:
    """The size definition of a mapped session (its run.json's params: `size_definition`) or of a merged one (its
    merge.json's `size_definition`, which `sosmatch merge` records from its flights': `merged_size_definition`);
    None when neither records it. The one reading for `match`, `changes` and `merge` (rev54 D2: a merged map, which
    has no run.json, was matched against a map of another size estimator without the warning its flights got).
    `record`: its run.json when read already (`session_io.map_record_of`)."""
    kept = _session_record(Path(session), record)
    if kept is None or "params" in kept:
        return size_definition(kept)
    found = kept.get("size_definition")
    if not isinstance(found, dict) or not found or not all(isinstance(v, str) for v in found.values()):
        return None
    return {str(k): v for k, v in found.items()}


def _shared_settings(parts: Sequence[dict[str, str] | None]) -> list[str] | None:
    """The settings every one of the size definitions `parts` records, sorted; None when there are none or any
    part's is unknown."""
    if not parts or any(p is None for p in parts):
        return None
    return sorted(set.intersection(*(set(p) for p in parts)))


def _differing_settings(parts: Sequence[dict[str, str] | None]) -> list[str]:
    """Those of `_shared_settings` whose values differ between `parts`, or are mixed (a mixed value differs from
    any other map's, its own kind included)."""
    return [key for key in _shared_settings(parts) or ()
            if len({p[key] for p in parts}) > 1 or any(_is_mixed(p[key]) for p in parts)]


def merged_size_definition(parts: Sequence[dict[str, str] | None]) -> dict[str, str] | None:
    """The size definition of a merge of maps of `parts` (`session_size_definition` each): each setting they all
    record, its value where they agree, else "mixed (a, b)" (`MIXED`); None when any part's is unknown."""
    if (shared := _shared_settings(parts)) is None:
        return None
    merged = {}
    for key in shared:
        values = sorted({v for p in parts for v in (p[key][len(MIXED) + 2:-1].split(", ") if _is_mixed(p[key])
                                                    else [p[key]])})
        merged[key] = values[0] if len(values) == 1 else f"{MIXED} ({', '.join(values)})"
    return merged or None


def size_definitions_differ(parts: Sequence[dict[str, str] | None], names: Sequence[str]) -> str | None:
    """What differs between the size definitions `parts` of the maps `names` ("key 'x' in NAME, 'y' in NAME2"),
    for the settings all of them record; a mixed value always differs (`MIXED`); None when they agree or any is
    unknown."""
    said = [f"{key} " + ", ".join(f"{p[key]!r} in {n}" for p, n in zip(parts, names))
            for key in _differing_settings(parts)]
    return "; ".join(said) or None


def size_definition_disagreement(a: dict[str, str] | None, b: dict[str, str] | None) -> str | None:
    """One line when both maps record how their sizes are defined (`size_definition`, `LoadedMap.size_definition`)
    and the definitions differ (the search compares the two maps' sizes within theta_r: a few percent of systematic
    difference costs associations and, on a kind of object, all of them), else None."""
    differ = _differing_settings([a, b])
    if not differ:
        return None
    said = ", ".join(f"{k} {a[k]!r} in A, {b[k]!r} in B" for k in differ)
    return (f"the maps define landmark sizes differently ({said}): the same object's size differs systematically "
            "between them, and the search compares sizes within a few tens of percent; map both sessions with the "
            "same setting (`--set " + differ[0] + "=...`)")


# what `sosmatch map` recorded as run.json's inputs.poses for poses of its structure from motion before run.json
# had `pose_source` (`workflows.poses.job`): such sessions are read as SfM-posed too
_SFM_SOURCE_TEXT = "structure from motion of "


def recorded_sfm_poses(record: dict | None) -> bool:
    """Whether a map's run.json says its poses came from sosmatch's structure from motion: its `pose_source`; for a
    record written before that field, its `inputs.poses`: the text it then held for SfM poses (`map --images`), or
    a poses.csv that a `sosmatch poses` record (poses.json) of its own SfM, not of an imported OpenSfM model, still
    lies beside (`poses`, then `map --poses`; `session_io.poses_of_own_sfm`).
    False for any other record or none (a map of given poses; an older session whose poses.csv is gone: unknown,
    taken as given)."""
    if not isinstance(record, dict):
        return False
    if "pose_source" in record:
        return record["pose_source"] == POSE_SOURCE_SFM
    inputs = record.get("inputs")
    source = inputs.get("poses") if isinstance(inputs, dict) else None
    if not isinstance(source, str):
        return False
    from .session_io import poses_of_own_sfm

    return source.startswith(_SFM_SOURCE_TEXT) or poses_of_own_sfm(Path(source))


def session_sfm_poses(session: str | Path, lmap: LandmarkMap | None = None, record: MapRecord | None = None) -> bool:
    """Whether a mapped (or merged) session's poses came from sosmatch's structure from motion: its map file's flag
    (`lmap`, read from it when None), else its record (`recorded_sfm_poses`): run.json, or for a merged session
    merge.json (whose `pose_source` `sosmatch merge` writes). The one reading for `match`, `merge` and `evaluate`.
    InputError naming a record that does not read. `record`: its run.json when read already."""
    session = Path(session)
    if lmap is None and (session / "landmarks.sosmap").is_file():
        lmap = read_landmark_map(session / "landmarks.sosmap")
    if lmap is not None and lmap.sfm_poses:
        return True
    return recorded_sfm_poses(_session_record(session, record))


def _session_record(session: Path, run: MapRecord | None = None) -> dict | None:
    """A session's record: run.json (`run` when read already, else `session_io.read_map_record`), else a merged
    session's merge.json; None when it has neither. InputError naming a record that does not read."""
    from .session_io import MERGE_RECORD, map_record_of
    from .text_input import read_user_json

    record = (map_record_of(session) if run is None else run).get()
    if record is None and (session / MERGE_RECORD).is_file():
        record = read_user_json(session / MERGE_RECORD, "merge record", redo="re-run `sosmatch merge`")
    return record


def session_map_noise(session: Path, lmap: LandmarkMap, record: MapRecord | None = None) -> MapNoise | None:
    """A mapped session's noise figures: those its map file carries (`landmark_map`, version 2), else those its
    run.json records (sessions mapped before map files carried them; the same figures of the same run). `record`:
    that run.json when read already."""
    return lmap.noise if lmap.noise is not None else read_map_noise(session, record)


def read_map_noise(session: Path, run: MapRecord | None = None) -> MapNoise | None:
    """The noise figures `sosmatch map` recorded in SESSION/run.json (`run` when read already, `plugin.map_noise`);
    None when the session has no run.json or the run predates them. A run.json that is not JSON is an InputError
    naming it."""
    from .session_io import map_record_of

    record = (map_record_of(session) if run is None else run).get()
    noise = None if record is None else record.get("noise")
    if not isinstance(noise, dict):
        return None
    try:
        figures = MapNoise.from_dict(noise)
    except (TypeError, ValueError):
        raise InputError("session record has a malformed 'noise' entry", Path(session) / "run.json") from None
    problem = figures.problem()
    if problem is not None:  # a session of an older version, or a record edited by hand: as if it had none
        log.warning("%s: session record's %s: taken as unknown", Path(session) / "run.json", problem)
        return None
    return figures


def _model_dir(path: Path) -> Path | None:
    for d in (path, path / "sparse", path / "sparse" / "0"):
        if d.is_dir() and any((d / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
            return d
    return None


def database_beside(model_dir: Path) -> Path | None:
    """The session's database.db next to a model (model/, its parent, or the parent of sparse/0)."""
    for d in (model_dir, model_dir.parent, model_dir.parent.parent):
        if (d / "database.db").is_file():
            return d / "database.db"
    return None


def track_sizes(rec: pycolmap.Reconstruction, ids: list[int], database: Path) -> np.ndarray:
    """Metric size of each point from its track: mean over observations of h_px * depth / f.

    h_px = sqrt(lambda_max(Sigma)) of the observing keypoint's affine shape A = sqrt(Sigma) (6-column keypoints,
    as `sosmatch map` writes them), depth from the image pose, f = sqrt(fx fy). Points whose keypoints carry no
    shape (2 or 4 columns) get NaN, so the size gate is off for them.
    """

    from .colmap_db import open_colmap_database

    db = open_colmap_database(database)
    h_px: dict[int, np.ndarray] = {}
    try:
        for iid in rec.images:
            sizes = keypoint_sizes_px(db.keypoints(iid))
            if sizes is not None:
                h_px[iid] = sizes
    finally:
        db.close()
    poses = {iid: img.cam_from_world().matrix() for iid, img in rec.images.items() if img.has_pose}
    focal = {cid: float(np.sqrt(cam.focal_length_x * cam.focal_length_y))
             for cid, cam in rec.cameras.items()}
    sizes = np.full(len(ids), np.nan, dtype=np.float32)
    for n, pid in enumerate(ids):
        point = rec.point3D(pid)
        vals = []
        for el in point.track.elements:
            h = h_px.get(el.image_id)
            m = poses.get(el.image_id)
            if h is None or m is None or el.point2D_idx >= len(h):
                continue
            depth = m[2, :3] @ point.xyz + m[2, 3]
            if depth > 0:
                vals.append(h[el.point2D_idx] * depth / focal[rec.images[el.image_id].camera_id])
        if vals:
            sizes[n] = np.mean(vals)
    return sizes


def read_colmap_points(model_dir: str | Path, database: str | Path | None = None) -> LandmarkMap:
    """Points of a COLMAP model as a landmark map (positions ordered by point3D id).

    Sizes come from the tracks (`track_sizes`) when a database is given or found beside the model, else NaN.
    """
    from .colmap_model import load_reconstruction

    model_dir = Path(model_dir)
    rec = load_reconstruction(model_dir)
    ids = sorted(rec.point3D_ids())
    if ids:
        xyz = np.array([rec.point3D(i).xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    else:
        xyz = np.zeros((0, 3))
    database = Path(database) if database is not None else database_beside(model_dir)
    if database is not None and ids:
        sizes = track_sizes(rec, ids, database)
    else:
        sizes = np.full(len(xyz), np.nan, dtype=np.float32)
    xyz, epsg = _earth_centred_to_grid(rec, xyz, model_dir)
    origin = xyz.mean(0) if len(xyz) else np.zeros(3)
    return LandmarkMap(xyz, sizes, origin, epsg=epsg)


def _earth_centred_to_grid(rec: pycolmap.Reconstruction, xyz: np.ndarray, model_dir: Path) -> tuple[np.ndarray, int]:
    """The points in the UTM zone `sosmatch map` gives the model's poses when those are Earth-centred (ECEF, as
    COLMAP's `model_aligner --alignment_type ecef` writes them; `plugin.geodesy.looks_like_ecef`), with its EPSG
    code; else as they are, EPSG 0. ECEF is metric but its z is not up: matched as a local frame, a model that
    matched in ENU gave "no match" (the nu18 sweep), as gravity-aligned matching needs z up."""
    from ..plugin.geodesy import ecef_to_grid, looks_like_ecef

    posed = [img for img in rec.images.values() if img.has_pose]
    if not posed or not len(xyz):
        return xyz, 0
    r_wc = np.array([np.asarray(img.cam_from_world().rotation.matrix()).T for img in posed])
    centers = np.array([np.asarray(img.projection_center()) for img in posed], dtype=np.float64)
    if not looks_like_ecef(centers, r_wc):
        return xyz, 0
    _, _, epsg = ecef_to_grid(centers, r_wc)  # the zone of the camera centres, as `map` chooses it
    grid, _, _ = ecef_to_grid(xyz, np.broadcast_to(np.eye(3), (len(xyz), 3, 3)), epsg)
    log.info("%s: the model is in Earth-centred (ECEF) coordinates; its points are matched in UTM, EPSG:%d",
             model_dir, epsg)
    return grid, epsg


def load_map(path: str | Path) -> LoadedMap:
    """Read a map to match from a .sosmap file, a session directory or a COLMAP model (see module docstring)."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file or directory", path)
    # the output a sosmatch command wrote it into (a map file's folder, a model's session) must be finished: a
    # killed `merge --overwrite` leaves its new landmarks.sosmap beside the old model
    check_input_finished(path)
    if path.is_file():
        if path.name == "landmarks.sosmap" and (path.parent / "run.json").is_file():
            # a session's own map file is that session (its checks, and its noise figures: without them a bare
            # .sosmap is matched at the configured tolerances, which lost pairs that matched as sessions)
            return load_map(path.parent)
        if path.suffix == ".sosmap":
            lmap = read_landmark_map(path)
            return LoadedMap(lmap, "sosmap", path, lmap.noise, sfm_poses=lmap.sfm_poses)
        if path.name.startswith("points3D."):
            return LoadedMap(read_colmap_points(path.parent), "colmap", path.parent)
        raise InputError("not a landmark map (.sosmap), session directory or COLMAP model", path)
    if not path.is_dir():  # a device, a pipe, a socket: neither a map file nor a folder of one (nu45: /dev/zero)
        raise InputError("not a file or directory (a device or a pipe?): a landmark map (.sosmap), session "
                         "directory or COLMAP model is expected", path)
    if (path / "landmarks.sosmap").is_file():
        from .session_io import check_map_of_record, check_session_usable, map_record_of

        record = map_record_of(path)  # read once, for every check and figure below
        check_session_usable(path, record)
        lmap = read_landmark_map(path / "landmarks.sosmap")
        check_map_of_record(path, lmap, record)  # its noise figures (run.json) must be this map's
        return LoadedMap(lmap, "session", path / "landmarks.sosmap", session_map_noise(path, lmap, record),
                         session_size_definition(path, record), session_sfm_poses(path, lmap, record))
    if (path / "run.json").is_file() and (path / "sparse").is_dir():  # landmarks.sosmap is not a file here
        # a session `sosmatch map` wrote has its map in landmarks.sosmap: matched from sparse/ instead, it lost its
        # sizes' noise figures and its checks, and every other command refused the folder (the nineteenth sweep)
        raise InputError("mapped session without its landmarks.sosmap (deleted or moved?): map it again, or give "
                         "its sparse/ model explicitly to match the COLMAP points", path)
    model = _model_dir(path)
    if model is not None:
        return LoadedMap(read_colmap_points(model), "colmap", model)
    if (path / "session.json").is_file() and (path / "images").is_dir():
        raise InputError("a synthetic session that is not mapped yet (no landmarks.sosmap): map it first "
                         f"(`sosmatch map --poses {path} --out MAPPED`) and give MAPPED", path)
    from .session_io import check_not_batch_output

    check_not_batch_output(path)  # it holds no landmarks.sosmap: `check_session_usable` above never saw it
    raise InputError("directory holds neither landmarks.sosmap nor a COLMAP model (points3D.bin/.txt): a mapped "
                     "session (`sosmatch map --out`) is expected", path)
