"""What a flight's images of more than 8 bits are read between: one white level, or one pair of levels, measured
over a few frames of the flight (`flight_white_level`), so every frame gets the same mapping to 8 bits
(`images.to_rgb_u8`). Split from `database.images`, which reads the pixels.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from ..plugin.sampling import evenly_spaced
from .images import Levels, decode, header_bits, white_level

log = logging.getLogger(__name__)

# images sampled over a flight to find its sensor's bit depth and range (`flight_white_level`)
WHITE_LEVEL_SAMPLES = 8
# values kept of each sample (evenly strided) for the flight's range: its percentiles hardly move beyond this
LEVEL_SAMPLE_VALUES = 250_000
# the flight's robust range: these percentiles of its sampled values (hot pixels, a sun glint or a dead column
# left out)
LEVEL_PERCENTILES = (0.1, 99.9)
# a flight whose robust range spans less than this fraction of its sensor's range (64 of 255 grey levels) is read
# from its own range: below it the 8-bit reading keeps fewer grey levels than the contrast stretch
# (`plugin.flight_contrast`, at most 3) can bring to the segmenter's reference (70 levels), while data that span
# more read exactly as before (the camera's exposure kept)
MIN_SPAN = 0.25


def flight_white_level(paths: Sequence[str | Path]) -> Levels | int | None:
    """What a flight's images of more than 8 bits are read between (`to_rgb_u8`): None for 8-bit images (told
    from the headers of WHITE_LEVEL_SAMPLES images spread over the flight, nothing decoded); else measured once
    over those samples, so that every frame gets the same mapping (a dark frame of a 16-bit flight, scaled by
    itself, came out 16 times brighter than its neighbours): the sensor's white level (`white_level` of the
    largest value, black 0: the camera's exposure kept), or `Levels` at the flight's own robust range
    (`flight_levels`) for data offset far from zero in a narrow range, for signed data reaching below zero and
    for float data that are not light in 0..1 or 0..255. Unreadable samples are skipped (the stage that needs
    their pixels names them).

    Why the flight's own range: a radiometric thermal file holds temperatures (DJI's Thermal SDK and FLIR tools
    write centi-kelvin: 20-40 degC is 29315-31315; others deci-degC in signed 16 bits, or degC as float), not
    light from 0 up; read from 0 to its white level it had 6 grey levels and its map no landmarks. Thermal
    cameras show such data between the scene's own limits."""
    paths = list(paths)
    if not paths:
        return None
    picks = evenly_spaced(len(paths), WHITE_LEVEL_SAMPLES)
    values, kinds, largest, nodata, total = [], set(), 0, 0, 0
    for i in picks:
        path = Path(paths[i])
        bits = header_bits(path)
        if bits is not None and bits <= 8:
            continue
        try:
            arr = decode(path)
        except InputError:
            continue
        if (arr.dtype.kind in "ui" and arr.dtype.itemsize > 1) or arr.dtype.kind == "f":
            # whole pixels, every channel: a stride over the flattened values reads one channel only whenever it
            # is a multiple of the channel count (3 at 640x512 RGB), and a narrow red band set the levels (rev24)
            pixels = arr.reshape(arr.shape[0] * arr.shape[1], -1) if arr.ndim == 3 else arr.reshape(-1, 1)
            sample = pixels[:: max(1, len(pixels) * pixels.shape[1] // LEVEL_SAMPLE_VALUES)].reshape(-1)
            valid = _valid_values(sample)
            total += sample.size
            nodata += sample.size - valid.size
            values.append(valid.astype(np.float64 if arr.dtype.kind == "f" else np.int64))
            kinds.add(arr.dtype.kind)
            if arr.dtype.kind in "ui":
                # the white level from every value, as before the sampled levels: a few highlights at 4000 in a
                # 12-bit flight's sample-missed pixels made it 1023, and the flight read 4x too bright (rev24)
                largest = max(largest, int(arr.max(initial=0)))
    if not values:
        return None
    pooled = np.concatenate(values)
    if pooled.size == 0:
        log.warning("the images hold only no-data values (0 or their type's maximum) in every sampled pixel: "
                    "blank frames?")
        return None if kinds == {"f"} else white_level(largest)
    floats = "f" in kinds
    # the nominal range other data are read in (`to_u8`): the sensor's white level, or 0..1 / 0..255 for floats
    white: float = (1.0 if pooled.max() <= 1.0 else 255.0) if floats else white_level(largest)
    lo, hi, clipped, outliers = flight_levels(pooled)
    p5, p95 = np.percentile(pooled, (5, 95))
    # below zero (signed deci-degC, float degC) or above 255 (float centi-kelvin) the data are not light in the
    # range they would be read in: read so, they lost every value outside it (65 % of a winter scene black).
    # Otherwise a narrow range near zero is a dark exposure (kept, as the README promises); one whose central
    # 5-95 % sits above zero by more than its own width is data offset from zero (temperatures): only that is read
    # between its own levels. Central statistics, not the tails: a row of zeros in 1 of 240 rows (0.4 %) set the
    # 0.1 % tail and flipped a thermal flight to 6 grey levels.
    lost = float(np.mean((pooled < 0) | (pooled > white)))
    # floats beyond 0..1 are measurements (degC, kelvin), not light of a known white: always their own levels, so
    # that a spring flight (5-40 degC) and a winter one (-5-30) of one site read alike (rev25: 36 grey levels
    # against 256, by whether a pixel fell below zero)
    if floats and white == 1.0 and lost < 0.001:
        return None
    if not floats and lost < 0.001 and (hi - lo >= MIN_SPAN * white or (p5 < p95 - p5 and hi > lo)):
        return white
    if floats:
        # six significant digits: the levels of degC data as the log and run.json show them, not 13.6899995803833
        levels = Levels(float(f"{lo:.6g}"), float(f"{max(hi, lo + white / 255.0):.6g}"))
    else:
        levels = Levels(int(lo), int(max(hi, lo + 1)))
    if hi == lo:
        # a flat flight (one value throughout) keeps a span of 1, not divided by zero: it reads black, and the
        # stages that need texture refuse it
        log.warning("the images hold one value (%s) in every sampled pixel: blank frames?", lo)
        return levels
    why = (f"{100 * lost:.0f} % of their values lie outside 0-{white:g} (below zero or beyond), which a reading "
           f"in that range loses" if lost >= 0.001
           else f"their values span only {lo:g}-{hi:g} of their range 0-{white:g} "
                f"({100.0 * (hi - lo) / white:.1f} %): a radiometric (thermal) file?")
    extra = ""
    if clipped:
        extra += f"; {100 * clipped / pooled.size:.2f} % of the sampled values lie beyond them and clip"
    if outliers:
        extra += (f" ({100 * outliers / pooled.size:.2f} % far beyond the rest: a hot object or dead pixels, "
                  "left out of the levels)")
    if nodata:
        extra += (f"; {100 * nodata / total:.2f} % are no-data or saturated (0 or the type's maximum) and "
                  "set no level")
    log.warning("the images are read between the flight's own levels %s: %s%s", levels, why, extra)
    return levels


# The flight's bulk: values in these percentiles, and a value farther beyond them than the bulk is wide is an
# outlier (a hot object, a dead pixel cluster), clipped rather than stretching every frame's grey levels (Tukey's
# fences, on the 1-99 % range instead of the quartiles: a thermal scene's own tails reach 0.5 of its 1-99 % width
# beyond it, a 20x20 patch at 87 degC in 3 of 40 frames 4 widths)
LEVEL_BULK = (1.0, 99.0)
LEVEL_FENCE = 1.0


def _valid_values(sample: np.ndarray) -> np.ndarray:
    """The values of a sample that can set a flight's levels: not no-data or saturated, which is exactly 0 or the
    type's maximum for unsigned data (a rectified frame's zero-filled corners, a blank line, a dead column), the
    type's minimum or maximum for signed data (0 is a temperature there), and for floats not NaN or infinite (0.0
    is a temperature too, and `to_u8` reads it as one: rev25)."""
    if sample.dtype.kind == "u":
        return sample[(sample != 0) & (sample != np.iinfo(sample.dtype).max)]
    if sample.dtype.kind == "i":
        info = np.iinfo(sample.dtype)
        return sample[(sample != info.min) & (sample != info.max)]
    return sample[np.isfinite(sample)]


def flight_levels(values: np.ndarray) -> tuple[float, float, int, int]:
    """(black, white, clipped, outliers) of a flight's valid sampled values: the LEVEL_PERCENTILES of the values
    within LEVEL_FENCE bulk widths of the bulk (LEVEL_BULK), rounded for integer data; how many values lie beyond
    them (they clip to 0 or 255), and how many lie beyond the fence (outliers). A small hot object then clips
    instead of setting the white level of the whole flight, while a scene without outliers gets the
    LEVEL_PERCENTILES of all its values, as before."""
    b_lo, b_hi = np.percentile(values, LEVEL_BULK)
    width = b_hi - b_lo
    inside = values[(values >= b_lo - LEVEL_FENCE * width) & (values <= b_hi + LEVEL_FENCE * width)]
    lo, hi = np.percentile(inside, LEVEL_PERCENTILES)
    if values.dtype.kind in "ui":
        lo, hi = float(round(lo)), float(round(hi))
    clipped = int(np.count_nonzero((values < lo) | (values > hi)))
    return float(lo), float(hi), clipped, int(values.size - inside.size)
