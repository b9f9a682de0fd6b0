"""Seasons, sun and the camera pipeline of a synthetic session.

Colours are 8-bit sRGB albedos. Lighting is computed in linear light: a per-session lighting raster
`ambient + direct * max(0, n . s) * (1 - shadow)` (normalised so that flat, sunlit ground is 1.0), where n is
the DSM normal, s the unit vector toward the sun and `shadow` comes from marching the DSM toward the sun (an
exact horizon test done as a running maximum along rows of the DSM rotated to the sun azimuth). The camera then
applies auto exposure plus a session exposure offset, white balance, vignetting, optical blur, shot and read
noise, and JPEG compression.

Sun azimuth is in degrees clockwise from north (+y), elevation in degrees above the horizon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .config import SEASON_NAMES  # noqa: F401 (re-exported)


@dataclass(frozen=True)
class SeasonLook:
    """Per-season defaults: sun, light balance and the camera's exposure bias."""

    sun_azimuth_deg: float
    sun_elevation_deg: float
    ambient: float  # diffuse sky light relative to the direct sun on a surface facing it
    exposure_ev: float  # bias of the auto exposure (snow is metered darker, as real cameras do)


SEASON_LOOKS: dict[str, SeasonLook] = {
    "summer": SeasonLook(150.0, 55.0, 0.45, 0.0),
    "autumn": SeasonLook(165.0, 32.0, 0.55, 0.0),
    "winter": SeasonLook(190.0, 20.0, 0.80, 0.6),
    "spring": SeasonLook(140.0, 42.0, 0.50, 0.0),
}

# Ground palettes (sRGB): class -> season -> colour. Crops: row colour and between-row colour.
GROUND = {
    "grass": {"summer": (84, 116, 52), "autumn": (124, 122, 70), "winter": (236, 239, 245), "spring": (96, 142, 56)},
    "grass2": {"summer": (118, 128, 64), "autumn": (146, 128, 78), "winter": (222, 227, 236),
               "spring": (120, 150, 62)},
    "soil": {"summer": (134, 110, 82), "autumn": (112, 90, 68), "winter": (214, 216, 222), "spring": (118, 94, 70)},
    "asphalt": {"summer": (92, 92, 94), "autumn": (86, 86, 88), "winter": (112, 111, 110), "spring": (90, 90, 92)},
    "gravel": {"summer": (164, 154, 136), "autumn": (150, 140, 124), "winter": (196, 194, 192),
               "spring": (158, 148, 130)},
    "water": {"summer": (44, 64, 62), "autumn": (50, 62, 58), "winter": (188, 198, 206), "spring": (54, 74, 72)},
    "margin": {"summer": (70, 98, 44), "autumn": (128, 108, 64), "winter": (226, 229, 236), "spring": (84, 122, 50)},
    "bank": {"summer": (104, 116, 66), "autumn": (138, 120, 74), "winter": (218, 222, 230), "spring": (98, 126, 62)},
}
CROPS = ("wheat", "corn", "rapeseed", "potato", "hay", "ploughed")
CROP_COLOURS = {  # crop -> season -> (row colour, between-row colour)
    "wheat": {"summer": ((202, 178, 98), (176, 150, 86)), "autumn": ((188, 168, 118), (150, 126, 92)),
              "winter": ((240, 242, 248), (216, 221, 232)), "spring": ((104, 148, 58), (128, 104, 78))},
    "corn": {"summer": ((62, 112, 40), (116, 96, 70)), "autumn": ((164, 142, 84), (122, 100, 72)),
             "winter": ((238, 240, 246), (206, 210, 220)), "spring": ((98, 138, 60), (132, 106, 80))},
    "rapeseed": {"summer": ((96, 128, 52), (84, 110, 48)), "autumn": ((112, 86, 66), (86, 66, 50)),
                 "winter": ((240, 242, 248), (220, 224, 234)), "spring": ((226, 206, 44), (196, 182, 52))},
    "potato": {"summer": ((78, 124, 50), (120, 96, 70)), "autumn": ((126, 102, 76), (100, 80, 60)),
               "winter": ((236, 238, 244), (200, 204, 214)), "spring": ((136, 110, 84), (104, 84, 64))},
    "hay": {"summer": (((138, 150, 78)), (122, 134, 70)), "autumn": ((136, 134, 80), (124, 120, 74)),
            "winter": ((238, 240, 246), (230, 233, 241)), "spring": ((100, 150, 60), (92, 138, 56))},
    "ploughed": {"summer": ((124, 100, 76), (94, 74, 56)), "autumn": ((104, 82, 62), (80, 62, 48)),
                 "winter": ((228, 230, 238), (190, 192, 200)), "spring": ((116, 90, 68), (90, 70, 52))},
}


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from the ground toward the sun (world x east, y north, z up)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])


