"""Telemetry CSVs: per-image attitude (and position) logged by the autopilot beside the images, as senseFly's
eMotion exports it (Seneca's telemetry.csv: FileName, Heading, PitchAngle, RollAngle, GPSLatitude, ...). Read
by `workflows.image_priors` where the images' own tags carry no attitude. A file laid out as OpenDroneMap's geo.txt
(a CRS on its first line: `database.geo_txt`) is read as one, for its positions."""

from __future__ import annotations

import csv
import logging
import math
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from .geo_txt import looks_like_geo_txt, read_geo_txt
from .images import name_key, unique_by_key
from .text_input import read_user_text

log = logging.getLogger(__name__)

_TELEMETRY_KEYS = {
    "name": ("filename", "name", "image", "image_name", "file"),
    "yaw": ("heading", "yaw", "yaw_deg", "flightyawdegree"),
    "pitch": ("pitchangle", "pitch", "pitch_deg", "flightpitchdegree"),
    "roll": ("rollangle", "roll", "roll_deg", "flightrolldegree"),
    "lat": ("gpslatitude", "latitude", "lat"),
    "lon": ("gpslongitude", "longitude", "lon"),
    "alt": ("gpsaltitude", "altitude", "alt"),
}
# The hemisphere columns of an export that keeps EXIF's unsigned coordinates beside their refs (exiftool's -csv of
# GPSLatitude/GPSLongitude and their Ref tags): (aliases, the positive and the negative letter). rev38: they were
# not read, so a flight in the west was placed in the east (Seneca, Ohio, in China) with exit 0.
_REF_KEYS = {
    "lat": (("gpslatituderef", "latituderef", "latref", "lat_ref"), "NS"),
    "lon": (("gpslongituderef", "longituderef", "lonref", "lon_ref"), "EW"),
}


def telemetry_rows(tele: dict[str, dict[str, float]], names: list[str], telemetry: str | Path | None,
                    images: Any) -> list[dict[str, float]]:
    """Each image's telemetry row, by file name (else by `images.name_key`, when that names one row and one
    image: a copy of the frames as .JPG, names decomposed by macOS). A telemetry
    file that names none of the images is an InputError (it was silently ignored: the attitudes then came from
    the course over ground); one that misses some is a warning naming how many."""
    if telemetry is None:
        return [{} for _ in names]
    # a name spelt otherwise (case, Unicode form) is paired when it folds to one row and one image only
    folded = {k: tele[row] for k, row in unique_by_key(tele).items()}
    unambiguous = unique_by_key(names)
    rows = [tele.get(n, folded.get(name_key(n), {}) if name_key(n) in unambiguous else {}) for n in names]
    missing = [n for n, r in zip(names, rows) if not r]
    if names and len(missing) == len(names):
        raise InputError(f"none of its {len(tele)} rows names an image of {images} (rows e.g. "
                         f"{next(iter(tele), '-')!r}, images e.g. {names[0]!r}): a telemetry file of other images?",
                         telemetry)
    if missing:
        log.warning("%s: no row for %d of %d images (e.g. %s): their poses come from their own tags", telemetry,
                    len(missing), len(names), missing[0])
    return rows


