"""Image metadata for poses and intrinsics: EXIF GPS, focal length and XMP attitude tags (Pillow only).

`read_image_metadata(path)` returns an `ImageMetadata` with what a survey image says about itself:
- GPS (EXIF GPS IFD 0x8825): latitude/longitude in degrees (signed by their N/S/E/W refs), altitude in metres
  (GPSAltitude, negative when GPSAltitudeRef is 1), GPSTrack (course over ground, degrees from north) if present;
- camera (EXIF IFD 0x8769): FocalLength (mm), FocalPlaneX/YResolution with their unit (pixels per inch or cm),
  the image size those refer to (ExifImageWidth/Height: the sensor readout, often larger than the file when
  images were downscaled after capture), Make/Model, ExposureTime (s);
- capture time: DateTimeOriginal + SubSecTimeOriginal (`capture_time_s`, seconds since 1970 in the camera's
  clock; only differences matter; the date written "YYYY:MM:DD", "YYYY-MM-DD" or "YYYY/MM/DD", a "T" or a space
  before the time), and where the image says how, the same instant in UTC (`capture_time_utc`): GPSDateStamp +
  GPSTimeStamp (UTC by definition) first, else DateTimeOriginal shifted by OffsetTimeOriginal / OffsetTime;
  `read_capture_time(path)` reads only these tags (headers, no pixels);
- XMP: every simple property of every rdf:Description of the x:xmpmeta packet(s) in the JPEG's APP1 segments
  (DJI `drone-dji:GimbalYawDegree`, `RelativeAltitude`..., senseFly `Heading`/`PitchAngle`/`RollAngle`...), keyed
  by local name.
No exiftool: the XMP packet is found by scanning the APP1 segments and parsed with xml.etree.

Damaged metadata never stops a flight: an EXIF block Pillow reports as corrupt, an XMP packet that is not
well-formed XML or a value out of range (a latitude beyond 90 degrees) is left out and named in
`ImageMetadata.problems`, which the pose workflows summarise in one warning.

`database.exif_write.embed_metadata(jpeg_bytes, meta)` is the writer (the synthetic world geotags its JPEGs with
it); `check_metadata` is the one validation of positions and focal lengths, used by both directions.
"""

from __future__ import annotations

import calendar
import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from PIL import Image, UnidentifiedImageError

from ..plugin.errors import InputError

GPS_IFD = 0x8825
EXIF_IFD = 0x8769
# EXIF tag ids (TIFF/EXIF 2.3).
TAG_MAKE, TAG_MODEL = 0x010F, 0x0110
TAG_ORIENTATION = 0x0112
# What a viewer does to the stored pixels for each EXIF Orientation (1: nothing). sosmatch, like COLMAP, does none
# of it: poses, cameras and tie points refer to the pixel grid as stored.
ORIENTATION_SHOWN = {2: "mirrored left to right", 3: "turned 180 deg", 4: "mirrored top to bottom",
                     5: "mirrored and turned 90 deg", 6: "turned 90 deg clockwise", 7: "mirrored and turned 90 deg",
                     8: "turned 90 deg counter-clockwise"}
TAG_FOCAL_LENGTH = 0x920A
TAG_FOCAL_35MM = 0xA405
TAG_DIGITAL_ZOOM = 0xA404
TAG_EXPOSURE_TIME = 0x829A
TAG_FP_XRES, TAG_FP_YRES, TAG_FP_UNIT = 0xA20E, 0xA20F, 0xA210
TAG_EXIF_WIDTH, TAG_EXIF_HEIGHT = 0xA002, 0xA003
TAG_DATETIME_ORIGINAL = 0x9003
TAG_SUBSEC_ORIGINAL = 0x9291
TAG_OFFSET_TIME, TAG_OFFSET_TIME_ORIGINAL = 0x9010, 0x9011
GPS_TIMESTAMP, GPS_DATESTAMP = 0x07, 0x1D
GPS_LAT_REF, GPS_LAT, GPS_LON_REF, GPS_LON, GPS_ALT_REF, GPS_ALT = 1, 2, 3, 4, 5, 6
GPS_TRACK = 0x0F
XMP_APP1_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
EXIF_APP1_HEADER = b"Exif\x00\x00"
RDF_NS = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # FocalPlaneResolutionUnit: inch, cm, mm, um
DJI_XMP_NAMESPACE = ("drone-dji", "http://www.dji.com/drone-dji/1.0/")
EXIF_DATETIME_FORMAT = "%Y:%m:%d %H:%M:%S"
# EXIF's "YYYY:MM:DD HH:MM:SS" and the variants software writes into it (dashes or slashes in the date, a "T",
# fractional seconds, an ISO zone suffix): nu41, a dashed date left a flight untimed without a word
_DATETIME_RE = re.compile(r"^(\d{4})[:\-/.](\d{1,2})[:\-/.](\d{1,2})[ T]+(\d{1,2}):(\d{2})(?::(\d{2})(\.\d+)?)?"
                          r"\s*(Z|[+-]\d{2}:?\d{2})?$")
