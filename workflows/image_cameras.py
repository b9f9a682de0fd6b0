"""A folder of survey images' cameras from their EXIF: one camera per make, model, image size and focal length.

Intrinsics: fx = FocalLength [mm] * FocalPlaneXResolution [px/mm] * (file width / ExifImageWidth): EXIF
describes the sensor readout, and images are often downscaled afterwards (Seneca: 4000x3000 -> 1200x900).
Without a focal-plane resolution, `sensor_width_mm` (the sensor's long side: fx = f / sensor width * the file's
long side) or the 35 mm equivalent focal length are used. The 35 mm figure refers to the diagonal of the sensor's
full frame, not of a crop of it (a DJI 16:9 still is a band of a 4:3 sensor: `full_frame_diagonal_px`).

Where the EXIF gives both, the two routes are checked against each other: a photo resized after capture keeps
the 35 mm ratio but not the pixel pitch, a cropped one the pixel pitch but not the frame, so where they disagree
the focal length in pixels is unknown (`_refuse_disagreement`). A frame of no camera's aspect was cropped, and
its principal point is unknown (`odd_aspect`).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..database.exif import ImageMetadata
from ..plugin.errors import InputError
from ..plugin.geometry import Camera

log = logging.getLogger(__name__)

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
# Aspect ratios (long side / short side) of photo sensors' full frames; other aspects are crops of a 4:3 frame.
SENSOR_ASPECTS = (4.0 / 3.0, 3.0 / 2.0)
CROPPED_FROM_ASPECT = 4.0 / 3.0


def photo_sensor_aspect(width: int, height: int) -> float | None:
    """The photo sensor's full-frame aspect (`SENSOR_ASPECTS`, long / short side, within 1 %) of a `width` x
    `height` frame, either way up; None for any other aspect (a crop of a frame)."""
    aspect = max(width, height) / min(width, height)
    return next((a for a in SENSOR_ASPECTS if abs(aspect - a) <= 0.01 * a), None)


def full_frame_diagonal_px(width: int, height: int, sensor_aspect: float | None = None) -> float:
    """Diagonal, in pixels of this image, of the sensor frame a 35 mm equivalent focal length refers to.

    The image is the largest crop of a frame of `sensor_aspect` (long / short side; default: the image's own
    aspect when it is a photo sensor's, 4:3 or 3:2, else 4:3) with the same pixel pitch: a wider image keeps the
    frame's long side, a squarer one its short side."""
    long_side, short_side = max(width, height), min(width, height)
    aspect = long_side / short_side
    if sensor_aspect is None:
        sensor_aspect = photo_sensor_aspect(width, height) or CROPPED_FROM_ASPECT
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


# The narrowest sensors, by their pixel pitch, which the focal plane resolution gives and which an export that
# rewrites ExifImageWidth leaves as the camera's. A focal plane resolution that puts an image on a narrower sensor
# refers to another readout than the file's: the image was downscaled after the camera wrote its EXIF, and
# ExifImageWidth, which said from what size, was dropped or rewritten to the new one (the sixteenth sweep:
# Seneca's 1200 px frames on a "1.86 mm" sensor gave fx 2775 px for 833, and a map 30-140 m too low passed).
# - A photo sensor (pixels finer than PHOTO_SENSOR_MAX_PITCH_UM: CMOS and CCD, 0.8-8.5 um) is no narrower than
#   1/3.2" (4.54 mm; phones' and compacts' smallest, survey cameras are 1/2.3", 6.2 mm, and up). With 3 mm for
#   all, exports of Seneca's Canon (4000 px, 6.2 mm, no 35 mm figure to check against) down to 1936 px passed
#   with fx up to 2x too long (rev38): now those below 2900 px (x1.38) are refused. A milder downscale (x1.33 at
#   3000 px: "4.65 mm") still reads as a real sensor: the tags cannot tell it from one.
# - A thermal core (microbolometer pixels of 10-17 um) is no narrower than 3 mm (a 320 px core at 12 um: 3.8
#   mm); smaller ones (160 px Lepton, 1.9 mm) take --sensor-width-mm.
PHOTO_SENSOR_MAX_PITCH_UM = 10.0
MIN_PHOTO_SENSOR_WIDTH_MM = 4.5
MIN_SENSOR_WIDTH_MM = 3.0


def min_sensor_width_mm(px_per_mm: float) -> float:
    """The narrowest real sensor of pixels `px_per_mm` apart (on its long side): a photo sensor's or a thermal
    core's (`MIN_PHOTO_SENSOR_WIDTH_MM`, `MIN_SENSOR_WIDTH_MM`)."""
    photo = 1000.0 / px_per_mm < PHOTO_SENSOR_MAX_PITCH_UM
    return MIN_PHOTO_SENSOR_WIDTH_MM if photo else MIN_SENSOR_WIDTH_MM


# Aspects (long / short side) of camera frames: photo sensors' full frames and their usual in-camera crops,
# the one list for every check that calls a frame cropped (`odd_aspect`, `poses.checks.cropped_frames`; two lists
# had called DJI DCI 4K and the P4 Multispectral's 1600x1300 cropped): square stills, 6:5 (MicaSense 2464x2056
# panchromatic), 5:4 (thermal 640x512, 1280x1024; P4 Multispectral 1600x1300 within the tolerance), 4:3 (thermal
# 336x256 and 382x288 within it), 4112x3008 (MicaSense Altum-PT panchromatic), 3:2, 16:10, 16:9 and 17:9 (DCI
# 4096x2160, 5120x2700). 7:6 (a 640x480 frame cut by 80 px, nu42) lies beyond the tolerance of 6:5.
CAMERA_ASPECTS = (1.0, 6.0 / 5.0, 5.0 / 4.0, 4.0 / 3.0, 4112.0 / 3008.0, 3.0 / 2.0, 16.0 / 10.0, 16.0 / 9.0,
                  17.0 / 9.0)
ASPECT_TOLERANCE = 0.02


def camera_aspect(width: int, height: int) -> bool:
    """Whether a `width` x `height` frame (either way up) has a camera's aspect (`CAMERA_ASPECTS`, within
    ASPECT_TOLERANCE); False for an empty size."""
    if width <= 0 or height <= 0:
        return False
    aspect = max(width, height) / min(width, height)
    return any(abs(aspect - a) <= ASPECT_TOLERANCE * a for a in CAMERA_ASPECTS)


def odd_aspect(meta: ImageMetadata) -> str | None:
    """What a frame of an aspect no camera makes says (a 640x480 frame with 80 px cut from one side: 7:6), None
    for a camera's aspect or a file of the size its EXIF records. Such a frame was cropped after capture, and the
    EXIF does not say where: its principal point is unknown (the image centre is taken; up to half the cut off,
    which reads as a shared attitude error of the cameras), and a 35 mm equivalent is taken as of a 4:3 frame."""
    w, h = meta.width, meta.height
    if w <= 0 or h <= 0 or (meta.exif_size and (tuple(meta.exif_size) in ((w, h), (h, w)))):
        return None
    if camera_aspect(w, h):
        return None
    aspect = max(w, h) / min(w, h)
    return (f"its {w}x{h} frames have an aspect ({aspect:.3f}) no camera makes: cropped after capture? Their "
            "principal point is unknown (the image centre is taken, which a one-sided crop moves: poses and "
            "heights off by up to half the cut's angle); map the uncropped frames, or give the camera (--camera)")


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
    length in pixels. A focal plane resolution that puts the image on a sensor narrower than any real one of its
    pixel pitch (`min_sensor_width_mm`) is refused (InputError) unless a 35 mm equivalent focal length can stand
    in."""
    camera, source = _camera_before_zoom(meta, sensor_width_mm)
    zoom = meta.digital_zoom
    if zoom and zoom > 1.0:
        camera = Camera(camera.width, camera.height, camera.fx * zoom, camera.fy * zoom, camera.cx, camera.cy)
        source += f", x{zoom:g} digital zoom"
    return camera, source


def _readout_aspect(meta: ImageMetadata) -> float | None:
    """The aspect (long / short side) of the readout the EXIF records when it is a photo sensor's (the frame a
    35 mm equivalent refers to, also for a file cropped from it), else None."""
    if not meta.exif_size or min(meta.exif_size) <= 0:
        return None
    return photo_sensor_aspect(*meta.exif_size)


def _by_35mm(meta: ImageMetadata) -> Camera:
    w, h = meta.width, meta.height
    fx = meta.focal_35mm / FULL_FRAME_DIAGONAL_MM * full_frame_diagonal_px(w, h, _readout_aspect(meta))
    return Camera(w, h, fx, fx, w / 2.0, h / 2.0)


def _refuse_disagreement(meta: ImageMetadata, by_plane: Camera, by_35: Camera) -> None:
    """InputError when the focal plane route and the 35 mm route of one image's EXIF disagree beyond
    EXIF_FOCAL_TOLERANCE (their nominal marking and whole-millimetre rounding are a few per cent). A resize after
    capture keeps the 35 mm figure (a ratio to the frame) right but not the pixel pitch the focal plane resolution
    gives, when ExifImageWidth was rewritten to the new size; a crop keeps the pixel pitch but not the frame the
    35 mm figure refers to. Which happened, the EXIF cannot say: the camera's focal length in pixels is unknown.

    Both routes are compared before a digital zoom (`camera_from_metadata` applies DigitalZoomRatio afterwards),
    but many cameras write a 35 mm figure that includes it: a zoomed frame agrees when either its 35 mm figure
    or the focal plane one multiplied by the zoom is like the other."""
    ratio = by_plane.fx / by_35.fx
    zoom = meta.digital_zoom if meta.digital_zoom and meta.digital_zoom > 1.0 else 1.0
    if min(abs(math.log(ratio)), abs(math.log(ratio * zoom))) <= math.log1p(EXIF_FOCAL_TOLERANCE):
        return
    size = f"ExifImageWidth {meta.exif_size[0]}x{meta.exif_size[1]}" if meta.exif_size else "no ExifImageWidth"
    raise InputError(
        f"EXIF focal lengths disagree x{ratio:.2f}: FocalLength x FocalPlaneXResolution gives {by_plane.fx:.1f} px, "
        f"FocalLengthIn35mmFilm {by_35.fx:.1f} px for the {meta.width}x{meta.height} file ({size}); resized after "
        "capture (the 35 mm one holds) or cropped (the focal plane one)? Give the sensor's width "
        "(poses-from-exif --sensor-width-mm, then map --poses) or a camera file (map --camera), or let structure "
        "from motion estimate it (map without --pose-source exif)", meta.path)


def _camera_before_zoom(meta: ImageMetadata, sensor_width_mm: float | None) -> tuple[Camera, str]:
    w, h = meta.width, meta.height
    if meta.focal_mm and sensor_width_mm:
        # A sensor's width is its long side (spec sheets, and the focal plane route here), and the file's long side
        # spans it whichever way the file is turned: by the file's width, a portrait file got fx 25 % short (rev38)
        fx = meta.focal_mm / sensor_width_mm * max(w, h)
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
            source += (f", EXIF size {ref_w}x{ref_h} and file {w}x{h} differ in aspect (cropped?): scaled by the "
                       "side cut least")
        # the sensor's long side in mm, as the focal plane resolution and the readout's size say
        long_px_per_mm = px_per_mm_x if ref_w >= ref_h else px_per_mm_y
        sensor_mm = (ref_w if ref_w >= ref_h else ref_h) / long_px_per_mm
        narrowest = min_sensor_width_mm(long_px_per_mm)
        if sensor_mm >= narrowest:
            # A resize scales both sides alike and a crop only shortens them, so the file's scale against the
            # readout is at least each side's ratio: the larger one (exact when one side was left whole). By width
            # alone, a 640x480 readout with 80 px cut from its width got fx x0.875.
            scale = max(w / ref_w, h / ref_h)
            fx = meta.focal_mm * px_per_mm_x * scale
            fy = meta.focal_mm * px_per_mm_y * scale
            by_plane = Camera(w, h, fx, fy, w / 2.0, h / 2.0)
            if meta.focal_35mm:
                _refuse_disagreement(meta, by_plane, _by_35mm(meta))
            return by_plane, source
        kind = "photo sensor" if narrowest == MIN_PHOTO_SENSOR_WIDTH_MM else "thermal core"
        stale = (f"FocalPlaneXResolution ({px_per_mm_x:.0f} px/mm) puts the {ref_w} px wide "
                 f"{'readout' if meta.exif_size else 'image'} on a {sensor_mm:.2f} mm sensor, narrower "
                 f"than any survey camera's: the image was downscaled after the camera wrote its EXIF, which no "
                 f"longer says from what size (ExifImageWidth {'rewritten' if meta.exif_size else 'missing'}; "
                 f"{1000.0 / long_px_per_mm:.1f} um pixels are a {kind}'s, none narrower than {narrowest:g} mm)")
    if meta.focal_35mm:
        if stale:
            log.debug("%s: %s; the 35 mm equivalent focal length is used", meta.path.name, stale)
        return _by_35mm(meta), "FocalLengthIn35mmFilm (full-frame diagonal)"
    if stale:
        raise NoFocalLength(stale, "give the sensor width (--sensor-width-mm), or `map` a camera file (--camera)",
                            meta.path, sep=": ")
    reason = "no usable focal length in EXIF (FocalLength with FocalPlaneXResolution, or FocalLengthIn35mmFilm)"
    if meta.focal_mm:
        raise NoFocalLength(reason, "give the sensor width (--sensor-width-mm)", meta.path)
    # a sensor width needs a focal length in mm to go with it: without one it cannot help
    raise NoFocalLength(f"{reason}: the images carry no focal length at all (EXIF stripped?)",
                        "take poses and intrinsics from structure from motion (`sosmatch poses`), or give "
                        "`sosmatch map` a pose CSV and --camera", meta.path)


class NoFocalLength(InputError):
    """An image whose EXIF gives no usable focal length: `reason` says why, and the message adds what the user can
    do; a caller that can do without it (structure from motion starts from a guess) says the reason alone."""

    def __init__(self, reason: str, advice: str, path: Path | None, sep: str = "; ") -> None:
        super().__init__(f"{reason}{sep}{advice}", path)
        self.reason = reason


# Images of one make, model and size at focal lengths set apart by a gap of more than this are cameras of their
# own: an optical zoom, or another lens on the same body (a Zenmuse P1 with its 24 and 35 mm lenses: one model
# name, one size). One camera at the median focal length was wrong for every image (rev38: a flight alternating
# 502 and 1005 px became one camera of 749 px; structure from motion put the centres 34 m off, blaming the GPS).
# Settings are told apart by GAPS between the sorted values, never by how far a value lies from some first one:
# a zoom's settings are discrete (the next is at least a step of the tag away, 0.1 mm at 4.3 mm: 2.3 %; and a
# survey flies one or two of them, 2x apart), while one setting's tag repeats itself or spreads continuously (a
# FocalLength rational that jitters with focus, 0.01 mm steps: 0.2 % at 4.5 mm). A rule "within 1 % of the
# group's shortest" cut such a spread at an arbitrary value (rev39: FocalLength 4.91-4.97 mm became two cameras
# 0.7 % apart, and map refused the folder). The gap sits between the two: above a jittering rational's steps,
# below a zoom's. A spread within one camera of a couple of per cent moves fx less than the lens marking's own 2 %
# (EXIF_NOMINAL_FOCAL_SIGMA); one beyond the tolerance is named (`focal_settings`).
FOCAL_GROUP_TOLERANCE = 0.01


def focal_clusters(readings: list[tuple[float, float]]) -> list[list[int]]:
    """Indices into `readings` (each image's focal length and the half-width of its tag's rounding, in one unit)
    grouped into settings, in ascending order: sorted by their lowest possible value, a reading starts a new
    group only where it lies more than FOCAL_GROUP_TOLERANCE above the highest possible value of every reading
    before it (a gap), so a continuous spread stays one group, readings whose rounding intervals touch (35 mm
    figures one millimetre apart) are one, and the grouping does not depend on the images' order."""
    order = sorted(range(len(readings)), key=lambda i: (readings[i][0] - readings[i][1], readings[i][0], i))
    groups: list[list[int]] = []
    reach = -math.inf
    for i in order:
        value, half = readings[i]
        if groups and value - half <= reach * (1.0 + FOCAL_GROUP_TOLERANCE):
            groups[-1].append(i)
            reach = max(reach, value + half)
        else:
            groups.append([i])
            reach = value + half
    return [sorted(g) for g in groups]


