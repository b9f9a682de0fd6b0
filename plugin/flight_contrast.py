"""A flight's contrast, and the one linear gain that brings a low-contrast (hazy) flight up to the contrast the
segmenter was tuned on.

Why: the classical segmenter's criteria are absolute CIELAB differences (`classical_min_contrast`, the
`classical_minima_depth` basins, the Ward merge costs), chosen on flights of normal contrast. Haze
(I' = (1 - a) I + a white) shrinks every difference by (1 - a): at a = 0.5 a rendered flight kept 78 of its 190
landmarks, with exit 0 and nothing said, while the matches stayed right. Stretching the images back restored them.

The gain is the flight's, not the frame's: measured once over images sampled across the flight (as
`database.flight_levels.flight_white_level` is), so a region has the same contrast, and masks the same sizes, in every
frame. It is never below 1, so a flight of normal contrast is segmented from its images exactly as before.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from ..database.images import Levels

log = logging.getLogger(__name__)

#: images sampled over a flight to measure its contrast
CONTRAST_SAMPLES = 12
#: the robust luminance range of an image: between these percentiles of its grey levels
RANGE_PERCENTILES = (1.0, 99.0)
#: the largest gain: the sensor's noise is stretched alike, and beyond ~3 (a haze of two thirds, or a flight over
#: snow, water or sand of 10-30 grey levels) it would be segmented as texture; such a flight is said, not rescued
MAX_GAIN = 3.0
#: images are measured at this longer side at most (the segmenter's working size; the range hardly depends on it)
MEASURE_SIDE = 400


def luminance_range(image: np.ndarray) -> tuple[float, float]:
    """(low, high): the `RANGE_PERCENTILES` of an (H, W, 3) or (H, W) uint8 image's grey levels (0..255),
    measured at `MEASURE_SIDE` px."""
    gray = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image, np.uint8), cv2.COLOR_RGB2GRAY)
    scale = MEASURE_SIDE / max(gray.shape[:2])
    if scale < 1:
        size = (max(1, round(gray.shape[1] * scale)), max(1, round(gray.shape[0] * scale)))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
    lo, hi = np.percentile(gray, RANGE_PERCENTILES)
    return float(lo), float(hi)


@dataclass(frozen=True)
class FlightContrast:
    """A flight's luminance range and the gain its images get before segmentation.

    `range`: the median over the sampled images of their luminance range (grey levels, 0..255); `centre`: the
    median of those ranges' mid-points; `reference`: the range the segmenter was tuned for
    (`SegmentationParams.contrast_reference`; 0: never stretch); `gain`: max(1, reference / range), at most `MAX_GAIN`;
    `samples`: images measured (0: none could be read, gain 1)."""

    range: float
    centre: float
    reference: float
    gain: float
    samples: int

    @property
    def stretched(self) -> bool:
        return self.gain > 1.0

    def apply(self, image: np.ndarray) -> np.ndarray:
        """The image as the segmenter sees it: unchanged (the same array) at gain 1; else every channel
        stretched linearly by `gain` about the flight's centre, the stretched range kept inside 0..255 (a hazy
        flight's range sits high: its centre moves down rather than its highlights clipping)."""
        if not self.stretched:
            return image
        half = 0.5 * min(255.0, self.gain * self.range)
        target = float(np.clip(self.centre, half, 255.0 - half))
        out = (image.astype(np.float32) - self.centre) * self.gain + target
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)

    def cause(self) -> str:
        """The flight's low contrast as the cause of a thin map ("" at normal contrast: not stretched)."""
        if not self.stretched:
            return ""
        return (f"the images' contrast is low (luminance range {self.range:.0f} of the {self.reference:g} grey "
                f"levels the segmenter was tuned for, stretched by {self.gain:.2f}): fewer regions stand out")

    def to_dict(self) -> dict:
        """The record run.json keeps."""
        return {"range": round(self.range, 2), "centre": round(self.centre, 2), "reference": self.reference,
                "gain": round(self.gain, 4), "samples": self.samples}

    def message(self, whose: str = "the flight's") -> str:
        """The line said when a gain is applied (`whose`: what was measured, "the flight's" or a folder's)."""
        capped = self.gain * self.range < self.reference - 1e-9
        return (f"{whose} contrast is {self.range / self.reference:.2f} of what the segmenter was tuned for "
                f"(luminance range {self.range:.0f} of {self.reference:g} grey levels: haze or flat light?): "
                f"stretched by {self.gain:.2f} for segmentation"
                + (f" (at most {MAX_GAIN:g}: the sensor's noise grows alike; expect a sparse map)" if capped else ""))


def contrast_of(ranges: Sequence[tuple[float, float]], reference: float) -> FlightContrast:
    """The flight's contrast from its sampled images' (low, high) ranges (`luminance_range`)."""
    if not ranges:
        return FlightContrast(float("nan"), float("nan"), reference, 1.0, 0)
    arr = np.asarray(ranges, np.float64)
    width = float(np.median(arr[:, 1] - arr[:, 0]))
    centre = float(np.median(arr.mean(axis=1)))
    # a flat frame (width 0: fog, a lens cap) gets no infinite gain: nothing there to stretch
    gain = min(MAX_GAIN, max(1.0, reference / width)) if reference > 0 and width > 0 else 1.0
    return FlightContrast(width, centre, reference, gain, len(arr))


def flight_contrast(paths: Sequence[str | Path], reference: float, white: Levels | int | None = None) -> FlightContrast:
    """The contrast of the flight of `paths` (`FlightContrast`) from `CONTRAST_SAMPLES` images spread over it.

    Why the median of per-image ranges and not one pooled histogram: the segmenter works frame by frame, and a
    flight whose frames drift in exposure (or pass from forest to fields) pools to a wider range than any of its
    frames has. Unreadable samples are skipped (the stage that needs their pixels names them). `white`: the
    flight's white level (`database.flight_levels.flight_white_level`)."""
    from ..database.images import read_image
    from .errors import InputError

    paths = list(paths)
    if reference <= 0 or not paths:
        return contrast_of([], reference)
    picks = sorted({round(i) for i in np.linspace(0, len(paths) - 1, min(len(paths), CONTRAST_SAMPLES))})
    ranges = []
    for i in picks:
        try:
            ranges.append(luminance_range(read_image(paths[i], white)))
        except InputError:
            continue
    return contrast_of(ranges, reference)