_OFFSET_RE = re.compile(r"^([+-])(\d{2}):?(\d{2})$")


def parse_exif_datetime(text: str) -> tuple[float, float | None] | None:
    """(seconds since 1970 of the wall-clock time written, the zone offset in seconds east of UTC when the text
    ends with one, else None) of an EXIF date-time in any of the common variants, or None when it is not one
    (blank, "0000:00:00 00:00:00", a month 13)."""
    m = _DATETIME_RE.match(text.strip())
    if m is None:
        return None
    year, month, day, hour, minute = (int(v) for v in m.group(1, 2, 3, 4, 5))
    second = int(m.group(6) or 0)
    if not (year >= 1 and 1 <= month <= 12 and 1 <= day <= calendar.monthrange(year, month)[1] and hour < 24
            and minute < 60 and second <= 60):
        return None
    seconds = float(calendar.timegm((year, month, day, hour, minute, second, 0, 0, 0))) + float(m.group(7) or 0.0)
    zone = m.group(8)
    return seconds, (0.0 if zone == "Z" else parse_exif_offset(zone)) if zone else None


def parse_exif_offset(text: str) -> float | None:
    """An EXIF OffsetTime* value ("+09:00", "-05:30", "+0530") as seconds east of UTC, or None (blank "   :  ",
    beyond +-14 h)."""
    m = _OFFSET_RE.match(text.strip())
    if m is None or int(m.group(3)) >= 60:
        return None
    seconds = (int(m.group(2)) * 3600 + int(m.group(3)) * 60) * (-1 if m.group(1) == "-" else 1)
    return float(seconds) if abs(seconds) <= 14 * 3600 else None


