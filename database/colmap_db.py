"""The COLMAP database of a mapped session: segment centroids as features, track associations as matches.

Layout written (pycolmap 4.2.1, the order COLMAP itself uses): one camera (id 1, in its own COLMAP model), one
rig (id 1) with that camera as reference sensor, images with ids 1..N in keyframe order, one frame per image
(frame id = image id), keypoints with 6 columns (x, y, a11, a12, a21, a22: the centroid and the affine shape
A = sqrt(Sigma) of the mask's pixel covariance, both in the real, distorted image), raw `matches` and
`two_view_geometries` with config CALIBRATED whose inlier matches are the track associations. Descriptors are
not written: triangulation does not need them.

COLMAP 3.8 (Debian's `colmap`) prepares an INSERT into `images` with seven prior_* columns that 4.x dropped;
`write_colmap_database` adds them (NULL) so `colmap point_triangulator` runs on the file and pycolmap still
reads it (checked facts: /work/shared/notes/pycolmap-4.md).
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from .atomic import atomic_path
from .cameras import pycolmap_camera
from .taken import make_dirs
from .text_input import open_without_waiting

if TYPE_CHECKING:
    from ..plugin.changes import KeyframeSegments

log = logging.getLogger(__name__)

PRIOR_COLUMNS_38 = ("prior_qw", "prior_qx", "prior_qy", "prior_qz", "prior_tx", "prior_ty", "prior_tz")
CAMERA_ID = 1
RIG_ID = 1
# Variance of a uniform pixel: the smallest honest covariance eigenvalue of a mask, so tiny or line-shaped
# masks still get a non-degenerate affine shape (COLMAP derives scale and orientation from it).
MIN_PIXEL_VARIANCE = 1.0 / 12.0


def affine_keypoints(centroids: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """(K, 6) float32 COLMAP keypoints: centroid (COLMAP pixel convention) and A = sqrt(Sigma), row-major.

    A is the symmetric square root of the covariance, so A maps the unit circle onto the mask's 1-sigma
    ellipse; eigenvalues are clamped at 1/12 px^2 to keep A invertible.
    """
    centroids = np.asarray(centroids, dtype=np.float64).reshape(-1, 2)
    covariances = np.asarray(covariances, dtype=np.float64).reshape(-1, 2, 2)
    if len(centroids) != len(covariances):
        raise ValueError(f"{len(centroids)} centroids but {len(covariances)} covariances")
    out = np.zeros((len(centroids), 6), dtype=np.float32)
    if not len(centroids):
        return out
    sym = 0.5 * (covariances + np.transpose(covariances, (0, 2, 1)))
    evals, evecs = np.linalg.eigh(sym)
    roots = np.sqrt(np.maximum(evals, MIN_PIXEL_VARIANCE))
    affine = np.einsum("kij,kj,klj->kil", evecs, roots, evecs)
    out[:, :2] = centroids
    out[:, 2:] = affine.reshape(-1, 4)
    return out


def keypoint_sizes_px(keypoints: np.ndarray) -> np.ndarray | None:
    """Pixel size h = sqrt(lambda_max(Sigma)) of each affine keypoint (the inverse of `affine_keypoints`: the
    largest singular value of A = sqrt(Sigma)); None for keypoints without a shape (2 or 4 columns)."""
    kp = np.asarray(keypoints)
    if kp.ndim != 2 or kp.shape[1] != 6:
        return None
    return np.linalg.svd(kp[:, 2:].astype(np.float64).reshape(-1, 2, 2), compute_uv=False)[:, 0]


SQLITE_MAGIC = b"SQLite format 3\x00"
MAX_IMAGE_ID = 2147483647  # COLMAP's pair ids: image_id1 * MAX_IMAGE_ID + image_id2


class DatabaseReader:
    """A user's COLMAP database read through a read-only SQLite connection: image ids by name and keypoints.

    Read-only because a reader must not write its input: pycolmap's Database opens read-write and commits its
    schema on open (the file's change counter and mtime move on every read, so a batch re-run saw its mapped
    flights as changed), and it cannot open a file it may not write. Keypoints are COLMAP's float32 blobs of
    `rows` x `cols` (2: x y, 4: similarity, 6: affine shape), as pycolmap's read_keypoints returns them."""

    def __init__(self, path: Path, con: sqlite3.Connection) -> None:
        self.path, self.con = path, con

    def image_ids(self) -> dict[str, int]:
        try:
            return {str(name): int(iid) for iid, name in self.con.execute("SELECT image_id, name FROM images")}
        except sqlite3.Error as exc:
            raise InputError(f"cannot read the images of the COLMAP database: {exc}", self.path) from None

    def keypoints(self, image_id: int) -> np.ndarray:
        """(rows, cols) float32 keypoints of one image; (0, 2) when it has none."""
        try:
            row = self.con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?",
                                   (int(image_id),)).fetchone()
        except sqlite3.Error as exc:
            raise InputError(f"cannot read the keypoints of the COLMAP database: {exc}", self.path) from None
        if row is None or not row[0]:
            return np.zeros((0, 2), np.float32)
        rows, cols, data = row
        if not isinstance(data, bytes) or cols not in (2, 4, 6) or len(data) != 4 * rows * cols:
            raise InputError(f"keypoints of image {image_id}: a blob of {rows} x {cols} float32 expected",
                             self.path)
        return np.frombuffer(data, dtype="<f4").reshape(rows, cols).copy()

    def matches(self) -> list[tuple[int, int, np.ndarray]]:
        """Every image pair's raw matches: (image id 1, image id 2, (M, 2) uint32 keypoint indices), pairs without
        matches left out. COLMAP stores a pair once, as pair_id = id1 * 2147483647 + id2 with id1 < id2."""
        try:
            rows = self.con.execute("SELECT pair_id, rows, cols, data FROM matches").fetchall()
        except sqlite3.Error as exc:
            raise InputError(f"cannot read the matches of the COLMAP database: {exc}", self.path) from None
        out = []
        for pair_id, n, cols, data in rows:
            if not n:
                continue
            if not isinstance(data, bytes) or cols != 2 or len(data) != 8 * n:
                raise InputError(f"matches of pair {pair_id}: a blob of {n} x 2 uint32 expected", self.path)
            id1, id2 = divmod(int(pair_id), MAX_IMAGE_ID)
            out.append((id1, id2, np.frombuffer(data, dtype="<u4").reshape(n, 2).copy()))
        return out

    def close(self) -> None:
        self.con.close()