def cast_shadow(dsm: np.ndarray, resolution_m: float, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Fraction in shadow (float32 0..1, soft by half a pixel) of every DSM cell for the given sun.

    The DSM (rows = +y, cols = +x) is rotated so that the direction toward the sun points to decreasing
    column; along each row a cell j is shadowed when some cell j' < j satisfies
    dsm[j'] - (j - j') * res * tan(elev) > dsm[j], i.e. when the running maximum of dsm[j'] + j' * c exceeds
    dsm[j] + j * c with c = res * tan(elev). One rotation, one cumulative max, one rotation back.
    """
    rows, cols = dsm.shape
    toward = (math.sin(math.radians(azimuth_deg)), math.cos(math.radians(azimuth_deg)))  # (d col, d row)
    phi = math.atan2(toward[1], toward[0])
    theta = math.pi - phi  # rotate the sun direction onto (-1, 0)
    c, s = math.cos(theta), math.sin(theta)
    size = int(math.ceil(math.hypot(rows, cols))) + 4
    src_c = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
    dst_c = np.array([(size - 1) / 2.0, (size - 1) / 2.0])
    rot = np.array([[c, -s], [s, c]])
    fwd = np.hstack([rot, (dst_c - rot @ src_c)[:, None]]).astype(np.float64)
    low = float(dsm.min()) - 1000.0
    rotated = cv2.warpAffine(dsm, fwd, (size, size), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=low)
    step = np.float32(resolution_m * math.tan(math.radians(max(elevation_deg, 0.5))))
    ramp = np.arange(size, dtype=np.float32) * step
    g = rotated + ramp[None, :]
    running = np.maximum.accumulate(g, axis=1)
    # 3 cm tolerance: bilinear resampling must not make flat or convex surfaces shadow themselves.
    shadow = (running > g + np.float32(0.03)).astype(np.float32)
    back = cv2.warpAffine(shadow, fwd, (cols, rows), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return back


def sky_occlusion(dsm: np.ndarray, terrain: np.ndarray, resolution_m: float) -> np.ndarray:
    """Fraction of the sky light that reaches each cell (float32, 0.45..1): ground next to trees and houses
    and the lower parts of crowns see less sky (a cheap ambient occlusion from the height above ground)."""
    rows, cols = dsm.shape
    small = (max(1, cols // 4), max(1, rows // 4))
    hag = cv2.resize(dsm - terrain, small, interpolation=cv2.INTER_AREA)
    sigma = 2.5 / (resolution_m * 4)  # a 2.5 m neighbourhood
    around = cv2.GaussianBlur(hag, (0, 0), sigma)
    occ = np.clip((around - hag) / np.float32(4.0), 0.0, 1.0)
    occ = cv2.resize(occ, (cols, rows), interpolation=cv2.INTER_LINEAR)
    return np.float32(1.0) - np.float32(0.55) * occ


def lighting(dsm: np.ndarray, resolution_m: float, azimuth_deg: float, elevation_deg: float,
             ambient: float, terrain: np.ndarray | None = None) -> np.ndarray:
    """Linear light multiplier per DSM cell (float32): 1.0 on flat sunlit ground, `ambient/(ambient+sin el)` in
    open shadow; Lambert shading from the DSM normals in between; with `terrain`, the sky light is reduced
    next to tall objects (`sky_occlusion`)."""
    s = sun_vector(azimuth_deg, elevation_deg).astype(np.float32)
    gx = cv2.Sobel(dsm, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / (8.0 * resolution_m))
    gy = cv2.Sobel(dsm, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / (8.0 * resolution_m))
    cos_i = (s[2] - gx * s[0] - gy * s[1]) / np.sqrt(gx * gx + gy * gy + np.float32(1.0))
    np.maximum(cos_i, 0.0, out=cos_i)
    # Shadows at half resolution (0.3 m by default): they are soft-edged anyway (the sun is 0.5 deg wide and
    # the shadow is upsampled bilinearly), and this is the most expensive part of a session's set-up.
    rows, cols = dsm.shape
    half = cv2.resize(dsm, ((cols + 1) // 2, (rows + 1) // 2), interpolation=cv2.INTER_AREA)
    shadow = cv2.resize(cast_shadow(half, resolution_m * cols / half.shape[1], azimuth_deg, elevation_deg),
                        (cols, rows), interpolation=cv2.INTER_LINEAR)
    direct = cos_i * (np.float32(1.0) - shadow)
    norm = np.float32(1.0 / (ambient + s[2]))
    sky = np.float32(ambient) if terrain is None else np.float32(ambient) * sky_occlusion(dsm, terrain, resolution_m)
    return (sky + direct) * norm


# ----------------------------------------------------------------------------------------------- camera pipeline

_SRGB_TO_LINEAR = ((np.arange(256, dtype=np.float64) / 255.0) ** 2.2).astype(np.float32)


def srgb_to_linear_lut() -> np.ndarray:
    """256-entry table from 8-bit sRGB (gamma 2.2 approximation) to linear light."""
    return _SRGB_TO_LINEAR


@dataclass(frozen=True)
class CameraLook:
    """Photometric settings of one session (drawn from the session seed unless given)."""

    exposure_ev: float  # offset added to the auto exposure
    white_balance: tuple[float, float, float]  # per-channel gains (R, G, B)
    vignetting: float  # relative light loss in the image corners
    blur_sigma_px: float
    noise_sigma: float  # read noise, 8-bit digital numbers at mid grey
    jpeg_quality: int


def finish_image(linear: np.ndarray, look: CameraLook, rng: np.random.Generator) -> np.ndarray:
    """Camera pipeline from linear radiance (H, W, 3 float32) to an 8-bit sRGB image (H, W, 3 uint8, RGB).

    Auto exposure maps the frame's mean luminance part way toward mid grey (a camera meters the scene, but a
    snowy frame still comes out brighter than a forest), then the session's exposure offset and white balance.
    """
    h, w, _ = linear.shape
    lum = float(linear.mean(dtype=np.float64)) + 1e-6
    gain = (0.20 / lum) ** 0.55 * 2.0 ** look.exposure_ev
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    vignette = 1.0 - look.vignetting * r2
    img = linear * (vignette * np.float32(gain))[:, :, None] * np.asarray(look.white_balance, np.float32)
    if look.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.blur_sigma_px)
    np.clip(img, 0.0, 1.0, out=img)
    srgb = img ** np.float32(1.0 / 2.2) * np.float32(255.0)
    # Shot noise grows with the signal, read noise does not (in 8-bit digital numbers).
    sigma = np.sqrt(np.float32(look.noise_sigma) ** 2 + np.float32(0.03 * look.noise_sigma ** 2) * srgb)
    srgb += rng.standard_normal(srgb.shape, dtype=np.float32) * sigma
    return np.clip(srgb + 0.5, 0, 255).astype(np.uint8)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of an RGB uint8 image (deterministic: same pixels and quality give the same bytes)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()
