"""A folder of survey images' cameras from their EXIF: one camera per make, model and image size.

Intrinsics: fx = FocalLength [mm] * FocalPlaneXResolution [px/mm] * (file width / ExifImageWidth): EXIF
describes the sensor readout, and images are often downscaled afterwards (Seneca: 4000x3000 -> 1200x900).
Without a focal-plane resolution, `sensor_width_mm` (fx = f / sensor width * file width) or the 35 mm
equivalent focal length are used. The 35 mm figure refers to the diagonal of the sensor's full frame, not of a
crop of it (a DJI 16:9 still is a band of a 4:3 sensor: `full_frame_diagonal_px`).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..database.exif import ImageMetadata
from ..plugin.errors import InputError
from ..plugin.geometry import Camera

log = logging.getLogger(__name__)

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
# Aspect ratios (long side / short side) of photo sensors' full frames; other aspects are crops of a 4:3 frame.
SENSOR_ASPECTS = (4.0 / 3.0, 3.0 / 2.0)
CROPPED_FROM_ASPECT = 4.0 / 3.0


def full_frame_diagonal_px(width: int, height: int, sensor_aspect: float | None = None) -> float:
    """Diagonal, in pixels of this image, of the sensor frame a 35 mm equivalent focal length refers to.

    The image is the largest crop of a frame of `sensor_aspect` (long / short side; default: the image's own
    aspect when it is a photo sensor's, 4:3 or 3:2, else 4:3) with the same pixel pitch: a wider image keeps the
    frame's long side, a squarer one its short side."""
    long_side, short_side = max(width, height), min(width, height)
    aspect = long_side / short_side
    if sensor_aspect is None:
        sensor_aspect = next((a for a in SENSOR_ASPECTS if abs(aspect - a) <= 0.01 * a), CROPPED_FROM_ASPECT)
    if aspect >= sensor_aspect:
        frame = (long_side, long_side / sensor_aspect)
    else:
        frame = (short_side * sensor_aspect, short_side)
    return math.hypot(*frame)


# How far a focal length may lie from the EXIF one (`camera_from_metadata`) before it is named: EXIF focal lengths
# are nominal and the 35 mm equivalent whole millimetres (a few %). Beyond it, structure from motion's focal length
# is not a calibration but a degenerate block (over flat ground a nadir camera's focal length trades against its
# height: 24 % off on a 26-frame, 320 px synthetic flight of one line and a half; within 0.1 % on 90-frame flights;
# `poses.checks`), and a given camera file is wrong (landmark heights scale with it: 15-30 m off at 100 m for the
# thirteenth sweep's 15-30 %; `map.inputs.focal_against_exif`)
EXIF_FOCAL_TOLERANCE = 0.10

# The marked focal length of a survey camera's lens against its calibrated one (the relative sigma taken): a
# couple of per cent (Seneca's 166 real frames: structure from motion +2.1 % off FocalLength). A 35 mm
# equivalent adds its rounding to whole millimetres (`exif_focal_uncertainty`).
EXIF_NOMINAL_FOCAL_SIGMA = 0.02


def exif_focal_uncertainty(camera: Camera, source: str) -> float:
    """The relative uncertainty of the EXIF focal length of `camera` taken from `source` (the intrinsics source
    `camera_from_metadata` names): the lens's nominal marking (`EXIF_NOMINAL_FOCAL_SIGMA`) and, for a 35 mm
    equivalent, its rounding to whole millimetres (half a millimetre of it; 1.9 % of 27 mm), combined."""
    rounding = 0.0
    if "35mm" in source and camera.fx > 0:
        f35 = camera.fx * FULL_FRAME_DIAGONAL_MM / full_frame_diagonal_px(camera.width, camera.height)
        rounding = 0.5 / f35
    return math.hypot(EXIF_NOMINAL_FOCAL_SIGMA, rounding)


# The narrowest sensor of a survey camera (1/4": 3.6 mm). A focal plane resolution that puts an image on a
# narrower one refers to another readout than the file's: the image was downscaled after the camera wrote its
# EXIF, and ExifImageWidth, which said from what size, was dropped or rewritten to the new one (the sixteenth
# sweep: Seneca's 1200 px frames on a "1.86 mm" sensor gave fx 2775 px for 833, and a map 30-140 m too low
# passed). Thermal cores this small (160 px Lepton, 1.9 mm) take --sensor-width-mm.
MIN_SENSOR_WIDTH_MM = 3.0


def turned_readout(meta: ImageMetadata) -> bool:
    """Whether the file is the readout its EXIF describes turned by 90 degrees (a portrait frame rotated by
    software, which leaves the EXIF as the camera wrote it): the aspects are each other's inverse."""
    if not meta.exif_size or not (meta.width > 0 and meta.height > 0):
        return False
    ref_w, ref_h = meta.exif_size
    w, h = meta.width, meta.height
    return abs(ref_w / ref_h - w / h) > 0.01 and abs(ref_h / ref_w - w / h) <= 0.01


def camera_from_metadata(meta: ImageMetadata, sensor_width_mm: float | None = None) -> tuple[Camera, str]:
    """Pinhole intrinsics of one image from its EXIF, scaled to the file's actual size, and the source used.
    EXIF DigitalZoomRatio (an in-camera zoom that crops the readout and scales it back up) multiplies the focal
    length in pixels. A focal plane resolution that puts the image on a sensor narrower than MIN_SENSOR_WIDTH_MM
    is refused (InputError) unless a 35 mm equivalent focal length can stand in."""
    camera, source = _camera_before_zoom(meta, sensor_width_mm)
    zoom = meta.digital_zoom
    if zoom and zoom > 1.0:
        camera = Camera(camera.width, camera.height, camera.fx * zoom, camera.fy * zoom, camera.cx, camera.cy)
        source += f", x{zoom:g} digital zoom"
    return camera, source


def _camera_before_zoom(meta: ImageMetadata, sensor_width_mm: float | None) -> tuple[Camera, str]:
    w, h = meta.width, meta.height
    if meta.focal_mm and sensor_width_mm:
        fx = meta.focal_mm / sensor_width_mm * w
        return Camera(w, h, fx, fx, w / 2.0, h / 2.0), "FocalLength + given sensor width"
    stale = None
    if meta.focal_mm and meta.focal_plane_px_per_mm:
        ref_w, ref_h = meta.exif_size if meta.exif_size else (w, h)
        px_per_mm_x, px_per_mm_y = meta.focal_plane_px_per_mm
        source = "FocalLength + FocalPlaneX/YResolution (scaled to file size)"
        if turned_readout(meta):
            # the readout the EXIF describes, turned by 90 degrees (a portrait frame rotated by software, which
            # leaves the EXIF as the camera wrote it): its width is the readout's height
            ref_w, ref_h, px_per_mm_x, px_per_mm_y = ref_h, ref_w, px_per_mm_y, px_per_mm_x
            source += f", the {meta.exif_size[0]}x{meta.exif_size[1]} readout turned by 90 degrees"
        elif meta.exif_size and abs(ref_w / ref_h - w / h) > 0.01:
            source += f", EXIF size {ref_w}x{ref_h} and file {w}x{h} differ in aspect (cropped?): scaled by width"
        # the sensor's long side in mm, as the focal plane resolution and the readout's size say
        sensor_mm = ref_w / px_per_mm_x if ref_w >= ref_h else ref_h / px_per_mm_y
        if sensor_mm >= MIN_SENSOR_WIDTH_MM:
            scale = w / ref_w
            fx = meta.focal_mm * px_per_mm_x * scale
            fy = meta.focal_mm * px_per_mm_y * scale
            return Camera(w, h, fx, fy, w / 2.0, h / 2.0), source
        stale = (f"FocalPlaneXResolution ({px_per_mm_x:.0f} px/mm) puts the {ref_w} px wide "
                 f"{'readout' if meta.exif_size else 'image'} on a {sensor_mm:.2f} mm sensor, narrower "
                 f"than any survey camera's: the image was downscaled after the camera wrote its EXIF, which no "
                 f"longer says from what size (ExifImageWidth {'rewritten' if meta.exif_size else 'missing'})")
    if meta.focal_35mm:
        if stale:
            log.debug("%s: %s; the 35 mm equivalent focal length is used", meta.path.name, stale)
        fx = meta.focal_35mm / FULL_FRAME_DIAGONAL_MM * full_frame_diagonal_px(w, h)
        return Camera(w, h, fx, fx, w / 2.0, h / 2.0), "FocalLengthIn35mmFilm (full-frame diagonal)"
    if stale:
        raise InputError(f"{stale}: give the sensor width (--sensor-width-mm), or `map` a camera file (--camera)",
                         meta.path)
    if meta.focal_mm:
        advice = "give the sensor width (--sensor-width-mm)"
    else:  # a sensor width needs a focal length in mm to go with it: without one it cannot help
        advice = ("the images carry no focal length at all (EXIF stripped?): take poses and intrinsics from "
                  "structure from motion (`sosmatch poses`), or give `sosmatch map` a pose CSV and --camera")
    raise InputError("no usable focal length in EXIF (FocalLength with FocalPlaneXResolution, or "
                     f"FocalLengthIn35mmFilm); {advice}", meta.path)


def camera_groups(metas: list[ImageMetadata], sensor_width_mm: float | None,
                  strict: bool) -> tuple[list[Camera], np.ndarray, list[str], list[str]]:
    """One camera per make + model + image size + digital zoom (the median focal length of its images), the
    camera of every image and the intrinsics source of each camera. Images of a camera whose EXIF gives no
    usable focal length share the others' (one warning counts them). Without any for a camera, it gets COLMAP's
    default guess (1.2 x the longer side) with a warning (also returned, last), or InputError when `strict`
    (the first image's reason)."""
    keys = sorted({m.camera_key for m in metas}, key=lambda k: [m.camera_key for m in metas].index(k))
    index = np.array([keys.index(m.camera_key) for m in metas], dtype=np.int64)
    cameras, sources, warnings = [], [], []
    for g, key in enumerate(keys):
        members = [m for m, i in zip(metas, index) if i == g]
        found, failed = [], []
        for m in members:
            try:
                found.append(camera_from_metadata(m, sensor_width_mm))
            except InputError as exc:
                failed.append(exc)
        w, h = key[2], key[3]
        name = f"{f'{key[0]} {key[1]}'.strip() or 'camera'} ({w}x{h}, {len(members)} images)"
        if not found:
            if strict:
                raise failed[0]
            f = 1.2 * max(w, h)
            warnings.append(f"{name}: no usable focal length in EXIF ({failed[0].problem}); starting from {f:.0f} px "
                            "(structure from motion estimates it)")
            log.warning("%s", warnings[-1])
            cameras.append(Camera(w, h, f, f, w / 2.0, h / 2.0))
            sources.append("none in EXIF (1.2 x the longer side)")
            continue
        if failed:
            example = failed[0].path.name if failed[0].path else "?"
            log.warning("%s: %d of its images have no usable focal length in EXIF (e.g. %s): they take the focal "
                        "length of the other %d", name, len(failed), example, len(found))
        cropped = [source for _, source in found if "cropped?" in source]
        if cropped:
            log.warning("%s: %d images' EXIF size and file size differ in aspect (cropped?): their focal length is "
                        "scaled by width (EXIF size %s)", name, len(cropped), cropped[0].split(", EXIF size ")[-1])
        fxs = np.array([c.fx for c, _ in found])
        fys = np.array([c.fy for c, _ in found])
        if fxs.max() > 1.01 * fxs.min():
            log.warning("focal lengths differ between images (%.1f..%.1f px): using the median", fxs.min(), fxs.max())
        c0 = found[0][0]
        cameras.append(Camera(c0.width, c0.height, float(np.median(fxs)), float(np.median(fys)), c0.cx, c0.cy))
        sources.append(found[0][1])
    return cameras, index, sources, warnings


def make_model(meta: ImageMetadata) -> str:
    return meta.model if meta.model.startswith(meta.make) else f"{meta.make} {meta.model}".strip()