def open_colmap_database(path: str | Path) -> DatabaseReader:
    """A user's COLMAP database opened for reading (read-only); InputError naming it when it is not one.

    The SQLite header is checked first, so that a file of another kind is named as such."""
    path = Path(path)
    try:
        with open_without_waiting(path) as f:
            head = f.read(len(SQLITE_MAGIC))
    except FileNotFoundError:
        raise InputError("COLMAP database not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read COLMAP database: {exc.strerror or exc}", path) from None
    if head != SQLITE_MAGIC:
        raise InputError("not a COLMAP database (not an SQLite file" + (": empty)" if not head else ")"), path)
    # pycolmap leaves its databases in WAL mode, where even a read-only reader creates -wal and -shm files beside
    # the database (left behind, as it may not checkpoint): without pending WAL content the file is complete, so
    # it is read as immutable (no locks, no side files); sosmatch publishes databases by rename, never in place
    wal = path.with_name(path.name + "-wal")
    immutable = "" if wal.is_file() and wal.stat().st_size > 0 else "&immutable=1"
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro{immutable}", uri=True)
        try:
            tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.Error:
            con.close()
            raise
    except sqlite3.Error as exc:
        raise InputError(f"cannot read COLMAP database: {exc}".splitlines()[0], path) from None
    missing = sorted({"cameras", "images", "keypoints"} - tables)
    if missing:
        con.close()
        raise InputError(f"not a COLMAP database (an SQLite file without the table {missing[0]})", path)
    return DatabaseReader(path, con)


