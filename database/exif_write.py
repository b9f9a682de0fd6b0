"""Image metadata written into JPEGs (the synthetic world geotags its images with it): EXIF GPS, focal lengths,
make/model and capture time, and XMP properties as attributes of one rdf:Description in the DJI namespace.
`embed_metadata(jpeg_bytes, meta)` validates with `exif.check_metadata`, the reader's one validation, and writes
what `exif.read_image_metadata` reads back."""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from .exif import (
    DJI_XMP_NAMESPACE,
    EXIF_APP1_HEADER,
    EXIF_IFD,
    GPS_ALT,
    GPS_ALT_REF,
    GPS_IFD,
    GPS_LAT,
    GPS_LAT_REF,
    GPS_LON,
    GPS_LON_REF,
    GPS_TRACK,
    TAG_DATETIME_ORIGINAL,
    TAG_EXIF_HEIGHT,
    TAG_EXIF_WIDTH,
    TAG_FOCAL_35MM,
    TAG_FOCAL_LENGTH,
    TAG_FP_UNIT,
    TAG_FP_XRES,
    TAG_FP_YRES,
    TAG_MAKE,
    TAG_MODEL,
    TAG_OFFSET_TIME_ORIGINAL,
    TAG_SUBSEC_ORIGINAL,
    XMP_APP1_HEADER,
    ImageMetadata,
    check_metadata,
)


def _rational(value: float, denominator: int) -> IFDRational:
    return IFDRational(int(round(value * denominator)), denominator)


def _dms_rationals(degrees: float) -> tuple[IFDRational, IFDRational, IFDRational]:
    """Decimal degrees (unsigned) as EXIF degrees, minutes and seconds (1e-6 arc-second resolution: ~3e-8 m)."""
    degrees = abs(degrees)
    d = int(degrees)
    m = int((degrees - d) * 60.0)
    s = (degrees - d - m / 60.0) * 3600.0
    return IFDRational(d, 1), IFDRational(m, 1), _rational(s, 1_000_000)


def encode_exif(meta: ImageMetadata) -> bytes:
    """The EXIF block (TIFF bytes, as Pillow's `exif=` takes them) of `meta`'s GPS, focal lengths, make/model,
    capture time and focal-plane resolution. ValueError when `check_metadata` finds a problem."""
    problems = check_metadata(meta)
    if problems:
        raise ValueError("; ".join(problems))
    exif = Image.Exif()
    if meta.make:
        exif[TAG_MAKE] = meta.make
    if meta.model:
        exif[TAG_MODEL] = meta.model
    sub = exif.get_ifd(EXIF_IFD)
    if meta.datetime_original:
        sub[TAG_DATETIME_ORIGINAL] = meta.datetime_original
    if meta.offset_time:
        sub[TAG_OFFSET_TIME_ORIGINAL] = meta.offset_time
    if meta.subsec_original:
        sub[TAG_SUBSEC_ORIGINAL] = meta.subsec_original
    if meta.focal_mm is not None:
        sub[TAG_FOCAL_LENGTH] = _rational(meta.focal_mm, 1000)
    if meta.focal_35mm is not None:
        sub[TAG_FOCAL_35MM] = int(round(meta.focal_35mm))  # EXIF: a SHORT, whole millimetres
    if meta.focal_plane_px_per_mm is not None:
        sub[TAG_FP_XRES] = _rational(meta.focal_plane_px_per_mm[0], 1000)
        sub[TAG_FP_YRES] = _rational(meta.focal_plane_px_per_mm[1], 1000)
        sub[TAG_FP_UNIT] = 4  # millimetres
    if meta.exif_size is not None:
        sub[TAG_EXIF_WIDTH], sub[TAG_EXIF_HEIGHT] = (int(v) for v in meta.exif_size)
    if meta.latitude is not None and meta.longitude is not None:
        gps = exif.get_ifd(GPS_IFD)
        gps[0] = b"\x02\x03\x00\x00"  # GPSVersionID 2.3
        gps[GPS_LAT_REF] = "N" if meta.latitude >= 0 else "S"
        gps[GPS_LAT] = _dms_rationals(meta.latitude)
        gps[GPS_LON_REF] = "E" if meta.longitude >= 0 else "W"
        gps[GPS_LON] = _dms_rationals(meta.longitude)
        if meta.altitude is not None:
            gps[GPS_ALT_REF] = b"\x01" if meta.altitude < 0 else b"\x00"
            gps[GPS_ALT] = _rational(abs(meta.altitude), 1000)
        if meta.gps_track_deg is not None:
            gps[GPS_TRACK] = _rational(meta.gps_track_deg % 360.0, 100)
    tiff = exif.tobytes()
    # Pillow (>= 8) puts the APP1 identifier in front of the TIFF bytes; the segment writer adds its own, and
    # two of them made "Exif\0\0Exif\0\0MM..." that Pillow tolerates but exiftool and COLMAP do not (nu35)
    return tiff[len(EXIF_APP1_HEADER):] if tiff.startswith(EXIF_APP1_HEADER) else tiff


def encode_xmp(properties: dict[str, str], namespace: tuple[str, str] = DJI_XMP_NAMESPACE) -> bytes:
    """An XMP packet with `properties` (local name -> text) as attributes of one rdf:Description in `namespace`
    (prefix, URI), the way DJI writes `drone-dji:GimbalYawDegree="+12.30"`."""
    prefix, uri = namespace
    attrs = "".join(f"\n   {prefix}:{k}={quoteattr(str(v))}" for k, v in properties.items())
    return ("<?xpacket begin='\ufeff' id='W5M0MpCehiHzreSzNTczkc9d'?>\n"
            "<x:xmpmeta xmlns:x='adobe:ns:meta/'>\n <rdf:RDF xmlns:rdf='http://www.w3.org/1999/02/22-rdf-syntax-ns#'>\n"
            f"  <rdf:Description rdf:about='' xmlns:{prefix}='{uri}'{attrs}/>\n"
            " </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end='w'?>").encode()


def _app1(payload: bytes) -> bytes:
    if len(payload) + 2 > 0xFFFF:
        raise ValueError(f"metadata segment of {len(payload)} bytes does not fit one JPEG APP1 segment")
    return b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload


def embed_metadata(jpeg: bytes, meta: ImageMetadata) -> bytes:
    """`jpeg` with `meta` written into it: an EXIF APP1 segment (`encode_exif`) and, when `meta.xmp` has
    properties, an XMP APP1 segment (`encode_xmp`), both right after the start-of-image marker (any metadata
    segments already there follow them, and readers take the first). The pixels are untouched."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG byte string")
    segments = _app1(EXIF_APP1_HEADER + encode_exif(meta))
    if meta.xmp:
        segments += _app1(XMP_APP1_HEADER + encode_xmp(meta.xmp))
    return jpeg[:2] + segments + jpeg[2:]

