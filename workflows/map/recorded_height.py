"""The map's flying height against the height above take-off the flight recorded (DJI XMP RelativeAltitude).

The map's flying height (cameras over the ground their landmarks make) scales with the camera's focal length:
a focal length 2x too long (a photo resized after capture whose EXIF was rewritten) put the ground 100 m too
low and every check passed, since poses, matches and georeference are all horizontal or scale-free. The
barometer's height above the take-off point is independent of the images and of the focal length: where the
surveyed ground lies near the take-off point's height it should match the map's flying height. It is a warning,
not a refusal: the take-off point may lie well above or below the surveyed ground (a valley, a roof).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..image_cameras import EXIF_FOCAL_TOLERANCE

log = logging.getLogger(__name__)

# How far the map's flying height may lie from the recorded height above take-off before it is said: the
# larger of this many metres (the take-off point's ground against the surveyed one: a few metres on flat land)
# and the EXIF focal length's own tolerance as a share of the height (a focal length within it is not in doubt).
TAKEOFF_GROUND_M = 20.0


def recorded_heights(paths: list[Path]) -> np.ndarray:
    """The DJI XMP RelativeAltitude (m above the take-off point) of each image, NaN where it has none or cannot
    be read."""
    from ...database.exif import read_image_metadata
    from ...plugin.errors import InputError

    out = np.full(len(paths), np.nan)
    for k, path in enumerate(paths):
        try:
            value = read_image_metadata(path).xmp_float("RelativeAltitude")
        except (InputError, OSError, ValueError):
            continue
        if value is not None:
            out[k] = value[0]
    return out


def takeoff_record(map_height_m: float, relative_m: np.ndarray) -> dict[str, float] | None:
    """run.json's "height_above_takeoff": the map's flying height, the median recorded height above take-off and
    the map's ground against where the recorded heights put it (m, + above); None without recorded heights or a
    flying height (`height_against_takeoff` says when they disagree)."""
    rel = relative_m[np.isfinite(relative_m)]
    if not np.isfinite(map_height_m) or not len(rel):
        return None
    recorded = float(np.median(rel))
    return {"map_flying_height_m": round(float(map_height_m), 2), "relative_altitude_m": round(recorded, 2),
            "ground_off_m": round(recorded - float(map_height_m), 2)}


def ground_off_beyond(record: object) -> float | None:
    """The "ground_off_m" of a run.json "height_above_takeoff" record when it lies beyond the tolerance of
    `height_against_takeoff` (the map's ground that far from where the recorded heights put it), else None."""
    if not isinstance(record, dict):
        return None
    try:
        off, recorded = float(record["ground_off_m"]), float(record["relative_altitude_m"])
    except (KeyError, TypeError, ValueError):
        return None
    return off if abs(off) > max(TAKEOFF_GROUND_M, EXIF_FOCAL_TOLERANCE * recorded) else None


def height_against_takeoff(map_height_m: float, relative_m: np.ndarray, camera_fx: float) -> str | None:
    """A warning when the map's flying height (`map_height_m`, cameras above the ground their landmarks make)
    and the median recorded height above take-off (`relative_m`, NaN: none) disagree beyond the larger of
    TAKEOFF_GROUND_M and EXIF_FOCAL_TOLERANCE of it; None when they agree, or when fewer than half the images
    record a height (or the heights are not above the take-off point)."""
    rel = relative_m[np.isfinite(relative_m)]
    if not np.isfinite(map_height_m) or map_height_m <= 0 or len(rel) < max(1, len(relative_m) / 2):
        return None
    recorded = float(np.median(rel))
    if recorded <= 0:
        return None
    off = map_height_m - recorded
    if abs(off) <= max(TAKEOFF_GROUND_M, EXIF_FOCAL_TOLERANCE * recorded):
        return None
    scale = map_height_m / recorded
    return (f"the map puts the cameras {map_height_m:.0f} m above its ground, the images' RelativeAltitude "
            f"{recorded:.0f} m above the take-off point: the landmarks lie {abs(off):.0f} m "
            f"{'below' if off > 0 else 'above'} where the recorded heights put the ground. A focal length x{scale:.2f} "
            f"off (fx {camera_fx:.1f} px; for {camera_fx / scale:.1f}: photos resized or cropped after capture?), "
            "or surveyed ground that far from the take-off point's")
