"""How good a flight's images are, measured on the keyframes' grey images at the segmenter's working size: noise,
contrast and sharpness per keyframe, their flight medians, and the keyframes that hold no structure at all.

A map can be thin because its poses do not fit its images or because its images hold little: sensor noise, blur,
blank frames. The map's own figures cannot tell these apart; these figures name the images (the 23rd new-user
sweep: Gaussian noise of sigma 40 left 20 of 108 landmarks with no word, or with one blaming the poses).

- **noise** sigma (DN): Immerkaer's fast noise-variance estimate (1996): the mean absolute response to the 3x3
  difference of two Laplacians, which cancels any locally planar image, times sqrt(pi / 2) / 6. Texture finer
  than the kernel counts as noise, so on real images it is an upper bound.
- **contrast** (DN): the image's standard deviation with that noise removed, sqrt(max(var - sigma^2, 0)).
- **sharpness**: the standard deviation of the Laplacian, its noise share (20 sigma^2) removed, over the
  contrast: how much of the image's contrast is fine detail (blur removes it first).

All are measured at the working size (the segmenter's, where segments and their boundaries are found), so a large
image's noise counts as the averaging of its pixels leaves it.

JPEG compression fools all three: it smooths the noise away and draws block edges that count as detail (the 35th
new-user sweep: quality 15 read noise 1.55 -> 0.88 DN, sharpness 0.33 -> 0.38). The flight's JPEG quality
(`plugin.jpeg_quality`, from the files' quantization tables) travels with the figures, and a flight compressed
below `QualityParams.min_jpeg_quality` is named as such wherever they are read.

A linear motion blur barely moves the sharpness (the detail across the track stays): the flight's smear along its
track (`plugin.motion_blur`, working px) travels with the figures and is named above
`QualityParams.max_motion_smear_px`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .jpeg_quality import FlightCompression

# the 3x3 kernel of Immerkaer's estimate: the difference of two Laplacians (zero on any planar patch)
_IMMERKAER = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
# contrast below one grey level (8 bits) after the noise is removed: nothing to segment or match (a constant or
# black frame measures 0, a frame of pure random noise 0 against its 50 DN of noise, a frame of sigma-40 noise
# over real ground 21)
BLANK_CONTRAST_DN = 1.0
# ... or below this share of the noise: the estimate's own scatter on a frame of pure noise (uniform noise of 74 DN
# on 160 x 120 pixels: contrast 0-9.5 DN, 0.13 of the noise; real ground under sigma-40 noise: 0.78)
BLANK_CONTRAST_TO_NOISE = 0.25
FIGURES = ("noise_dn", "contrast_dn", "sharpness")


def image_figures(gray: np.ndarray, max_side: int) -> np.ndarray:
    """(noise sigma DN, contrast DN, sharpness) of an 8-bit grey image, downscaled (area) to `max_side`."""
    import cv2

    g = np.asarray(gray, np.float32)
    scale = max_side / max(g.shape[:2])
    if scale < 1.0:
        g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    if min(g.shape[:2]) < 3:
        return np.full(3, np.nan)
    r = cv2.filter2D(g, cv2.CV_32F, _IMMERKAER)[1:-1, 1:-1]
    sigma = float(np.sqrt(np.pi / 2.0) * np.abs(r, dtype=np.float64).mean() / 6.0)
    contrast = float(np.sqrt(max(float(g.var(dtype=np.float64)) - sigma ** 2, 0.0)))
    lap = cv2.Laplacian(g, cv2.CV_32F)[1:-1, 1:-1]
    detail = float(np.sqrt(max(float(lap.var(dtype=np.float64)) - 20.0 * sigma ** 2, 0.0)))
    return np.array([sigma, contrast, detail / contrast if contrast >= BLANK_CONTRAST_DN else 0.0])


def _blank(noise_dn: float, contrast_dn: float) -> bool:
    """No structure above the noise (`BLANK_CONTRAST_DN`, `BLANK_CONTRAST_TO_NOISE`); False when not measured."""
    if not (np.isfinite(noise_dn) and np.isfinite(contrast_dn)):
        return False
    return contrast_dn < max(BLANK_CONTRAST_DN, BLANK_CONTRAST_TO_NOISE * noise_dn)


@dataclass(frozen=True)
class FlightImages:
    """The keyframes' image figures (K, 3: `FIGURES`, NaN where not measured) and their names; `compression`: the
    flight's JPEG quality (`plugin.jpeg_quality`; None: not measured); `smear_px`: the flight's median smear
    along its track (`plugin.motion_blur.flight_smear`, working px; NaN: not measured); `predicted_smear_px`: the
    smear its speed and exposure predict (`plugin.motion_blur.exposure_smear`; NaN: no ExposureTime or times)."""

    figures: np.ndarray
    names: tuple[str, ...]
    compression: FlightCompression | None = None
    smear_px: float = float("nan")
    predicted_smear_px: float = float("nan")

    def _measured(self) -> np.ndarray:
        f = np.asarray(self.figures, np.float64).reshape(-1, 3)
        return f[np.isfinite(f).all(axis=1)]

    def blank(self) -> list[str]:
        """Names of the keyframes with no contrast above their noise (`_blank`)."""
        f = np.asarray(self.figures, np.float64).reshape(-1, 3)
        return [n for n, (sigma, c) in zip(self.names, f[:, :2]) if _blank(sigma, c)]

    def medians(self) -> dict[str, float]:
        """The flight's median noise, contrast, sharpness and contrast-to-noise ratio over the keyframes that
        have structure (blank ones are named apart); NaN without any."""
        f = self._measured()
        f = f[[not _blank(sigma, c) for sigma, c in f[:, :2]]]
        if not len(f):
            return {k: float("nan") for k in (*FIGURES, "contrast_to_noise")}
        out = {k: float(np.median(f[:, i])) for i, k in enumerate(FIGURES)}
        out["contrast_to_noise"] = float(np.median(f[:, 1] / np.maximum(f[:, 0], 1e-3)))
        return out

    def to_dict(self) -> dict[str, object]:
        """run.json's `quality.images`: the medians (rounded), the blank keyframes and how many were measured."""
        med = {k: (round(v, 3) if np.isfinite(v) else None) for k, v in self.medians().items()}
        out: dict[str, object] = {**med, "keyframes_measured": int(len(self._measured())),
                                  "blank_keyframes": self.blank()}
        if self.compression is not None:
            out["jpeg"] = self.compression.to_dict()
        out["motion_smear_px"] = round(self.smear_px, 2) if np.isfinite(self.smear_px) else None
        p = self.predicted_smear_px
        out["motion_smear_predicted_px"] = round(p, 3) if np.isfinite(p) else None
        return out