@dataclass
class ImageMetadata:
    """What one image's EXIF/XMP says. Missing values are None; `sources` names the tag behind each value."""

    path: Path
    width: int
    height: int
    latitude: float | None = None
    longitude: float | None = None
    altitude: float | None = None
    gps_track_deg: float | None = None
    focal_mm: float | None = None
    focal_35mm: float | None = None
    focal_plane_px_per_mm: tuple[float, float] | None = None  # (x, y) from FocalPlaneX/YResolution and unit
    exif_size: tuple[int, int] | None = None  # the size FocalPlane*Resolution refers to
    digital_zoom: float | None = None  # EXIF DigitalZoomRatio > 1: the readout's middle scaled up by it
    exposure_s: float | None = None  # EXIF ExposureTime (s): how long the ground moved across the sensor
    make: str = ""
    model: str = ""
    datetime_original: str = ""  # EXIF "YYYY:MM:DD HH:MM:SS"
    subsec_original: str = ""  # EXIF SubSecTimeOriginal: the digits of the fraction of a second
    offset_time: str = ""  # EXIF OffsetTimeOriginal (else OffsetTime): the camera clock's zone, "+09:00"
    orientation: int | None = None  # EXIF Orientation 1-8 (`ORIENTATION_SHOWN`); not applied to the pixels
    gps_time_utc_s: float | None = None  # EXIF GPSDateStamp + GPSTimeStamp: the receiver's UTC (seconds since 1970)
    xmp: dict[str, str] = field(default_factory=dict)
    xmp_position: tuple[float, float] | None = None  # DJI XMP's (lat, lon) where EXIF GPS's position was taken
    sources: dict[str, str] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)  # damaged or implausible metadata that was left out

    @property
    def has_gps(self) -> bool:
        return self.latitude is not None and self.longitude is not None

    @property
    def capture_time_s(self) -> float | None:
        """DateTimeOriginal (+ SubSecTimeOriginal) as seconds since 1970 of the camera's clock, or None."""
        parsed = parse_exif_datetime(self.datetime_original)
        if parsed is None:
            return None
        digits = self.subsec_original.strip()
        return parsed[0] + (float("0." + digits) if digits.isdigit() and parsed[0] % 1 == 0 else 0.0)

    @property
    def capture_offset_s(self) -> float | None:
        """The camera clock's zone in seconds east of UTC, as DateTimeOriginal's own suffix or OffsetTimeOriginal
        (else OffsetTime) says it, or None."""
        parsed = parse_exif_datetime(self.datetime_original)
        if parsed is not None and parsed[1] is not None:
            return parsed[1]
        return parse_exif_offset(self.offset_time)

    @property
    def capture_time_utc(self) -> tuple[float, str] | None:
        """(the capture time in UTC, seconds since 1970; the tags it comes from), or None when the image does not
        say its zone: GPSDateStamp + GPSTimeStamp first (UTC by definition, and a camera's own clock is often set
        by hand), else DateTimeOriginal shifted by its zone (`capture_offset_s`)."""
        if self.gps_time_utc_s is not None:
            return self.gps_time_utc_s, "GPSDateStamp/GPSTimeStamp"
        local, offset = self.capture_time_s, self.capture_offset_s
        return (local - offset, "DateTimeOriginal + its zone") if local is not None and offset is not None else None

    @property
    def camera_key(self) -> tuple[str, str, int, int, float]:
        """What makes images share one camera: make, model, image size and digital zoom (1 without);
        `workflows.image_cameras.camera_groups` splits the images of one key further by focal length (a zoom)."""
        return (self.make, self.model, self.width, self.height, self.digital_zoom or 1.0)

    def xmp_float(self, *names: str) -> tuple[float, str] | None:
        """The first XMP property among `names` (local names) that parses as a finite float, with its name."""
        for name in names:
            value = self.xmp.get(name)
            if value is None:
                continue
            try:
                number = float(value.strip())
            except ValueError:
                continue
            if math.isfinite(number):
                return number, name
        return None


def _float(value: object) -> float | None:
    try:
        number = float(value)  # IFDRational, int, float
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) else None


_DMS_PARTS = ("degrees", "minutes", "seconds")


def _dms(value: object, tag: str = "GPS coordinate") -> tuple[float | None, str | None]:
    """EXIF GPSLatitude/GPSLongitude (degrees, minutes, seconds: 3 rationals) -> (decimal degrees, None); (None,
    None) when it holds no value (absent, or every part x/0: what a device with its GPS switched off writes, as
    others write 0, 0: no fix); (None, the problem naming `tag` and its parts) when some parts are x/0 beside
    others with a value (seconds 0/0 beside degrees and decimal minutes: exiftool drops such a coordinate too).
    Pillow reads a rational x/0 as NaN, which was reported as a position "nan ... off the globe" (rev38)."""
    try:
        raw = list(value)  # type: ignore[call-overload]
        parts = [float(v) for v in raw]
    except (TypeError, ValueError, ZeroDivisionError):
        return _float(value), None
    if len(parts) != 3:
        return None, None
    empty = [f"{name} {getattr(v, 'numerator', 0)}/0" for name, v, f in zip(_DMS_PARTS, raw, parts) if math.isnan(f)]
    if len(empty) == 3:
        return None, None
    if empty:
        return None, f"{tag} {' and '.join(empty)}"
    d, m, s = parts
    return d + m / 60.0 + s / 3600.0, None


def _text(value: object) -> str:
    if isinstance(value, bytes):
        value = value.decode("latin-1", "replace")
    return str(value).strip().strip("\x00").strip() if value is not None else ""


def xmp_packets(data: bytes) -> list[bytes]:
    """The XMP packets in a JPEG byte string: payloads of APP1 segments that start with the XMP namespace."""
    if data[:2] != b"\xff\xd8":
        start = data.find(b"<x:xmpmeta")  # not a JPEG: a bare scan still finds an embedded packet
        end = data.find(b"</x:xmpmeta>", start)
        return [data[start:end + 12]] if start >= 0 and end > start else []
    return app1_payloads(data, XMP_APP1_HEADER)


