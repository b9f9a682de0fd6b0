"""Least-squares rigid / similarity transform between associated landmarks (Arun 1987, Umeyama 1991).

Convention: the transform maps map B into map A's frame, x_A = s R x_B + t (A_from_B). World z is up and
gravity-aligned in both maps, so a correct R is (nearly) a yaw; its tilt (angle between R e_z and e_z) is the
roll/pitch difference SOS-Match checks against theta_alpha.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import rotation_angle_deg  # noqa: F401 (the association API re-exports it)


@dataclass(frozen=True)
class Transform:
    rotation: np.ndarray  # (3, 3), det +1
    translation: np.ndarray  # (3,)
    scale: float = 1.0

    def apply(self, points: np.ndarray) -> np.ndarray:
        """x_A = s R x_B + t for rows of `points`."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def to_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix of the transform."""
        t = np.eye(4)
        t[:3, :3] = self.scale * self.rotation
        t[:3, 3] = self.translation
        return t


def fit_transform(src: np.ndarray, dst: np.ndarray, similarity: bool = False) -> Transform:
    """Least-squares `dst ~ s R src + t` (s = 1 unless `similarity`). Raises InputError on degenerate input.

    Degenerate: fewer than 3 points, non-finite values, or points (nearly) on one line in either set, where
    the rotation about that line is unobservable.
    """
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst):
        raise InputError(f"transform fit needs equally many points, got {len(src)} and {len(dst)}")
    if len(src) < 3:
        raise InputError(f"transform fit needs at least 3 associations, got {len(src)}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise InputError("transform fit got NaN or infinite coordinates")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    for x in (xs, xd):
        ev = np.linalg.eigvalsh(x.T @ x)  # squared singular values, ascending (3x3: cheaper than an n x 3 SVD)
        if ev[2] <= 0 or ev[1] < 1e-12 * ev[2]:
            raise InputError("associated landmarks are colinear or coincident: the rotation is not determined")
    cov = xd.T @ xs / len(src)
    u, s, vt = np.linalg.svd(cov)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    r = u @ fix @ vt
    scale = 1.0
    if similarity:
        var_s = (xs * xs).sum() / len(src)
        scale = float(np.trace(np.diag(s) @ fix) / var_s)
    t = mu_d - scale * r @ mu_s
    return Transform(r, t, scale)


def tilts_deg(rotations: np.ndarray) -> np.ndarray:
    """`tilt_deg` of every rotation of a (..., 3, 3) stack (the same ufuncs element by element: the same floats)."""
    return np.degrees(np.arccos(np.clip(rotations[..., 2, 2], -1.0, 1.0)))


def tilt_deg(rotation: np.ndarray) -> float:
    """Angle (degrees) between R e_z and e_z: the roll/pitch part of the rotation, independent of yaw."""
    return float(tilts_deg(rotation))


def rolls_pitches_deg(rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (`roll_pitch_yaw_deg`) of every rotation of a (..., 3, 3) stack, in degrees."""
    r = rotations
    return (np.degrees(np.arctan2(r[..., 2, 1], r[..., 2, 2])),
            np.degrees(np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))))


def roll_pitch_yaw_deg(rotation: np.ndarray) -> tuple[float, float, float]:
    """Aerospace angles of R = Rz(yaw) Ry(pitch) Rx(roll), in degrees."""
    roll, pitch = rolls_pitches_deg(rotation)
    yaw = np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0]))
    return float(roll), float(pitch), float(yaw)


def rotation_from_rpy_deg(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from degrees (inverse of `roll_pitch_yaw_deg`)."""
    a, b, c = np.radians([roll, pitch, yaw])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


