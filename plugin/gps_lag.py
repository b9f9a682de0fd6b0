"""GPS lag (camera trigger latency or a clock offset) in the georegistration (pure numpy).

A photo is often tagged with the drone's position a fraction of a second before (or after) the exposure: the tag
is dt * v away from the camera along the track. On a lawnmower the error flips sign with the flight direction, so
a similarity cannot absorb it: the robust horizontal fit (`georegistration.robust_horizontal_similarity`) keeps
the lines flown one way and drops the others as outliers, and the whole map lies dt * v off (the 30th new-user
sweep: 5 m of latency, the map 4.85 m off with verdict ok). Modelled instead: the camera was at gps_i + dt * v_i,
v_i the drone's velocity from the GPS track itself, and dt is a fifth unknown of the (still linear) horizontal fit
s R src + t = gps + dt v. dt is significant only beyond `LAG_SIGNIFICANCE_SIGMAS` standard errors, the error
the larger of the formal one and the scatter between the passes of the track (the GPS error wanders slowly, so
the passes, not the images, are the independent measurements: rev22 found 2-9 % of clean flights "lagging" on the
formal error alone), and only when dt * speed is beyond the fit's own noise (what a map can see depends on how
precise the positions are: 0.4 m of lag is nothing on a 1.5 m GPS and ten times the noise of an RTK fix).
`georegistration.georegister` then applies it only when it is plausible and improves the fit, so a flight
without lag is registered exactly as before. With fewer passes than the jackknife needs a lag cannot be verified
(two passes flown either way cannot tell it from the GPS wandering between them); one formally far beyond the
noise is then `unverified`: said, not applied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .robust_fit import jackknife_sigma, lmeds_then_least_squares

# dt is applied only beyond this many of its standard errors: GPS noise correlated along a line makes the formal
# error optimistic, and a lag that is not there must never be "corrected" into a flight
LAG_SIGNIFICANCE_SIGMAS = 5.0
# passes (lines flown one way, `TrackVelocity.passes`) needed to measure a lag's error honestly
MIN_PASSES = 3
# a step this many times the median capture interval (or step length) is a gap (another flight, a battery swap):
# no velocity is taken across it
GAP_FACTOR = 3.0


@dataclass
class TrackVelocity:
    """The drone's velocity per image from its GPS track."""

    velocity: np.ndarray  # (N,3) per `unit` (NaN: unknown, e.g. a lone image between gaps; z NaN without altitude)
    unit: str  # "s" (capture times resolve the interval) or "image" (per image step)
    interval_s: float  # the mean capture interval within gap-free stretches (NaN when the times are not known)
    # (N,) the pass of each image: a run of the track in capture order flown one way, cut at gaps and where the
    # direction reverses (a line with its turn); -1 without a velocity. The GPS error wanders slowly, nearly
    # constant along a pass: passes, not images, are the independent units of a lag's error (`fit_lag`)
    passes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def _times_resolve(times: np.ndarray) -> bool:
    """Capture times good for velocities: finite, strictly increasing, finer than the interval (whole seconds
    at an interval of a few seconds make the speed wrong by tens of percent)."""
    if len(times) < 2 or not np.all(np.isfinite(times)):
        return False
    d = np.diff(times)
    if np.any(d <= 0):
        return False
    whole = np.allclose(times - times[0], np.round(times - times[0]), atol=1e-3)
    return not (whole and float(np.median(d)) < 5.0)


def _mean_interval(times: np.ndarray, steady: np.ndarray) -> float:
    """The mean step of sorted `times` over the steps `steady` (no gap): per gap-free stretch (last - first) /
    (n - 1), pooled. Whole-second times at 1.4 s give steps of 1 and 2 s whose median (1 s) is 30 % off; the
    mean of a stretch is off by at most 1 s / its steps."""
    d = np.diff(times)
    keep = steady & np.isfinite(d)
    return float(np.sum(d[keep]) / keep.sum()) if keep.any() else math.nan