def app1_payloads(data: bytes, header: bytes) -> list[bytes]:
    """The payloads (after `header`) of a JPEG's APP1 segments that start with `header` (metadata segments come
    before the first scan)."""
    packets: list[bytes] = []
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan: no more metadata segments
            break
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 2
            continue
        length = int.from_bytes(data[i + 2:i + 4], "big")
        payload = data[i + 4:i + 2 + length]
        if marker == 0xE1 and payload.startswith(header):
            packets.append(payload[len(header):])
        i += 2 + length
    return packets


def parse_xmp(packet: bytes) -> dict[str, str]:
    """Simple XMP properties (attributes and leaf elements of rdf:Description) keyed by local name.

    A packet without an x:xmpmeta element gives {}; one that is not well-formed XML raises ValueError."""
    start = packet.find(b"<x:xmpmeta")
    end = packet.rfind(b"</x:xmpmeta>")
    if start < 0 or end < 0:
        return {}
    try:
        root = ET.fromstring(packet[start:end + len(b"</x:xmpmeta>")])
    except ET.ParseError as exc:
        raise ValueError(f"XMP packet is not well-formed XML ({exc})") from None
    out: dict[str, str] = {}
    for desc in root.iter(f"{{{RDF_NS}}}Description"):
        for key, value in desc.attrib.items():
            local = key.rsplit("}", 1)[-1]
            if not key.startswith(f"{{{RDF_NS}}}"):
                out.setdefault(local, value)
        for child in desc:
            if len(child) == 0 and child.text is not None and child.text.strip():
                out.setdefault(child.tag.rsplit("}", 1)[-1], child.text.strip())
    return out


# XMP attitude tags (degrees) the pose workflows read (`workflows.image_priors`: DJI gimbal and airframe, Parrot
# camera, senseFly): a value beyond one turn is a damaged tag, not an angle (a yaw of 1e308 would otherwise be taken
# as a heading; rev38: Parrot's were missing, so theirs was)
XMP_ANGLE_TAGS = ("GimbalYawDegree", "GimbalPitchDegree", "GimbalRollDegree", "CameraYawDegree", "CameraPitchDegree",
                  "CameraRollDegree", "FlightYawDegree", "FlightPitchDegree", "FlightRollDegree", "Heading",
                  "PitchAngle", "RollAngle")


# DJI's (and Parrot's) camera pitch: -90 straight down, 0 at the horizon, positive above it. A survey camera looks
# down; a few degrees above the horizon is gimbal play on a level shot, beyond this the picture is mostly sky, which
# no survey takes: a damaged or sign-flipped tag (nu59: +87.9 was taken as the attitude without a word)
UP_PITCH_MAX_DEG = 10.0
UP_PITCH_TAGS = ("GimbalPitchDegree", "CameraPitchDegree")


def _bad_angle(value: object) -> bool:
    """A tag value that is no angle: not a number, not finite, or beyond one turn."""
    try:
        number = float(str(value).strip())
    except ValueError:
        return True  # "abc": the reader left it out silently before nu59 (the image fell back to other tags)
    return not (math.isfinite(number) and abs(number) <= 360.0)


def xmp_angle_problem(name: str, value: str) -> str | None:
    """What is wrong with the XMP attitude tag `name` = `value` (None if nothing): the one test the reader drops
    a tag by and the writer refuses one by, so every dropped angle is named the same way."""
    if _bad_angle(value):
        return f"XMP {name} {str(value).strip()} is not an angle"
    if name in UP_PITCH_TAGS and float(value) > UP_PITCH_MAX_DEG:
        return (f"XMP {name} {float(value):+g} puts the camera above the horizon (-90 looks straight down), "
                "implausible for a survey")
    return None


def _position_problem(lat: float, lon: float) -> str | None:
    """What is wrong with a GPS position (off the globe, or 0, 0: a receiver without a fix), else None: the one
    test for an EXIF position (`check_metadata`) and an XMP one (`_position_from_xmp`)."""
    if not (abs(lat) <= 90 and abs(lon) <= 180):
        return f"GPS position {lat:.6f}, {lon:.6f} is off the globe"
    if lat == 0 and lon == 0:
        return "GPS position 0, 0 (receiver without a fix)"
    return None


