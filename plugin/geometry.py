"""Cameras, poses and projection: the small shared geometry vocabulary (pure numpy).

Conventions (docs/ARCHITECTURE.md): world z up, metres; camera axes x right, y down, z forward; pixels in the
COLMAP convention (centre of the top-left pixel at (0.5, 0.5)); quaternions as (w, x, y, z).
`Poses` stores world_from_camera rotations and camera centres; COLMAP's cam_from_world is derived.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Camera:
    """A pinhole camera (COLMAP PINHOLE; SIMPLE_PINHOLE reads into it with fx == fy)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (the usual name)
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by `factor` (COLMAP convention keeps cx = factor * cx)."""
        return Camera(
            round(self.width * factor), round(self.height * factor),
            self.fx * factor, self.fy * factor, self.cx * factor, self.cy * factor,
        )


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:  # noqa: N803
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (w, x, y, z) with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    t = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of 4w^2, 4x^2, 4y^2, 4z^2 for numerical stability.
    cand = np.stack([t, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    k = np.argmax(cand, axis=1)
    q = np.empty((len(m), 4))
    for i in range(len(m)):
        r = m[i]
        if k[i] == 0:
            s = 2.0 * np.sqrt(1.0 + t[i])
            q[i] = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif k[i] == 1:
            s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q[i] = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif k[i] == 2:
            s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            q[i] = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            q[i] = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray | float:
    """Geodesic angle (degrees) between rotations r_a and r_b: (3,3) pairs give a float, (N,3,3) stacks an array."""
    r_a = np.asarray(r_a, dtype=np.float64)
    r_b = np.asarray(r_b, dtype=np.float64)
    trace = np.einsum("...ij,...ij->...", r_a, r_b)  # = trace(r_a r_b^T)
    angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle) if angle.ndim == 0 else angle


@dataclass
class Poses:
    """Camera poses of a session: names, world_from_camera rotations (N,3,3), camera centres (N,3)."""

    names: list[str]
    rotations: np.ndarray
    centers: np.ndarray

    def __post_init__(self) -> None:
        self.rotations = np.asarray(self.rotations, dtype=np.float64).reshape(-1, 3, 3)
        self.centers = np.asarray(self.centers, dtype=np.float64).reshape(-1, 3)
        if not (len(self.names) == len(self.rotations) == len(self.centers)):
            raise ValueError("names, rotations and centers must have the same length")

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, indices: np.ndarray | list[int]) -> Poses:
        idx = np.asarray(indices, dtype=int)
        return Poses([self.names[i] for i in idx], self.rotations[idx], self.centers[idx])

    def cam_from_world(self) -> tuple[np.ndarray, np.ndarray]:
        """COLMAP's pose: (R_cw (N,3,3), t_cw (N,3)) with x_cam = R_cw x_world + t_cw."""
        r_cw = np.transpose(self.rotations, (0, 2, 1))
        t_cw = -np.einsum("nij,nj->ni", r_cw, self.centers)
        return r_cw, t_cw

    @classmethod
    def from_cam_from_world(cls, names: list[str], r_cw: np.ndarray, t_cw: np.ndarray) -> Poses:
        r_wc = np.transpose(np.asarray(r_cw, dtype=np.float64), (0, 2, 1))
        centers = -np.einsum("nij,nj->ni", r_wc, np.asarray(t_cw, dtype=np.float64))
        return cls(list(names), r_wc, centers)


def project(camera: Camera, r_wc: np.ndarray, center: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (M,3) into one camera; returns pixels (M,2) (COLMAP convention) and depths (M,)."""
    p_cam = (np.asarray(points, dtype=np.float64) - center) @ r_wc  # = R_wc^T (X - C)
    depth = p_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack(
            [camera.fx * p_cam[:, 0] / depth + camera.cx, camera.fy * p_cam[:, 1] / depth + camera.cy], 1
        )
    return uv, depth


def pixel_rays(camera: Camera, uv: np.ndarray, r_wc: np.ndarray) -> np.ndarray:
    """World-frame ray directions (M,3), not normalised, with unit camera depth, through pixels uv (M,2)."""
    uv = np.asarray(uv, dtype=np.float64)
    d_cam = np.stack([(uv[:, 0] - camera.cx) / camera.fx, (uv[:, 1] - camera.cy) / camera.fy, np.ones(len(uv))], 1)
    return d_cam @ r_wc.T