def _passes(velocity: np.ndarray, steady: np.ndarray) -> np.ndarray:
    """Pass id per image in capture order (velocity (n,2) in that order, `steady` the n-1 steps without a gap):
    a new pass after a gap and where the heading is more than 120 deg from the pass's first (a lawnmower's turn
    of 90 deg stays with its line; the next line, flown back, starts a pass)."""
    n = len(velocity)
    ids = np.full(n, -1, np.int64)
    current, ref = -1, None
    for k in range(n):
        v = velocity[k]
        if not np.all(np.isfinite(v)) or np.hypot(*v) <= 0:
            ref = None
            continue
        u = v / np.hypot(*v)
        if ref is None or (k > 0 and not steady[k - 1]) or float(u @ ref) < math.cos(math.radians(120.0)):
            current, ref = current + 1, u
        ids[k] = current
    return ids


def track_velocity(positions: np.ndarray, times_s: np.ndarray, times_known: bool = True) -> TrackVelocity:
    """Velocity of each image (N,3 positions, NaN altitude allowed) from its neighbours in capture order (the
    times' order; given order without times): a central difference, one-sided at the ends and at gaps, NaN for
    an image alone between gaps. Per second when the capture times resolve the interval, else per image step.
    `times_known` False: `times_s` is only the capture order (no EXIF time), so no interval in seconds."""
    p = np.asarray(positions, float)
    t = np.asarray(times_s, float)
    n = len(p)
    vel = np.full((n, 3), np.nan)
    order = np.argsort(t, kind="stable") if np.all(np.isfinite(t)) else np.arange(n)
    ts = t[order]
    resolved = times_known and _times_resolve(ts)
    if n < 2:
        return TrackVelocity(vel, "s" if resolved else "image", math.nan, np.full(n, -1, np.int64))
    x = p[order]
    clock = ts if resolved else np.arange(n, dtype=float)
    dt = np.diff(clock)
    length = np.linalg.norm(np.diff(x[:, :2], axis=0), axis=1)
    ok = (dt <= GAP_FACTOR * np.median(dt)) & (length <= GAP_FACTOR * max(float(np.median(length)), 1e-9))
    ok &= np.all(np.isfinite(np.diff(x[:, :2], axis=0)), axis=1)
    if times_known and not resolved and np.all(np.isfinite(ts)):
        # a gap in time, even where the times are too coarse for speeds (whole seconds: steps of 0 or 1 s at
        # 0.5 s, so nothing below a second is a gap)
        steps = np.diff(ts)
        ok &= steps <= GAP_FACTOR * max(float(np.median(steps)), 1.0)
    for k in range(n):
        lo = k - 1 if k > 0 and ok[k - 1] else k
        hi = k + 1 if k < n - 1 and ok[k] else k
        if hi > lo:
            vel[order[k]] = (x[hi] - x[lo]) / (clock[hi] - clock[lo])
    interval = _mean_interval(ts, ok) if times_known else math.nan
    passes = np.full(n, -1, np.int64)
    passes[order] = _passes(vel[order, :2], ok)
    return TrackVelocity(vel, "s" if resolved else "image", interval, passes)


