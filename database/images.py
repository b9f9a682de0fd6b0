"""Robust image reading: every image the pipeline touches comes in here as (H, W, 3) uint8 RGB.

Handled: 8-bit and 16-bit, gray, gray+alpha, RGB, RGBA, palette, CMYK, 32-bit float; the alpha channel is
dropped (survey frames carry none that matters). Missing, unreadable, truncated or corrupt files raise
`InputError` naming the file. EXIF orientation is deliberately NOT applied: COLMAP does not apply it either,
and the poses and intrinsics refer to the stored pixel grid.
"""

from __future__ import annotations

import unicodedata
import warnings
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..plugin.errors import InputError

# The largest frame read: 600 megapixels (1.8 GB as 8-bit RGB). Survey cameras reach 100-280 MP (Phase One
# iXM-100 102 MP, iXM-RS280F 280 MP); a file declaring more is refused before it is decoded, since a few kB of
# JPEG can declare gigapixels.
MAX_IMAGE_PIXELS = 600_000_000

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")


# Integer data of more than 8 bits is scaled from its sensor's white level, 2^b - 1 for the smallest of these bit
# depths that holds the data: 10-, 12- and 14-bit sensor data stored in 16 bits would otherwise be nearly black.
SENSOR_BITS = (10, 12, 14, 16)


def white_level(max_value: int) -> int:
    """The white level of integer data whose largest value is `max_value`: 2^b - 1 for the smallest b of
    SENSOR_BITS that holds it (32-bit data beyond 16 bits: its own maximum)."""
    for bits in SENSOR_BITS:
        if max_value < 2**bits:
            return 2**bits - 1
    return int(max_value)


@dataclass(frozen=True)
class Levels:
    """The black and white level an image of more than 8 bits is read between (to 0 and 255): one pair per
    flight (`flight_levels.flight_white_level`), so every frame gets the same mapping and a region the same grey
    in each."""

    # int for integer data; float for float data (degC), whose levels are fractions of a unit
    black: float
    white: float

    def __str__(self) -> str:
        # the keyframe cache key and log lines: a flight read from its own range is never mixed with one read
        # from its sensor's white level (a bare number, as before, for those)
        return f"{self.white}" if self.black == 0 else f"{self.black}-{self.white}"


def _levels(white: Levels | int | None, a: np.ndarray) -> tuple[float, float]:
    """(black, white) for `to_u8`: the flight's `Levels`, a bare white level (black 0), or the white level of
    the array's own maximum."""
    if isinstance(white, Levels):
        return white.black, white.white
    return 0, int(white) if white else white_level(int(a.max(initial=0)))


def to_rgb_u8(array: np.ndarray, white: Levels | int | None = None) -> np.ndarray:
    """Convert a decoded pixel array (H, W), (H, W, 1|2|3|4) of uint8/uint16/float to (H, W, 3) uint8 RGB.

    Channel order is taken as RGB(A). Values are scaled as `to_u8` does (`white`: the flight's white level).
    """
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[2] in (2, 4):  # drop alpha
        a = a[:, :, : a.shape[2] - 1]
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ValueError(f"unsupported pixel array shape {a.shape}")
    out = to_u8(a, white)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    return np.ascontiguousarray(out)