def image_causes(images: FlightImages | None, min_contrast_to_noise: float, min_sharpness: float,
                 min_jpeg_quality: float = 0.0, max_smear_px: float = 0.0) -> list[str]:
    """What is wrong with the flight's images, one phrase each ("images noisy: ..."), [] when nothing is (or
    nothing was measured). Blank keyframes are named by `blank_warning`. `min_jpeg_quality`: a flight compressed
    below it is named first (0: never), and its noise and sharpness figures are said to read the compression.
    `max_smear_px`: a flight smeared along its track by more (working px) is named (0: never)."""
    if images is None:
        return []
    m = images.medians()
    causes = []
    c = images.compression
    if c is not None and c.below(min_jpeg_quality):
        causes.append(f"images heavily compressed: JPEG quality {c.quality:.0f} (median of {c.jpeg} sampled images; "
                      f"below {min_jpeg_quality:g} the block artefacts cost landmarks and cut the ground into "
                      "segments that are no objects; the noise and sharpness figures read the compression's "
                      "smoothing and block edges, not the scene)")
    if max_smear_px > 0 and np.isfinite(images.smear_px) and images.smear_px > max_smear_px:
        causes.append(motion_blur_phrase(images.smear_px, max_smear_px, images.predicted_smear_px))
    if np.isfinite(m["contrast_to_noise"]) and m["contrast_to_noise"] < min_contrast_to_noise:
        causes.append(f"images noisy: sigma {m['noise_dn']:.0f} DN against {m['contrast_dn']:.0f} DN of contrast "
                      f"(median of the keyframes; at least {min_contrast_to_noise:g} x the noise expected)")
    elif np.isfinite(m["sharpness"]) and m["sharpness"] < min_sharpness:
        # noisy images measure no sharpness (the noise's share is removed first): blur is named only without noise
        causes.append(f"images blurred: sharpness {m['sharpness']:.2f} (fine detail over contrast, median of the "
                      f"keyframes; at least {min_sharpness:g} expected)")
    return causes


def motion_blur_phrase(smear_px: float, max_smear_px: float, predicted_px: float = float("nan")) -> str:
    """The phrase naming a flight smeared by `smear_px` working px along its track (limit `max_smear_px`); the
    smear its speed and exposure predict (`predicted_px`) is said when it agrees (within a factor 2), as the
    physical cause; one that does not agree stays in the record only (either may be off: a wrong height, a
    shutter that does not write its time)."""
    cause = ""
    if np.isfinite(predicted_px) and smear_px / 2 <= predicted_px <= 2 * smear_px:
        cause = f", as the speed and exposure time predict ({predicted_px:.1f} px)"
    return (f"images motion-blurred: the ground is smeared {smear_px:.1f} working px along the track (median of the "
            f"keyframes, from the spectrum along the motion; at most {max_smear_px:g} expected{cause}): objects "
            "narrower than the smear merge with their surroundings and boundaries along the track are lost (a 7.5 px "
            "smear kept 120 of 205 landmarks of a clean flight)")


def blank_warning(images: FlightImages | None, keyframes: int) -> str:
    """A warning naming the keyframes that hold no structure (constant, black, white, pure noise), "" if none."""
    blank = images.blank() if images is not None else []
    if not blank:
        return ""
    shown = ", ".join(blank[:6]) + (", ..." if len(blank) > 6 else "")
    return (f"{len(blank)} of {keyframes} keyframes are blank or featureless (no contrast above their noise: "
            f"{shown}): nothing in them can be segmented or tracked")


def flight_images(figures: Sequence[np.ndarray], names: Sequence[str],
                  compression: FlightCompression | None = None,
                  smears: Sequence[float] | np.ndarray | None = None,
                  predicted_smear_px: float = float("nan")) -> FlightImages:
    """`FlightImages` from per-keyframe figures (each 3 values, NaN where not measured), the flight's JPEG
    compression (`plugin.jpeg_quality.flight_compression`; None: not measured) and the keyframes' smears along
    the track (`plugin.motion_blur.motion_smear`, working px; None: not measured) and the smear the speed and
    exposure predict (`plugin.motion_blur.exposure_smear`; NaN: not known)."""
    from .motion_blur import flight_smear

    arr = np.array([np.asarray(f, np.float64).reshape(3) for f in figures]) if len(figures) else np.zeros((0, 3))
    smear = flight_smear(np.asarray(smears, np.float64)) if smears is not None else float("nan")
    return FlightImages(arr, tuple(names), compression, smear, predicted_smear_px)