def check_metadata(meta: ImageMetadata) -> list[str]:
    """The problems of `meta`'s values (empty if none): a position off the globe or (0, 0) (a receiver without a
    fix), a non-finite altitude, a non-positive focal length, a GPS track or an XMP attitude angle beyond one
    turn. The reader drops such values, the writer refuses."""
    problems = []
    if (meta.latitude is None) != (meta.longitude is None):
        problems.append("GPS latitude without longitude (or the reverse)")
    elif meta.latitude is not None and meta.longitude is not None and (
            position := _position_problem(meta.latitude, meta.longitude)) is not None:
        problems.append(position)
    if meta.altitude is not None and not math.isfinite(meta.altitude):
        problems.append("GPS altitude is not a number")
    for name in ("focal_mm", "focal_35mm"):
        value = getattr(meta, name)
        if value is not None and not value > 0:
            problems.append(f"{name} {value} is not positive")
    if meta.gps_track_deg is not None and _bad_angle(meta.gps_track_deg):
        problems.append(f"GPS track {meta.gps_track_deg} is not an angle")
    problems += [p for name in XMP_ANGLE_TAGS if name in meta.xmp
                 and (p := xmp_angle_problem(name, meta.xmp[name])) is not None]
    return problems


def _gps_time(gps: dict) -> float | None:
    """GPSDateStamp ("YYYY:MM:DD") + GPSTimeStamp (hours, minutes, seconds as rationals) in seconds since 1970
    (UTC), or None when either is missing or not a time."""
    parsed = parse_exif_datetime(_text(gps.get(GPS_DATESTAMP)) + " 00:00:00")
    try:
        h, m, s = (float(v) for v in gps.get(GPS_TIMESTAMP))  # type: ignore[union-attr]
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    if parsed is None or not (0 <= h < 24 and 0 <= m < 60 and 0 <= s < 61):
        return None
    return parsed[0] + h * 3600.0 + m * 60.0 + s


def _read_times(meta: ImageMetadata, sub: dict, gps: dict) -> None:
    meta.datetime_original = _text(sub.get(TAG_DATETIME_ORIGINAL))
    meta.subsec_original = _text(sub.get(TAG_SUBSEC_ORIGINAL))
    meta.offset_time = _text(sub.get(TAG_OFFSET_TIME_ORIGINAL)) or _text(sub.get(TAG_OFFSET_TIME))
    meta.gps_time_utc_s = _gps_time(gps)


def read_capture_time(path: str | Path) -> ImageMetadata:
    """Only the capture-time tags of one image (DateTimeOriginal, SubSecTimeOriginal, OffsetTime*, GPS date and
    time), from its header: no pixels, no XMP scan of the file. Unreadable images raise InputError."""
    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a damaged EXIF block gives no time: the caller says so
            with Image.open(path) as img:
                width, height = img.size
                exif = img.getexif()
                gps, sub = exif.get_ifd(GPS_IFD), exif.get_ifd(EXIF_IFD)
    except FileNotFoundError:
        raise InputError("image not found", path) from None
    except Exception as exc:  # noqa: BLE001 (Pillow raises assorted errors on a damaged file or EXIF block)
        raise InputError(f"cannot read image: {exc}", path) from None
    meta = ImageMetadata(path=path, width=int(width), height=int(height))
    _read_times(meta, sub, gps)
    return meta


def _orientation(value: object) -> int | None:
    """An EXIF Orientation value (1-8), None when missing or not one of them."""
    return value if isinstance(value, int) and 1 <= value <= 8 else None