def focal_readings(metas: list[ImageMetadata], cameras: list[Camera]) -> list[tuple[float, float]]:
    """The focal length of each image (`cameras`: its camera from `camera_from_metadata`, all of one make, model,
    size and digital zoom) as the finest tag it has, in pixels, with the half-width of the tag's rounding
    (`focal_clusters`). FocalLength is a rational (0.01 mm or finer: taken as exact) and fx is proportional to it
    on every route, so where an image has it, it is the reading, scaled to pixels by the images' median fx per
    mm; a 35 mm equivalent alone is whole millimetres, so 24 and 25 may both be 24.5 (half a millimetre either
    way; a DJI tag alternating 24/25 with FocalLength 4.5 throughout was two cameras)."""
    per_mm = [c.fx / m.focal_mm for m, c in zip(metas, cameras) if m.focal_mm]
    scale = float(np.median(per_mm)) if per_mm else 0.0
    readings = []
    for m, c in zip(metas, cameras):
        if m.focal_mm:
            readings.append((m.focal_mm * scale, 0.0))
        else:  # only the 35 mm route gives a focal length without FocalLength
            readings.append((c.fx, c.fx * 0.5 / m.focal_35mm if m.focal_35mm else 0.0))
    return readings


def focal_settings(metas: list[ImageMetadata], cameras: list[Camera]) -> list[list[int]]:
    """Indices into `metas` (images of one make, model, size and digital zoom, `cameras` their cameras) grouped
    into the settings of a zoom (`focal_clusters` of `focal_readings`), in ascending focal length. Neighbouring
    settings whose median fx lie within FOCAL_GROUP_TOLERANCE are one camera: FocalLength can set apart two
    settings whose fx, from one whole-millimetre 35 mm figure, is the same, and two cameras of one fx only make
    map refuse the folder. Where a setting's readings and its fx spread beyond the tolerance (and the tags'
    rounding), a warning names the spread (a zoom moved while flying is one camera at the median, off for the
    ends)."""
    readings = focal_readings(metas, cameras)
    settings: list[list[int]] = []
    for group in focal_clusters(readings):
        if settings and (float(np.median([cameras[i].fx for i in group]))
                         <= float(np.median([cameras[i].fx for i in settings[-1]])) * (1.0 + FOCAL_GROUP_TOLERANCE)):
            settings[-1] = sorted(settings[-1] + group)
        else:
            settings.append(group)
    for group in settings:
        lowest_high = min(readings[i][0] + readings[i][1] for i in group)
        highest_low = max(readings[i][0] - readings[i][1] for i in group)
        m0, fxs = metas[group[0]], [cameras[i].fx for i in group]
        if (highest_low > lowest_high * (1.0 + FOCAL_GROUP_TOLERANCE)
                and max(fxs) > min(fxs) * (1.0 + FOCAL_GROUP_TOLERANCE)):
            log.warning("%s (%dx%d): focal lengths spread over %.1f..%.1f px (%.1f %%) with no gap between zoom "
                        "settings: one camera at the median (a tag that jitters, or a zoom moved while flying?)",
                        make_model(m0) or "camera", m0.width, m0.height, min(fxs), max(fxs),
                        100.0 * (max(fxs) / min(fxs) - 1.0))
    return settings


