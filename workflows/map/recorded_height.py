"""The map's flying height against the height above take-off the flight recorded (DJI XMP RelativeAltitude).

The map's flying height (cameras over their ground, `ground_flying_height`) scales with the camera's focal length:
a focal length 2x too long (a photo resized after capture whose EXIF was rewritten) put the ground 100 m too
low and every check passed, since poses, matches and georeference are all horizontal or scale-free. The
barometer's height above the take-off point is independent of the images and of the focal length: where the
surveyed ground lies near the take-off point's height it should match the map's flying height. It is a warning,
not a refusal: the take-off point may lie well above or below the surveyed ground (a valley, a roof), which
one flying height cannot tell from a focal scale. The map's verdict is recorded in run.json and match repeats
it (`ground_off_beyond`) rather than judging anew.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ...plugin.map_quality import heights_seen_by_keyframe
from ..image_cameras import EXIF_FOCAL_TOLERANCE

log = logging.getLogger(__name__)

# How far the map's flying height may lie from the recorded height above take-off before it is said: the
# larger of this many metres (the take-off point's ground against the surveyed one: a few metres on flat land)
# and the EXIF focal length's own tolerance as a share of the height (a focal length within it is not in doubt).
TAKEOFF_GROUND_M = 20.0
# The share of a keyframe's landmarks below its ground (`ground_flying_height`): low enough to pass the canopy
# and the roofs, high enough to leave a few landmarks triangulated too deep.
GROUND_QUANTILE = 10.0


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


def ground_flying_height(positions: np.ndarray, observed_keyframes: list[np.ndarray], centers: np.ndarray) -> float:
    """The cameras' height above the ground they see: per keyframe its centre's height over the GROUND_QUANTILE
    of the heights of the landmarks it observes, the median over keyframes (NaN without any). The map quality's
    flying height measures to the landmarks' median, and landmarks are objects (tree tops, roofs): over a forest
    that reads 20 m low, which alone is the tolerance. A low quantile is the ground wherever some of it shows."""
    z = np.asarray(positions, np.float64).reshape(-1, 3)[:, 2]
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    seen = heights_seen_by_keyframe(z, observed_keyframes, len(centers))
    heights = [centers[k, 2] - np.percentile(g, GROUND_QUANTILE) for k, g in enumerate(seen) if g]
    return float(np.median(heights)) if heights else float("nan")


def _judged(map_height_m: float, relative_m: np.ndarray) -> tuple[float, float] | None:
    """(median recorded height, map height - recorded) when the two can be compared: a positive flying height,
    at least half the keyframes recording a height, and their median above the take-off point (a take-off above
    the surveyed ground records heights at or below 0, saying nothing of the focal length); None otherwise. The
    one rule for the map's warning and for its run.json record, which match reads."""
    rel = np.asarray(relative_m, np.float64)
    finite = rel[np.isfinite(rel)]
    if not np.isfinite(map_height_m) or map_height_m <= 0 or len(finite) < max(1, len(rel) / 2):
        return None
    recorded = float(np.median(finite))
    return (recorded, float(map_height_m) - recorded) if recorded > 0 else None


def _beyond(recorded: float, off: float) -> bool:
    return abs(off) > max(TAKEOFF_GROUND_M, EXIF_FOCAL_TOLERANCE * recorded)


def takeoff_record(map_height_m: float, relative_m: np.ndarray) -> dict[str, float | bool] | None:
    """run.json's "height_above_takeoff": the map's flying height (over its ground), the median recorded height
    above take-off, the map's ground against where the recorded heights put it (m, + above) and "beyond": the
    map's own verdict (`height_against_takeoff` warned), the only thing match reads; None without recorded
    heights or a flying height."""
    rel = np.asarray(relative_m, np.float64)
    rel = rel[np.isfinite(rel)]
    if not np.isfinite(map_height_m) or not len(rel):
        return None
    recorded = float(np.median(rel))
    judged = _judged(map_height_m, relative_m)
    return {"map_flying_height_m": round(float(map_height_m), 2), "relative_altitude_m": round(recorded, 2),
            "ground_off_m": round(recorded - float(map_height_m), 2),
            "beyond": judged is not None and _beyond(*judged)}


def ground_off_beyond(record: object) -> float | None:
    """The "ground_off_m" of a run.json "height_above_takeoff" record whose map warned ("beyond"), else None:
    match repeats the map's verdict rather than judging anew (a record written before "beyond" existed: None)."""
    if not isinstance(record, dict) or record.get("beyond") is not True:
        return None
    try:
        return float(record["ground_off_m"])
    except (KeyError, TypeError, ValueError):
        return None


def height_against_takeoff(map_height_m: float, relative_m: np.ndarray, camera_fx: float) -> str | None:
    """A warning when the map's flying height (`map_height_m`, cameras above their ground,
    `ground_flying_height`) and the median recorded height above take-off (`relative_m`, NaN: none) disagree
    beyond the larger of TAKEOFF_GROUND_M and EXIF_FOCAL_TOLERANCE of it; None when they agree, or when they
    cannot be compared (`_judged`).

    Two causes fit: a focal length off scales every height (the cameras' and the relief's), a take-off point
    above or below the surveyed ground adds a constant. Over flat ground, from one flying height, they cannot be
    told apart, so the warning states what each would have to be and asserts neither."""
    judged = _judged(map_height_m, relative_m)
    if judged is None or not _beyond(*judged):
        return None
    recorded, off = judged
    scale = map_height_m / recorded
    where, why = ("below", "a take-off from a hill or a roof") if off > 0 else ("above", "a take-off in a valley")
    return (f"the map puts the cameras {map_height_m:.0f} m above its ground, the images' RelativeAltitude "
            f"{recorded:.0f} m above the take-off point. Either the surveyed ground lies {abs(off):.0f} m "
            f"{where} the take-off point ({why}), "
            f"or the focal length is x{scale:.2f} off (fx {camera_fx:.1f} px would be {camera_fx / scale:.1f}: "
            "photos resized or cropped after capture?); from one flying height the two cannot be told apart")