def read_orientation(path: str | Path) -> int | None:
    """The EXIF Orientation of one image from its header (None: none, or not readable)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                return _orientation(img.getexif().get(TAG_ORIENTATION))
    except Exception:  # noqa: BLE001 (a header PIL cannot read carries no tag to name; the readers name the file)
        return None


def orientation_note(orientations: list[int | None]) -> str | None:
    """A sentence for a message about images whose poses contradict them, when some carry an EXIF Orientation
    that turns or mirrors them (not 1): which and how many, and that sosmatch does not apply it (pixels stored
    turned from the camera's readout make its attitude tags describe other pixels: nu53, frames stored turned
    180 deg with Orientation 3 refused as a 64 m drift and a 61 deg tilt, the tag unnamed). None without any."""
    odd = [v for v in orientations if v is not None and v != 1]
    if not odd:
        return None
    tags = ", ".join(f"{v} ({ORIENTATION_SHOWN[v]} by viewers{'' if len(set(odd)) == 1 else f', {odd.count(v)}'})"
                     for v in sorted(set(odd)))
    return (f"{len(odd)} of {len(orientations)} images carry EXIF Orientation {tags}, which sosmatch does not "
            "apply: pixels stored turned from the camera's view contradict their tags and poses")


# DJI's position tags in its XMP (signed decimal degrees; some firmware spells the longitude "GpsLongtitude") and
# its altitude (the receiver's, as EXIF GPSAltitude): an image whose EXIF GPS was stripped by an editor or an
# uploader still carries them, and a flight read without them was put in a local frame although every image says
# where it was (nu58 D3)
XMP_POSITION_TAGS = (("GpsLatitude",), ("GpsLongitude", "GpsLongtitude"))
XMP_ALTITUDE_TAG = "AbsoluteAltitude"
XMP_POSITION_SOURCE = "XMP drone-dji:GpsLatitude/GpsLongitude"


def _position_from_xmp(meta: ImageMetadata) -> None:
    """Take DJI's XMP position (and AbsoluteAltitude) where EXIF gives none; where both give one, keep EXIF's and
    keep the XMP's in `xmp_position` (the two should be one fix: `workflows.image_priors` says where they part)."""
    lat, lon = meta.xmp_float(*XMP_POSITION_TAGS[0]), meta.xmp_float(*XMP_POSITION_TAGS[1])
    if lat is None or lon is None:
        return
    if meta.latitude is None or meta.longitude is None:
        meta.latitude, meta.longitude = lat[0], lon[0]
        meta.sources["position"] = XMP_POSITION_SOURCE
        if meta.altitude is None and (alt := meta.xmp_float(XMP_ALTITUDE_TAG)) is not None:
            meta.altitude = alt[0]
            meta.sources["altitude"] = f"XMP drone-dji:{XMP_ALTITUDE_TAG}"
    elif _position_problem(lat[0], lon[0]) is None:
        meta.xmp_position = (lat[0], lon[0])