def to_u8(a: np.ndarray, white: Levels | int | None = None) -> np.ndarray:
    """Pixel values of any shape (uint8/uint16/wider integers/bool/float) as uint8 of the same shape.

    Integer data of more than 8 bits is scaled by `white`, what the flight's data are read between
    (`flight_levels.flight_white_level`): `Levels` (black to 0, white to 255) or a bare white level (to 255,
    black 0); without it, from the white level of the array's own maximum (`white_level`), which a dark frame of
    a 16-bit flight reads as 10- or 12-bit data (64 or 16 times brighter than its neighbours): the readers of a
    flight's images pass its levels. Signed 16-bit data and floats are read between `Levels` when given
    (`flight_levels.flight_white_level` gives them for data below zero or offset from it); else signed data from
    0 (values below it black) and floats as 0..1 when their maximum is <= 1, else as 0..255.
    """
    a = np.asarray(a)
    if a.dtype == np.uint8:
        return a
    if a.dtype.kind == "i" and a.dtype.itemsize == 2 and isinstance(white, Levels):
        # signed 16-bit between the flight's levels (deci-degC thermal TIFFs, below zero in winter): a table of
        # the 65536 values as for unsigned data, indexed from -32768
        black, level = white.black, white.white
        lut = np.clip(np.rint((np.arange(65536) - 32768 - black) * (255.0 / max(level - black, 1))), 0, 255)
        return lut.astype(np.uint8)[(a.astype(np.int32) + 32768)]
    if a.dtype.kind == "i" and a.dtype.itemsize == 2:  # signed 16-bit without the flight's levels: light from 0
        a = np.clip(a, 0, None).astype(np.uint16)
    if a.dtype.kind == "u" and a.dtype.itemsize == 2:  # any byte order (big-endian TIFF: >u2)
        black, level = _levels(white, a)
        # a table of the 65536 values: the uint8 result is written directly (a float copy of a 24 MP RGB frame
        # took 288 MB per temporary, review rev17)
        lut = np.clip(np.rint((np.arange(65536) - black) * (255.0 / max(level - black, 1))), 0, 255).astype(np.uint8)
        return lut[a.astype(np.uint16, copy=False)]
    if a.dtype.kind in "ui" and a.dtype.itemsize > 2:
        black, level = _levels(white, a)
        scaled = (a.astype(np.float64) - black) * (255.0 / max(level - black, 1))
        return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    if a.dtype == bool:
        return a.astype(np.uint8) * 255
    if np.issubdtype(a.dtype, np.floating) and isinstance(white, Levels):
        # float data between the flight's levels (degC thermal TIFFs); NaN (no data) reads black
        a = np.nan_to_num(a.astype(np.float64), nan=white.black, posinf=white.white, neginf=white.black)
        span = white.white - white.black
        return np.clip(np.rint((a - white.black) * (255.0 / (span if span > 0 else 1.0))), 0, 255).astype(np.uint8)
    if np.issubdtype(a.dtype, np.floating):
        a = np.nan_to_num(a.astype(np.float64))
        scale = 255.0 if a.max(initial=0) <= 1.0 else 1.0
        return np.clip(np.rint(a * scale), 0, 255).astype(np.uint8)
    raise ValueError(f"unsupported pixel type {a.dtype}")


def _pil_image() -> Any:
    """PIL's Image module with its decompression-bomb guard at this module's limit. PIL's own default (a warning
    from 89 MP, taken here as an error) refused a 102 MP Phase One iXM-100 survey frame as "corrupt"."""
    from PIL import Image

    Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS
    return Image


