"""Plausibility of a flight's GPS track and attitude tags, before any pose is made from them (pure numpy).

A survey's images carry their own GPS fixes and often attitude tags; `poses-from-exif` turns them into poses as
they are, and `poses` uses them as priors. Faults a receiver or a tag writer makes are physical impossibilities
that can be named per image, whatever the drone:
- a frozen fix (the receiver without a lock repeats one position): the whole flight at one point;
- a jump: consecutive fixes farther apart than the aircraft can fly in the time between them;
- cameras that do not look down: a mapping camera looks at the ground; tags that put most cameras near the
  horizon were written in another pitch convention (DJI gimbal pitch -90 = nadir, 0 = horizon).
"""

from __future__ import annotations

import numpy as np

FROZEN_SPREAD_M = 1.0  # fixes of >= 3 images all within this of their median: the receiver did not move
# a jump is faster than this multiple of the flight's own median speed between consecutive fixes (a survey flies
# its lines at one speed, turns included), and faster than SURVEY_SPEED_M_S (slow flights' GPS noise over 1 s)
JUMP_SPEED_FACTOR = 4.0
SURVEY_SPEED_M_S = 20.0
TIME_RESOLUTION_S = 1.0  # EXIF DateTimeOriginal without sub-seconds: two captures in one second are <= 1 s apart
# a camera tagged this far from nadir (median of the flight) looks at the horizon: nadir tags read in the other
# pitch convention give ~90; oblique surveys (gimbal pitch -25 .. -60) stay below
OFF_NADIR_LIMIT_DEG = 80.0


def frozen_fix(east: np.ndarray, north: np.ndarray) -> bool:
    """Whether the horizontal fixes of at least 3 images all lie within `FROZEN_SPREAD_M` of their median."""
    xy = np.column_stack([east, north])
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if len(xy) < 3:
        return False
    return bool(np.max(np.linalg.norm(xy - np.median(xy, axis=0), axis=1)) <= FROZEN_SPREAD_M)


def gps_jumps(east: np.ndarray, north: np.ndarray, times_s: np.ndarray,
              height: np.ndarray | None = None) -> list[tuple[int, int, float, float]]:
    """Consecutive fixes (in capture order) the aircraft cannot have flown between: (i, j, distance m, speed m/s)
    where the speed (distance over the capture interval, at least `TIME_RESOLUTION_S`) exceeds both
    `JUMP_SPEED_FACTOR` x the flight's median speed and `SURVEY_SPEED_M_S`. With `height`, the distance is in 3D
    where both fixes have one (one altitude read with the wrong sign is 500 m off its neighbours). Fixes without
    a position are skipped; without capture times (any NaN), or with times that do not advance (one clock stamp on
    every frame), there is no speed to judge: empty (the step between lines or batteries is no evidence)."""
    xy = np.column_stack([east, north])
    t = np.asarray(times_s, np.float64)
    ok = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    if len(ok) < 3 or not np.all(np.isfinite(t[ok])):
        return []
    if np.median(np.abs(np.diff(t[ok]))) <= 0.0:
        return []
    step = np.linalg.norm(np.diff(xy[ok], axis=0), axis=1)
    if height is not None:
        dz = np.diff(np.asarray(height, np.float64)[ok])
        step = np.where(np.isfinite(dz), np.hypot(step, np.nan_to_num(dz)), step)
    dt = np.maximum(np.abs(np.diff(t[ok])), TIME_RESOLUTION_S)
    speed = step / dt
    limit = max(JUMP_SPEED_FACTOR * float(np.median(speed)), SURVEY_SPEED_M_S)
    return [(int(ok[k]), int(ok[k + 1]), float(step[k]), float(speed[k])) for k in np.flatnonzero(speed > limit)]


def off_nadir_deg(rotations: np.ndarray) -> np.ndarray:
    """(N,) angle between each camera's viewing axis (world_from_camera rotations, camera z forward; world z up)
    and straight down, degrees."""
    axis_z = np.asarray(rotations, np.float64).reshape(-1, 3, 3)[:, 2, 2]
    return np.degrees(np.arccos(np.clip(-axis_z, -1.0, 1.0)))
