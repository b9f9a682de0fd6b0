"""Image metadata for poses and intrinsics: EXIF GPS, focal length and XMP attitude tags (Pillow only).

`read_image_metadata(path)` returns an `ImageMetadata` with what a survey image says about itself:
- GPS (EXIF GPS IFD 0x8825): latitude/longitude in degrees (signed by their N/S/E/W refs), altitude in metres
  (GPSAltitude, negative when GPSAltitudeRef is 1), GPSTrack (course over ground, degrees from north) if present;
- camera (EXIF IFD 0x8769): FocalLength (mm), FocalPlaneX/YResolution with their unit (pixels per inch or cm),
  the image size those refer to (ExifImageWidth/Height: the sensor readout, often larger than the file when
  images were downscaled after capture), Make/Model;
- XMP: every simple property of every rdf:Description of the x:xmpmeta packet(s) in the JPEG's APP1 segments
  (DJI `drone-dji:GimbalYawDegree`..., senseFly `Heading`/`PitchAngle`/`RollAngle`...), keyed by local name.
No exiftool: the XMP packet is found by scanning the APP1 segments and parsed with xml.etree.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from PIL import Image, UnidentifiedImageError

from ..plugin.errors import InputError

GPS_IFD = 0x8825
EXIF_IFD = 0x8769
# EXIF tag ids (TIFF/EXIF 2.3).
TAG_MAKE, TAG_MODEL = 0x010F, 0x0110
TAG_FOCAL_LENGTH = 0x920A
TAG_FOCAL_35MM = 0xA405
TAG_FP_XRES, TAG_FP_YRES, TAG_FP_UNIT = 0xA20E, 0xA20F, 0xA210
TAG_EXIF_WIDTH, TAG_EXIF_HEIGHT = 0xA002, 0xA003
TAG_DATETIME_ORIGINAL = 0x9003
GPS_LAT_REF, GPS_LAT, GPS_LON_REF, GPS_LON, GPS_ALT_REF, GPS_ALT = 1, 2, 3, 4, 5, 6
GPS_TRACK = 0x0F
XMP_APP1_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
RDF_NS = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # FocalPlaneResolutionUnit: inch, cm, mm, um


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
    make: str = ""
    model: str = ""
    datetime_original: str = ""
    xmp: dict[str, str] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def has_gps(self) -> bool:
        return self.latitude is not None and self.longitude is not None

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


def _dms(value: object) -> float | None:
    """EXIF degrees/minutes/seconds (3 rationals) -> decimal degrees."""
    try:
        d, m, s = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError, ZeroDivisionError):
        return _float(value)
    return d + m / 60.0 + s / 3600.0


def _text(value: object) -> str:
    if isinstance(value, bytes):
        value = value.decode("latin-1", "replace")
    return str(value).strip().strip("\x00").strip() if value is not None else ""


def xmp_packets(data: bytes) -> list[bytes]:
    """The XMP packets in a JPEG byte string: payloads of APP1 segments that start with the XMP namespace."""
    packets: list[bytes] = []
    if data[:2] != b"\xff\xd8":
        start = data.find(b"<x:xmpmeta")  # not a JPEG: a bare scan still finds an embedded packet
        end = data.find(b"</x:xmpmeta>", start)
        return [data[start:end + 12]] if start >= 0 and end > start else []
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
        if marker == 0xE1 and payload.startswith(XMP_APP1_HEADER):
            packets.append(payload[len(XMP_APP1_HEADER):])
        i += 2 + length
    return packets


def parse_xmp(packet: bytes) -> dict[str, str]:
    """Simple XMP properties (attributes and leaf elements of rdf:Description) keyed by local name."""
    start = packet.find(b"<x:xmpmeta")
    end = packet.rfind(b"</x:xmpmeta>")
    if start < 0 or end < 0:
        return {}
    try:
        root = ET.fromstring(packet[start:end + len(b"</x:xmpmeta>")])
    except ET.ParseError:
        return {}
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


def read_image_metadata(path: str | Path) -> ImageMetadata:
    """Read GPS, camera and XMP metadata of one image (no pixel decoding). Unreadable images raise InputError."""
    path = Path(path)
    try:
        with Image.open(path) as img:
            width, height = img.size
            exif = img.getexif()
            gps = exif.get_ifd(GPS_IFD)
            sub = exif.get_ifd(EXIF_IFD)
    except FileNotFoundError:
        raise InputError("image not found", path) from None
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"cannot read image: {exc}", path) from None
    meta = ImageMetadata(path=path, width=int(width), height=int(height))
    meta.make, meta.model = _text(exif.get(TAG_MAKE)), _text(exif.get(TAG_MODEL))
    meta.datetime_original = _text(sub.get(TAG_DATETIME_ORIGINAL))

    lat, lon = _dms(gps.get(GPS_LAT)), _dms(gps.get(GPS_LON))
    if lat is not None and lon is not None:
        if _text(gps.get(GPS_LAT_REF)).upper().startswith("S"):
            lat = -lat
        if _text(gps.get(GPS_LON_REF)).upper().startswith("W"):
            lon = -lon
        if abs(lat) <= 90 and abs(lon) <= 180 and not (lat == 0 and lon == 0):  # 0,0: receiver without a fix
            meta.latitude, meta.longitude = lat, lon
            meta.sources["position"] = "EXIF GPSLatitude/GPSLongitude"
    alt = _float(gps.get(GPS_ALT))
    if alt is not None:
        ref = gps.get(GPS_ALT_REF)
        if (ref[0] if isinstance(ref, bytes) and ref else ref) == 1:
            alt = -alt
        meta.altitude = alt
        meta.sources["altitude"] = "EXIF GPSAltitude"
    meta.gps_track_deg = _float(gps.get(GPS_TRACK))

    meta.focal_mm = _float(sub.get(TAG_FOCAL_LENGTH))
    meta.focal_35mm = _float(sub.get(TAG_FOCAL_35MM))
    xres, yres = _float(sub.get(TAG_FP_XRES)), _float(sub.get(TAG_FP_YRES))
    unit = sub.get(TAG_FP_UNIT, 2)  # EXIF default unit: inch
    if xres and xres > 0 and unit in MM_PER_UNIT:
        yres = yres if yres and yres > 0 else xres
        meta.focal_plane_px_per_mm = (xres / MM_PER_UNIT[unit], yres / MM_PER_UNIT[unit])
    ew, eh = sub.get(TAG_EXIF_WIDTH), sub.get(TAG_EXIF_HEIGHT)
    if isinstance(ew, int) and isinstance(eh, int) and ew > 0 and eh > 0:
        meta.exif_size = (ew, eh)

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read image: {exc.strerror}", path) from None
    for packet in xmp_packets(data):
        for key, value in parse_xmp(packet).items():
            meta.xmp.setdefault(key, value)
    return meta