def _too_large(width: int, height: int) -> str | None:
    if width * height <= MAX_IMAGE_PIXELS:
        return None
    return (f"image is {width}x{height} ({width * height / 1e6:.0f} megapixels), more than the "
            f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels of the largest frame read")


def _check_pixels(path: Path) -> None:
    """InputError when the image's header declares more pixels than MAX_IMAGE_PIXELS (read from the header only:
    a small file can declare a huge image); formats PIL does not know are left to the decoder."""
    Image = _pil_image()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as img:
                problem = _too_large(*img.size)
    except Image.DecompressionBombError:
        problem = f"image has more than the {MAX_IMAGE_PIXELS / 1e6:.0f} megapixels of the largest frame read"
    except (OSError, SyntaxError, ValueError):
        return
    if problem:
        raise InputError(problem, path)


def _read_pil(path: Path) -> np.ndarray | None:
    """The pixels as PIL decodes them; None for colour images of more than 8 bits per sample, which PIL cuts to
    their high byte (12-bit data in a 16-bit RGB TIFF or PNG came out 16 times too dark): OpenCV keeps them."""
    Image = _pil_image()
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        with Image.open(path) as img:
            img.load()  # decodes everything now: truncated files raise here
            mode = img.mode
            if mode in ("RGB", "RGBA") and _bits_per_sample(img, path) > 8:
                return None
            if mode in ("P", "PA"):
                img = img.convert("RGBA" if "transparency" in img.info or mode == "PA" else "RGB")
            elif mode == "CMYK" or mode == "YCbCr" or mode == "LAB" or mode == "HSV":
                img = img.convert("RGB")
            elif mode == "1":
                img = img.convert("L")
            return np.asarray(img)


def _read_cv2(path: Path) -> np.ndarray | None:
    import cv2

    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        return None
    try:
        arr = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return None
    if arr is None:
        return None
    # OpenCV's channel order reversed by indexing, not cv2.cvtColor: that takes 8-, 16-bit and float32 data only
    # (nu53: a float64 RGB TIFF was a cv2 traceback in `segment`); any depth is converted later (`to_rgb_u8`)
    if arr.ndim == 3 and arr.shape[2] == 3:
        arr = np.ascontiguousarray(arr[..., ::-1])
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = np.ascontiguousarray(arr[..., [2, 1, 0, 3]])
    return arr


def read_image(path: str | Path, white: Levels | int | None = None) -> np.ndarray:
    """Read an image file as (H, W, 3) uint8 RGB; raise InputError naming the file if it cannot be read.
    `white`: the white level of the flight's integer data beyond 8 bits (`flight_levels.flight_white_level`;
    None: the image's own, `to_rgb_u8`)."""
    path = Path(path)
    arr = decode(path)
    try:
        out = to_rgb_u8(arr, white)
    except ValueError as exc:
        raise InputError(f"unsupported image: {exc}", path) from None
    if out.shape[0] == 0 or out.shape[1] == 0:
        raise InputError("empty image", path)
    return out


def header_bits(path: Path) -> int | None:
    """Bits per sample from the image's header, nothing decoded (None: PIL cannot read the header)."""
    Image = _pil_image()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                return _bits_per_sample(img, path)
    except Exception:  # any header PIL cannot read: decoded (or named) by the reader
        return None


def _bits_per_sample(img: Any, path: Path) -> int:
    """Bits per sample of an open PIL image: its mode's, or for TIFF and PNG the file's own (PIL opens 16-bit
    colour as mode RGB)."""
    if img.mode.startswith("I;16"):
        return 16
    if img.mode in ("I", "F"):
        return 32
    if img.format == "TIFF":
        bits = img.tag_v2.get(258, (8,))
        return int(max(bits if isinstance(bits, tuple) else (bits,)))
    if img.format == "PNG":
        with open(path, "rb") as f:
            header = f.read(25)  # signature (8), IHDR length and type (8), width, height (8), bit depth (1)
        return int(header[24]) if len(header) == 25 else 8
    return 8


def decode(path: Path) -> np.ndarray:
    """The pixels of an image file as decoded (any dtype and channel count); InputError naming the file."""
    if not path.is_file():
        raise InputError("image file not found" if not path.exists() else "not a file", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)
    _check_pixels(path)
    try:
        arr = _read_pil(path)
    except (OSError, SyntaxError, ValueError, Warning) as exc:  # PIL: unknown format, truncated, corrupt
        pil_error = exc
        arr = None
    else:
        pil_error = None
    if arr is None or arr.dtype == object or arr.size == 0:
        # PIL cannot do some valid files (e.g. 16-bit multi-channel TIFF); OpenCV can. Only for formats PIL
        # did not recognise: a truncated JPEG that PIL rejected must stay an error, not be half-decoded.
        from PIL import UnidentifiedImageError

        if pil_error is not None and not isinstance(pil_error, UnidentifiedImageError):
            raise InputError(f"corrupt or truncated image ({pil_error})", path) from None
        arr = _read_cv2(path)
        if arr is None:
            raise InputError("unreadable image (not a supported image format, or corrupt)", path)
    return arr


def check_images_decode(paths: Iterable[str | Path]) -> None:
    """InputError naming the first image whose pixels do not decode whole (`read_image`: a truncated JPEG), one
    image in memory at a time. For stages that hand the files to a reader that half-decodes quietly (COLMAP's
    extractor registered a JPEG cut to 150 kB, whose map then refused it)."""
    for path in paths:
        read_image(path)


def read_gray(path: str | Path, white: Levels | int | None = None) -> np.ndarray:
    """Read an image file as (H, W) uint8 gray, on its stored pixel grid like `read_image` (OpenCV's imread would
    turn it by its EXIF Orientation tag, while the poses, the intrinsics and COLMAP see the stored grid), data of
    more than 8 bits scaled from the flight's white level `white` (`to_u8`; OpenCV alone keeps a 16-bit value's
    high byte, so 12-bit data came out 16 times too dark); raise InputError naming the file if it cannot be
    read."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError("image file not found" if not path.exists() else "not a file", path)
    _check_pixels(path)
    data = np.fromfile(path, dtype=np.uint8)
    flags = cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # a decode it cannot do is read below: no
    try:                                                               # "[ERROR] imdecode_" line per image (rev47)
        gray = cv2.imdecode(data, flags) if data.size else None
    except cv2.error:
        gray = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if gray is None:
        # OpenCV cannot turn some valid files to gray while decoding (a float64 RGB TIFF): read as every image
        # is (`read_image`, which names a file nothing can read) and take its luminance
        return cv2.cvtColor(read_image(path, white), cv2.COLOR_RGB2GRAY)
    try:
        return np.ascontiguousarray(to_u8(gray, white))
    except ValueError as exc:
        raise InputError(str(exc), path) from exc


def name_key(name: str) -> str:
    """An image name as other files may spell it: Unicode NFC (macOS writes file names decomposed, NFD, while
    a CSV typed elsewhere holds the composed form) and case-folded (a camera's IMG_0001.JPG copied as .jpg). For
    pairing names of pose and telemetry files with image files when the exact name is absent."""
    return unicodedata.normalize("NFC", name).casefold()


def unique_by_key(names: Iterable[str]) -> dict[str, str]:
    """{`name_key`: name} for the names no other of `names` folds to: a name spelt otherwise is paired only when
    its folded form is unambiguous."""
    names = list(names)
    counts = Counter(name_key(n) for n in names)
    return {name_key(n): n for n in names if counts[name_key(n)] == 1}


def image_files(folder: str | Path) -> list[Path]:
    """The image files of a folder (not recursive), sorted by name: files with an image extension, hidden ones
    (a leading dot) left out. Those are never the user's images: macOS writes a `._NAME.JPG` AppleDouble file (a
    few kB of metadata) beside every image it copies to an SD card or a FAT/exFAT drive, and one of them stopped a
    whole folder ("cannot identify image file"). Every command that takes a folder of images lists it here."""
    return sorted(f for f in Path(folder).iterdir()
                  if f.suffix.lower() in IMAGE_EXTENSIONS and not f.name.startswith(".") and f.is_file())


# files a drone or camera writes beside (or instead of) its images that no stage reads
RAW_EXTENSIONS = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw", ".3fr", ".iiq")
OTHER_MEDIA = {".heic": "HEIC", ".heif": "HEIF", ".mov": "video", ".mp4": "video", ".avi": "video"}


def no_images_message(folder: str | Path) -> str:
    """Why a folder holds no image a stage reads (for the InputError naming it): the extensions read, and what it
    holds instead, where that tells the user what to do (camera raw files to export, images one level down as in
    DCIM/100MEDIA, HEIC or video)."""
    folder = Path(folder)
    text = f"no images ({'/'.join(IMAGE_EXTENSIONS)}) in directory"
    files = [f for f in folder.iterdir() if f.is_file() and not f.name.startswith(".")]
    raw = [f for f in files if f.suffix.lower() in RAW_EXTENSIONS]
    other = sorted({OTHER_MEDIA[f.suffix.lower()] for f in files if f.suffix.lower() in OTHER_MEDIA})
    if raw:
        return (f"{text}; its {len(raw)} {raw[0].suffix.upper().lstrip('.')} files are camera raw, which is not read: "
                "export them as JPEG or 16-bit TIFF (keeping their EXIF) first")
    if other:
        return f"{text}; it holds {' and '.join(other)} files, which are not read: export frames as JPEG or TIFF"
    below = sorted(d for d in folder.iterdir() if d.is_dir() and not d.name.startswith(".") and image_files(d))
    if below:
        return (f"{text}; {len(below)} folder(s) below hold images (e.g. {below[0].name}): give the folder of one "
                "flight's images")
    return text


def list_images(paths: Iterable[str | Path]) -> list[Path]:
    """Expand files and directories (not recursive) into a sorted list of image files.

    Files given explicitly are kept whatever their extension (read_image decides); directories contribute
    their `image_files`. A missing path raises InputError.
    """
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out.extend(image_files(p))
        elif p.exists():
            out.append(p)
        else:
            raise InputError("no such file or directory", p)
    return out


def shared_file_name(paths: Iterable[str | Path]) -> tuple[Path, Path] | None:
    """The first two of `paths` that share a file name, or None. COLMAP keeps an image under its file name (a
    map's database, `segment`'s outputs NAME.json / NAME.png), so two such images would be stored as one: the
    earlier one's record silently replaced by the later's."""
    seen: dict[str, Path] = {}
    for p in paths:
        p = Path(p)
        if p.name in seen:
            return seen[p.name], p
        seen[p.name] = p
    return None


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image from its header (no decoding); InputError naming the file if unreadable."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with Image.open(path) as img:
            return int(img.size[0]), int(img.size[1])
    except FileNotFoundError:
        raise InputError("image not found", path) from None
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"cannot read image: {exc}", path) from None
