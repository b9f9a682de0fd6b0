"""Inputs of the evaluation read with validation: terrain, landmark observers, match.json hypotheses.

Only these functions know the layouts, so a schema change elsewhere is one edit here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from ..plugin.evaluation.footprints import FlatGround, HeightField
from ..plugin.evaluation.landmark_truth import objects_under
from .match_io import MatchSummary, read_match
from .session_io import LandmarkTable, read_landmark_table  # noqa: F401 (re-exported for the evaluation)
from .text_input import read_user_npz

# Key names accepted in terrain.npz for the height grid and its georeferencing.
_Z_KEYS = ("z", "height", "heights", "elevation", "dem")


def read_terrain_npz(path: str | Path) -> HeightField:
    """A height field from terrain.npz.

    Accepted layouts: a 2-D grid (`z`, `height`, `heights`, `elevation` or `dem`, indexed [row=y, col=x]) with
    either axis vectors `x`, `y` (regular spacing) or scalars `x0`, `y0`, `dx`, `dy` (`cell`/`resolution` for a
    square cell, `resolution_m` as `sosmatch synth` writes it; `origin` as [x0, y0]).
    """
    path = Path(path)
    data = read_user_npz(path, "terrain file")
    key = next((k for k in _Z_KEYS if k in data), None)
    if key is None:
        raise InputError(f"no height grid (one of {', '.join(_Z_KEYS)}) in {sorted(data)}", path)
    z = np.asarray(data[key], dtype=np.float64)
    if z.ndim != 2:
        raise InputError(f"height grid must be 2-D, got shape {z.shape}", path)

    def scalar(*names: str) -> float | None:
        for n in names:
            if n in data:
                return float(np.asarray(data[n]).reshape(-1)[0])
        return None

    if "x" in data and "y" in data and np.asarray(data["x"]).ndim == 1:
        xs, ys = np.asarray(data["x"], float), np.asarray(data["y"], float)
        if len(xs) != z.shape[1] or len(ys) != z.shape[0]:
            raise InputError(f"axis lengths {len(xs)}, {len(ys)} do not fit grid {z.shape}", path)
        x0, y0, dx, dy = xs[0], ys[0], xs[1] - xs[0], ys[1] - ys[0]
    else:
        x0, y0 = scalar("x0", "x_min", "xmin"), scalar("y0", "y_min", "ymin")
        if (x0 is None or y0 is None) and "origin" in data:
            x0, y0 = (float(v) for v in np.asarray(data["origin"], float).reshape(-1)[:2])
        cell = scalar("resolution_m", "cell", "cell_m", "resolution", "spacing")
        dx, dy = scalar("dx") or cell, scalar("dy") or cell
        if None in (x0, y0, dx, dy):
            raise InputError(f"cannot find the grid origin and spacing in {sorted(data)}", path)
    try:
        return HeightField(z, float(x0), float(y0), float(dx), float(dy))
    except ValueError as exc:
        raise InputError(str(exc), path) from None


def crs_name(epsg: int) -> str:
    """How an EPSG code (0: none) reads in a message."""
    return f"EPSG:{epsg}" if epsg else "a local frame (no CRS)"


def check_same_crs(what: str, epsg: int, truth: str, truth_epsg: int, path: Path) -> None:
    """Refuse WHAT (at PATH) georeferenced in EPSG (0: none) against a ground truth TRUTH in TRUTH_EPSG: no rigid
    transform relates two frames, so its coordinates would be read as the other's (a map scored 5.2e6 m off, a
    DEM covering none of the flights)."""
    if epsg != truth_epsg:
        raise InputError(f"{what} is in {crs_name(epsg)} but {truth} is in {crs_name(truth_epsg)}: no rigid "
                         "transform relates them", path)


def read_dem(path: str | Path, poses_epsg: int = 0, cameras_xy: np.ndarray | None = None,
             poses_path: Path | None = None) -> HeightField:
    """A north-up elevation raster (GeoTIFF etc., via rasterio) as a height field in the raster's CRS, which must
    be the poses' (POSES_EPSG, 0 for a local frame: a raster without CRS) and cover their cameras (CAMERAS_XY,
    (N, 2)), as POSES_PATH names them: a DEM of another frame gave every footprint 0 m^2 and the refusal blamed
    the flights ("do not overlap")."""
    import rasterio

    path = Path(path)
    try:
        with rasterio.open(path) as src:
            z = src.read(1).astype(np.float64)
            tr = src.transform
            nodata = src.nodata
            crs = src.crs
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"cannot read elevation raster: {exc}", path) from None
    epsg = 0 if crs is None else crs.to_epsg()
    if epsg is None:
        raise InputError(f"elevation raster's CRS has no EPSG code ({crs}): reproject it to the poses' "
                         f"{crs_name(poses_epsg)}", path)
    check_same_crs("elevation raster", epsg, str(poses_path or "the poses"), poses_epsg,
                   path)
    if tr.b != 0 or tr.d != 0:
        raise InputError("rotated rasters are not supported", path)
    if nodata is not None:
        z[z == nodata] = np.nan
    if np.isnan(z).all():
        raise InputError("elevation raster holds no data", path)
    z = np.where(np.isnan(z), np.nanmedian(z), z)
    if cameras_xy is not None and len(cameras_xy):
        xs, ys = sorted((tr.c, tr.c + tr.a * z.shape[1])), sorted((tr.f, tr.f + tr.e * z.shape[0]))
        out = ~((cameras_xy[:, 0] >= xs[0]) & (cameras_xy[:, 0] <= xs[1]) & (cameras_xy[:, 1] >= ys[0]) &
                (cameras_xy[:, 1] <= ys[1]))
        if out.any():
            x, y = cameras_xy[np.flatnonzero(out)[0]]
            raise InputError(f"elevation raster (x {xs[0]:.6g}..{xs[1]:.6g}, y {ys[0]:.6g}..{ys[1]:.6g}) does not "
                             f"cover {int(out.sum())} of the {len(out)} cameras of "
                             f"{poses_path or 'the poses'}, e.g. at ({x:.6g}, {y:.6g})", path)
    # Pixel centres: x = c + a (col + 0.5), y = f + e (row + 0.5).
    return HeightField(z, tr.c + 0.5 * tr.a, tr.f + 0.5 * tr.e, tr.a, tr.e)


def terrain_of_session(session: Path, dem: str | Path | None = None, ground_height: float = 0.0,
                       poses_epsg: int = 0, cameras_xy: np.ndarray | None = None,
                       poses_path: Path | None = None) -> FlatGround | HeightField:
    """The terrain for ground truth: `dem` if given (checked against the poses' CRS and cameras: `read_dem`), else
    SESSION/terrain.npz if present, else a flat ground."""
    if dem is not None:
        return read_dem(dem, poses_epsg, cameras_xy, poses_path)
    npz = Path(session) / "terrain.npz"
    if npz.exists():
        return read_terrain_npz(npz)
    return FlatGround(ground_height)


@dataclass
class MatchHypotheses:
    """Every window-pair hypothesis of a match.json: associations, |S|, whether it passed the gravity check."""

    associations: list[np.ndarray]
    sizes: np.ndarray
    gravity_ok: np.ndarray
    accepted: np.ndarray
    seconds: float | None
    min_associations: int | None
    match: MatchSummary


def read_match_hypotheses(path: str | Path, max_gravity_angle_deg: float = 22.5) -> MatchHypotheses:
    """match.json's `hypotheses` (read and validated by `match_io.read_match`) as the evaluation scores them.

    A hypothesis passes the gravity check when its transform exists and its tilt (or max |roll|, |pitch|) is
    at most `max_gravity_angle_deg`; without those fields, `accepted` or a present transform decides.
    """
    match = read_match(path)
    ok = []
    for h in match.hypotheses:
        if h.tilt_deg is not None:
            ok.append(h.transform is not None and h.tilt_deg <= max_gravity_angle_deg)
        else:
            ok.append(h.accepted if h.accepted is not None else h.transform is not None)
    return MatchHypotheses([h.associations for h in match.hypotheses],
                           np.array([len(h.associations) for h in match.hypotheses], dtype=np.int64),
                           np.asarray(ok, bool), np.array([bool(h.accepted) for h in match.hypotheses], bool),
                           match.seconds, match.min_associations, match)


def landmark_observed_objects(map_dir: str | Path, labels_dir: str | Path) -> list[np.ndarray]:
    """Per landmark of a mapped session (landmarks.csv order), the object id under each observed mask centroid.

    Observations come from the session's sparse/ model (the keypoints are the mask centroids, COLMAP pixel
    convention: pixel i spans [i, i + 1)); ids from `labels_dir/IMAGE_STEM.png` (uint16 object id per pixel,
    0 = ground cover), as `sosmatch synth` writes them. A missing label image is an InputError naming it."""
    import pycolmap

    map_dir, labels_dir = Path(map_dir), Path(labels_dir)
    table = read_landmark_table(map_dir / "landmarks.csv")
    model = map_dir / "sparse"
    try:
        rec = pycolmap.Reconstruction(str(model))
    except Exception as exc:  # pycolmap raises plain RuntimeError / ValueError for unreadable models
        raise InputError(f"cannot read the sparse model: {exc}", model) from None
    labels: dict[str, np.ndarray] = {}
    out = []
    for pid in table.point3d_ids:
        if int(pid) not in rec.points3D:
            raise InputError(f"landmark point {int(pid)} is not in the sparse model", map_dir / "landmarks.csv")
        ids = []
        for el in rec.points3D[int(pid)].track.elements:
            image = rec.images[el.image_id]
            lab = labels.get(image.name)
            if lab is None:
                cam = rec.cameras[image.camera_id]
                lab = labels[image.name] = read_label_image(labels_dir, image.name, (cam.width, cam.height))
            ids.append(int(objects_under(lab, np.asarray(image.points2D[el.point2D_idx].xy))[0]))
        out.append(np.asarray(ids, dtype=np.int64))
    return out


def segment_objects(map_dir: str | Path, labels_dir: str | Path, names: Sequence[str],
                    size: tuple[int, int] | None = None) -> list[np.ndarray]:
    """Per keyframe `names` of a mapped session, the object id under each segment centroid (every mask, as the
    map's database.db holds them as keypoints), from `labels_dir/IMAGE_STEM.png` as `landmark_observed_objects`."""
    from .colmap_db import read_segment_detections

    dets = read_segment_detections(Path(map_dir) / "database.db", names)
    return [objects_under(read_label_image(labels_dir, name, size), det.centroids) for name, det in zip(names, dets)]


def read_label_image(labels_dir: str | Path, image_name: str, size: tuple[int, int] | None = None) -> np.ndarray:
    """The label image of a keyframe (`labels_dir/IMAGE_STEM.png`, uint16 object id per pixel, 0 = ground cover, as
    `sosmatch synth` writes it); an unreadable or missing one, one of another pixel type or, given `size` (width,
    height of its image), of another size is an InputError naming it."""
    import cv2

    path = Path(labels_dir) / (Path(image_name).stem + ".png")
    lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if lab is None:
        raise InputError("cannot read label image", path)
    # object ids are looked up at pixel positions: another depth wraps the ids, another size moves every lookup
    # (clipped to the border), and the evaluation's object counts came out wrong with exit 0
    if lab.ndim != 2 or lab.dtype != np.uint16:
        channels = 1 if lab.ndim == 2 else lab.shape[2]
        raise InputError(f"label image must hold one 16-bit object id per pixel (as `sosmatch synth` writes it), got "
                         f"{channels} channel(s) of {lab.dtype}", path)
    if size is not None and (lab.shape[1], lab.shape[0]) != tuple(size):
        raise InputError(f"label image is {lab.shape[1]}x{lab.shape[0]} but its image is {size[0]}x{size[1]}", path)
    return lab
