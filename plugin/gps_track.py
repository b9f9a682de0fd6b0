"""Plausibility of a flight's GPS track and attitude tags, before any pose is made from them (pure numpy).

A survey's images carry their own GPS fixes and often attitude tags; `poses-from-exif` turns them into poses as
they are, and `poses` uses them as priors. Faults a receiver or a tag writer makes are physical impossibilities
that can be named per image, whatever the drone:
- a frozen fix (the receiver without a lock repeats one position): the whole flight at one point;
- a jump: consecutive fixes farther apart than the aircraft can fly in the time between them;
- positions rounded to a coarse grid (a privacy tool's 4 decimals of a degree: ~11 m): not a fault of the
  receiver, but an error the pipeline must count as GPS noise (`quantisation`);
- cameras that do not look down: a mapping camera looks at the ground; tags that put most cameras near the
  horizon were written in another pitch convention (DJI gimbal pitch -90 = nadir, 0 = horizon).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geodesy import METRES_PER_DEGREE
from .geometry import SAME_POSITION

FROZEN_SPREAD_M = 1.0  # fixes of >= 3 images all within this of their median: the receiver did not move
# consecutive distinct fixes farther apart than this (median) are a moving aircraft, not a hover's GPS noise: an
# exact repeat of a fix between them is a receiver slower than the camera
MOVING_STEP_M = 3.0 * FROZEN_SPREAD_M
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

# a grid step is said when it is coarser than this: finer ones (an EXIF rational's 1e-4 arc second, 3 mm; a fix
# written to 6 decimals, 0.1 m) are far below any receiver's noise; a warning when the rounding's own noise
# (step / sqrt(12)) reaches QUANTISATION_WARN_SIGMA_M, a good consumer fix's noise (5 decimals, ~1.1 m, add
# 0.3 m: said, no warning; 4 decimals, ~11 m, add 3.2 m: a warning)
QUANTISATION_NOTE_M = 1.0
QUANTISATION_WARN_SIGMA_M = 1.0
# a set of fixes lies on a grid when every difference between its distinct values is a multiple of the step within
# this fraction of it; chance gives that with probability (2 x 0.01) per difference, so MIN_GRID_VALUES distinct
# values (MIN_GRID_VALUES - 1 differences) on one grid are no accident
GRID_TOLERANCE = 0.01
MIN_GRID_VALUES = 6
# steps tried (the smallest difference / 1 .. this): even so many tries leave a chance grid unlikely
# (MAX_GRID_DIVISIONS x 0.02 ** (MIN_GRID_VALUES - 1) ~ 3e-5)
MAX_GRID_DIVISIONS = 10_000


def grid_step(values: np.ndarray, min_step: float) -> tuple[float, bool] | None:
    """The coarsest step of at least `min_step` every value lies on (a common divisor of the differences between
    the distinct values: the smallest difference / k for k = 1, 2, ...), measured from the values alone, and
    whether the differences are of more than one multiple of it (values evenly spaced, a regular synthetic line,
    lie on the grid of their spacing without having been rounded); None when fewer than `MIN_GRID_VALUES`
    distinct values, or when no such step divides all differences (values of full precision, or a grid finer
    than `min_step`)."""
    v = np.unique(np.asarray(values, np.float64)[np.isfinite(values)])
    if len(v) < MIN_GRID_VALUES or min_step <= 0:
        return None
    diffs = v[1:] - v[:-1]
    smallest = float(diffs.min())
    for k in range(1, min(int(smallest / min_step), MAX_GRID_DIVISIONS) + 1):
        ratio = diffs / (smallest / k)
        if np.all(np.abs(ratio - np.round(ratio)) <= GRID_TOLERANCE):
            # the step measured over all the differences, not the smallest one alone
            return float(np.sum(diffs) / np.sum(np.round(ratio))), len(np.unique(np.round(ratio))) > 1
    return None


@dataclass
class Quantisation:
    """Fixes rounded to a grid of latitude and longitude: its step (degrees, and metres north and east) and the
    noise the rounding adds, uniform over a step: step / sqrt(12) per axis."""

    step_lat_deg: float
    step_lon_deg: float
    step_north_m: float
    step_east_m: float

    @property
    def sigma_m(self) -> float:
        """The rounding's standard deviation along the coarser axis, metres."""
        return max(self.step_north_m, self.step_east_m) / math.sqrt(12.0)

    def to_dict(self) -> dict[str, float]:
        """The summary's record (`gps_quantisation`)."""
        return {"step_lat_deg": self.step_lat_deg, "step_lon_deg": self.step_lon_deg,
                "step_north_m": round(self.step_north_m, 3), "step_east_m": round(self.step_east_m, 3),
                "sigma_m": round(self.sigma_m, 3)}


