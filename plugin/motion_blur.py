"""Motion blur along the flight: how far the ground smeared across each keyframe during its exposure, measured in
the image's own spectrum along the camera's direction of motion, in working pixels (the segmenter's size).

Why: a drone flying while the shutter is open smears the ground along its track. The 35th new-user sweep: a 12 px
linear blur along the track (2.4 m at 0.2 m/px) kept 120 of 205 landmarks with no word, and a comparison with a
clean session of the same ground claimed 4 changes at high confidence where nothing had changed. The isotropic
sharpness figure (`plugin.image_quality`) barely moves under such a blur: the detail across the track is intact.

How: a linear smear of length L multiplies the image's spectrum by sinc^2(L f) along the motion and leaves it
alone across it. The power spectrum (Hann window, disc |f| <= 0.5 cycles/px) is summed into bands of frequency
along the motion (P) and, identically, across it (Q). Their ratio cancels what the scene gives everywhere, and
its log is fitted by log(sinc^2(L f) + b) + c over L (0-16 px), a floor b (noise and compression fill the nulls)
and a free level c (a scene that is anisotropic at all scales, rows of crops or roads, moves c, not L). The
sinc's nulls and the lobes after them are a signature no ground texture has; a scene whose detail fades
smoothly along the track fits at most L ~ 2 px (the first null beyond Nyquist), hence the limit of ~2 working
pixels (`QualityParams.max_motion_smear_px`). Measured on world 7 session B (640 x 480, working size 400, so
1 full px = 0.625 working px): clean 0.0, linear blur of 3 / 6 / 12 full px 1.75 / 3.5 / 7.5 (expected 1.9 /
3.75 / 7.5).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .geometry import Poses

#: frequency bands (0 - 0.5 cycles/px) of the along / across spectra
_BANDS = 24
_F = (np.arange(_BANDS) + 0.5) / _BANDS * 0.5
#: the smear lengths (working px) and noise floors fitted: 16 px covers a smear that leaves nothing to segment
_LENGTHS = np.arange(0.0, 16.01, 0.25)
_FLOORS = 10.0 ** np.arange(-3.0, 0.01, 0.25)
# the model's log10 attenuation for every (length, floor), normalised to 1 at f = 0: (lengths, floors, bands)
_MODELS = np.log10((np.sinc(_LENGTHS[:, None, None] * _F[None, None, :]) ** 2 + _FLOORS[None, :, None])
                   / (1.0 + _FLOORS[None, :, None]))
# a smear is measured only where its model explains at least half the variance of the along / across log ratio
# that a constant (no smear) leaves: a single step or slope of the ratio (a scene that has less coarse detail along
# the track) otherwise fits the longest smear with the highest floor, a half-depth dip (nu22's clean BIGS flight:
# 4 frames of 17 at 15.75 px, explaining 11-21 %); a linear blur explains 85-95 %
_MIN_EXPLAINED = 0.5
# a frame smaller than this (working px) holds too few bands of each direction to fit
_MIN_SIDE = 32
#: the directions measured per image (`smears_by_angle`), every 180 / ANGLES degrees: the motion's direction comes
#: from the poses, which enter no cache key of the image, so each keyframe's entry holds the smear along every bin
#: and a run with other poses picks another bin, as a fresh run would. 3 degrees: a 16 px smear measured 1.5
#: degrees off its direction moves 0.4 px across it
ANGLES = 60


def motion_directions(poses: Poses) -> np.ndarray:
    """(N, 2) unit image-plane (x right, y down) directions of each camera's motion, from its neighbours' centres
    (central difference; one-sided at the ends); NaN where the camera did not move across its view (a hover,
    a single frame, a vertical climb)."""
    c = np.asarray(poses.centers, np.float64)
    n = len(c)
    out = np.full((n, 2), np.nan)
    for i in range(n):
        j, k = min(i + 1, n - 1), max(i - 1, 0)
        if j == k:
            continue
        d = poses.rotations[i].T @ (c[j] - c[k])  # the motion in the camera's frame
        norm = float(np.hypot(d[0], d[1]))
        if norm > 1e-6 * max(float(np.linalg.norm(d)), 1e-12) and norm > 0:
            out[i] = d[:2] / norm
    return out


def _band_spectra(g: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The windowed power spectrum of `g` summed into `_BANDS` bands of |f| along each of `directions` ((D, 2)
    unit vectors), over the disc |f| <= 0.5, so an isotropic image gives the same bands along every direction.
    Returns (D, bands); the spectrum is taken once (the half plane fx >= 0: a real image's is symmetric)."""
    g = g - g.mean()
    h, w = g.shape
    spec = np.abs(np.fft.rfft2(g * np.outer(np.hanning(h), np.hanning(w)))) ** 2
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    r = np.hypot(fx, fy)
    inside = (r <= 0.5) & (r > 0)
    power = spec[inside]
    fx, fy = np.broadcast_to(fx, r.shape)[inside], np.broadcast_to(fy, r.shape)[inside]
    out = np.empty((len(directions), _BANDS))
    for i, (dx, dy) in enumerate(np.asarray(directions, np.float64)):
        band = np.minimum((np.abs(fx * dx + fy * dy) * (2 * _BANDS)).astype(int), _BANDS - 1)
        out[i] = np.bincount(band, power, _BANDS) / np.maximum(np.bincount(band, None, _BANDS), 1)
    return out