def _reason(exc: InputError) -> str:
    """Why an image has no usable focal length (`NoFocalLength.reason`; another InputError's problem)."""
    return exc.reason if isinstance(exc, NoFocalLength) else exc.problem


def camera_groups(metas: list[ImageMetadata], sensor_width_mm: float | None,
                  strict: bool) -> tuple[list[Camera], np.ndarray, list[str], list[str]]:
    """One camera per make + model + image size + digital zoom + focal length setting (`focal_settings`: a
    zoom's or swapped lens's settings, apart by gaps, are cameras of their own; the median focal length of its
    images), the camera of every image and the intrinsics source of each camera, in the order of their first
    images. Images of a camera whose EXIF gives no usable focal length share the others' (one warning counts
    them); where those others are at several focal lengths, which is theirs is unknown: InputError when `strict`,
    else a camera of their own.
    Without any for a camera, it gets COLMAP's default guess (1.2 x the longer side) with a warning (also
    returned, last), or InputError when `strict` (the first image's reason)."""
    by_key: dict[tuple, list[int]] = {}
    for i, m in enumerate(metas):
        by_key.setdefault(m.camera_key, []).append(i)
    groups: list[tuple[list[int], list[tuple[Camera, str]], list[InputError]]] = []
    for members in by_key.values():
        found: list[tuple[int, tuple[Camera, str]]] = []
        failed: list[tuple[int, InputError]] = []
        for i in members:
            try:
                found.append((i, camera_from_metadata(metas[i], sensor_width_mm)))
            except InputError as exc:
                failed.append((i, exc))
        settings = [[found[k] for k in c] for c in focal_settings([metas[i] for i, _ in found],
                                                                  [cam for _, (cam, _) in found])]
        if len(settings) > 1:
            m0 = metas[members[0]]
            log.info("%s (%dx%d): images at %d focal lengths (fx %s px; a zoom or another lens): a camera for each",
                     make_model(m0) or "camera", m0.width, m0.height, len(settings),
                     ", ".join(f"{float(np.median([c.fx for _, (c, _) in s])):.0f}" for s in settings))
        if failed and len(settings) > 1:
            if strict:
                i, exc = failed[0]
                raise InputError(f"{_reason(exc)}, and the other images of its camera are at {len(settings)} "
                                 f"focal lengths (a zoom or another lens): which is its is unknown; give a camera "
                                 f"file (map --camera) or let structure from motion estimate it (`sosmatch poses`)",
                                 metas[i].path)
            groups += [([i for i, _ in s], [r for _, r in s], []) for s in settings]
            groups.append(([i for i, _ in failed], [], [e for _, e in failed]))
        elif settings:
            groups += [([i for i, _ in s] + ([i for i, _ in failed] if g == 0 else []), [r for _, r in s],
                        [e for _, e in failed] if g == 0 else []) for g, s in enumerate(settings)]
        else:
            groups.append(([i for i, _ in failed], [], [e for _, e in failed]))
    groups.sort(key=lambda g: min(g[0]))
    index = np.empty(len(metas), dtype=np.int64)
    cameras, sources, warnings = [], [], []
    for g, (images, found_cams, failed_exc) in enumerate(groups):
        index[images] = g
        m0 = metas[min(images)]
        w, h = m0.width, m0.height
        name = f"{make_model(m0) or 'camera'} ({w}x{h}, {len(images)} images)"
        if not found_cams:
            if strict:
                raise failed_exc[0]
            f = 1.2 * max(w, h)
            # the reason alone: the error's advice (run `sosmatch poses`) is for the callers that refuse (nu53)
            warnings.append(f"{name}: {_reason(failed_exc[0])}; starting from {f:.0f} px (structure from motion "
                            "estimates it)")
            log.warning("%s", warnings[-1])
            cameras.append(Camera(w, h, f, f, w / 2.0, h / 2.0))
            sources.append("none in EXIF (1.2 x the longer side)")
            continue
        if failed_exc:
            example = failed_exc[0].path.name if failed_exc[0].path else "?"
            log.warning("%s: %d of its images have no usable focal length in EXIF (e.g. %s): they take the focal "
                        "length of the other %d", name, len(failed_exc), example, len(found_cams))
        cropped = [source for _, source in found_cams if "cropped?" in source]
        if cropped:
            sizes = cropped[0].split(", EXIF size ")[-1].split(" differ")[0]
            warnings.append(f"{name}: {len(cropped)} images' EXIF size and file size differ in aspect (cropped?): "
                            f"their focal length is scaled by the side cut least, their principal point is unknown "
                            f"(the image centre taken; EXIF size {sizes})")
            log.warning("%s", warnings[-1])
        elif (odd := odd_aspect(m0)) is not None:
            warnings.append(f"{name}: {odd}")
            log.warning("%s", warnings[-1])
        c0 = found_cams[0][0]
        cameras.append(Camera(c0.width, c0.height, float(np.median([c.fx for c, _ in found_cams])),
                              float(np.median([c.fy for c, _ in found_cams])), c0.cx, c0.cy))
        sources.append(found_cams[0][1])
    return cameras, index, sources, warnings


def make_model(meta: ImageMetadata) -> str:
    return meta.model if meta.model.startswith(meta.make) else f"{meta.make} {meta.model}".strip()