def read_image_metadata(path: str | Path) -> ImageMetadata:
    """Read GPS, camera and XMP metadata of one image (no pixel decoding). Unreadable images raise InputError;
    damaged metadata is left out and listed in `problems` (see the module doc)."""
    path = Path(path)
    problems: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with Image.open(path) as img:
                width, height = img.size
                exif = img.getexif()
                gps = exif.get_ifd(GPS_IFD)
                sub = exif.get_ifd(EXIF_IFD)
        problems += [f"EXIF: {w.message}" for w in caught if "EXIF" in str(w.message) or "exif" in str(w.message)]
    except FileNotFoundError:
        raise InputError("image not found", path) from None
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"cannot read image: {exc}", path) from None
    except Exception as exc:  # noqa: BLE001 (Pillow raises assorted errors on a damaged EXIF block)
        raise InputError(f"cannot read image metadata: {exc}", path) from None
    meta = ImageMetadata(path=path, width=int(width), height=int(height))
    meta.make, meta.model = _text(exif.get(TAG_MAKE)), _text(exif.get(TAG_MODEL))
    meta.orientation = _orientation(exif.get(TAG_ORIENTATION))
    _read_times(meta, sub, gps)

    (lat, lat_problem), (lon, lon_problem) = _dms(gps.get(GPS_LAT), "GPSLatitude"), _dms(gps.get(GPS_LON),
                                                                                          "GPSLongitude")
    if lat_problem or lon_problem:  # a coordinate without part of its value: the position is left out, said so
        problems.append(", ".join(p for p in (lat_problem, lon_problem) if p) + " (a rational without a value): "
                        "GPS position left out")
        lat = lon = None
    lat_ref, lon_ref = _text(gps.get(GPS_LAT_REF)).strip().upper()[:1], _text(gps.get(GPS_LON_REF)).strip().upper()[:1]
    if lat is not None and lon is not None and (lat_ref not in ("N", "S") or lon_ref not in ("E", "W")):
        # the hemisphere is part of the position (EXIF requires the refs): without it a flight in the south or
        # west would be placed mirrored on the other side of the globe without a word
        problems.append(f"GPS position without its hemisphere (GPSLatitudeRef {lat_ref or 'missing'}, "
                        f"GPSLongitudeRef {lon_ref or 'missing'}; N/S and E/W expected)")
    elif lat is not None and lon is not None:
        meta.latitude = -lat if lat_ref == "S" else lat
        meta.longitude = -lon if lon_ref == "W" else lon
        meta.sources["position"] = "EXIF GPSLatitude/GPSLongitude"
    alt = _float(gps.get(GPS_ALT))
    if alt is not None:
        ref = gps.get(GPS_ALT_REF)
        if (ref[0] if isinstance(ref, bytes) and ref else ref) == 1:
            alt = -alt
        meta.altitude = alt
        meta.sources["altitude"] = "EXIF GPSAltitude"
    meta.gps_track_deg = _float(gps.get(GPS_TRACK))

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read image: {exc.strerror}", path) from None
    if not exif and data[:2] == b"\xff\xd8" and any(len(p) > 8 for p in app1_payloads(data, EXIF_APP1_HEADER)):
        problems.append("EXIF: the EXIF segment is unreadable")
    for packet in xmp_packets(data):
        try:
            properties = parse_xmp(packet)
        except ValueError as exc:
            problems.append(str(exc))
            continue
        for key, value in properties.items():
            meta.xmp.setdefault(key, value)
    _position_from_xmp(meta)

    meta.focal_mm = _float(sub.get(TAG_FOCAL_LENGTH))
    meta.focal_35mm = _float(sub.get(TAG_FOCAL_35MM))
    for problem in check_metadata(meta):
        if problem.startswith("GPS position") or problem.startswith("GPS latitude"):
            if "without a fix" not in problem:
                problems.append(problem)
            meta.latitude = meta.longitude = None
            meta.sources.pop("position", None)
        elif problem.startswith("GPS altitude"):
            problems.append(problem)
            meta.altitude = None
            meta.sources.pop("altitude", None)
        elif problem.startswith("GPS track"):
            problems.append(problem)
            meta.gps_track_deg = None
        else:  # a focal length that is not positive
            problems.append(problem)
            meta.focal_mm = meta.focal_mm if meta.focal_mm and meta.focal_mm > 0 else None
            meta.focal_35mm = meta.focal_35mm if meta.focal_35mm and meta.focal_35mm > 0 else None
    zoom = _float(sub.get(TAG_DIGITAL_ZOOM))  # 0: no digital zoom (EXIF), and only a ratio above 1 zooms
    meta.digital_zoom = zoom if zoom is not None and math.isfinite(zoom) and 1.0 < zoom <= 100.0 else None
    exposure = _float(sub.get(TAG_EXPOSURE_TIME))  # (1 min: longer is no survey frame)
    meta.exposure_s = exposure if exposure is not None and math.isfinite(exposure) and 0 < exposure <= 60 else None
    xres, yres = _float(sub.get(TAG_FP_XRES)), _float(sub.get(TAG_FP_YRES))
    unit = sub.get(TAG_FP_UNIT, 2)  # EXIF default unit: inch
    if xres and xres > 0 and unit in MM_PER_UNIT:
        yres = yres if yres and yres > 0 else xres
        meta.focal_plane_px_per_mm = (xres / MM_PER_UNIT[unit], yres / MM_PER_UNIT[unit])
    ew, eh = sub.get(TAG_EXIF_WIDTH), sub.get(TAG_EXIF_HEIGHT)
    if isinstance(ew, int) and isinstance(eh, int) and ew > 0 and eh > 0:
        meta.exif_size = (ew, eh)

    for name in XMP_ANGLE_TAGS:  # a damaged attitude tag is left out (the image falls back to the other sources)
        if name in meta.xmp and (problem := xmp_angle_problem(name, meta.xmp[name])) is not None:
            problems.append(problem)
            del meta.xmp[name]
    meta.problems = problems
    return meta