@dataclass
class LagFit:
    """The horizontal similarity with a lag: s R src + t = gps + dt v."""

    dt: float  # in the velocity's unit
    sigma_dt: float  # its standard error: the larger of the formal and the passes' (inf when not observable)
    significant: bool  # beyond LAG_SIGNIFICANCE_SIGMAS of sigma_dt and dt * speed beyond the fit's noise
    unit: str  # "s" or "image"
    seconds: float  # dt in seconds (NaN when the capture times do not tell)
    metres: float  # dt at the median horizontal speed
    speed: float  # median horizontal speed, m per `unit`
    inliers: np.ndarray  # bool (N,)
    sigma_m: float  # per-axis noise of the positions with the lag modelled
    sigma_dt_formal: float = math.inf  # least squares, every image independent
    sigma_dt_passes: float = math.inf  # jackknife over the passes (inf: fewer than MIN_PASSES)
    passes: int = 0  # passes with inliers
    # too few passes to verify (sigma_dt_passes inf) but beyond LAG_SIGNIFICANCE_SIGMAS of the formal error and
    # the fit's noise: measured, to be said, never applied
    unverified: bool = False

    def shift(self) -> str:
        """"lag the images by 0.42 s (4.9 m along the track at 11.7 m/s)", for a warning."""
        verb = "lag" if self.dt > 0 else "lead"
        if self.unit == "s":
            when, speed = f"{abs(self.dt):.2f} s", f" at {self.speed:.1f} m/s"
        else:
            when = f"{abs(self.dt):.2f} image intervals" + (
                f" (~{abs(self.seconds):.2f} s)" if math.isfinite(self.seconds) else "")
            speed = ""
        return f"{verb} the images by {when} ({abs(self.metres):.1f} m along the track{speed})"

    def to_dict(self) -> dict:
        def finite(x: float) -> float | None:
            return x if math.isfinite(x) else None
        return {"dt": self.dt, "sigma_dt": finite(self.sigma_dt), "sigma_dt_formal": finite(self.sigma_dt_formal),
                "sigma_dt_passes": finite(self.sigma_dt_passes), "passes": self.passes,
                "unit": self.unit, "seconds": finite(self.seconds),
                "metres": self.metres, "speed": self.speed, "significant": self.significant,
                "unverified": self.unverified,
                "inliers": int(self.inliers.sum()), "sigma_m": self.sigma_m}


def _design(src: np.ndarray, vel: np.ndarray) -> np.ndarray:
    """Rows (2N, 5) of the linear model [a, b, tx, ty, dt]: a x - b y + tx - dt vx = gx, b x + a y + ty - dt vy
    = gy (s R = [[a, -b], [b, a]])."""
    n = len(src)
    a = np.zeros((2 * n, 5))
    a[0::2] = np.column_stack([src[:, 0], -src[:, 1], np.ones(n), np.zeros(n), -vel[:, 0]])
    a[1::2] = np.column_stack([src[:, 1], src[:, 0], np.zeros(n), np.ones(n), -vel[:, 1]])
    return a


def _solve(src: np.ndarray, dst: np.ndarray, vel: np.ndarray) -> np.ndarray | None:
    a = _design(src, vel)
    if np.linalg.matrix_rank(a) < 5:
        return None
    return np.linalg.lstsq(a, dst[:, :2].reshape(-1), rcond=None)[0]


def _residuals(params: np.ndarray, src: np.ndarray, dst: np.ndarray, vel: np.ndarray) -> np.ndarray:
    return np.linalg.norm((_design(src, vel) @ params - dst[:, :2].reshape(-1)).reshape(-1, 2), axis=1)


