"""How strongly a flight's images are JPEG-compressed: the IJG quality (1-100) their luminance quantization table
says, read from the files' headers alone (no pixel is decoded).

Why: heavy compression smooths fine detail into 8 x 8 blocks and draws block edges. The segmenter then cuts the
ground differently (the 35th new-user sweep: `synth --jpeg-quality 15` kept 160 of 205 landmarks, with exit 0
and no word) and a comparison with a clean session claims objects gone and new that are not (11 at confidences up
to 0.999). The image figures (`plugin.image_quality`) cannot see it: the smoothing lowers the measured noise
(1.55 -> 0.88 DN) and the block edges raise the sharpness (0.33 -> 0.38), so a compressed flight reads better than
its original. The quantization table says it directly.

The quality is the IJG (libjpeg) scaling of the standard luminance table (ITU-T T.81 Annex K) that comes closest to
the file's own table, as libjpeg's and ImageMagick's estimates do: exact for files written by libjpeg, OpenCV,
Pillow, ImageMagick and most cameras' IJG-derived encoders; for an encoder with its own tables it is the IJG
quality of equal quantization. Files that are not baseline JPEGs (PNG, TIFF, ...) are lossless here: None.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: ITU-T T.81 Annex K.1 luminance quantization table, natural (row-major) order, as Pillow reports tables
_STD_LUMINANCE = np.array([
    16, 11, 10, 16, 24, 40, 51, 61,
    12, 12, 14, 19, 26, 58, 60, 55,
    14, 13, 16, 24, 40, 57, 69, 56,
    14, 17, 22, 29, 51, 87, 80, 62,
    18, 22, 37, 56, 68, 109, 103, 77,
    24, 35, 55, 64, 81, 104, 113, 92,
    49, 64, 78, 87, 103, 121, 120, 101,
    72, 92, 95, 98, 112, 100, 103, 99], np.float64)
#: images sampled over a flight (spread as `plugin.flight_contrast` samples them; reading a header is cheap)
QUALITY_SAMPLES = 12


def ijg_table(quality: int) -> np.ndarray:
    """The luminance table libjpeg writes at `quality` (1-100): jpeg_quality_scaling, baseline (1..255)."""
    q = min(max(int(quality), 1), 100)
    scale = 5000.0 / q if q < 50 else 200.0 - 2.0 * q
    return np.clip(np.floor((_STD_LUMINANCE * scale + 50.0) / 100.0), 1, 255)


_TABLES = np.array([ijg_table(q) for q in range(1, 101)])


def quality_of_table(table: Sequence[int]) -> int:
    """The IJG quality (1-100) whose luminance table is closest to `table` (64 values, natural order): the least
    sum of log ratios, so the coarse high frequencies and the fine low ones count alike."""
    t = np.asarray(table, np.float64).reshape(-1)[:64]
    if t.size != 64 or not np.all(t > 0):
        raise ValueError("a quantization table has 64 positive entries")
    err = np.abs(np.log(_TABLES) - np.log(t)[None, :]).sum(axis=1)
    return int(np.argmin(err)) + 1


def jpeg_quality(path: str | Path) -> int | None:
    """The IJG quality of one image file's luminance table (`quality_of_table`); None for a file that is no JPEG
    or has no table (nothing lossy to report). Only the header is read. Unreadable files raise OSError."""
    from PIL import Image

    with Image.open(path) as im:  # lazy: Pillow parses the markers up to the scan, no pixel is decoded
        tables = getattr(im, "quantization", None) if im.format in ("JPEG", "MPO") else None
        if not tables:
            return None
        first = tables[min(tables)]  # table 0: the luminance (Y) table of every IJG and camera encoder
        try:
            return quality_of_table(list(first))
        except ValueError:
            return None


@dataclass(frozen=True)
class FlightCompression:
    """A flight's JPEG compression: the median and the lowest quality over `samples` sampled images that are JPEGs
    (`jpeg` of them; the others are lossless or unreadable). `quality` is None when none is a JPEG."""

    quality: float | None
    lowest: int | None
    samples: int
    jpeg: int

    def below(self, limit: float) -> bool:
        """True when the flight's median quality is below `limit` (0: never)."""
        return self.quality is not None and limit > 0 and self.quality < limit

    def to_dict(self) -> dict[str, object]:
        """run.json's `quality.images.jpeg` and changes.json's record of a session's compression."""
        return {"quality": self.quality, "lowest": self.lowest, "samples": self.samples, "jpeg": self.jpeg}


def flight_compression(paths: Sequence[str | Path]) -> FlightCompression:
    """The JPEG compression of the flight of `paths` (`FlightCompression`) from `QUALITY_SAMPLES` images spread
    over it (headers only). Unreadable samples are skipped: the stage that needs their pixels names them."""
    paths = list(paths)
    picks = sorted({round(i) for i in np.linspace(0, len(paths) - 1, min(len(paths), QUALITY_SAMPLES))}) \
        if paths else []
    found: list[int] = []
    for i in picks:
        try:
            q = jpeg_quality(paths[i])
        except (OSError, SyntaxError, ValueError):
            continue
        if q is not None:
            found.append(q)
    if not found:
        return FlightCompression(None, None, len(picks), 0)
    return FlightCompression(float(np.median(found)), int(min(found)), len(picks), len(found))
