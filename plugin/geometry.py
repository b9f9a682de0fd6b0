"""Cameras, poses and projection: the small shared geometry vocabulary (pure numpy).

Conventions (docs/ARCHITECTURE.md): world z up, metres; camera axes x right, y down, z forward; pixels in the
COLMAP convention (centre of the top-left pixel at (0.5, 0.5)); quaternions as (w, x, y, z).
`Poses` stores world_from_camera rotations and camera centres; COLMAP's cam_from_world is derived.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .camera_models import camera_model, fold_radius, img_from_normalized, normalized_from_img


@dataclass(frozen=True)
class Camera:
    """A camera of any COLMAP perspective or fisheye model (`plugin.camera_models`); PINHOLE by default.

    `fx, fy, cx, cy` are the model's focal lengths and principal point (fx == fy for the one-focal SIMPLE_* /
    RADIAL* / *DIVISION / SIMPLE_FISHEYE models) and `extra` its distortion parameters in COLMAP's order, so
    `params` is COLMAP's parameter list. `pinhole()` is the ideal camera with the same K: distortion-free
    ("undistorted") pixels, `undistort_points`, live in it, and the pinhole math of tracking and the gates runs
    there, while the COLMAP database and model keep this camera and the real, distorted keypoints.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "PINHOLE"
    extra: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        spec = camera_model(self.model)
        extra = tuple(float(e) for e in self.extra)
        object.__setattr__(self, "extra", extra)
        if len(extra) != len(spec.extra_names):
            raise ValueError(f"camera model {self.model} takes {len(spec.extra_names)} extra parameter(s) "
                             f"({', '.join(spec.extra_names) or 'none'}), got {len(extra)}")
        if spec.num_focal == 1 and self.fx != self.fy:
            raise ValueError(f"camera model {self.model} has one focal length, got fx={self.fx} fy={self.fy}")

    @classmethod
    def from_colmap(cls, model: str, width: int, height: int, params: Sequence[float]) -> Camera:
        """From COLMAP's model name and parameter list (ValueError on an unknown model or a wrong count)."""
        spec = camera_model(model)
        p = [float(v) for v in params]
        if len(p) != spec.num_params:
            raise ValueError(f"camera model {model} takes {spec.num_params} parameters "
                             f"({', '.join(spec.param_names)}), got {len(p)}")
        if spec.num_focal == 1:
            fx = fy = p[0]
        else:
            fx, fy = p[0], p[1]
        cx, cy = p[spec.num_focal], p[spec.num_focal + 1]
        return cls(int(width), int(height), fx, fy, cx, cy, model, tuple(p[spec.num_focal + 2:]))

    @property
    def params(self) -> list[float]:
        """COLMAP's parameter list of this model."""
        focal = [self.fx] if camera_model(self.model).num_focal == 1 else [self.fx, self.fy]
        return [float(v) for v in focal + [self.cx, self.cy, *self.extra]]

    @property
    def is_pinhole(self) -> bool:
        """True when pixels are ideal pinhole pixels (PINHOLE, SIMPLE_PINHOLE, or a model with zero distortion)."""
        return camera_model(self.model).is_identity(self.extra)

    def lens_folds(self) -> bool:
        """True when the distortion folds the image over: some pixel inside the sensor does not lift to one ray
        and back, or lifts beyond the radius where the lens model turns back (`camera_models.fold_radius`; a
        strong negative k1: 480x360, f 377, k -0.6). Judged for the additive radial-tangential models only
        (SIMPLE_RADIAL .. FULL_OPENCV); the fisheye and closed-form models (FOV, division, EUCM) are taken as
        given."""
        spec = camera_model(self.model)
        if self.is_pinhole or spec.fisheye or spec.forward is not None:
            return False
        t = np.linspace(0.0, 1.0, 33)
        grid = np.stack(np.meshgrid(t * self.width, t * self.height), -1).reshape(-1, 2)
        with np.errstate(all="ignore"):
            normal = self.cam_from_img(grid)
            # NaN: no lift, or a lift beyond the turn (`img_from_cam` has no pixel there)
            if not np.all(np.abs(self.img_from_cam(normal) - grid) <= 1e-3):
                return True
        return bool(np.hypot(normal[:, 0], normal[:, 1]).max() >= self.fold_radius)

    @property
    def fold_radius(self) -> float:
        """The normalised radius from the axis where the lens model turns back (`camera_models.fold_radius`):
        world points beyond it have no pixel (`img_from_cam` gives NaN). inf for a pinhole."""
        return fold_radius(camera_model(self.model), self.extra)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (the usual name)
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def pinhole(self) -> Camera:
        """The ideal PINHOLE camera with this camera's size, focal lengths and principal point."""
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by `factor`: `resized` to the rounded size, as COLMAP's
        `Camera::Rescale(scale)`."""
        return self.resized(round(self.width * factor), round(self.height * factor))

    def resized(self, width: int, height: int) -> Camera:
        """The same camera for the image resized to `width` x `height`, as COLMAP's `Camera::Rescale`: focal
        lengths and principal point scale with their axis (pixels in COLMAP's convention, where the image spans
        0..width, so cx scales as it is; a one-focal model's f by the mean of the two scales); the distortion
        parameters act on normalised coordinates in every model (`plugin.camera_models`) and stay."""
        sx, sy = width / self.width, height / self.height
        fx, fy = (self.fx * sx, self.fy * sy) if camera_model(self.model).num_focal == 2 else \
            (self.fx * (sx + sy) / 2.0,) * 2
        return Camera(int(width), int(height), fx, fy, self.cx * sx, self.cy * sy, self.model, self.extra)

    def cropped(self, left: float, top: float, width: int, height: int) -> Camera:
        """The camera of the `width` x `height` crop whose top-left corner is at pixel (left, top)."""
        return Camera(int(width), int(height), self.fx, self.fy, self.cx - left, self.cy - top, self.model,
                      self.extra)

    def img_from_cam(self, points: np.ndarray) -> np.ndarray:
        """Pixels (M, 2) of camera-frame points (M, 3), or of normalised coordinates (M, 2) = (X/Z, Y/Z)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1] == 3:
            with np.errstate(divide="ignore", invalid="ignore"):
                p = p[..., :2] / p[..., 2:3]
        u, v = img_from_normalized(camera_model(self.model), (self.fx, self.fy), (self.cx, self.cy), self.extra,
                                   p[..., 0], p[..., 1])
        return np.stack([u, v], -1)

    def cam_from_img(self, uv: np.ndarray) -> np.ndarray:
        """Normalised camera coordinates (M, 2) of pixels (M, 2); NaN where the model cannot lift a pixel."""
        uv = np.asarray(uv, dtype=np.float64)
        u, v = normalized_from_img(camera_model(self.model), (self.fx, self.fy), (self.cx, self.cy), self.extra,
                                   uv[..., 0], uv[..., 1])
        return np.stack([u, v], -1)

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Pixels of `pinhole()` seeing the same rays as pixels `uv` (M, 2) of this camera (a copy if pinhole)."""
        uv = np.array(uv, dtype=np.float64)
        if self.is_pinhole or not uv.size:
            return uv
        return self.pinhole().img_from_cam(self.cam_from_img(uv))

    def distort_points(self, uv: np.ndarray) -> np.ndarray:
        """Inverse of `undistort_points`: pixels of this camera for pixels `uv` (M, 2) of `pinhole()`."""
        uv = np.array(uv, dtype=np.float64)
        if self.is_pinhole or not uv.size:
            return uv
        return self.img_from_cam(self.pinhole().cam_from_img(uv))

    def undistortion_jacobians(self, uv: np.ndarray, step_px: float = 0.5) -> np.ndarray:
        """(M, 2, 2) Jacobians of `undistort_points` at pixels `uv` (central differences, `step_px` apart)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.is_pinhole:
            return np.broadcast_to(np.eye(2), (len(uv), 2, 2)).copy()
        offsets = np.array([[step_px, 0.0], [-step_px, 0.0], [0.0, step_px], [0.0, -step_px]])
        moved = self.undistort_points((uv[:, None, :] + offsets[None]).reshape(-1, 2)).reshape(-1, 4, 2)
        d_dx = (moved[:, 0] - moved[:, 1]) / (2.0 * step_px)
        d_dy = (moved[:, 2] - moved[:, 3]) / (2.0 * step_px)
        return np.stack([d_dx, d_dy], axis=-1)

    def undistort_covariances(self, uv: np.ndarray, covariances: np.ndarray) -> np.ndarray:
        """Pixel covariances (M, 2, 2) at pixels `uv` carried into `pinhole()` to first order: J Sigma J^T."""
        cov = np.asarray(covariances, dtype=np.float64).reshape(-1, 2, 2)
        if self.is_pinhole:
            return cov.copy()
        jac = self.undistortion_jacobians(uv)
        return np.einsum("kij,kjl,kml->kim", jac, cov, jac)


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
    """Project world points (M,3) into one camera (through its lens model); returns pixels (M,2) (COLMAP convention)
    and depths (M,)."""
    p_cam = (np.asarray(points, dtype=np.float64) - center) @ r_wc  # = R_wc^T (X - C)
    depth = p_cam[:, 2]
    if not camera.is_pinhole:
        return camera.img_from_cam(p_cam), depth
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack(
            [camera.fx * p_cam[:, 0] / depth + camera.cx, camera.fy * p_cam[:, 1] / depth + camera.cy], 1
        )
    return uv, depth