def read_segment_detections(path: str | Path, names: Sequence[str]) -> list[KeyframeSegments]:
    """The keypoints of the images `names` in a session's database.db (segment centroids and pixel sizes).

    A name missing from the database is an InputError (the database belongs to another session); an image
    without keypoints gives an empty detection set.
    """

    from ..plugin.changes import KeyframeSegments

    path = Path(path)
    if not path.is_file():
        raise InputError("COLMAP database not found", path)
    db = open_colmap_database(path)
    try:
        ids = db.image_ids()
        out = []
        for name in names:
            if name not in ids:
                raise InputError(f"image {name!r} of the model is not in the database", path)
            kp = np.asarray(db.keypoints(ids[name]), dtype=np.float64)
            sizes = keypoint_sizes_px(kp)
            out.append(KeyframeSegments(kp[:, :2].copy(), sizes if sizes is not None else np.full(len(kp), np.nan)))
        return out
    finally:
        db.close()


def read_keyframe_matches(path: str | Path, names: Sequence[str]) -> list[tuple[int, int, np.ndarray]]:
    """The matched keypoint pairs of a session's database.db between the images `names` (the tracks the map
    wrote there, `write_colmap_database`): (index a, index b into names, (M, 2) keypoint indices). Pairs with an
    image outside `names` are left out; an unreadable database is an InputError. Read-only, as every reader here
    (`DatabaseReader`)."""
    db = open_colmap_database(Path(path))
    try:
        order = {name: k for k, name in enumerate(names)}
        index = {iid: order[name] for name, iid in db.image_ids().items() if name in order}
        pairs = db.matches()
    finally:
        db.close()
    return [(index[i1], index[i2], m.astype(np.int64)) for i1, i2, m in pairs if i1 in index and i2 in index]


def track_associations(
    track_ids: Sequence[np.ndarray], mode: str = "all", min_observations: int = 0
) -> dict[tuple[int, int], np.ndarray]:
    """Match lists implied by per-keyframe track ids.

    Args:
        track_ids: per keyframe, the track id of every mask (-1 = no track).
        mode: "consecutive" links each observation to the next one of the same track; "all" links every pair
            of observations of a track (a clique, so one bad link cannot split a track in COLMAP's graph).
        min_observations: tracks with this many observations or fewer produce no matches (they could never
            become landmarks, and leaving them out keeps triangulation fast).

    Returns:
        {(a, b): (M, 2) uint32 mask indices} for keyframe pairs a < b, rows sorted by the first column.
    """
    frames, masks, tracks = [], [], []
    for k, ids in enumerate(track_ids):
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        keep = np.flatnonzero(ids >= 0)
        frames.append(np.full(len(keep), k, dtype=np.int64))
        masks.append(keep)
        tracks.append(ids[keep])
    if not frames:
        return {}
    frame = np.concatenate(frames)
    mask = np.concatenate(masks)
    track = np.concatenate(tracks)
    if not len(track):
        return {}
    # Group observations by track, in keyframe order inside each track.
    order = np.lexsort((frame, track))
    frame, mask, track = frame[order], mask[order], track[order]
    starts = np.flatnonzero(np.r_[True, track[1:] != track[:-1]])
    counts = np.diff(np.r_[starts, len(track)])
    if np.any(np.diff(frame)[track[1:] == track[:-1]] == 0):
        raise ValueError("a track holds two masks of the same keyframe")
    keep_group = counts > min_observations
    pairs_a: list[np.ndarray] = []
    pairs_b: list[np.ndarray] = []
    if mode == "consecutive":
        same = track[1:] == track[:-1]
        long_obs = np.repeat(keep_group, counts)
        sel = np.flatnonzero(same & long_obs[1:])
        pairs_a.append(sel)
        pairs_b.append(sel + 1)
    elif mode == "all":
        # Vectorised per track length: every (i, j) with i < j inside each group.
        for length in np.unique(counts[keep_group]):
            group_starts = starts[keep_group & (counts == length)]
            ii, jj = np.triu_indices(int(length), k=1)
            pairs_a.append((group_starts[:, None] + ii[None, :]).ravel())
            pairs_b.append((group_starts[:, None] + jj[None, :]).ravel())
    else:
        raise ValueError(f"mode must be 'consecutive' or 'all', got {mode!r}")
    if not pairs_a:
        return {}
    a = np.concatenate(pairs_a)
    b = np.concatenate(pairs_b)
    fa, fb, ma, mb = frame[a], frame[b], mask[a], mask[b]
    result: dict[tuple[int, int], np.ndarray] = {}
    order = np.lexsort((ma, fb, fa))
    fa, fb, ma, mb = fa[order], fb[order], ma[order], mb[order]
    bounds = np.flatnonzero(np.r_[True, (fa[1:] != fa[:-1]) | (fb[1:] != fb[:-1]), True])
    for s, e in zip(bounds[:-1], bounds[1:]):
        result[(int(fa[s]), int(fb[s]))] = np.stack([ma[s:e], mb[s:e]], 1).astype(np.uint32)
    return result


