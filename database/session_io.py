"""Mapped session directories as the multi-session stages see them: the COLMAP model, the landmark map and
the landmark -> COLMAP 3D point table (landmarks.csv), read with validation; landmarks.csv written atomically.

A mapped session (docs/ARCHITECTURE.md) holds `sparse/`, `landmarks.sosmap` and `landmarks.csv`
(index,point3d_id,x,y,z,size_m,num_observations,image_names_json: `LANDMARK_CSV_COLUMNS`). A merged model written
by `sosmatch merge` has the same three, so it can itself be matched and merged again. A session's keyframe
images: `database.session_images`.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plugin.errors import InputError
from .atomic import write_text_atomic
from .landmark_map import MAX_WORLD_COORD_M, LandmarkMap, landmark_map_fingerprint, read_landmark_map
from .text_input import read_user_json, read_user_text

if TYPE_CHECKING:
    from ..plugin.changes import SessionObservations

MAX_ROWS = 2**31 - 1
MERGE_RECORD = "merge.json"  # a merged session's record (`sosmatch merge`, written last: it marks one)
# image_names_json: the observing keyframes' image names as a JSON list (["DJI 00000.jpg", "DJI 00001.jpg"]): any
# file name reads back whole. Earlier versions wrote the column `image_names`, the names joined by spaces, which a
# name holding a space cut apart (8 observations of `DJI 00000.jpg`... read back as 16 names 'DJI', '00000.jpg', ..);
# the column's name tells the two formats apart, and an older sosmatch refuses a new table (no `image_names`)
# rather than misreading it
LANDMARK_CSV_COLUMNS = ["index", "point3d_id", "x", "y", "z", "size_m", "num_observations", "image_names_json"]
LEGACY_NAMES_COLUMN = "image_names"  # space separated (written up to this change)


@dataclass
class SessionFiles:
    """The parts of a mapped session that merging needs (the reconstruction is loaded separately, on demand)."""

    path: Path
    name: str
    landmarks: LandmarkMap
    point3d_ids: np.ndarray  # (N,) COLMAP point3D id of landmark i (-1 when the landmark has no 3D point)
    record: MapRecord  # its run.json, read once for every stage that consults it (`map_record_of`)

    @property
    def sparse_dir(self) -> Path:
        return self.path / "sparse"

    @property
    def is_merged(self) -> bool:
        """A merged model (`sosmatch merge`'s output), not one flight's session (`is_merged_session`)."""
        return is_merged_session(self.path)


def is_merged_session(path: str | Path) -> bool:
    """Whether the session directory `path` is a merged model (`sosmatch merge`'s output): its merge.json, or the
    folder's own output marker naming `merge` (a merged session whose merge.json was lost is still one: rev45 D9)."""
    from .output_markers import output_command

    return (Path(path) / MERGE_RECORD).is_file() or output_command(path) == "merge"


@dataclass
class LandmarkTable:
    """landmarks.csv of a mapped session, ordered by landmark index."""

    positions: np.ndarray  # (N, 3)
    sizes: np.ndarray  # (N,) metres, NaN where unknown
    image_names: list[list[str]]  # observing keyframes per landmark
    point3d_ids: np.ndarray  # (N,) COLMAP point3D id (-1 when absent or not recorded)
    num_observations: np.ndarray | None = None  # (N,) when the table has the column
    # why `image_names` are not the keyframes' names (a table of an earlier sosmatch whose names held spaces,
    # which its format cut apart), or None; the counts (`support`) stand all the same
    names_problem: str | None = None

    @property
    def support(self) -> np.ndarray:
        """(N,) each landmark's number of observations: the num_observations column, else (tables without it)
        the number of its image names."""
        if self.num_observations is not None:
            return self.num_observations.astype(np.float64)
        return np.array([len(names) for names in self.image_names], dtype=np.float64)

    def names_or_raise(self, path: str | Path) -> list[list[str]]:
        """`image_names`, or InputError naming `path` when they are not the keyframes' names (`names_problem`)."""
        if self.names_problem is not None:
            raise InputError(self.names_problem, path)
        return self.image_names


def image_names_problem(names: object) -> str | None:
    """Why `names` is not a landmark's list of image names (the reader and the writer of landmarks.csv alike):
    a list of non-empty strings; None when it is."""
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        return "image_names_json is not a JSON list of image names"
    return None


def _read_names(field: str, legacy: bool) -> list[str] | str:
    """A row's image names: a JSON list, or (the legacy column) names separated by white space; or why the field
    holds none."""
    if legacy:
        return field.split()
    try:
        names = json.loads(field)
    except ValueError:
        return "image_names_json is not JSON"
    return image_names_problem(names) or names


def read_landmark_table(path: str | Path) -> LandmarkTable:
    """Read landmarks.csv (LANDMARK_CSV_COLUMNS; point3d_id and num_observations may be absent; an earlier
    sosmatch's `image_names`, space separated, in place of image_names_json).

    Rows may come in any order but their indices must be 0..N-1 without gaps or repeats.
    """
    path = Path(path)
    text = read_user_text(path, "landmark table")
    header = None
    legacy = False
    cut = None  # the first legacy row whose names do not count its observations: names that held spaces
    rows: dict[int, tuple[list[float], list[str], int, int]] = {}
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        if not row or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = [c.strip() for c in row]
            legacy = LANDMARK_CSV_COLUMNS[-1] not in header and LEGACY_NAMES_COLUMN in header
            names_column = LEGACY_NAMES_COLUMN if legacy else LANDMARK_CSV_COLUMNS[-1]
            missing = [c for c in ("index", "x", "y", "z", "size_m", names_column) if c not in header]
            if missing:
                raise InputError(f"landmark table lacks column(s) {', '.join(missing)}", path, lineno)
            col = {c: header.index(c) for c in header}
            continue
        try:
            idx = int(row[col["index"]])
            vals = [float(row[col[c]]) if row[col[c]].strip() else float("nan") for c in ("x", "y", "z", "size_m")]
            field = row[col[names_column]]
            pid = int(row[col["point3d_id"]]) if "point3d_id" in col else -1
            nobs = int(row[col["num_observations"]]) if "num_observations" in col else 0
        except (ValueError, IndexError):
            raise InputError("malformed landmark row", path, lineno) from None
        if isinstance(names := _read_names(field, legacy), str):
            raise InputError(f"malformed landmark row: {names}", path, lineno)
        if legacy and cut is None and "num_observations" in col and len(names) > nobs:
            cut = (lineno, len(names), nobs)
        if not all(np.isfinite(vals[:3])) or np.abs(vals[:3]).max() > MAX_WORLD_COORD_M or not (
                np.isnan(vals[3]) or 0 <= vals[3] < np.inf):  # the writer rounds sizes to mm
            raise InputError("landmark row holds a non-finite or far-off position or a negative or infinite size",
                             path, lineno)
        if not (0 <= idx < MAX_ROWS and -1 <= pid < 2**63 and 0 <= nobs < 2**31):
            raise InputError("landmark row holds an index, point3d_id or num_observations out of range", path, lineno)
        if idx in rows:
            raise InputError(f"duplicate landmark index {idx}", path, lineno)
        rows[idx] = (vals, names, pid, nobs)
    if header is None:
        raise InputError("landmark table is empty (no header)", path)
    n = len(rows)
    if sorted(rows) != list(range(n)):
        raise InputError("landmark indices must be 0..N-1 without gaps", path)
    vals = np.array([rows[i][0] for i in range(n)], dtype=np.float64).reshape(-1, 4)
    ids = np.array([rows[i][2] for i in range(n)], dtype=np.int64)
    nobs = np.array([rows[i][3] for i in range(n)], dtype=np.int64) if "num_observations" in col else None
    problem = None
    if cut is not None:
        problem = (f"holds image names of an earlier sosmatch that cut names with spaces apart (line {cut[0]}: "
                   f"{cut[1]} names for {cut[2]} observations): map the session again")
    return LandmarkTable(vals[:, :3], vals[:, 3], [rows[i][1] for i in range(n)], ids, nobs, problem)


def read_landmark_point_ids(path: str | Path, count: int | None = None) -> np.ndarray:
    """The point3d_id column of landmarks.csv by landmark index; with `count`, N must equal the map's size."""
    table = read_landmark_table(path)
    n = len(table.point3d_ids)
    if count is not None and n != count:
        raise InputError(f"landmark table has {n} rows but the landmark map has {count} landmarks", path)
    return table.point3d_ids


def read_map_record(map_dir: str | Path) -> dict | None:
    """MAP_DIR/run.json, the record `sosmatch map` writes last (inputs, keyframes, noise, verdict), as a dict; None
    when the directory has none (a merged model, an older sosmatch). InputError naming the file when it is
    unreadable, not JSON or not a JSON object: the one reader of the record, for every stage that consults it."""
    path = Path(map_dir) / "run.json"
    if not path.is_file():
        return None
    return read_user_json(path, "session record", redo="re-run `sosmatch map`")


@dataclass(frozen=True)
class MapRecord:
    """A session's run.json as read once (`map_record_of`), handed to every reader of one load (the checks of
    `read_session` and `load_map`, the noise, size definition and pose source, merge's flights): `record` (None:
    the session has none), or `error`, the InputError reading it raised. An unreadable record decides nothing for
    the checks that pass it (`check_session_usable`, `check_map_of_record`); the readers that need it raise that
    error (`get`), as `read_map_record` raised it to each."""

    record: dict | None
    error: InputError | None = None

    def get(self) -> dict | None:
        """The record (None: the session has none); the InputError naming run.json when it does not read."""
        if self.error is not None:
            raise self.error
        return self.record


def map_record_of(map_dir: str | Path) -> MapRecord:
    """MAP_DIR/run.json read once (`read_map_record`), its InputError kept for the readers that need it."""
    try:
        return MapRecord(read_map_record(map_dir))
    except InputError as exc:
        return MapRecord(None, exc)


def poses_record_beside(poses_csv: Path) -> dict | None:
    """The record (poses.json, format "sosmatch-poses") of the `sosmatch poses` output a poses.csv was taken from:
    its structure from motion made the CSV's poses; None for a CSV of another origin or a record that cannot be
    read."""
    record = Path(poses_csv).parent / "poses.json"
    try:
        if Path(poses_csv).name != "poses.csv" or not record.is_file():
            return None
        report = read_user_json(record, "poses record")
    except (InputError, OSError):  # a path too long to be a file's (a record edited by hand): not one
        return None
    return report if isinstance(report, dict) and report.get("format") == "sosmatch-poses" else None


# the `source` of a `poses` record of a model imported, not made by sosmatch's structure from motion (`poses
# --opensfm`): its poses are taken as given, as the same model given to `map --poses` is (README "Poses from a folder
# of photos"; rev51 D4: one model was "given" or "structure from motion" by the path taken)
IMPORTED_POSE_SOURCES = ("opensfm",)


def poses_of_own_sfm(poses_csv: Path) -> bool:
    """Whether a poses.csv was made by sosmatch's own structure from motion: the `sosmatch poses` record beside it
    (`poses_record_beside`) is not one of an imported model (`IMPORTED_POSE_SOURCES`)."""
    return record_of_own_sfm(poses_record_beside(poses_csv))


def record_of_own_sfm(report: dict | None) -> bool:
    """Whether a `sosmatch poses` record (`poses_record_beside`; None: none) is of sosmatch's own structure from
    motion, not of an imported model (`IMPORTED_POSE_SOURCES`)."""
    return report is not None and report.get("source") not in IMPORTED_POSE_SOURCES


def georeference_sigma_m(map_dir: str | Path) -> float | None:
    """The measured horizontal noise (m, per axis) of the GPS positions a session was georegistered on:
    MAP_DIR/poses/poses.json's `georegistration.gps_horizontal_sigma_m`, which `sosmatch map` of a folder of
    photos writes (structure from motion inside the session). None when not known: a map of given poses, a merged
    model, a local frame, or a record that does not read (the georeference is then not ranked by it)."""
    path = Path(map_dir) / "poses" / "poses.json"
    if not path.is_file():
        return None
    try:
        record = read_user_json(path, "poses record")
    except InputError:
        return None
    geo = record.get("georegistration") if isinstance(record, dict) else None
    sigma = geo.get("gps_horizontal_sigma_m") if isinstance(geo, dict) else None
    return float(sigma) if isinstance(sigma, (int, float)) and np.isfinite(sigma) and sigma > 0 else None


def map_keyframe_names(map_dir: str | Path) -> list[str] | None:
    """The keyframes (image names, flight order) the map in MAP_DIR was built from: run.json's `keyframes`; None
    for directories without a record or a record without them (merged models, older runs). InputError naming
    run.json when the record is unreadable or its `keyframes` is not a list of names (a record edited by hand)."""
    record = read_map_record(map_dir)
    if record is None or "keyframes" not in record:
        return None
    names = record["keyframes"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise InputError("session record has no list of keyframe names (`keyframes`)", Path(map_dir) / "run.json")
    return names


def map_min_observations(map_dir: str | Path, record: MapRecord | None = None) -> int | None:
    """theta_n (`triangulation.min_observations`) the map in MAP_DIR was made with: run.json's
    counts.min_observations, which the flight's views may have lowered below the configured one
    (`params.for_flight`); None for maps without it (merged models, older runs: the configured one is the best
    guess). A landmark there needed more than this many observations. InputError naming run.json when it is
    unreadable; a record whose `counts` is not an object (edited by hand) says nothing of it. `record`: the
    run.json when read already (`map_record_of`)."""
    counts = ((map_record_of(map_dir) if record is None else record).get() or {}).get("counts")
    value = counts.get("min_observations") if isinstance(counts, dict) else None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 1 else None


def check_not_batch_output(path: str | Path) -> None:
    """InputError when `path` is the output folder of `sosmatch batch` (its marker), which holds sessions and
    merged models but is none: naming what in it is one, relative to it (an error is cut at 400 characters; nu60
    D3: export said its landmarks.sosmap was not found)."""
    from .output_markers import output_command

    path = Path(path)
    if output_command(path) != "batch":
        return
    inside = [f"{kind}/{p.name}" for kind in ("merged", "sessions") if (path / kind).is_dir()
              for p in sorted((path / kind).iterdir()) if p.is_dir()]
    shown = ", ".join(inside[:4]) + (f" (and {len(inside) - 4} more)" if len(inside) > 4 else "")
    raise InputError("is the output folder of `sosmatch batch`, not a session: give one of its merged models "
                     f"(merged/REFERENCE) or mapped sessions (sessions/NAME) in it{': ' + shown if shown else ''}",
                     path)


def check_session_usable(path: str | Path, record: MapRecord | None = None) -> None:
    """InputError when `sosmatch map` refused the session directory `path` (run.json's verdict): its map is
    implausible or empty and no later stage may use it. Directories without a verdict (merged models, older
    sessions) pass. Also when a run of sosmatch into `path` has not finished (interrupted, or running now): what
    the directory holds may be an earlier run's, from other inputs (a killed `map --overwrite` leaves the old
    map beside its unfinished successor). `record`: its run.json when read already (`map_record_of`)."""
    from .output_markers import check_finished

    check_not_batch_output(path)
    check_finished(path)
    record = map_record_of(path) if record is None else record
    if record.error is not None:  # an unreadable record decides nothing here; the stage that needs it says so
        return
    verdict = (record.record or {}).get("verdict") or {}
    if isinstance(verdict, dict) and verdict.get("status") == "refused":
        reasons = "; ".join(str(r) for r in verdict.get("refusals", [])) or "no reason recorded"
        # the advice is the refusal's own: it may lie in the images (no landmarks at low contrast or blur) as
        # well as in the poses or camera, and the reasons say which (nu39: "fix its poses or camera" was said of
        # a thermal flight whose poses were right)
        raise InputError(f"`sosmatch map` refused this session ({reasons}); remedy what the refusal names and "
                         "map it again (see quality.png and run.json there)", path)


def read_session(path: str | Path, name: str | None = None) -> SessionFiles:
    """Open a mapped (or merged) session directory; raises InputError naming what is missing, or when the map
    was refused (`check_session_usable`)."""
    path = Path(path)
    if not path.is_dir():
        raise InputError("is a file, not a session directory (give the folder `sosmatch map` wrote)"
                         if path.exists() else "session directory not found", path)
    record = map_record_of(path)  # read once: the checks below, and the stages that take the session (`record`)
    check_session_usable(path, record)
    sparse = path / "sparse"
    if not (sparse / "images.bin").exists() and not (sparse / "images.txt").exists():
        raise InputError("session has no COLMAP model in sparse/ (was it mapped?)", path)
    lmap = read_landmark_map(path / "landmarks.sosmap")
    check_map_of_record(path, lmap, record)
    ids = read_landmark_point_ids(path / "landmarks.csv", len(lmap))
    check_model_of_landmarks(path, lmap, ids)
    return SessionFiles(path=path, name=name or path.resolve().name, landmarks=lmap, point3d_ids=ids, record=record)


def check_map_of_record(path: str | Path, lmap: LandmarkMap, record: MapRecord | None = None) -> None:
    """InputError when the session's run.json records another landmark map than its landmarks.sosmap (files of
    two sessions mixed in one folder: the map of one, the model and database of the other). Records without the
    fingerprint (merged models, older runs) and unreadable ones (the stage that needs them says so) pass.
    `record`: its run.json when read already (`map_record_of`)."""
    record = map_record_of(path) if record is None else record
    if record.error is not None:
        return
    recorded = (record.record or {}).get("landmarks_fingerprint")
    if isinstance(recorded, str) and recorded != landmark_map_fingerprint(lmap):
        raise InputError("is not the landmark map this session's run.json was written with (files of two sessions "
                         "mixed in one folder?); map the session again or copy its own landmarks.sosmap back",
                         Path(path) / "landmarks.sosmap")


# landmarks.sosmap keeps positions as float32 offsets from an origin near the data (about 1e-4 m at a few km): a
# point of sparse/ farther than this from its landmark belongs to another map
MODEL_POINT_TOLERANCE_M = 0.01


def check_model_of_landmarks(path: str | Path, lmap: LandmarkMap, point3d_ids: np.ndarray) -> None:
    """InputError when the session's sparse/ does not hold its landmarks: each landmark with a COLMAP point id
    (landmarks.csv) must find that point of sparse/ at its own position. Files of two sessions mixed in one folder
    pass every other check when the sessions share image names (the nineteenth sweep: another session's sparse/
    beside this one's map, and `merge` fused 11 landmarks instead of 98, exit 0)."""
    from .colmap_model import load_reconstruction

    have = np.flatnonzero(np.asarray(point3d_ids) >= 0)
    if not len(have):
        return
    sparse = Path(path) / "sparse"
    rec = load_reconstruction(sparse)
    points = rec.points3D
    if not len(points):
        raise InputError(f"holds none of the session's {len(have)} landmarks (no 3D points"
                         + ("" if len(rec.images) else ", no keyframes") + "): was it emptied or replaced? map the "
                         "session again", sparse)
    missing = [int(point3d_ids[i]) for i in have if int(point3d_ids[i]) not in points]
    if missing:
        raise InputError(f"holds no 3D point {missing[0]} of landmarks.csv ({len(missing)} of {len(have)} missing): "
                         "the model of another session or run? map the session again", sparse)
    xyz = np.array([points[int(point3d_ids[i])].xyz for i in have], dtype=np.float64)
    off = np.linalg.norm(xyz - lmap.positions[have], axis=1)
    worst = int(np.argmax(off))
    if not off[worst] <= MODEL_POINT_TOLERANCE_M:
        far = int(np.sum(~(off <= MODEL_POINT_TOLERANCE_M)))
        raise InputError(f"its 3D points are not the session's landmarks (point {int(point3d_ids[have[worst]])} "
                         f"lies {off[worst]:.2f} m from landmark {int(have[worst])}; {far} of {len(have)} off): the "
                         "model of another session or run? map the session again", sparse)


def check_database_of_model(path: str | Path, names: Sequence[str], centroids: Sequence[np.ndarray]) -> None:
    """InputError when the keypoints read from the session's database.db for the keyframes `names` are not the
    2D points of those images in its sparse/ (COLMAP keeps one list: the model's points2D are the database's
    keypoints): another session's database in this folder (the nineteenth sweep: `changes` read B's segments as
    A's and reported 1 gone / 1 new instead of 4 / 10, exit 0). Images the model lacks are left to the caller."""
    from .colmap_model import load_reconstruction

    sparse = Path(path) / "sparse"
    images = {im.name: im for im in load_reconstruction(sparse).images.values()}
    for name, xy in zip(names, centroids):
        image = images.get(name)
        if image is None:
            continue
        points = np.array([p.xy for p in image.points2D], dtype=np.float64).reshape(-1, 2)
        if len(points) != len(xy) or not np.allclose(points, xy, atol=1e-3):
            raise InputError(f"its keypoints of {name} are not the 2D points of {name} in sparse/ ({len(xy)} against "
                             f"{len(points)}): the database of another session or run? map the session again or copy "
                             "its own database.db back", Path(path) / "database.db")


def format_landmarks_csv(
    lmap: LandmarkMap, point3d_ids: np.ndarray, num_observations: np.ndarray, image_names: list[list[str]]
) -> str:
    """The landmarks.csv text (columns LANDMARK_CSV_COLUMNS; each landmark's image names a JSON list).
    ValueError for names the reader would refuse (`image_names_problem`)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(LANDMARK_CSV_COLUMNS)
    for i, (xyz, size) in enumerate(zip(lmap.positions, lmap.sizes)):
        writer.writerow(
            [
                i,
                int(point3d_ids[i]),
                f"{xyz[0]:.4f}",
                f"{xyz[1]:.4f}",
                f"{xyz[2]:.4f}",
                "nan" if not np.isfinite(size) else f"{float(size):.3f}",
                int(num_observations[i]),
                _names_field(image_names[i]),
            ]
        )
    return buf.getvalue()


def _names_field(names: Sequence[str]) -> str:
    """One landmark's image names as landmarks.csv holds them (JSON, non-ASCII kept as it is: the file is UTF-8)."""
    names = list(names)
    if (problem := image_names_problem(names)) is not None:
        raise ValueError(problem)
    return json.dumps(names, ensure_ascii=False)


def write_landmarks_csv(
    path: str | Path,
    lmap: LandmarkMap,
    point3d_ids: np.ndarray,
    num_observations: np.ndarray,
    image_names: list[list[str]],
) -> None:
    """Write landmarks.csv atomically."""
    write_text_atomic(path, format_landmarks_csv(lmap, point3d_ids, num_observations, image_names))


def read_session_observations(session: str | Path | SessionFiles, with_segments: bool = True,
                              with_tracks: bool = True, images_dir: str | Path | None = None,
                              ) -> SessionObservations:
    """A mapped (or merged) session (a directory, or one opened by `read_session`) as change detection needs it:
    landmarks, their support (observing keyframes), the keyframes' poses and cameras from sparse/ and, from
    database.db when present and `with_segments`, every segment each keyframe saw and (`with_tracks`) the tracks
    there that no landmark holds (for the objects it never mapped), and with `images_dir` the keyframes' images
    (read on demand, `KeyframeImages`). InputError when the session has no keyframe poses."""
    from ..plugin.changes import SessionObservations
    from .colmap_db import read_segment_detections
    from .colmap_model import read_colmap_model_poses
    from .session_images import KeyframeImages, recorded_levels  # it reads run.json through this module

    if not isinstance(session, SessionFiles):
        session = read_session(session)
    table = read_landmark_table(session.path / "landmarks.csv")
    poses, cameras, camera_of = read_colmap_model_poses(session.sparse_dir)
    if not len(poses):
        raise InputError("session has no keyframes with poses in sparse/ (nothing says what it observed)",
                         session.path)
    segments = tracks = None
    database = session.path / "database.db"
    if with_segments and database.exists() and not database.is_file():
        raise InputError("is a folder, not the session's COLMAP database", database)
    if with_segments and database.is_file():
        segments = tuple(read_segment_detections(database, poses.names))
        check_database_of_model(session.path, poses.names, [seg.centroids for seg in segments])
        if with_tracks:
            tracks = _unmapped_tracks(session, database, poses.names, segments)
    support = table.support  # counted, not the names split (a name with a space was two observations)
    lmap = session.landmarks
    cams = tuple(cameras[camera_of[n]] for n in poses.names)
    images = None if images_dir is None else KeyframeImages(Path(images_dir), poses.names,
                                                             [(c.width, c.height) for c in cams],
                                                             levels=recorded_levels(session.path, session.record))
    return SessionObservations(lmap.positions, lmap.sizes.astype(np.float64), poses, cams, segments, support,
                               tracks, images, map_min_observations(session.path, session.record))


def _unmapped_tracks(session: SessionFiles, database: Path, names: list[str], segments: tuple) -> tuple:
    """The tracks of database.db that share no observation with a landmark of sparse/ (pieces the map never
    promoted), as (n, 2) rows (keyframe index into `names`, keypoint index)."""
    from ..plugin.changes import tracks_from_matches
    from .colmap_db import read_keyframe_matches
    from .colmap_model import load_reconstruction

    tracks = tracks_from_matches(read_keyframe_matches(database, names), [len(s.centroids) for s in segments])
    order = {name: k for k, name in enumerate(names)}
    rec = load_reconstruction(session.sparse_dir)
    used = set()
    for point in rec.points3D.values():
        for el in point.track.elements:
            name = rec.images[el.image_id].name
            if name in order:
                used.add((order[name], int(el.point2D_idx)))
    return tuple(t for t in tracks if not any((int(k), int(i)) in used for k, i in t))
