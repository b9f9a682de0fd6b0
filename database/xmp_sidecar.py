"""GPS positions held in `.xmp` sidecar files beside images (Lightroom, darktable, exiftool write them as
`<image>.xmp` or `<stem>.xmp`, values like exif:GPSLatitude "42,30.123N"). sosmatch takes positions from the
images' own EXIF (or a telemetry CSV) only: a sidecar can change without the image, which the outputs' fingerprints
(the images' size and time) would not see. These functions find such sidecars so that an error about missing GPS
can say where the positions are and how to bring them into the images."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from .exif import parse_xmp

# "42,30.123N" (degrees, decimal minutes) or "42,30,7.38N" (degrees, minutes, seconds), as XMP's exif: schema
_XMP_COORDINATE = re.compile(r"^\s*(\d+),(\d+(?:\.\d*)?)(?:,(\d+(?:\.\d*)?))?\s*([NSEW])\s*$", re.IGNORECASE)
# the copy back into the images, from the sidecars' names ({name}: exiftool's %d%f.xmp for `<stem>.xmp`,
# %d%f.%e.xmp for darktable's `<image>.xmp`): a sidecar holds the position as XMP-exif tags, which `-gps:all`
# alone does not read; the references (N/S, E/W) come from exiftool's composite tags
EXIFTOOL_COPY = ('exiftool -tagsfromfile {name} "-GPS:all<XMP-exif:all" "-GPS:GPSLatitudeRef<Composite:GPSLatitudeRef" '
                 '"-GPS:GPSLongitudeRef<Composite:GPSLongitudeRef" DIR')


def sidecar_of(image: Path) -> Path | None:
    """The `.xmp` sidecar of `image` (`<name>.xmp`, then `<stem>.xmp`, either case), or None."""
    for candidate in (image.parent / (image.name + ".xmp"), image.with_suffix(".xmp"),
                      image.parent / (image.name + ".XMP"), image.with_suffix(".XMP")):
        if candidate.is_file():
            return candidate
    return None


def xmp_coordinate(text: str) -> float | None:
    """Degrees of an XMP exif:GPSLatitude/GPSLongitude value ("42,30.123N", "42,30,7.38W": west and south
    negative), or None when it is not one."""
    match = _XMP_COORDINATE.match(text)
    if match is None:
        return None
    degrees, minutes, seconds, ref = match.groups()
    value = float(degrees) + float(minutes) / 60.0 + (float(seconds) / 3600.0 if seconds else 0.0)
    return -value if ref.upper() in ("S", "W") else value


def sidecar_position(sidecar: Path) -> tuple[float, float] | None:
    """The latitude and longitude (degrees) a sidecar holds, or None (none, unreadable, damaged)."""
    try:
        props = parse_xmp(sidecar.read_bytes())
    except (OSError, ValueError):
        return None
    lat, lon = (xmp_coordinate(props.get(k, "")) for k in ("GPSLatitude", "GPSLongitude"))
    return (lat, lon) if lat is not None and lon is not None else None


def sidecars_with_gps(images: Sequence[Path]) -> str | None:
    """One clause for an error about images without GPS: how many of `images` have a sidecar holding a position,
    with an example and the way to copy them into the images; None when none has."""
    found = [(image, side, pos) for image in images if (side := sidecar_of(image)) is not None
             and (pos := sidecar_position(side)) is not None]
    if not found:
        return None
    image, side, (lat, lon) = found[0]
    name = "%d%f.%e.xmp" if side.name.lower() == image.name.lower() + ".xmp" else "%d%f.xmp"
    return (f"their .xmp sidecars hold GPS ({len(found)} of them, e.g. {side.name}: {lat:.6f}, {lon:.6f}), which "
            f"sosmatch does not read: copy it into the images, e.g. {EXIFTOOL_COPY.format(name=name)}")