def epipolar_errors_px(
    camera: Camera, poses: Poses, a: int, b: int, xy_a: np.ndarray, xy_b: np.ndarray
) -> np.ndarray:
    """Sampson distance in pixels of point pairs between keyframes a and b under the known poses.

    Uses pycolmap.essential_matrix_from_pose (cam_b_from_cam_a) and compute_squared_sampson_error on the
    fundamental matrix F = K^-T E K^-1, so the result is in pixels (about the distance to the epipolar line).
    """
    import pycolmap

    r_cw, t_cw = poses.cam_from_world()
    r_ba = r_cw[b] @ r_cw[a].T
    t_ba = t_cw[b] - r_ba @ t_cw[a]
    rel = pycolmap.Rigid3d(pycolmap.Rotation3d(r_ba), t_ba)
    e_mat = pycolmap.essential_matrix_from_pose(rel)
    k_inv = np.linalg.inv(camera.K)
    f_mat = k_inv.T @ e_mat @ k_inv
    if not len(xy_a):
        return np.zeros(0)
    sq = pycolmap.compute_squared_sampson_error(
        np.asarray(xy_a, dtype=np.float64), np.asarray(xy_b, dtype=np.float64), f_mat
    )
    return np.sqrt(np.asarray(sq, dtype=np.float64))


def verify_associations(
    camera: Camera,
    poses: Poses,
    centroids: Sequence[np.ndarray],
    pairs: dict[tuple[int, int], np.ndarray],
    max_error_px: float,
    shifts: Sequence[np.ndarray] | None = None,
) -> tuple[dict[tuple[int, int], np.ndarray], int]:
    """Drop associations whose centroids violate the epipolar geometry of the known poses.

    Unverified outliers written as inliers make wrong COLMAP tracks (shared notes), so every pair is checked
    with the Sampson distance against `max_error_px`. `shifts`, optional (per keyframe, (K, 2)): the outward box
    by which the image border may have shifted each centroid (`TrackingResult.shifts`); such a pair is
    checked at the boxes' centres with the tolerance widened by their half-diagonals, as the tracker gated it.
    Returns the kept pairs (empty ones dropped) and the number of associations removed.
    """
    kept: dict[tuple[int, int], np.ndarray] = {}
    removed = 0
    for (a, b), m in pairs.items():
        xy_a, xy_b = centroids[a][m[:, 0]], centroids[b][m[:, 1]]
        tolerance: float | np.ndarray = max_error_px
        if shifts is not None:
            sa, sb = shifts[a][m[:, 0]], shifts[b][m[:, 1]]
            xy_a, xy_b = xy_a + 0.5 * sa, xy_b + 0.5 * sb
            tolerance = max_error_px + 0.5 * (np.linalg.norm(sa, axis=1) + np.linalg.norm(sb, axis=1))
        err = epipolar_errors_px(camera, poses, a, b, xy_a, xy_b)
        ok = err <= tolerance
        removed += int(np.count_nonzero(~ok))
        if np.any(ok):
            kept[(a, b)] = m[ok]
    return kept, removed


@dataclass(frozen=True)
class DatabaseSummary:
    """Counts of what `write_colmap_database` wrote."""

    num_images: int
    num_keypoints: int
    num_pairs: int
    num_matches: int