def _fit_smear(p: np.ndarray, q: np.ndarray) -> float:
    """The smear (px) that the along / across band spectra `p`, `q` show; 0 when no smear explains enough of
    their ratio, NaN when a band holds no power."""
    if not (np.all(p > 0) and np.all(q > 0)):
        return float("nan")
    y = np.log10(p / q)
    resid = y[None, None, :] - _MODELS
    err = ((resid - resid.mean(axis=2, keepdims=True)) ** 2).mean(axis=2)
    li, _ = np.unravel_index(int(np.argmin(err)), err.shape)
    if err[li].min() > (1.0 - _MIN_EXPLAINED) * err[0].min():
        return 0.0
    return float(_LENGTHS[li])


def angle_directions() -> np.ndarray:
    """(`ANGLES`, 2) the unit image-plane directions (x right, y down) at which `smears_by_angle` measures: bin i
    is i * 180 / `ANGLES` degrees from the image's x axis (a smear has no sign, so half a turn covers all)."""
    a = np.deg2rad(np.arange(ANGLES) * 180.0 / ANGLES)
    return np.stack([np.cos(a), np.sin(a)], axis=1)


def smears_by_angle(gray: np.ndarray, max_side: int) -> np.ndarray:
    """(`ANGLES`,) the smear (working px) of an 8-bit grey image along each direction of `angle_directions`, at the
    working size `max_side` (area downscale); all NaN when the frame is too small or without contrast.

    What depends on the image alone, so that a keyframe's cache entry holds it whatever the poses say:
    `smear_along` picks the direction of the camera's motion from it."""
    import cv2

    g = np.asarray(gray, np.float32)
    scale = max_side / max(g.shape[:2])
    if scale < 1.0:
        g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    if min(g.shape[:2]) < _MIN_SIDE or float(g.std()) < 1e-3:
        return np.full(ANGLES, np.nan)
    # the bins are half a turn: the one across bin i is bin i + ANGLES / 2
    p = _band_spectra(g.astype(np.float64), angle_directions())
    return np.array([_fit_smear(p[i], p[(i + ANGLES // 2) % ANGLES]) for i in range(ANGLES)])


def smear_along(by_angle: np.ndarray, direction: np.ndarray | None) -> float:
    """The smear (working px) along `direction` (unit image-plane vector of the camera's motion,
    `motion_directions`) from a keyframe's `smears_by_angle`: the nearest angle bin's; NaN when the direction is
    unknown or the image was not measured."""
    by_angle = np.asarray(by_angle, np.float64).reshape(-1)
    if direction is None or not np.all(np.isfinite(direction)) or len(by_angle) != ANGLES:
        return float("nan")
    deg = float(np.degrees(np.arctan2(direction[1], direction[0]))) % 180.0
    return float(by_angle[int(np.floor(deg / (180.0 / ANGLES) + 0.5)) % ANGLES])


def motion_smear(gray: np.ndarray, max_side: int, direction: np.ndarray | None) -> float:
    """The smear (working px) of an 8-bit grey image along `direction` (unit image-plane vector of the camera's
    motion, `motion_directions`), at the working size `max_side` (area downscale), measured along the nearest
    angle bin (`smears_by_angle`); NaN when the direction is unknown, the frame too small or without contrast."""
    if direction is None or not np.all(np.isfinite(direction)):
        return float("nan")
    return smear_along(smears_by_angle(gray, max_side), direction)


def flight_smear(smears: np.ndarray) -> float:
    """The flight's smear: the median over the keyframes measured (NaN without any). A median, because frames
    at the ends of a pass (turning, braking) are slower or measured along the wrong direction."""
    s = np.asarray(smears, np.float64)
    s = s[np.isfinite(s)]
    return float(np.median(s)) if len(s) else float("nan")


def exposure_smear(centers: np.ndarray, times: Sequence[float | None], exposures: Sequence[float | None],
                   ground_px_m: float) -> float:
    """The smear (working px) the shutter predicts: per image, its speed (the distance between its neighbours'
    centres, metres, over the time between their captures) times its exposure (EXIF ExposureTime, s) over the
    ground one working pixel covers (`ground_px_m`, m); the flight's median, NaN where no image has both.

    Physical evidence beside the spectrum's measure (`motion_smear`): a fixed camera moving at v for the exposure
    t smears the ground by v t, and the two agreeing make a smear certain (Seneca: ~7 m/s x 1/320 s over 0.3 m:
    0.1 px)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    t = np.array([np.nan if v is None else float(v) for v in times])
    e = np.array([np.nan if v is None else float(v) for v in exposures])
    if len(c) < 2 or not (np.isfinite(ground_px_m) and ground_px_m > 0):
        return float("nan")
    nxt, prv = np.minimum(np.arange(len(c)) + 1, len(c) - 1), np.maximum(np.arange(len(c)) - 1, 0)
    dt = t[nxt] - t[prv]
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.where(dt > 0, np.linalg.norm(c[nxt] - c[prv], axis=1) / dt, np.nan)
    px = speed * e / ground_px_m
    px = px[np.isfinite(px)]
    return float(np.median(px)) if len(px) else float("nan")
