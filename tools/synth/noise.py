"""Deterministic fractal (value) noise on rasters, built from upsampled random grids.

Everything is float32 and derived from a numpy Generator, so the same seed gives the same bytes.
"""

from __future__ import annotations

import cv2
import numpy as np


def rng_for(*keys: int) -> np.random.Generator:
    """A generator for one named random stream: keys are small non-negative ints (seed, tag, index, ...)."""
    return np.random.default_rng([int(k) for k in keys])


def value_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[float, float]) -> np.ndarray:
    """Smooth noise of `shape` (rows, cols) with about `cells` (rows, cols) random values across it (std ~1)."""
    rows, cols = shape
    gr = max(2, int(np.ceil(cells[0])) + 1)
    gc = max(2, int(np.ceil(cells[1])) + 1)
    grid = rng.standard_normal((gr, gc)).astype(np.float32)
    return cv2.resize(grid, (cols, rows), interpolation=cv2.INTER_CUBIC)


def fractal_noise(
    rng: np.random.Generator,
    shape: tuple[int, int],
    extent_m: tuple[float, float],
    wavelength_m: float,
    octaves: int = 4,
    persistence: float = 0.5,
    min_wavelength_m: float = 0.0,
) -> np.ndarray:
    """Sum of `octaves` value-noise layers, the first with features of about `wavelength_m`, each next one
    half as large and `persistence` times as strong; normalised to zero mean and unit standard deviation."""
    out = np.zeros(shape, np.float32)
    amp = 1.0
    wl = wavelength_m
    for _ in range(octaves):
        if wl < min_wavelength_m:
            break
        cells = (extent_m[0] / wl, extent_m[1] / wl)
        out += np.float32(amp) * value_noise(rng, shape, cells)
        amp *= persistence
        wl /= 2.0
    sample = out[::7, ::7]  # statistics of a subsample are accurate enough and 50x cheaper
    out -= np.float32(sample.mean(dtype=np.float64))
    std = float(sample.std(dtype=np.float64))
    if std > 0:
        out *= np.float32(1.0 / std)
    return out
