"""Survey flights: nominal paths, their transforms, the flown (jittered) poses and EKF-like pose estimates.

Paths are sampled every `spacing_m` metres of arc length. The camera looks straight down with the top of the
image pointing along the direction of travel (camera y axis = -forward, z = down, x = y cross z), then the
body's small roll and pitch tilt it. Yaw, roll, pitch, cross-track position and altitude wander as smooth
AR(1) processes drawn from the session seed, so two sessions over the same nominal path have similar but not
identical poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...plugin.geometry import Poses
from .config import FLIGHT_KINDS
from .noise import rng_for

_T_FREEFORM, _T_JITTER, _T_EKF = 11, 12, 13


@dataclass(frozen=True)
class FlightConfig:
    kind: str = "lawnmower"
    frames: int = 100
    spacing_m: float = 7.0
    altitude_m: float = 100.0  # above the mean terrain height of the world
    line_length_m: float = 160.0
    line_spacing_m: float = 30.0
    seed: int = 0  # shape of the free-form path
    shift_m: tuple[float, float] = (0.0, 0.0)
    reverse: bool = False
    rotate_deg: float = 0.0  # counter-clockwise about the path's centre
    attitude_jitter_deg: float = 1.5  # std of roll and pitch
    # the gimbal tilted forward from nadir along the direction of travel (a -60 deg gimbal pitch is 30 here):
    # oblique surveys, where tall objects show their sides and the footprint reaches ahead
    camera_tilt_deg: float = 0.0
    yaw_jitter_deg: float = 1.0
    position_jitter_m: float = 0.5
    altitude_jitter_m: float = 0.5


def _resample(poly: np.ndarray, spacing: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """`count` points every `spacing` m along a polyline (N, 2), with the heading of their segment."""
    seg = np.diff(poly, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    keep = seg_len > 1e-9
    seg, seg_len, starts = seg[keep], seg_len[keep], poly[:-1][keep]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.arange(count) * spacing
    if s[-1] > cum[-1] + 1e-6:
        raise ValueError("path too short for the requested frames")
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    t = (s - cum[idx]) / seg_len[idx]
    pts = starts[idx] + t[:, None] * seg[idx]
    heading = np.arctan2(seg[idx, 1], seg[idx, 0])
    return pts, heading


def _lawnmower(cfg: FlightConfig) -> np.ndarray:
    need = (cfg.frames - 1) * cfg.spacing_m + 1.0
    n_lines = max(1, int(math.ceil(need / (cfg.line_length_m + cfg.line_spacing_m))) + 1)
    pts = []
    for i in range(n_lines):
        x = i * cfg.line_spacing_m
        ys = (0.0, cfg.line_length_m) if i % 2 == 0 else (cfg.line_length_m, 0.0)
        pts += [(x, ys[0]), (x, ys[1])]
    return np.array(pts)


def _freeform(cfg: FlightConfig) -> np.ndarray:
    """A smooth wandering closed-ish curve (two sinusoids per axis), long enough for the frames."""
    rng = rng_for(_T_FREEFORM, cfg.seed)
    fx = rng.uniform(0.8, 1.3, 2) * np.array([1.0, 2.0 + rng.integers(0, 2)])
    fy = rng.uniform(0.8, 1.3, 2) * np.array([1.0, 2.0 + rng.integers(0, 2)])
    ph = rng.uniform(0, 2 * np.pi, 4)
    amp = np.array([90.0, 35.0])
    need = (cfg.frames - 1) * cfg.spacing_m + 1.0
    s_max = 2 * np.pi
    while True:
        s = np.linspace(0, s_max, int(s_max * 400))
        x = amp[0] * np.sin(fx[0] * s + ph[0]) + amp[1] * np.sin(fx[1] * s + ph[1])
        y = amp[0] * np.sin(fy[0] * s + ph[2]) + amp[1] * np.sin(fy[1] * s + ph[3])
        poly = np.stack([x, y], 1)
        if np.linalg.norm(np.diff(poly, axis=0), axis=1).sum() >= need:
            return poly
        s_max *= 1.5


def nominal_path(cfg: FlightConfig, center_xy: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Frame positions (N, 2) and headings (N,) (radians, counter-clockwise from +x) of the nominal path,
    centred on `center_xy`, then rotated, shifted and reversed as configured."""
    if cfg.kind not in FLIGHT_KINDS:
        raise ValueError(f"unknown flight {cfg.kind!r}")
    poly = _lawnmower(cfg) if cfg.kind == "lawnmower" else _freeform(cfg)
    pts, heading = _resample(poly, cfg.spacing_m, cfg.frames)
    mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    a = math.radians(cfg.rotate_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    pts = (pts - mid) @ rot.T + np.asarray(center_xy) + np.asarray(cfg.shift_m, dtype=np.float64)
    heading = heading + a
    if cfg.reverse:
        pts, heading = pts[::-1].copy(), heading[::-1] + math.pi
    return pts, np.arctan2(np.sin(heading), np.cos(heading))


def flight_line_ids(cfg: FlightConfig) -> np.ndarray:
    """Per frame, the flight line it was taken on, numbered in the order flown (0, 1, ...); -1 on the short
    crossings between lawnmower lines and everywhere on a free-form path, which has no lines."""
    frames = np.full(cfg.frames, -1, dtype=np.int64)
    if cfg.kind != "lawnmower":
        return frames
    poly = _lawnmower(cfg)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    seg = np.clip(np.searchsorted(cum, np.arange(cfg.frames) * cfg.spacing_m, side="right") - 1, 0, len(poly) - 2)
    frames = np.where(seg % 2 == 0, seg // 2, -1)  # segments alternate: line, crossing, line, ...
    if cfg.reverse:
        frames = frames[::-1]
        lines = frames >= 0
        frames[lines] = frames[lines].max() - frames[lines]
    return frames


def _ar1(rng: np.random.Generator, n: int, sigma: float, rho: float = 0.85, dims: int = 1) -> np.ndarray:
    """A smooth stationary AR(1) sequence with standard deviation `sigma`."""
    out = np.zeros((n, dims))
    state = rng.normal(0, sigma, dims)
    innov = sigma * math.sqrt(1 - rho * rho)
    for i in range(n):
        out[i] = state
        state = rho * state + rng.normal(0, innov, dims)
    return out if dims > 1 else out[:, 0]


def camera_rotation(heading: float, roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """world_from_camera rotation of a nadir camera whose image top points along `heading` (rad), tilted by
    body roll (about the direction of travel) and pitch (about the cross-track axis), radians."""
    f = np.array([math.cos(heading), math.sin(heading), 0.0])
    y = -f
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    base = np.stack([x, y, z], axis=1)  # columns: camera axes in the world
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    roll_m = np.array([[cr, 0, sr], [0, 1, 0], [-sr, 0, cr]])  # about camera y (= along track)
    pitch_m = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])  # about camera x (= cross track)
    return base @ roll_m @ pitch_m


def flight_poses(cfg: FlightConfig, center_xy: tuple[float, float], ground_z: float, session_seed: int,
                 world_seed: int) -> Poses:
    """The poses actually flown: the nominal path with smooth attitude, position and altitude wander."""
    pts, heading = nominal_path(cfg, center_xy)
    n = len(pts)
    rng = rng_for(_T_JITTER, world_seed, session_seed)
    d2r = math.pi / 180.0
    yaw = heading + _ar1(rng, n, cfg.yaw_jitter_deg * d2r)
    roll = _ar1(rng, n, cfg.attitude_jitter_deg * d2r)
    pitch = _ar1(rng, n, cfg.attitude_jitter_deg * d2r) + cfg.camera_tilt_deg * d2r
    wander = _ar1(rng, n, cfg.position_jitter_m, dims=2)
    alt = _ar1(rng, n, cfg.altitude_jitter_m)
    centers = np.column_stack([pts + wander, np.full(n, ground_z + cfg.altitude_m) + alt])
    rotations = np.stack([camera_rotation(yaw[i], roll[i], pitch[i]) for i in range(n)])
    return Poses([f"frame_{i:05d}.jpg" for i in range(n)], rotations, centers)


@dataclass(frozen=True)
class EkfNoise:
    """Navigation-filter-like errors: white noise plus a random-walk drift growing with distance flown."""

    position_sigma_m: float = 0.3
    attitude_sigma_deg: float = 0.3
    drift_m_per_sqrt_m: float = 0.05  # position random walk: std grows as drift * sqrt(distance)
    attitude_drift_deg_per_sqrt_m: float = 0.01


def _small_rotation(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (radians), Rodrigues."""
    theta = float(np.linalg.norm(v))
    if theta < 1e-12:
        return np.eye(3)
    k = v / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * kx + (1 - math.cos(theta)) * kx @ kx


def ekf_poses(truth: Poses, noise: EkfNoise, session_seed: int, world_seed: int) -> Poses:
    """`truth` with EKF-like noise (the same seed always gives the same noise)."""
    rng = rng_for(_T_EKF, world_seed, session_seed)
    n = len(truth)
    steps = np.concatenate([[0.0], np.linalg.norm(np.diff(truth.centers, axis=0), axis=1)])
    d2r = math.pi / 180.0
    drift = np.cumsum(rng.normal(0, 1, (n, 3)) * np.sqrt(steps)[:, None], axis=0) * noise.drift_m_per_sqrt_m
    drift[:, 2] *= 0.5  # barometric altitude drifts less than horizontal position
    centers = truth.centers + drift + rng.normal(0, noise.position_sigma_m, (n, 3))
    att_drift = np.cumsum(rng.normal(0, 1, (n, 3)) * np.sqrt(steps)[:, None], axis=0)
    att_drift *= noise.attitude_drift_deg_per_sqrt_m * d2r
    att = att_drift + rng.normal(0, noise.attitude_sigma_deg * d2r, (n, 3))
    rotations = np.stack([_small_rotation(att[i]) @ truth.rotations[i] for i in range(n)])
    return Poses(list(truth.names), rotations, centers)