def fit_lag(src: np.ndarray, dst: np.ndarray, track: TrackVelocity, seed: int = 0, samples: int = 500,
            min_sigma_m: float = 1e-3) -> LagFit | None:
    """The lag of GPS positions `dst` (N,3) behind levelled block centres `src` (N,3), with `track` their
    velocities: least median of squares over 3-point samples of the 5-unknown linear fit (the lines flown either
    way are in one model), then least squares on the 99 % inliers of the measured sigma, iterated. None when
    fewer than 3 positions have a velocity or the lag is not observable (every image flown one way)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    have = np.all(np.isfinite(track.velocity[:, :2]), axis=1) & np.all(np.isfinite(dst[:, :2]), axis=1)
    idx = np.flatnonzero(have)
    if len(idx) < 3:
        return None
    # centred: in UTM coordinates (10^6 m) the normal equations lose the lag's digits
    s, d, v = src[idx] - src[idx].mean(0), dst[idx] - dst[idx].mean(0), track.velocity[idx]
    n = len(idx)
    rng = np.random.default_rng(seed)

    def candidate() -> np.ndarray | None:
        pick = rng.choice(n, 3, replace=False)
        p = _solve(s[pick], d[pick], v[pick])
        return p if p is not None and math.hypot(p[0], p[1]) > 0 else None

    fitted = lmeds_then_least_squares(
        (candidate() for _ in range(samples)), lambda inl: _solve(s[inl], d[inl], v[inl]),
        lambda p: _residuals(p, s, d, v), n, unknowns=5, min_points=3, min_sigma=min_sigma_m)
    if fitted is None:
        return None
    params, inl, sigma = fitted
    a = _design(s[inl], v[inl])
    normal = a.T @ a
    formal = math.inf
    if np.linalg.cond(normal) < 1e12:
        formal = sigma * math.sqrt(float(np.linalg.inv(normal)[4, 4]))
    passes = track.passes[idx] if len(track.passes) == len(src) else np.zeros(n, np.int64)
    by_passes, n_passes = _jackknife_dt(s, d, v, inl, passes)
    sigma_dt = max(formal, by_passes)
    dt = float(params[4])
    speed = float(np.median(np.linalg.norm(v[:, :2], axis=1)))
    seconds = dt if track.unit == "s" else dt * track.interval_s
    inliers = np.zeros(len(src), bool)
    inliers[idx[inl]] = True
    # a lag smaller than the noise of one fix changes nothing a landmark map can see: lines flown either way are
    # 2 dt v apart, and are set right only when that is beyond 2 sigma of a fix. The fit's own noise, not a fixed
    # floor: an RTK flight (4 cm) sees 0.4 m of lag that a 1.5 m GPS flight cannot
    matters = abs(dt * speed) >= sigma
    significant = math.isfinite(sigma_dt) and abs(dt) > LAG_SIGNIFICANCE_SIGMAS * sigma_dt and matters
    # too few passes for the jackknife: each pass is then one measurement whose offset is as uncertain as one fix
    # (the wander is nearly constant along it, so averaging its images does not help), and the lag, half the
    # offset between two passes, has the standard error sigma / sqrt(2). Beyond LAG_SIGNIFICANCE_SIGMAS of that
    # (and of the formal error) it is said. Measured on 2-pass clean flights (fix36): 0 of 100 with RTK-like noise
    # and wander, 2-3 of 100 with 1-2 m of wander (the wander between passes exceeds the one within them)
    unverified = (not math.isfinite(by_passes) and n_passes < MIN_PASSES and matters
                  and abs(dt) > LAG_SIGNIFICANCE_SIGMAS * formal
                  and abs(dt * speed) > LAG_SIGNIFICANCE_SIGMAS * sigma / math.sqrt(2.0))
    return LagFit(dt, sigma_dt, significant, track.unit, seconds, dt * speed, speed, inliers, sigma, formal,
                  by_passes, n_passes, unverified)


def _jackknife_dt(s: np.ndarray, d: np.ndarray, v: np.ndarray, inl: np.ndarray,
                  passes: np.ndarray) -> tuple[float, int]:
    """Standard error of dt from the scatter between passes (delete-one-pass jackknife on the inliers), and the
    number of passes. The GPS error wanders slowly, nearly constant along a pass and changing between passes,
    so dt is measured by the passes' offsets, not by independent images: the formal error was 2.7x too small
    on clean flights with 1-2 m of wander (rev22). inf with fewer than MIN_PASSES passes (two passes flown
    either way cannot tell a lag from the GPS wandering between them)."""
    ids = [p for p in np.unique(passes[inl]) if p >= 0]
    if len(ids) < MIN_PASSES:
        return math.inf, len(ids)
    dts = []
    for p in ids:
        keep = inl & (passes != p)
        q = _solve(s[keep], d[keep], v[keep]) if keep.sum() >= 3 else None
        if q is None:  # without this pass the lag is not observable: the passes do not measure it
            return math.inf, len(ids)
        dts.append(float(q[4]))
    return jackknife_sigma(dts), len(dts)


def corrected(values: np.ndarray, velocity: np.ndarray, dt: float) -> np.ndarray:
    """values + dt * velocity where the velocity is known (elsewhere unchanged): the camera's position from a
    lagging GPS position (any columns: x, y, altitude)."""
    v = np.asarray(velocity, float)
    return np.where(np.isfinite(v), np.asarray(values, float) + dt * np.nan_to_num(v), values)