def quantisation(lat: np.ndarray, lon: np.ndarray) -> Quantisation | None:
    """The grid the fixes' latitudes and longitudes (degrees) lie on, when its step is coarser than
    `QUANTISATION_NOTE_M` on either axis; None otherwise (full precision, or a grid far below GPS noise). An axis
    without a grid of its own (a flight straight north-south has few distinct longitudes) takes the other's step
    in degrees: a tool rounds both alike. Evidence of rounding, not of a regular track: the differences of more
    than one multiple of the step on an axis, or the same fix at two images."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    ok = np.isfinite(lat) & np.isfinite(lon)
    if ok.sum() < MIN_GRID_VALUES:
        return None
    cos_lat = math.cos(math.radians(float(np.median(lat[ok]))))
    # one search floor in degrees for both axes (a tool rounds both to the same decimals): the finer of the two
    # axes' degrees of QUANTISATION_NOTE_M
    floor_deg = QUANTISATION_NOTE_M / METRES_PER_DEGREE
    grid_lat, grid_lon = grid_step(lat[ok], floor_deg), grid_step(lon[ok], floor_deg)
    if grid_lat is None and grid_lon is None:
        return None
    repeated = len(np.unique(np.column_stack([lat[ok], lon[ok]]), axis=0)) < int(ok.sum())
    if not (repeated or any(g is not None and g[1] for g in (grid_lat, grid_lon))):
        return None
    step_lat = grid_lat[0] if grid_lat is not None else None
    step_lon = grid_lon[0] if grid_lon is not None else None
    # an axis with too few distinct values to measure, but all of them on the other's grid
    for mine, other, vals in ((step_lat, step_lon, lat[ok]), (step_lon, step_lat, lon[ok])):
        if mine is None and other is not None and len(np.unique(vals)) >= MIN_GRID_VALUES:
            return None  # enough values to show a grid, and they do not lie on one: not a rounding tool
    step_lat = step_lat if step_lat is not None else step_lon
    step_lon = step_lon if step_lon is not None else step_lat
    q = Quantisation(float(step_lat), float(step_lon), float(step_lat) * METRES_PER_DEGREE,
                     float(step_lon) * METRES_PER_DEGREE * cos_lat)
    return q if max(q.step_north_m, q.step_east_m) > QUANTISATION_NOTE_M else None


def repeated_fixes(east: np.ndarray, north: np.ndarray, times: np.ndarray | None = None,
                   exposures: np.ndarray | None = None) -> tuple[int, float]:
    """How many fixes (in capture order) repeat the previous one (within rounding, `geometry.SAME_POSITION`), and the
    median distance between the consecutive fixes that differ (m; NaN with none): a receiver updating slower than the
    camera repeats its fix while the aircraft flies on; a hovering aircraft's repeats come with differing fixes only
    as far apart as the GPS noise. A repeat is that evidence only if the aircraft moved between the two captures, so
    with capture `times` (s) a repeat counts only when it comes at least half the flight's pace between places (the
    median time from one fix to the next) after the previous capture and the flight's speed (its differing fixes over
    the time between them) carries it `MOVING_STEP_M` beyond where the fix last changed: shots of a burst or a
    bracket at each waypoint are one place, not a lag. A repeat whose `exposures` (s) differ from the previous
    image's is exposure bracketing (AEB: one place, several exposure times) and never counts."""
    ok = np.isfinite(east) & np.isfinite(north)
    xy = np.column_stack([east, north])[ok]
    if len(xy) < 2:
        return 0, float("nan")
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    changed = step > SAME_POSITION  # a fix repeated is one within rounding (`geometry.SAME_POSITION`)
    moved = step[changed]
    repeat = ~changed
    if exposures is not None:
        e = np.asarray(exposures, np.float64)[ok]
        repeat &= ~(np.isfinite(e[1:]) & np.isfinite(e[:-1]) & (e[1:] != e[:-1]))
    if times is not None and repeat.any() and len(moved):
        t = np.asarray(times, np.float64)[ok]
        # index of the image where each image's fix first appeared
        since = np.maximum.accumulate(np.where(np.r_[True, changed], np.arange(len(t)), 0))
        change = np.flatnonzero(changed) + 1
        pace = t[change] - t[since[change - 1]]
        good = np.isfinite(pace) & (pace > 0)
        if good.any():
            speed = float(np.median(step[change - 1][good] / pace[good]))
            gap, lag = np.diff(t), t[1:] - t[since[:-1]]
            repeat &= (gap >= 0.5 * float(np.median(pace[good]))) & (speed * lag > MOVING_STEP_M)
    return int(np.sum(repeat)), float(np.median(moved)) if len(moved) else float("nan")


def with_quantisation(sigma_m: float, summary: dict | None) -> float:
    """A GPS noise `sigma_m` with the rounding the priors' summary found (`gps_quantisation`) added in quadrature:
    the noise every consumer of those fixes must assume."""
    q = (summary or {}).get("gps_quantisation")
    return math.hypot(float(sigma_m), float(q["sigma_m"])) if q else float(sigma_m)


def off_nadir_deg(rotations: np.ndarray) -> np.ndarray:
    """(N,) angle between each camera's viewing axis (world_from_camera rotations, camera z forward; world z up)
    and straight down, degrees."""
    axis_z = np.asarray(rotations, np.float64).reshape(-1, 3, 3)[:, 2, 2]
    return np.degrees(np.arccos(np.clip(-axis_z, -1.0, 1.0)))
