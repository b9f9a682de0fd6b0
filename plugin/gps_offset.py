"""An offset between the GPS positions and the registered camera centres that is fixed in the cameras' own frame.

A receiver's errors are fixed in the world (or wander with time): whichever way the camera faces, they are the
same. A reconstruction whose camera model is wrong in the image plane is off in the camera's frame instead: a
principal point 40 px off the image centre (a photo cropped on one side after capture, the centre of the new
frame taken for it) turns every ray by atan(40 / f), and structure from motion places each camera metres to one
side of where it was to see the ground where the images show it (nu42 crops: 560x480 of a 640x480 frame, the
camera centres 6.9 m off the truth, landmarks 3 m off, exit 0 and nothing said: the GPS residual's 5.1 m sigma
under the 3-times-the-receiver level). Flight lines flown both ways turn that offset with the camera, so the
georegistration's translation cannot absorb it and it stands in the residuals: fitted here jointly with a
translation, r_i = t + [right_i, top_i] b, r_i the horizontal residual of image i and right_i, top_i the
horizontal directions of its image's x axis and of its top. Not separable from the translation where every
image faces the same way (one line, one direction): None then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the normal matrix's smallest eigenvalue against its largest below this: the images face (nearly) one way and
# the offset is the translation's
MIN_CONDITION = 1e-3


@dataclass(frozen=True)
class CameraFrameOffset:
    """The GPS positions' horizontal offset from the camera centres in the cameras' frame (m) and its chi-square
    against the residuals' own scatter (2 degrees of freedom)."""

    right_m: float  # toward the images' right (their x axis)
    top_m: float  # toward the images' top
    chi2: float
    sigma_m: float  # the residuals' scatter per axis once the offset is fitted
    images: int

    @property
    def size_m(self) -> float:
        """The offset's length (m)."""
        return math.hypot(self.right_m, self.top_m)


def camera_frame_offset(residual_xy: np.ndarray, world_from_cam: np.ndarray) -> CameraFrameOffset | None:
    """The offset fixed in the cameras' frame that the horizontal residuals `residual_xy` (N,2: GPS minus the
    registered camera centre) carry, with a translation fitted jointly (`world_from_cam`: the registered rotations
    (N,3,3)). None with fewer than 4 images, cameras looking straight along the vertical axis of their image
    (no horizontal image axes), or images all facing one way (the offset not separable from the translation)."""
    res = np.asarray(residual_xy, float).reshape(-1, 2)
    rot = np.asarray(world_from_cam, float).reshape(-1, 3, 3)
    n = len(res)
    if n < 4 or len(rot) != n:
        return None
    right, top = rot[:, :2, 0], -rot[:, :2, 1]  # image x axis, and its top (-y), in the world's horizontal
    norms = np.stack([np.linalg.norm(right, axis=1), np.linalg.norm(top, axis=1)], axis=1)
    if np.any(norms < 0.1):
        return None
    right, top = right / norms[:, :1], top / norms[:, 1:]
    a = np.zeros((2 * n, 4))
    a[0::2, 0], a[1::2, 1] = 1.0, 1.0
    a[0::2, 2], a[1::2, 2] = right[:, 0], right[:, 1]
    a[0::2, 3], a[1::2, 3] = top[:, 0], top[:, 1]
    normal = a.T @ a
    eig = np.linalg.eigvalsh(normal)
    if eig[0] < MIN_CONDITION * eig[-1]:
        return None
    y = res.reshape(-1)
    x = np.linalg.solve(normal, a.T @ y)
    dof = 2 * n - 4
    sigma = math.sqrt(float(np.sum((y - a @ x) ** 2)) / dof) if dof > 0 else math.nan
    b = x[2:]
    cov = np.linalg.inv(normal)[2:, 2:] * sigma**2
    chi2 = float(b @ np.linalg.solve(cov, b)) if sigma > 0 else math.inf
    return CameraFrameOffset(float(b[0]), float(b[1]), chi2, sigma, n)
