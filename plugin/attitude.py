"""Attitude conventions of survey cameras (pure numpy): aerospace body angles -> world_from_camera rotations.

Angles are aerospace (yaw clockwise from north, pitch nose up, roll right wing down; R_ned_from_body =
Rz(yaw) Ry(pitch) Rx(roll)); the world frame is east-north-up (a projected grid such as UTM, whose north differs
from true north by the meridian convergence). A camera fixed to the airframe looks down with one of
`FIXED_MOUNTS`; a gimbal camera (DJI) looks along the gimbal's forward axis (`GIMBAL_MOUNT`, pitch -90 = nadir).
Which mount and signs the Seneca telemetry follows was measured (`workflows.image_priors`, BENCHMARKS.md).
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

# Camera axes (x right, y down, z forward) expressed in the airframe's forward-right-down (FRD) axes, as the
# columns of R_body_from_cam. A downward camera has z = body down; the mounts differ in where the image top is.
FIXED_MOUNTS: dict[str, np.ndarray] = {
    # image top towards the nose, image x along the right wing
    "top_forward": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    # image x towards the nose (image top towards the left wing)
    "right_forward": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    # image top towards the tail
    "top_backward": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    # image x towards the tail (image top towards the right wing)
    "left_forward": np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]),
}
# A gimbal camera looks along its forward axis: x = right, y = down, z = forward.
GIMBAL_MOUNT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# Chosen by the Seneca flow check (tools/benchmarks/bench_real.py, BENCHMARKS.md real-data section).
DEFAULT_MOUNT = "top_forward"
DEFAULT_PITCH_SIGN = 1.0
DEFAULT_ROLL_SIGN = 1.0
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def ned_from_body(yaw_deg: np.ndarray, pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """(N,3,3) aerospace rotations Rz(yaw) Ry(pitch) Rx(roll): yaw clockwise from north, pitch nose up."""
    y, p, r = (np.radians(np.asarray(a, dtype=np.float64)).reshape(-1) for a in (yaw_deg, pitch_deg, roll_deg))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    one, zero = np.ones_like(y), np.zeros_like(y)
    rz = np.stack([np.stack([cy, -sy, zero], -1), np.stack([sy, cy, zero], -1), np.stack([zero, zero, one], -1)], -2)
    ry = np.stack([np.stack([cp, zero, sp], -1), np.stack([zero, one, zero], -1), np.stack([-sp, zero, cp], -1)], -2)
    rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cr, -sr], -1), np.stack([zero, sr, cr], -1)], -2)
    return rz @ ry @ rx


def camera_rotations(
    yaw_deg: np.ndarray,
    pitch_deg: np.ndarray,
    roll_deg: np.ndarray,
    mount: str | np.ndarray = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    grid_azimuth_of_north_deg: np.ndarray | float = 0.0,
) -> np.ndarray:
    """world_from_camera rotations (N,3,3) in an east-north-up grid frame from aerospace body angles.

    `mount` is a name in FIXED_MOUNTS, "gimbal", or a 3x3 R_body_from_cam. `grid_azimuth_of_north_deg` is the
    azimuth of true north in the grid (clockwise from grid north), added to the yaw (meridian convergence).
    """
    if isinstance(mount, str):
        if mount == "gimbal":
            m = GIMBAL_MOUNT
        elif mount in FIXED_MOUNTS:
            m = FIXED_MOUNTS[mount]
        else:
            raise InputError(f"unknown camera mount {mount!r} (use gimbal or one of {sorted(FIXED_MOUNTS)})")
    else:
        m = np.asarray(mount, dtype=np.float64)
    yaw = np.asarray(yaw_deg, dtype=np.float64) + np.asarray(grid_azimuth_of_north_deg, dtype=np.float64)
    r = ned_from_body(yaw, pitch_sign * np.asarray(pitch_deg, float), roll_sign * np.asarray(roll_deg, float))
    return ENU_FROM_NED @ r @ m