def pixel_rays(camera: Camera, uv: np.ndarray, r_wc: np.ndarray) -> np.ndarray:
    """World-frame ray directions (M,3), not normalised, with unit camera depth, through pixels uv (M,2) of `camera`
    (through its lens model)."""
    uv = np.asarray(uv, dtype=np.float64)
    if camera.is_pinhole:
        d_cam = np.stack([(uv[:, 0] - camera.cx) / camera.fx, (uv[:, 1] - camera.cy) / camera.fy, np.ones(len(uv))], 1)
    else:  # through the lens model; NaN rows where it cannot lift the pixel
        d_cam = np.concatenate([camera.cam_from_img(uv).reshape(-1, 2), np.ones((len(uv), 1))], 1)
    return d_cam @ r_wc.T


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues, vectorised: (N,3) rotation vectors -> (N,3,3)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = np.where(small[:, None], 0.0, w / np.where(small, 1.0, theta)[:, None])
    kx = np.zeros((len(w), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    kx[:, 1, 2], kx[:, 2, 0], kx[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3)[None] + s * kx + (1 - c) * (kx @ kx)


def skew(v: np.ndarray) -> np.ndarray:
    """(N,3) -> (N,3,3) cross-product matrices [v]x."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 0] = -v[..., 2], v[..., 1], v[..., 2]
    out[..., 1, 2], out[..., 2, 0], out[..., 2, 1] = -v[..., 0], -v[..., 1], v[..., 0]
    return out


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """(N,3,3) -> (N,3) rotation vectors (angles below pi, which is all the priors need)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def hull_area(xy: np.ndarray) -> float:
    """The area of the convex hull of (N, 2) points, in their units squared (0 for fewer than 3 points or points
    on one line)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(xy, np.float64).reshape(-1, 2)
    if len(pts) < 3:
        return 0.0
    try:
        return float(ConvexHull(pts).volume)  # 2D: volume is the area
    except QhullError:
        return 0.0


# Two recorded camera positions closer than this (pose units: metres for georeferenced or GPS-checked poses) are
# one position, differing by rounding alone. A float's rounding of coordinates as large as UTM or Earth-centred
# ones is ~1e-9 m (one ulp below 1.7e7 m is at most 1.9e-9 m; a conversion such as ECEF -> UTM or a quaternion
# round trip a few ulps), three orders below; the finest position a survey records (an RTK fix to a millimetre, an
# EXIF GPS rational to ~1 cm) and any baseline a pair can map from are three orders above or more. Not the
# receiver's jitter (centimetres to metres): a hover's positions that differ by its noise are distinct recorded
# positions (their pairs' direction is not judged, `pose_check.PairCheck.sees_direction`), and with a jitter-sized
# tolerance a slow flight's consecutive frames would be one position. In feet, or in the units of an unscaled
# reconstruction (extent ~1), the margins hold within a factor of a few hundred.
SAME_POSITION = 1e-6


def position_groups(centers: np.ndarray, tol: float = SAME_POSITION) -> list[list[int]]:
    """The recorded positions (N, D) grouped into one per place: indices in order, each group the positions within
    `tol` (Euclidean) of its first, groups in order of their first index (singletons included; a non-finite
    position is its own group). Linear time: a grid of `tol` cells, each position compared with the groups whose
    first lies in the 3^D cells around it."""
    c = np.asarray(centers, np.float64)
    c = c.reshape(len(c), -1)
    groups: list[list[int]] = []
    firsts: dict[tuple[int, ...], list[int]] = {}  # grid cell -> the groups whose first position lies in it
    around = np.stack(np.meshgrid(*[[-1, 0, 1]] * c.shape[1], indexing="ij"), -1).reshape(-1, c.shape[1])
    for i, p in enumerate(c):
        if not np.all(np.isfinite(p)):
            groups.append([i])
            continue
        cell = np.floor(p / tol).astype(np.int64)
        found = None
        for d in around:
            for g in firsts.get(tuple((cell + d).tolist()), []):
                if np.linalg.norm(c[groups[g][0]] - p) <= tol and (found is None or g < found):
                    found = g
        if found is None:
            firsts.setdefault(tuple(cell.tolist()), []).append(len(groups))
            groups.append([i])
        else:
            groups[found].append(i)
    return groups
