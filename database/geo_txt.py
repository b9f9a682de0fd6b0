"""OpenDroneMap's image geolocation file (`geo.txt`): image positions beside a folder of images.

The layout (ODM docs, "Image Geolocation Files"): the first line names the CRS of the coordinates, as an EPSG code
(`EPSG:4326`), a PROJ string (`+proj=utm +zone=10 ...`) or `WGS84 UTM <zone>[N|S]`; every following line is
`image_name geo_x geo_y [geo_z] [yaw pitch roll] [horz_accuracy vert_accuracy] [extras...]`, whitespace separated.
geo_x is the CRS's first axis in the traditional GIS order: the longitude for EPSG:4326, the easting for a
projected CRS. Only the positions are read (x, y, z): ODM itself uses the angles for radiometric calibration only
and their convention is not fixed by the format. `read_geo_txt` returns rows in `telemetry_io`'s form (`lat`,
`lon`, `alt` per image name), so a geo.txt is taken wherever a telemetry file is (`--telemetry`).

`looks_like_geo_txt` recognises the layout from its first line; `geo_txt_hint` names a geo.txt lying in an images
folder for the messages about images without GPS (ODM reads it from the project folder by itself; sosmatch takes
positions from the images or from the file given, so a file beside them is named, with how to give it).
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

from ..plugin.errors import InputError
from .text_input import read_user_text

log = logging.getLogger(__name__)

GEO_TXT_NAME = "geo.txt"
_UTM_RE = re.compile(r"^WGS84\s+UTM\s+(\d{1,2})\s*([NS])$", re.IGNORECASE)


def _crs_text(line: str) -> str | None:
    """The CRS of a geo.txt first line as pyproj takes it ("EPSG:4326", a PROJ string), or None when the line is
    none of ODM's three forms."""
    text = line.strip()
    if re.fullmatch(r"EPSG:\d+", text, re.IGNORECASE):
        return text.upper()
    if text.startswith("+proj="):
        return text
    if (m := _UTM_RE.match(text)) is not None and 1 <= int(m.group(1)) <= 60:
        return f"EPSG:{(32600 if m.group(2).upper() == 'N' else 32700) + int(m.group(1))}"
    return None


def looks_like_geo_txt(text: str) -> bool:
    """Whether `text` (a file's contents) is laid out as an ODM geo.txt: its first non-blank line is a CRS."""
    first = next((ln for ln in text.splitlines() if ln.strip()), "")
    return _crs_text(first) is not None


def _to_lonlat(crs: str, xs: list[float], ys: list[float], path: Path) -> tuple[list[float], list[float]]:
    """Longitudes and latitudes (degrees) of `xs`, `ys` in `crs` (pyproj, in the CRS's x/y order)."""
    if crs == "EPSG:4326":
        return xs, ys
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    try:
        source = CRS.from_user_input(crs)
    except CRSError as exc:
        raise InputError(f"geo.txt CRS {crs!r} is not one pyproj knows ({exc})", path, 1) from None
    transformer = Transformer.from_crs(source, CRS.from_epsg(4326), always_xy=True)
    lon, lat = transformer.transform(xs, ys)
    return [float(v) for v in lon], [float(v) for v in lat]


def read_geo_txt(path: str | Path, text: str | None = None) -> dict[str, dict[str, float]]:
    """Per image name: `lat`, `lon` (degrees, signed) and `alt` (geo_z, where given) of an ODM geo.txt (`text`:
    its content when the caller has read it already). A first line that is no CRS, a row with fewer than three
    fields, a coordinate that is not a number, a name given twice or a position off the globe is an InputError
    naming the line."""
    path = Path(path)
    text = read_user_text(path, "geo.txt") if text is None else text
    numbered = [(k, ln.split()) for k, ln in enumerate(text.splitlines(), start=1) if ln.strip()
                and not ln.lstrip().startswith("#")]
    if not numbered:
        raise InputError("empty geo.txt", path)
    first_no, first = numbered[0]
    crs = _crs_text(" ".join(first))
    if crs is None:
        raise InputError(f"the first line of a geo.txt names the coordinates' CRS (EPSG:4326, a +proj string or "
                         f"'WGS84 UTM 16N'), not {' '.join(first)[:40]!r}", path, first_no)
    line_of: dict[str, int] = {}  # name -> its line (a dict: a name given twice is found at once on any length)
    xs: list[float] = []
    ys: list[float] = []
    zs: list[float] = []
    for lineno, fields in numbered[1:]:
        if len(fields) < 3:
            raise InputError("a geo.txt row needs image_name geo_x geo_y [geo_z ...] (whitespace separated; a name "
                             "with spaces cannot be given)", path, lineno)
        try:
            x, y = float(fields[1]), float(fields[2])
            z = float(fields[3]) if len(fields) > 3 else math.nan
        except ValueError:
            raise InputError(f"non-numeric coordinate in {' '.join(fields[1:4])!r}", path, lineno) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(f"coordinate {fields[1]} {fields[2]} is not a number", path, lineno)
        if (earlier := line_of.get(fields[0])) is not None:
            raise InputError(f"{fields[0]} is given twice (also line {earlier})", path, lineno)
        line_of[fields[0]] = lineno
        xs.append(x)
        ys.append(y)
        zs.append(z)
    names, lines = list(line_of), list(line_of.values())
    if not names:
        raise InputError("geo.txt has a CRS line but no image rows", path)
    lons, lats = _to_lonlat(crs, xs, ys, path)
    out: dict[str, dict[str, float]] = {}
    for name, lineno, lon, lat, z in zip(names, lines, lons, lats, zs):
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0 and abs(lon) <= 180.0):
            swapped = " (geo_x is the longitude: latitude and longitude swapped?)" if crs == "EPSG:4326" else ""
            raise InputError(f"position of {name} is off the globe in {crs}{swapped}", path, lineno)
        out[name] = {"lat": lat, "lon": lon} | ({"alt": z} if math.isfinite(z) else {})
    # latitude and longitude swapped read as another place whenever both are within +-90 (rev56 D7): only the
    # images' own GPS can tell (`image_positions.swapped_columns`); without it the place is said, to be looked at
    first_row = out[names[0]]
    log.info("%s: %d image positions in %s, %s at lat %.6f, lon %.6f", path, len(out), crs, names[0],
             first_row["lat"], first_row["lon"])
    return out


def geo_txt_hint(folder: Path) -> str | None:
    """One clause for a message about images without GPS when `folder` holds an ODM geo.txt: how to give it;
    None when it holds none."""
    candidate = folder / GEO_TXT_NAME
    if not candidate.is_file():
        return None
    return (f"{candidate} (OpenDroneMap's image positions) is not read by itself: give it with --telemetry "
            f"{candidate}")