def _add_colmap38_columns(path: Path) -> None:
    con = sqlite3.connect(path)
    try:
        have = {row[1] for row in con.execute("PRAGMA table_info(images)")}
        for col in PRIOR_COLUMNS_38:
            if col not in have:
                con.execute(f"ALTER TABLE images ADD COLUMN {col} REAL")
        con.commit()
    finally:
        con.close()


def write_colmap_database(
    path: str | Path,
    camera: Camera,
    image_names: Sequence[str],
    keypoints: Sequence[np.ndarray],
    pairs: dict[tuple[int, int], np.ndarray],
) -> DatabaseSummary:
    """Write a new COLMAP database atomically (the file appears complete or not at all).

    Args:
        path: database file to create (replaced if it exists).
        camera: the one camera of the session (COLMAP camera id 1), the real lens model: keypoints are
            the real (distorted) pixels.
        image_names: keyframe image names; image i gets COLMAP image id and frame id i + 1.
        keypoints: per image, (K, 2|4|6) float32 keypoints in the COLMAP pixel convention (row = point2D index).
        pairs: {(a, b): (M, 2) mask index pairs} with a < b (0-based image positions); written both as raw
            matches and as CALIBRATED two-view geometries whose inliers are these matches.
    """
    import pycolmap

    path = Path(path)
    if len(keypoints) != len(image_names):
        raise ValueError(f"{len(image_names)} images but {len(keypoints)} keypoint arrays")
    try:
        make_dirs(path.parent)  # a taken output directory moved away under its run is not re-created
    except OSError as exc:
        raise InputError(f"cannot create output directory: {exc.strerror}", path.parent) from None
    num_matches = 0
    with atomic_path(path) as tmp:
        db = pycolmap.Database.open(str(tmp))
        try:
            with pycolmap.DatabaseTransaction(db):
                cam = pycolmap_camera(camera, CAMERA_ID)
                db.write_camera(cam, use_camera_id=True)
                rig = pycolmap.Rig(rig_id=RIG_ID)
                rig.add_ref_sensor(cam.sensor_id)
                db.write_rig(rig, use_rig_id=True)
                for i, name in enumerate(image_names):
                    img = pycolmap.Image(name=str(name), camera_id=CAMERA_ID, image_id=i + 1)
                    db.write_image(img, use_image_id=True)
                    frame = pycolmap.Frame(frame_id=i + 1, rig_id=RIG_ID)
                    frame.add_data_id(img.data_id)
                    db.write_frame(frame, use_frame_id=True)
                    db.write_keypoints(i + 1, np.ascontiguousarray(keypoints[i], dtype=np.float32))
                for (a, b), m in sorted(pairs.items()):
                    if not a < b:
                        raise ValueError(f"pair ({a}, {b}) must have a < b")
                    m = np.ascontiguousarray(m, dtype=np.uint32).reshape(-1, 2)
                    db.write_matches(a + 1, b + 1, m)
                    tvg = pycolmap.TwoViewGeometry()
                    tvg.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
                    tvg.inlier_matches = m
                    db.write_two_view_geometry(a + 1, b + 1, tvg)
                    num_matches += len(m)
        finally:
            db.close()
        _add_colmap38_columns(tmp)
    return DatabaseSummary(
        num_images=len(image_names),
        num_keypoints=int(sum(len(k) for k in keypoints)),
        num_pairs=len(pairs),
        num_matches=num_matches,
    )


def check_database_writable(path: str | Path) -> None:
    """Raise InputError if an existing database is locked by another process (e.g. COLMAP's GUI) or is not a
    file. A file that is not a database (corrupt) is no obstacle: it is an output about to be replaced."""
    path = Path(path)
    if not path.exists():
        return
    if not path.is_file():
        raise InputError("is not a file where the COLMAP database goes; not replaced", path)
    try:
        con = sqlite3.connect(path, timeout=0.5)
    except sqlite3.Error:
        return
    try:
        con.execute("BEGIN EXCLUSIVE")
        con.execute("ROLLBACK")
    except sqlite3.OperationalError as exc:
        if "locked" in str(exc) or "busy" in str(exc):
            raise InputError(f"database is locked by another process ({exc})", path) from None
    except sqlite3.DatabaseError:
        pass  # not a database (corrupt): replaced by this run
    finally:
        con.close()
