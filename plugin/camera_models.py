"""COLMAP's camera models in numpy: projection of normalised camera coordinates to pixels and back.

Every perspective model of COLMAP 4.x (`src/colmap/sensor/models.h`) maps a camera-frame point (u, v, w) with
w > 0 to pixels in three steps: normalise (u/w, v/w); optionally bend the ray to the fisheye plane (theta = atan r,
the equidistant projection: `_fisheye_from_normal`); add the model's distortion (du, dv) to that plane; scale by
the focal length(s) and shift by the principal point. The inverse (`cam_from_img`) solves the distortion by the
same damped Newton iteration COLMAP uses (100 iterations, trust region 0.1, stop at a step below 1e-5) and
returns NaN where it fails, so results agree with `pycolmap.Camera.img_from_cam / cam_from_img` to rounding
(tests/test_camera_models.py checks every model). FOV, the division models and EUCM have closed forms both ways.

The spherical EQUIRECTANGULAR model has no focal length or image plane; it is listed so that readers can name it
in their refusal, but it has no `CameraModel` entry here (a 360 degree panorama is not a survey camera).

Parameter order is COLMAP's: focal length(s) (`f` or `fx, fy`), principal point (`cx, cy`), extra parameters.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

Array = np.ndarray
# (u, v, extra) -> (du, dv): COLMAP's additive `Distortion` on the (fisheye-bent) normalised plane
DistortionFn = Callable[[Array, Array, tuple[float, ...]], tuple[Array, Array]]
# (u, v, extra) -> (x, y): a closed-form map between the normalised plane and the focal-scaled image plane
PlaneMapFn = Callable[[Array, Array, tuple[float, ...]], tuple[Array, Array]]


@dataclass(frozen=True)
class CameraModel:
    """One COLMAP camera model: its name and id, its parameter layout, and how it bends rays."""

    name: str
    model_id: int
    num_focal: int  # 1: f shared by both axes; 2: fx, fy
    extra_names: tuple[str, ...]
    fisheye: bool = False  # the equidistant theta = atan(r) bend comes before the distortion
    distortion: DistortionFn | None = None  # additive; inverted by Newton's method
    forward: PlaneMapFn | None = None  # closed form, replaces the additive distortion (FOV, division, EUCM)
    inverse: PlaneMapFn | None = None

    @property
    def param_names(self) -> tuple[str, ...]:
        focal = ("f",) if self.num_focal == 1 else ("fx", "fy")
        return focal + ("cx", "cy") + self.extra_names

    @property
    def num_params(self) -> int:
        return self.num_focal + 2 + len(self.extra_names)

    def is_identity(self, extra: tuple[float, ...]) -> bool:
        """True when these extra parameters make the model an ideal pinhole (no fisheye bend, no distortion)."""
        if self.fisheye or self.forward is not None:
            return False
        return all(float(e) == 0.0 for e in extra)


# ---------------------------------------------------------------------------------------------------------------
# Distortion functions (COLMAP models.h, `Distortion` of each model)
# ---------------------------------------------------------------------------------------------------------------
def _radial_tangential(u: Array, v: Array, k1: float, k2: float, p1: float, p2: float) -> tuple[Array, Array]:
    u2, v2, uv = u * u, v * v, u * v
    r2 = u2 + v2
    radial = k1 * r2 + k2 * r2 * r2
    return u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2), v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2)


def _simple_radial(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    radial = e[0] * (u * u + v * v)
    return u * radial, v * radial


def _radial(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    r2 = u * u + v * v
    radial = e[0] * r2 + e[1] * r2 * r2
    return u * radial, v * radial


def _opencv(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    return _radial_tangential(u, v, e[0], e[1], e[2], e[3])


def _opencv_fisheye(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    t2 = u * u + v * v
    radial = e[0] * t2 + e[1] * t2**2 + e[2] * t2**3 + e[3] * t2**4
    return u * radial, v * radial


def _full_opencv(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    k1, k2, p1, p2, k3, k4, k5, k6 = e
    u2, v2, uv = u * u, v * v, u * v
    r2 = u2 + v2
    r4, r6 = r2 * r2, r2 * r2 * r2
    radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6)
    return (u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2) - u,
            v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2) - v)


def _thin_prism_fisheye(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    k1, k2, p1, p2, k3, k4, sx1, sy1 = e
    u2, v2, uv = u * u, v * v, u * v
    r2 = u2 + v2
    radial = k1 * r2 + k2 * r2**2 + k3 * r2**3 + k4 * r2**4
    return (u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2) + sx1 * r2,
            v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2) + sy1 * r2)


def _rad_tan_thin_prism_fisheye(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    radial_coeffs, (p0, p1, s0, s1, s2, s3) = e[:6], e[6:]
    t2 = u * u + v * v
    th_radial = np.ones_like(t2)
    power = np.ones_like(t2)
    for k in radial_coeffs:
        power = power * t2
        th_radial = th_radial + k * power
    x, y = th_radial * u, th_radial * v
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    r4 = r2 * r2
    xd = x + 2.0 * p1 * xy + p0 * (r2 + 2.0 * x2) + s0 * r2 + s1 * r4
    yd = y + 2.0 * p0 * xy + p1 * (r2 + 2.0 * y2) + s2 * r2 + s3 * r4
    return xd - u, yd - v


# ---------------------------------------------------------------------------------------------------------------
# Closed-form models
# ---------------------------------------------------------------------------------------------------------------
_FOV_EPS = 1e-4  # COLMAP's switch to the Taylor expansions


def _fov(u: Array, v: Array, e: tuple[float, ...], inverse: bool) -> tuple[Array, Array]:
    """FOV model: the radius scales by atan(2 r tan(omega / 2)) / (r omega) (`inverse`: tan(r omega) /
    (2 r tan(omega / 2))), with COLMAP's Taylor expansions near omega = 0 and r = 0."""
    omega = e[0]
    r2 = u * u + v * v
    omega2 = omega * omega
    if omega2 < _FOV_EPS:
        factor = omega2 * r2 / 3.0 - omega2 / 12.0 + 1.0  # the same expansion both ways
    else:
        tan_half = np.tan(omega / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.sqrt(r2)
            if inverse:
                exact = np.tan(r * omega) / (r * 2.0 * tan_half)
                taylor = omega * (omega * omega * r2 + 3.0) / (6.0 * tan_half)
            else:
                exact = np.arctan(r * 2.0 * tan_half) / (r * omega)
                taylor = -2.0 * tan_half * (4.0 * r2 * tan_half * tan_half - 3.0) / (3.0 * omega)
        factor = np.where(r2 < _FOV_EPS, taylor, exact)
    return u * factor, v * factor


def _fov_forward(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    return _fov(u, v, e, inverse=False)


def _fov_inverse(x: Array, y: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    return _fov(x, y, e, inverse=True)


def _division_forward(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    k = e[0]
    rho2 = u * u + v * v
    disc = 1.0 - 4.0 * rho2 * k  # w = 1 on the normalised plane
    with np.errstate(invalid="ignore"):
        r = np.where(disc >= 0.0, 2.0 / (1.0 + np.sqrt(np.maximum(disc, 0.0))), np.nan)
    return r * u, r * v


def _division_inverse(x: Array, y: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    denom = 1.0 + e[0] * (x * x + y * y)
    return x / denom, y / denom


def _eucm_forward(u: Array, v: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    alpha, beta = e
    rho2 = beta * (u * u + v * v) + 1.0
    with np.errstate(invalid="ignore"):
        den = alpha * np.sqrt(rho2) + (1.0 - alpha)
    ok = (rho2 >= 0.0) & (den >= np.finfo(float).eps)
    den = np.where(ok, den, np.nan)
    return u / den, v / den


def _eucm_inverse(x: Array, y: Array, e: tuple[float, ...]) -> tuple[Array, Array]:
    alpha, beta = e
    r2 = x * x + y * y
    gamma = 1.0 - alpha
    radicand = 1.0 - (alpha - gamma) * beta * r2
    with np.errstate(invalid="ignore"):
        helper_den = alpha * np.sqrt(radicand) + gamma
        helper = (1.0 - alpha * alpha * beta * r2) / helper_den
    eps = np.finfo(float).eps
    ok = (radicand >= 0.0) & (helper_den >= eps) & (helper >= eps)
    helper = np.where(ok, helper, np.nan)
    return x / helper, y / helper


# ---------------------------------------------------------------------------------------------------------------
# The registry
# ---------------------------------------------------------------------------------------------------------------
_MODELS = (
    CameraModel("SIMPLE_PINHOLE", 0, 1, ()),
    CameraModel("PINHOLE", 1, 2, ()),
    CameraModel("SIMPLE_RADIAL", 2, 1, ("k",), distortion=_simple_radial),
    CameraModel("RADIAL", 3, 1, ("k1", "k2"), distortion=_radial),
    CameraModel("OPENCV", 4, 2, ("k1", "k2", "p1", "p2"), distortion=_opencv),
    CameraModel("OPENCV_FISHEYE", 5, 2, ("k1", "k2", "k3", "k4"), fisheye=True, distortion=_opencv_fisheye),
    CameraModel("FULL_OPENCV", 6, 2, ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), distortion=_full_opencv),
    CameraModel("FOV", 7, 2, ("omega",), forward=_fov_forward, inverse=_fov_inverse),
    CameraModel("SIMPLE_RADIAL_FISHEYE", 8, 1, ("k",), fisheye=True, distortion=_simple_radial),
    CameraModel("RADIAL_FISHEYE", 9, 1, ("k1", "k2"), fisheye=True, distortion=_radial),
    CameraModel("THIN_PRISM_FISHEYE", 10, 2, ("k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1"), fisheye=True,
                distortion=_thin_prism_fisheye),
    CameraModel("RAD_TAN_THIN_PRISM_FISHEYE", 11, 2,
                ("k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3"), fisheye=True,
                distortion=_rad_tan_thin_prism_fisheye),
    CameraModel("SIMPLE_DIVISION", 12, 1, ("k",), forward=_division_forward, inverse=_division_inverse),
    CameraModel("DIVISION", 13, 2, ("k",), forward=_division_forward, inverse=_division_inverse),
    CameraModel("SIMPLE_FISHEYE", 14, 1, (), fisheye=True),
    CameraModel("FISHEYE", 15, 2, (), fisheye=True),
    CameraModel("EUCM", 16, 2, ("alpha", "beta"), forward=_eucm_forward, inverse=_eucm_inverse),
)
CAMERA_MODELS: dict[str, CameraModel] = {m.name: m for m in _MODELS}
SPHERICAL_MODELS = ("EQUIRECTANGULAR",)  # COLMAP models without an image plane (not supported here)


def camera_model(name: str) -> CameraModel:
    """The model called `name` (COLMAP spelling); ValueError naming the known ones otherwise."""
    try:
        return CAMERA_MODELS[name]
    except KeyError:
        if name in SPHERICAL_MODELS:
            raise ValueError(f"camera model {name} is spherical (a 360 degree panorama has no image plane); "
                             "survey mapping needs a perspective or fisheye model") from None
        raise ValueError(f"unknown camera model {name!r} (known: {', '.join(CAMERA_MODELS)})") from None


# ---------------------------------------------------------------------------------------------------------------
# Projection
# ---------------------------------------------------------------------------------------------------------------
def _fisheye_from_normal(u: Array, v: Array) -> tuple[Array, Array]:
    r = np.sqrt(u * u + v * v)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > np.finfo(float).eps, np.arctan(r) / r, 1.0)
    return u * scale, v * scale


def _normal_from_fisheye(uu: Array, vv: Array) -> tuple[Array, Array]:
    theta = np.sqrt(uu * uu + vv * vv)
    t_cos_t = theta * np.cos(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(t_cos_t > np.finfo(float).eps, np.sin(theta) / t_cos_t, 1.0)
    # beyond 90 degrees the ray has no normalised coordinates (COLMAP returns a point mirrored through the centre)
    scale = np.where(theta < np.pi / 2.0, scale, np.nan)
    return uu * scale, vv * scale


_NEWTON_ITERATIONS = 100
_NEWTON_MIN_STEP_SQ = 1e-10
_NEWTON_RADIUS = 0.1
_JACOBIAN_STEP = 1e-7


def _iterative_undistortion(fn: DistortionFn, x0: Array, y0: Array, extra: tuple[float, ...]) -> tuple[Array, Array]:
    """Solve p + d(p) = p0 per point with COLMAP's damped Newton iteration; NaN where it does not converge."""
    x, y = x0.copy(), y0.copy()
    active = np.isfinite(x) & np.isfinite(y)
    done = ~active
    h = _JACOBIAN_STEP
    for _ in range(_NEWTON_ITERATIONS):
        idx = np.flatnonzero(~done)
        if not len(idx):
            break
        xi, yi = x[idx], y[idx]
        du, dv = fn(xi, yi, extra)
        # central differences: the Jacobian only steers the steps, the fixed point is exact
        dxp, dyp = fn(xi + h, yi, extra)
        dxm, dym = fn(xi - h, yi, extra)
        j00 = 1.0 + (dxp - dxm) / (2 * h)
        j10 = (dyp - dym) / (2 * h)
        dxp, dyp = fn(xi, yi + h, extra)
        dxm, dym = fn(xi, yi - h, extra)
        j01 = (dxp - dxm) / (2 * h)
        j11 = 1.0 + (dyp - dym) / (2 * h)
        rx, ry = xi + du - x0[idx], yi + dv - y0[idx]
        det = j00 * j11 - j01 * j10
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = (j11 * rx - j01 * ry) / det
            sy = (-j10 * rx + j00 * ry) / det
        radius_sq = np.maximum((xi * xi + yi * yi) * _NEWTON_RADIUS**2, _NEWTON_RADIUS**2)
        step_sq = sx * sx + sy * sy
        shrink = np.where(step_sq > radius_sq, np.sqrt(radius_sq / np.where(step_sq > 0, step_sq, 1.0)), 1.0)
        sx, sy = sx * shrink, sy * shrink
        x[idx], y[idx] = xi - sx, yi - sy
        converged = (sx * sx + sy * sy) < _NEWTON_MIN_STEP_SQ
        bad = ~np.isfinite(sx) | ~np.isfinite(sy)
        done[idx[converged | bad]] = True
        x[idx[bad]], y[idx[bad]] = np.nan, np.nan
    x[~done], y[~done] = np.nan, np.nan
    return x, y


def _plane_from_normalized(model: CameraModel, extra: tuple[float, ...], u: Array, v: Array) -> tuple[Array, Array]:
    """The model's map from normalised coordinates to the focal-scaled image plane (before focal and centre)."""
    if model.forward is not None:
        return model.forward(u, v, extra)
    x, y = _fisheye_from_normal(u, v) if model.fisheye else (u, v)
    if model.distortion is not None:
        du, dv = model.distortion(x, y, extra)
        x, y = x + du, y + dv
    return x, y


# The fold search runs out to this normalised radius (a ray 89.94 deg off the axis): a lens that turns only beyond
# it turns where no survey camera looks, and is taken as one that never does.
_FOLD_SEARCH_RADIUS = 1e3
_FOLD_SAMPLES = 4000  # radii, log-spaced from 1e-4 to the search radius: 0.3 % apart
_FOLD_DIRECTIONS = 32  # the tangential and thin-prism terms make the turn depend on the direction


@lru_cache(maxsize=256)
def _fold_radius(name: str, extra: tuple[float, ...]) -> float:
    model = CAMERA_MODELS[name]
    if model.is_identity(extra):
        return float("inf")
    angle = np.arange(_FOLD_DIRECTIONS) * (2.0 * np.pi / _FOLD_DIRECTIONS)
    c, s = np.cos(angle), np.sin(angle)

    def keeps_orientation(r: Array, direction: int | None = None) -> Array:
        # the sign of the map's Jacobian determinant at radius r (D, n) along each direction (or (1, n) along
        # `direction`; central differences, relative step): positive while the map is one-to-one there; NaN (no
        # image) is a fold too
        h = np.maximum(r * 1e-6, 1e-9)
        cs, sn = (c, s) if direction is None else (c[direction:direction + 1], s[direction:direction + 1])
        u, v = r * cs[:, None], r * sn[:, None]
        with np.errstate(all="ignore"):
            xp, yp = _plane_from_normalized(model, extra, u + h, v)
            xm, ym = _plane_from_normalized(model, extra, u - h, v)
            xq, yq = _plane_from_normalized(model, extra, u, v + h)
            xn, yn = _plane_from_normalized(model, extra, u, v - h)
            return ((xp - xm) * (yq - yn) - (xq - xn) * (yp - ym)) > 0

    radii = np.geomspace(1e-4, _FOLD_SEARCH_RADIUS, _FOLD_SAMPLES)
    # one direction at a time: all 32 at once held ~20 arrays of 32 x 4000 (18 MB) for a reader of a 91-byte
    # cameras.txt (the readers' bounded-memory fuzz test)
    bad = np.stack([~keeps_orientation(radii[None, :], k)[0] for k in range(len(angle))])
    if not bad.any():
        return float("inf")
    first = np.where(bad.any(1), bad.argmax(1), len(radii) - 1)
    hi = np.where(bad.any(1), radii[first], np.inf)
    lo = np.where(first > 0, radii[np.maximum(first - 1, 0)], 0.0)
    turning = np.isfinite(hi)
    lo, hi = lo[turning], hi[turning]
    c, s = c[turning], s[turning]
    for _ in range(50):  # bisection to the turn along each direction that has one
        mid = 0.5 * (lo + hi)
        ok = keeps_orientation(mid[:, None])[:, 0]
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return float(lo.min())


def fold_radius(model: CameraModel, extra: tuple[float, ...]) -> float:
    """The normalised radius sqrt((X/Z)^2 + (Y/Z)^2) below which the model's projection is one-to-one (inf when it
    never folds within 89.94 deg of the axis).

    A polynomial lens model is a fit over the sensor; beyond it the polynomial turns back (r (1 + k1 r^2) with
    k1 = -0.1 peaks at r = 1.83, 61 deg off the axis) and maps rays far outside the view onto pixels inside the
    image. Found where the Jacobian determinant of the map from normalised coordinates to the image plane first
    stops being positive along any of 32 directions (the tangential and thin-prism terms make it depend on the
    direction), or the model has no image of the point (division, EUCM), then bisected; cached per model and
    parameters. Every projection (`img_from_normalized`) is NaN at and beyond it."""
    return _fold_radius(model.name, tuple(float(e) for e in extra))


def img_from_normalized(model: CameraModel, focal: tuple[float, float], principal: tuple[float, float],
                        extra: tuple[float, ...], u: Array, v: Array) -> tuple[Array, Array]:
    """Pixels (COLMAP convention) of normalised camera coordinates (u, v) = (X/Z, Y/Z); NaN at and beyond the
    model's `fold_radius`, where the lens model has turned back and its pixel is not where the ray lands (COLMAP
    projects there regardless, onto pixels inside the image)."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    x, y = _plane_from_normalized(model, extra, u, v)
    turn = fold_radius(model, extra)
    if np.isfinite(turn):
        with np.errstate(invalid="ignore"):
            folded = ~(u * u + v * v < turn * turn)
        if folded.any():  # copies only where a point lies beyond (single-point calls are many: track fusion)
            x, y = np.where(folded, np.nan, x), np.where(folded, np.nan, y)
    return focal[0] * x + principal[0], focal[1] * y + principal[1]




def normalized_from_img(model: CameraModel, focal: tuple[float, float], principal: tuple[float, float],
                        extra: tuple[float, ...], px: Array, py: Array) -> tuple[Array, Array]:
    """Normalised camera coordinates of pixels; NaN where the model cannot lift the pixel."""
    x = (np.asarray(px, dtype=np.float64) - principal[0]) / focal[0]
    y = (np.asarray(py, dtype=np.float64) - principal[1]) / focal[1]
    if model.inverse is not None:
        return model.inverse(x, y, extra)
    if model.distortion is not None:
        x, y = _iterative_undistortion(model.distortion, x.ravel(), y.ravel(), extra)
    if model.fisheye:
        x, y = _normal_from_fisheye(x, y)
    return x.reshape(np.shape(px)), y.reshape(np.shape(py))