def read_telemetry_csv(path: str | Path) -> dict[str, dict[str, float]]:
    """Per image name: yaw/pitch/roll (and lat/lon/alt where present) from a telemetry CSV (header names as in
    Seneca's telemetry.csv: FileName, Heading, PitchAngle, RollAngle, GPSLatitude, ...; case-insensitive).
    Latitudes and longitudes are signed (south, west negative), or signed by a GPSLatitudeRef / GPSLongitudeRef
    column (N/S, E/W, or North/South...: `_REF_KEYS`); a ref that is none of these, or a negative value beside N
    or E, is an InputError naming the line."""
    path = Path(path)
    text = read_user_text(path, "telemetry file")
    if looks_like_geo_txt(text):  # OpenDroneMap's image positions (nu58 D4: refused for want of a name column)
        return read_geo_txt(path, text)
    lines = text.splitlines()
    first = next((ln for ln in lines if ln.strip()), "")
    # spreadsheets in many locales export ';' (a ',' is their decimal mark), others tabs
    delimiter = max(",;\t", key=first.count) if first else ","
    rows = list(csv.reader(lines, delimiter=delimiter))
    if not rows:
        raise InputError("empty telemetry file", path)
    header = [h.strip().lower() for h in rows[0]]
    col = {key: next((header.index(a) for a in aliases if a in header), None)
           for key, aliases in _TELEMETRY_KEYS.items()}
    if all(col[k] is None for k in ("yaw", "pitch", "roll")) and {"omega", "phi", "kappa"} <= set(header):
        log.warning("%s: omega/phi/kappa columns (photogrammetric angles of the camera) are not read; attitude "
                    "comes from yaw/pitch/roll columns (%s, %s, %s)", path, *(_TELEMETRY_KEYS[k][0]
                                                                           for k in ("yaw", "pitch", "roll")))
    if col["name"] is None:
        raise InputError(f"telemetry header needs an image name column (one of {_TELEMETRY_KEYS['name']})", path, 1)
    refs = {key: (idx, letters) for key, (aliases, letters) in _REF_KEYS.items()
            if (idx := next((header.index(a) for a in aliases if a in header), None)) is not None}
    out: dict[str, dict[str, float]] = {}
    placeholders = []  # rows whose position is no fix (module doc of `_position_is_a_fix`)
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        values: dict[str, float] = {}
        for key, idx in col.items():
            if key == "name" or idx is None or idx >= len(row) or not row[idx].strip():
                continue
            try:  # a ';' or tab file may carry the decimal comma of its locale
                values[key] = float(row[idx] if delimiter == "," else row[idx].replace(",", "."))
            except ValueError:
                raise InputError(f"non-numeric {header[idx]} value {row[idx]!r}", path, lineno) from None
        for key, (idx, letters) in refs.items():
            if key in values and idx < len(row) and row[idx].strip():
                values[key] = _signed_by_ref(values[key], row[idx], letters, header[col[key]], header[idx], path,
                                             lineno)
        had_position = "lat" in values or "lon" in values
        values = {k: v for k, v in values.items() if math.isfinite(v)}  # "nan", "inf": no value
        if had_position and not _position_is_a_fix(values):
            placeholders.append(lineno)
            for key in ("lat", "lon", "alt"):
                values.pop(key, None)
        out[row[col["name"]].strip()] = values
    if placeholders:
        log.warning("%s: %d rows hold no GPS fix (lat/lon 0,0, missing or out of range, e.g. line %d: logged before "
                    "the receiver's lock?): their images keep their own GPS", path, len(placeholders), placeholders[0])
    return out


def _signed_by_ref(value: float, ref: str, letters: str, name: str, ref_name: str, path: Path,
                   lineno: int) -> float:
    """`value` signed by its hemisphere `ref` (`letters`: the positive and the negative one; "North", "w" read by
    their first letter). A value already negative beside the negative letter stays so (an export of signed values
    beside their refs); one beside the positive letter contradicts it: InputError."""
    letter = ref.strip().upper()[:1]
    if letter not in letters:
        raise InputError(f"{ref_name} {ref.strip()!r} is not {letters[0]} or {letters[1]}", path, lineno)
    if letter == letters[1]:
        return -abs(value)
    if value < 0:
        raise InputError(f"{name} {value!r} is negative beside {ref_name} {ref.strip()!r}: which hemisphere?", path,
                         lineno)
    return value


def _position_is_a_fix(values: dict[str, float]) -> bool:
    """Whether a row's lat/lon is a fix: both present and in range, and not 0,0 (autopilot logs write 0,0 or leave
    the fields empty until the receiver locks; taken as positions, such rows overrode the images' valid EXIF GPS
    and put the flight in the Gulf of Guinea). Its altitude is dropped with it (then 0 as well, or stale)."""
    lat, lon = values.get("lat"), values.get("lon")
    return (lat is not None and lon is not None and abs(lat) <= 90.0 and abs(lon) <= 180.0
            and not (lat == 0.0 and lon == 0.0))
