"""`sosmatch synth-from-ortho`: a session of nadir views with exact poses rendered from a georeferenced orthophoto.

The output has the layout of a synthetic session (docs/ARCHITECTURE.md; `load_synth_session` reads it) without
segmentation ground truth:
    SESSION/session.json   format sosmatch-synth-session v1, source "orthophoto", raster, CRS, flight plan, camera
    SESSION/cameras.txt    one PINHOLE camera, id 1
    SESSION/images/        frame_00000.jpg ...
    SESSION/poses.csv      exact world_from_camera poses, `# crs: EPSG:<the raster's code>`, ground at z = 0
    SESSION/poses_ekf.csv  the same poses (or with `ekf_position_sigma_m` / `ekf_attitude_sigma_deg` noise)
    SESSION/objects.csv    header only (no object ground truth)
    SESSION/frames.json    per image: name, visible_object_ids (empty), footprint (ground polygon, world)
    SESSION/terrain.npz    a flat 2x2 grid at z = 0 over the raster
so mapping, matching and evaluation (flat ground at z = 0) consume it unchanged. The same arguments on two
orthophotos of one area (e.g. NAIP 2009 and 2015) give two sessions flown along the same path with exact,
shared ground truth.

Scale. NAIP is 5 m/px, so views are rendered at a ground sampling distance of a few m/px (default 2.5 m/px;
upsampling a 5 m raster 2x keeps every orthophoto pixel visible without inventing detail). With the default
640x480 camera and 60 degree horizontal field of view that is an altitude of ~1390 m, a footprint of
1600 x 1200 m, frames every 150 m (each ground point in ~8 consecutive frames of a line) and lines every 800 m
(50% sidelap), so a pond, tree belt or farmstead is seen in >= 8 and typically ~16 keyframes.
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..database.cameras import format_cameras_txt
from ..database.output_markers import fingerprint
from ..database.outputs import open_output_dir
from ..database.poses import format_poses_csv
from ..plugin.errors import InputError
from ..plugin.geometry import Poses
from ..tools import ortho_session as osess

log = logging.getLogger(__name__)


# The synthetic session's format (sosmatch.database.synth_session), repeated so this module has no dependency on
# the synthetic world; tests/test_synth_from_ortho.py checks the synthetic reader accepts the result.
SESSION_FORMAT = "sosmatch-synth-session"
SESSION_VERSION = 1
OBJECT_COLUMNS = ["id", "kind", "x", "y", "z", "radius", "height", "present"]
# the files it publishes beside images/, its record last: a user's file at one of their names is refused when the
# folder is taken
ORTHO_FILES = ("cameras.txt", "poses.csv", "poses_ekf.csv", "objects.csv", "frames.json", "terrain.npz",
               "session.json")


def noisy_poses(poses: Poses, position_sigma_m: float, attitude_sigma_deg: float, seed: int) -> Poses:
    """The poses with seeded independent Gaussian position and small-rotation noise (the exact ones if both 0)."""
    from ..plugin.geometry import rotvec_to_matrix

    rng = np.random.default_rng(seed)
    dc = rng.normal(0.0, position_sigma_m, poses.centers.shape) if position_sigma_m > 0 else 0.0
    dr = rotvec_to_matrix(rng.normal(0.0, np.radians(attitude_sigma_deg), (len(poses), 3))) \
        if attitude_sigma_deg > 0 else np.eye(3)
    return Poses(list(poses.names), dr @ poses.rotations, poses.centers + dc)


MAX_PLAN_FRAMES = 100_000  # as `sosmatch synth`: a plan beyond this is a wrong spacing, not a survey
MAX_TILT_DEG = 45.0
DEFAULT_GSD_M = 2.5  # m/px when neither the altitude nor the GSD is given
MAX_UPSAMPLING = 4.0  # raster pixel / GSD beyond which the views are warned of (module docstring: 2x is the default)


def check_settings(altitude_m: float | None, gsd_m: float | None, width: int, height: int, hfov_deg: float,
                   frame_spacing_m: float | None, line_spacing_m: float | None, heading_deg: float | None,
                   offset_m: float, frames: int | None, max_tilt_deg: float, seed: int, jpeg_quality: int,
                   ekf_position_sigma_m: float, ekf_attitude_sigma_deg: float) -> None:
    """Refuse (one-line InputError naming the setting) values that cannot make a session, before the orthophoto
    is read. Before: a NaN offset or negative frame spacing was a traceback, a frame spacing of 1e-6 m or a
    90 degree tilt asked for tens of GB (MemoryError), and 0 frames, a negative tilt or sigma rendered with exit 0."""
    numbers = {"altitude": altitude_m, "gsd": gsd_m, "hfov": hfov_deg, "frame spacing": frame_spacing_m,
               "line spacing": line_spacing_m, "heading": heading_deg, "offset": offset_m, "max tilt": max_tilt_deg,
               "ekf position sigma": ekf_position_sigma_m, "ekf attitude sigma": ekf_attitude_sigma_deg}
    if altitude_m is not None and gsd_m is not None:  # each sets the other: one of them would be ignored
        raise InputError(f"give the altitude ({altitude_m!r} m) or the GSD ({gsd_m!r} m/px), not both: the altitude "
                         "sets the GSD (altitude / focal length in px)")
    for name, value in numbers.items():
        if value is not None and not math.isfinite(value):
            raise InputError(f"{name} must be a finite number, got {value!r}")
    for name in ("altitude", "gsd", "frame spacing", "line spacing"):
        if numbers[name] is not None and numbers[name] <= 0:
            raise InputError(f"{name} must be positive, got {numbers[name]!r}")
    if not 16 <= width <= 8192 or not 16 <= height <= 8192:
        raise InputError(f"image width and height must be between 16 and 8192 pixels, got {width}x{height}")
    if not 1.0 < hfov_deg < 170.0:
        raise InputError(f"field of view must be within (1, 170) degrees, got {hfov_deg!r}")
    if frames is not None and not 1 <= frames <= MAX_PLAN_FRAMES:
        raise InputError(f"frames must be between 1 and {MAX_PLAN_FRAMES}, got {frames}")
    if not 0.0 <= max_tilt_deg <= MAX_TILT_DEG:
        raise InputError(f"max tilt must be between 0 and {MAX_TILT_DEG:g} degrees, got {max_tilt_deg!r}")
    if ekf_position_sigma_m < 0 or ekf_attitude_sigma_deg < 0:
        raise InputError("ekf sigmas must be >= 0")
    if seed < 0:
        raise InputError(f"seed must be >= 0, got {seed}")
    if not 1 <= jpeg_quality <= 100:
        raise InputError(f"jpeg quality must be between 1 and 100, got {jpeg_quality}")


def read_orthophoto(path: str | Path) -> osess.Orthophoto:
    """Read the first three bands of a north-up GeoTIFF in a projected CRS as RGB (pixels equal to the raster's
    nodata value in every band are invalid; a 4th band is not taken as alpha, since NAIP's 4th band is NIR)."""
    import rasterio

    path = Path(path)
    try:
        with warnings.catch_warnings():  # an image without georeference is refused below, in one line
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(path) as src:
                data = src.read()
                tr, crs, nodata = src.transform, src.crs, src.nodata
                mask = src.dataset_mask()
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"cannot read orthophoto: {exc}", path) from None
    if crs is None or not crs.is_projected or crs.to_epsg() is None:
        raise InputError(f"orthophoto must be in a projected CRS with an EPSG code (metres), got {crs}", path)
    if tr.b != 0 or tr.d != 0 or tr.a <= 0 or tr.e >= 0:
        raise InputError("orthophoto must be north-up without rotation", path)
    if data.dtype != np.uint8:
        lo, hi = np.percentile(data[:3], [1, 99])
        data = np.clip((data.astype(np.float64) - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    bands = data[:3] if len(data) >= 3 else np.repeat(data[:1], 3, axis=0)
    rgb = np.ascontiguousarray(np.moveaxis(bands, 0, -1))
    valid = mask > 0
    if nodata is not None:
        valid &= ~np.all(data == nodata, axis=0)
    if not valid.any():
        raise InputError("orthophoto holds no valid pixels", path)
    return osess.Orthophoto(rgb, tr.c, tr.f, tr.a, tr.e, int(crs.to_epsg()), valid)


def _stat(path: str | Path) -> list[int]:
    try:
        st = Path(path).stat()
    except OSError:
        return []
    return [st.st_size, st.st_mtime_ns]


def _check_over_the_raster(poses: Any, camera: Any, bounds: tuple[float, float, float, float],
                           geotiff: str | Path) -> None:
    """InputError, before any frame is rendered, when every frame's ground footprint lies off the orthophoto
    (`--offset 100000` rendered five black images and called it a session); a warning naming how many when some
    do."""
    e0, n0, e1, n1 = bounds
    off = 0
    for r, c in zip(poses.rotations, poses.centers):
        fp = np.asarray(osess.footprint(camera, r, c), dtype=np.float64).reshape(-1, 2)
        off += int(fp[:, 0].max() < e0 or fp[:, 0].min() > e1 or fp[:, 1].max() < n0 or fp[:, 1].min() > n1)
    if off == len(poses):
        raise InputError(f"all {off} frames of the flight plan look at ground outside the orthophoto (it covers "
                         f"x {e0:.0f}..{e1:.0f}, y {n0:.0f}..{n1:.0f}): check --offset and the path", geotiff)
    if off:
        log.warning("%d of %d frames look at ground outside the orthophoto (their images are blank)", off, len(poses))


def run(
    geotiff: str | Path,
    out: str | Path,
    path: str = "lawnmower",
    altitude_m: float | None = None,
    gsd_m: float | None = None,
    width: int = 640,
    height: int = 480,
    hfov_deg: float = 60.0,
    frame_spacing_m: float | None = None,
    line_spacing_m: float | None = None,
    heading_deg: float | None = None,
    offset_m: float = 0.0,
    frames: int | None = None,
    max_tilt_deg: float = 0.0,
    seed: int = 0,
    jpeg_quality: int = 95,
    ekf_position_sigma_m: float = 0.0,
    ekf_attitude_sigma_deg: float = 0.0,
    overwrite: bool = False,
) -> dict:
    """Render the session into `out` (built in OUT/.partial, published at the end; `overwrite` replaces a session
    this command rendered with other settings, see `sosmatch.database.outputs`) and return a summary.

    `altitude_m` or `gsd_m` (not both; neither: 2.5 m/px) sets the flight height (GSD = altitude / focal length in
    px). `frames` caps the number of frames
    (the first ones along the path). `max_tilt_deg` adds a seeded random tilt to every view (poses stay exact).
    `ekf_*_sigma` put seeded Gaussian noise on poses_ekf.csv (independent per frame; poses.csv stays exact).
    """
    import cv2

    check_settings(altitude_m, gsd_m, width, height, hfov_deg, frame_spacing_m, line_spacing_m, heading_deg,
                   offset_m, frames, max_tilt_deg, seed, jpeg_quality, ekf_position_sigma_m, ekf_attitude_sigma_deg)
    ortho = read_orthophoto(geotiff)
    camera = osess.camera_for(width, height, hfov_deg)
    if altitude_m is None:
        altitude_m = (DEFAULT_GSD_M if gsd_m is None else gsd_m) * camera.fx
    gsd, raster_m = altitude_m / camera.fx, min(abs(ortho.dx), abs(ortho.dy))
    if gsd * MAX_UPSAMPLING < raster_m:  # each raster cell spread over many pixels: blurred blocks, no detail
        log.warning("%s: views at %.3g m/px upsample the orthophoto's %.3g m/px %.0fx (more than %gx): each image "
                    "shows a few blurred raster cells, which segmentation and matching cannot use; a GSD of "
                    "%.3g m/px or more keeps the detail the raster has", geotiff, gsd, raster_m, raster_m / gsd,
                    MAX_UPSAMPLING, raster_m / 2.0)
    try:
        # Tilted views shift their footprint by up to altitude * tan(tilt) per axis: keep that margin too.
        margin = altitude_m * math.tan(math.radians(max(max_tilt_deg, 0.0))) * math.sqrt(2.0)
        e0, n0, e1, n1 = ortho.bounds()
        centers, headings = osess.plan_path((e0 + margin, n0 + margin, e1 - margin, n1 - margin), camera,
                                            altitude_m, path, frame_spacing_m,
                                            line_spacing_m, heading_deg, offset_m, frames, MAX_PLAN_FRAMES)
    except ValueError as exc:
        raise InputError(str(exc), geotiff) from None
    if len(centers) == 0:
        raise InputError("the flight plan has no frames", geotiff)
    poses = osess.make_poses(centers, headings, max_tilt_deg, seed)
    _check_over_the_raster(poses, camera, ortho.bounds(), geotiff)
    out = Path(out)
    identity = fingerprint({"geotiff": str(Path(geotiff).resolve()), "stat": _stat(geotiff), "path": path,
                            "altitude_m": altitude_m, "width": width, "height": height, "hfov_deg": hfov_deg,
                            "frame_spacing_m": frame_spacing_m, "line_spacing_m": line_spacing_m,
                            "heading_deg": heading_deg, "offset_m": offset_m, "frames": frames,
                            "max_tilt_deg": max_tilt_deg, "seed": seed, "jpeg_quality": jpeg_quality,
                            "ekf": [ekf_position_sigma_m, ekf_attitude_sigma_deg]})
    with open_output_dir(out, "synth-from-ortho", identity, inputs=[geotiff], overwrite=overwrite,
                         legacy_record="session.json", files=ORTHO_FILES) as taken:
        taken.clear_staging()
        tmp = taken.staging
        records = []
        blank = 0
        (tmp / "images").mkdir(parents=True)
        for i, name in enumerate(poses.names):
            img = osess.render_view(ortho, camera, poses.rotations[i], poses.centers[i])
            blank += int(np.mean(np.all(img == 0, axis=2)) > 0.05)
            ok = cv2.imwrite(str(tmp / "images" / name), img[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            if not ok:
                raise OSError(f"could not write {name}")
            fp = osess.footprint(camera, poses.rotations[i], poses.centers[i])
            records.append({"name": name, "visible_object_ids": [], "footprint": fp.round(3).tolist()})
        (tmp / "cameras.txt").write_text(format_cameras_txt({1: camera}), encoding="utf-8")
        (tmp / "poses.csv").write_text(format_poses_csv(poses, ortho.epsg), encoding="utf-8")
        ekf = noisy_poses(poses, ekf_position_sigma_m, ekf_attitude_sigma_deg, seed + 1)
        (tmp / "poses_ekf.csv").write_text(format_poses_csv(ekf, ortho.epsg), encoding="utf-8")
        (tmp / "objects.csv").write_text(",".join(OBJECT_COLUMNS) + "\n", encoding="utf-8")
        (tmp / "frames.json").write_text(json.dumps(records, indent=1) + "\n", encoding="utf-8")
        e0, n0, e1, n1 = ortho.bounds()
        with open(tmp / "terrain.npz", "wb") as f:
            np.savez(f, heights=np.zeros((2, 2), np.float32), x0=e0, y0=n0, resolution_m=max(e1 - e0, n1 - n0))
        session = {
            "format": SESSION_FORMAT, "version": SESSION_VERSION, "source": "orthophoto",
            "orthophoto": str(Path(geotiff).resolve()), "epsg": ortho.epsg, "ground_z": 0.0,
            "orthophoto_gsd_m": abs(ortho.dx),
            "flight": {"path": path, "altitude_m": float(altitude_m), "gsd_m": float(altitude_m / camera.fx),
                       "frame_spacing_m": frame_spacing_m, "line_spacing_m": line_spacing_m,
                       "heading_deg": heading_deg, "offset_m": offset_m, "frames": len(poses),
                       "max_tilt_deg": max_tilt_deg, "seed": seed},
            "camera": asdict(camera), "hfov_deg": hfov_deg,
            "ekf": {"position_sigma_m": ekf_position_sigma_m, "attitude_sigma_deg": ekf_attitude_sigma_deg},
        }
        (tmp / "session.json").write_text(json.dumps(session, indent=2), encoding="utf-8")
        taken.publish(["images", *ORTHO_FILES[:-1]], last=ORTHO_FILES[-1])
        taken.finish()
    along = height * altitude_m / camera.fx
    spacing = float(np.median(np.linalg.norm(np.diff(centers[:, :2], axis=0), axis=1))) if len(centers) > 1 else 0.0
    summary = {"session": str(out), "frames": len(poses), "epsg": ortho.epsg, "altitude_m": float(altitude_m),
               "gsd_m": float(altitude_m / camera.fx), "footprint_m": [width * altitude_m / camera.fx, along],
               "frame_spacing_m": spacing,
               "views_per_point_along_track": math.floor(along / spacing) if spacing else 1,
               "frames_with_blank_border": blank}
    if blank:
        log.warning("%d frames see more than 5%% outside the orthophoto", blank)
    log.info("rendered %d frames from %s into %s", len(poses), geotiff, out)
    return summary
