"""Heights over a flight: a robust line, or a step, through one value per image (`fit_drift`: how a GPS altitude
drifts or jumps against the barometer or the block, over capture time), and the take-off altitude each image's
barometric height is measured from when a folder holds several flights (`takeoff_altitudes`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .landmark_filters import MAD_TO_SIGMA

# A height drift smaller than this over a flight is within what the vertical of a block can explain (0.1 degree
# over 300 m is 0.5 m) and is not followed nor warned about (it is still measured and recorded).
MIN_HEIGHT_DRIFT_M = 1.0
# A step (one change point: an RTK receiver losing its fix and reporting another height datum, nu34: 30 m) is
# taken instead of the line only when its residuals' robust sigma is at most this fraction of the line's (a
# ramp, the best step through it leaves change/7 of misfit where the line leaves only the noise, so a drift is
# never read as a step) and the step stands STEP_NOISE_SIGMAS of its own noise out: a line through a step
# extrapolates to the first image a quarter of the step off (nu34 mAmix1: +36.9 m for a 30 m step).
STEP_SIGMA_RATIO = 0.5
STEP_NOISE_SIGMAS = 10.0
MIN_STEP_SIDE = 3  # images on each side of a step: fewer are outliers, not a segment


@dataclass
class DriftFit:
    """A robust straight line value(t) = offset + slope (t - t0) through one value per image."""

    offset: float  # the value at the first image (t0)
    slope_per_s: float
    change: float  # slope x the flight's duration: the drift from the first to the last image
    sigma: float  # robust standard deviation of the values about the line
    change_sigma: float  # standard error of `change`
    significant: bool  # |change| beyond 3 standard errors and beyond 2 sigma
    median: float  # the median of the values (the offset to use when there is no drift)
    # a step instead of a line (`kind` "step"; `change` is then the step, after - before, and `offset` the level
    # of the segment kept, `kept`): the time of the first value after it, the levels and numbers of values of
    # the two segments
    step_time: float | None = None
    levels: tuple[float, float] | None = None
    counts: tuple[int, int] | None = None
    kept: str | None = None  # "before" or "after": the segment whose level is the reference

    @property
    def kind(self) -> str:
        """"step" (one change point), "drift" (a significant line) or "constant"."""
        return "step" if self.step_time is not None else ("drift" if self.significant else "constant")

    @property
    def reference(self) -> float:
        """The offset that applies to the block: at the start of the flight when the value drifts, the kept
        segment's level across a step (one datum for all, never a line through the step), else the median."""
        return self.offset if self.significant else self.median

    def first_at_step(self, indices: np.ndarray, times: np.ndarray) -> int:
        """Of the values `indices` (into `times`, seconds), the earliest at or after the step (the last one given
        when none is, or for a fit without a step): the image a jump is named at."""
        idx = np.asarray(indices)
        t = np.asarray(times, float)
        later = idx[t[idx] >= (self.step_time if self.step_time is not None else -math.inf)]
        return int(later[np.argmin(t[later])]) if len(later) else int(idx[-1])

    def value_at(self, t0: float, t: float) -> float:
        """The fitted value at time `t` of a fit whose first time is `t0`."""
        if self.levels is not None and self.step_time is not None:
            return self.levels[0] if t < self.step_time else self.levels[1]
        return self.offset + self.slope_per_s * (t - t0) if self.significant else self.median

    def to_dict(self) -> dict:
        d = {"model": self.kind, "offset_at_start": self.offset, "median": self.median,
             "change_over_flight": self.change, "change_sigma": self.change_sigma,
             "slope_per_min": self.slope_per_s * 60.0, "sigma": self.sigma, "significant": self.significant}
        if self.levels is not None:
            d.update(step_at_s=self.step_time, levels=list(self.levels), counts=list(self.counts or ()),
                     kept=self.kept)
        return d


def _robust_sigma(residuals: np.ndarray) -> float:
    return float(MAD_TO_SIGMA * np.median(np.abs(residuals - np.median(residuals)))) if len(residuals) else 0.0


def fit_drift(times: np.ndarray, values: np.ndarray, min_change: float = 0.0, iterations: int = 10,
              value_sigma: np.ndarray | None = None) -> DriftFit:
    """Huber-weighted (k = 2 sigma) least-squares line of `values` over `times` (seconds), scale re-estimated
    from the residuals' MAD every round; the line's change over the time span with its standard error. The
    change is significant beyond 3 standard errors, 2 sigma and `min_change`. When a step (`fit_step`) fits
    the values far better than the line (module constants), the step is returned instead: `value_sigma` (per
    value, its a-priori standard deviation, e.g. an RTK receiver's RtkStdHgt; NaN unknown) chooses the segment
    whose level is the reference (`_kept_segment`)."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    q = np.full(len(v), np.nan) if value_sigma is None else np.asarray(value_sigma, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v, q = t[ok], v[ok], q[ok]
    line = _fit_line(t, v, min_change, iterations)
    step = fit_step(t, v, q, min_change)
    if step is not None and step.sigma <= STEP_SIGMA_RATIO * line.sigma:
        return step
    return line


def _noise_floor(residuals: np.ndarray, values: np.ndarray) -> float:
    """The least noise the residuals of a fit to `values` can be said to have: their resolution's (Sheppard: a
    rounding to steps of q adds q^2 / 12 of variance), at least a float's. Altitudes recorded in whole metres
    leave most residuals about a segment's median exactly 0, so their MAD is 0 and any split "stood out" of no
    noise: a 4 m drift read as a datum jump in 30 % of flights (rev23). Residuals of values with decimals, or
    of values without noise (all 0), have a resolution far below any step."""
    v = np.asarray(values, np.float64)
    floor = 1e-9 * max(1.0, float(np.abs(v).max())) if len(v) else 1e-9
    steps = np.diff(np.unique(np.asarray(residuals, np.float64)))
    steps = steps[steps > floor]
    return max(float(steps.min()) / math.sqrt(12.0), floor) if len(steps) else floor


def _fit_line(t: np.ndarray, v: np.ndarray, min_change: float, iterations: int) -> DriftFit:
    """`fit_drift`'s line, on finite values."""
    if len(v) == 0:
        raise ValueError("no finite values to fit")
    median = float(np.median(v))
    t0, span = float(t.min()), float(t.max() - t.min())
    if len(v) < 3 or span <= 0:
        sigma = _robust_sigma(v)
        return DriftFit(median, 0.0, 0.0, sigma, math.inf, False, median)
    x = t - t0
    w = np.ones(len(v))
    coef = np.zeros(2)
    sigma = _robust_sigma(v)
    for _ in range(iterations):
        a = np.stack([np.ones_like(x), x], 1) * np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(a, v * np.sqrt(w), rcond=None)[0]
        r = v - coef[0] - coef[1] * x
        sigma = max(_robust_sigma(r), 1e-9 * max(1.0, float(np.abs(v).max())))
        k = 2.0 * sigma
        w = np.where(np.abs(r) <= k, 1.0, k / np.maximum(np.abs(r), 1e-300))
    sw = w.sum()
    xm = (w @ x) / sw
    sxx = float(w @ (x - xm) ** 2)
    slope_se = sigma / math.sqrt(sxx) if sxx > 0 else math.inf
    change, change_se = float(coef[1] * span), float(slope_se * span)
    significant = bool(abs(change) > max(3.0 * change_se, 2.0 * sigma, min_change))
    return DriftFit(float(coef[0]), float(coef[1]), change, float(sigma), change_se, significant, median)


def _kept_segment(q_before: np.ndarray, q_after: np.ndarray, n_before: int, n_after: int) -> str:
    """Which side of a step gives the reference level: the one whose values are known to be better (a-priori
    sigmas, median, at least 2x apart: an RTK fixed altitude of 2 cm over a single-point fix of metres), else
    the one with more values, else the first (the take-off's)."""
    qb = float(np.nanmedian(q_before)) if np.isfinite(q_before).any() else math.nan
    qa = float(np.nanmedian(q_after)) if np.isfinite(q_after).any() else math.nan
    if math.isfinite(qb) and math.isfinite(qa) and max(qa, qb) >= 2.0 * min(qa, qb):
        return "before" if qb < qa else "after"
    return "after" if n_after > n_before else "before"


def fit_step(times: np.ndarray, values: np.ndarray, value_sigma: np.ndarray | None = None,
             min_change: float = 0.0) -> DriftFit | None:
    """The best single step (change point) of `values` over `times`: the split (>= MIN_STEP_SIDE values each
    side, in time order) of least squared misfit about the two segments' means, then each segment's level its
    median and the noise the MAD of the residuals. None when there is no room for one or the step does not
    stand out: |step| beyond STEP_NOISE_SIGMAS sigma, 3 standard errors and `min_change`."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    q = np.full(len(v), np.nan) if value_sigma is None else np.asarray(value_sigma, dtype=np.float64)
    order = np.argsort(t, kind="stable")
    t, v, q = t[order], v[order], q[order]
    n = len(v)
    if n < 2 * MIN_STEP_SIDE:
        return None
    # squared misfit about the means of [0, k) and [k, n) for every k, from cumulative sums
    c1, c2 = np.cumsum(v - v.mean()), np.cumsum((v - v.mean()) ** 2)
    k = np.arange(MIN_STEP_SIDE, n - MIN_STEP_SIDE + 1)
    left = c2[k - 1] - c1[k - 1] ** 2 / k
    right = (c2[-1] - c2[k - 1]) - (c1[-1] - c1[k - 1]) ** 2 / (n - k)
    split = int(k[np.argmin(left + right)])
    while split < n and split > MIN_STEP_SIDE and t[split] == t[split - 1]:
        split -= 1  # values of one time on one side
    before, after = float(np.median(v[:split])), float(np.median(v[split:]))
    r = np.concatenate([v[:split] - before, v[split:] - after])
    sigma = max(_robust_sigma(r), _noise_floor(r, v))
    # a median's standard error is 1.25 x a mean's
    step_se = 1.25 * sigma * math.sqrt(1.0 / split + 1.0 / (n - split))
    step = after - before
    if not abs(step) > max(STEP_NOISE_SIGMAS * sigma, 3.0 * step_se, min_change):
        return None
    kept = _kept_segment(q[:split], q[split:], split, n - split)
    level = before if kept == "before" else after
    return DriftFit(level, 0.0, step, sigma, step_se, True, float(np.median(v)), float(t[split]),
                    (before, after), (split, n - split), kept)


# A break in the capture times longer than this (and than 20 of the flight's own intervals) is a landing: a
# battery change takes minutes, survey images come every few seconds.
FLIGHT_BREAK_S = 60.0
# Two flights whose take-off altitudes (GPS altitude - RelativeAltitude) differ by less than this took off from
# one place: an uncorrected receiver's altitude wanders by a few metres between flights (2 x GNSS_WANDER_M of the
# pose check's horizontal floor), and a step that size is no evidence of another home point. Beyond it (and
# beyond the estimates' own noise) each flight keeps its own take-off altitude.
MIN_TAKEOFF_STEP_M = 5.0


def takeoff_altitudes(times: np.ndarray, offsets: np.ndarray, min_change: float = 0.0,
                      value_sigma: np.ndarray | None = None,
                      ) -> tuple[np.ndarray, list[tuple[np.ndarray, DriftFit]]]:
    """Per image, the altitude its barometric height (DJI RelativeAltitude, above the take-off point) is measured
    from, and the flights: [(image indices, their `fit_drift` of GPS altitude - RelativeAltitude)], in capture
    order. `offsets` (N,) is GPS altitude - RelativeAltitude (NaN without a GPS altitude), `times` (N,) seconds.

    A folder of two batteries taken off from two places has two: the barometer restarts at each take-off, and one
    line through both (the nu20 sweep: a second home 15 m higher, read as a GPS drift of +16 m) put the second
    flight's cameras 15 m low, landmarks 6 m low (some twice, 17 m apart), with the map's verdict "ok". So the
    images are split into flights at breaks in the capture times (`FLIGHT_BREAK_S`), and a flight joins the one
    before unless its take-off altitude (at its start) differs from that flight's line at its last image by more
    than `MIN_TAKEOFF_STEP_M` and 3 standard errors. One flight: the one fit of the whole folder, as before.
    Within a flight the barometer does not restart: a step there is the GPS's (`fit_drift`'s step; its
    take-off altitude the level of the segment `value_sigma`, per image, says is better, else the longer)."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(offsets, dtype=np.float64)
    q = np.full(len(v), np.nan) if value_sigma is None else np.asarray(value_sigma, dtype=np.float64)
    order = np.argsort(t, kind="stable")
    dt = np.diff(t[order])
    step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    segments = np.split(order, np.flatnonzero(dt > max(FLIGHT_BREAK_S, 20.0 * step)) + 1)
    groups: list[np.ndarray] = []
    for seg in segments:
        fixed = seg[np.isfinite(v[seg])]
        if groups and len(fixed):
            prev = groups[-1][np.isfinite(v[groups[-1]])]
            if len(prev):
                before = fit_drift(t[prev], v[prev], min_change, value_sigma=q[prev])
                after = fit_drift(t[fixed], v[fixed], min_change, value_sigma=q[fixed])
                # each flight's line where it has images (not extended across the break: a drift that is noise,
                # stretched over a 5 min pause, made a step of 5 m in one flight; review rev19)
                t1 = float(t[fixed].min())
                start = after.value_at(t1, t1)
                jump = start - before.value_at(float(t[prev].min()), float(t[prev].max()))
                if before.levels is not None:  # a flight with a step of the GPS's datum: the next may be on either
                    jump = min((start - level for level in before.levels), key=abs)  # (rev23: RTK regained)
                noise = 3.0 * math.hypot(before.sigma / math.sqrt(len(prev)), after.sigma / math.sqrt(len(fixed)))
                if abs(jump) > max(MIN_TAKEOFF_STEP_M, noise):
                    groups.append(seg)
                    continue
        if groups:
            groups[-1] = np.concatenate([groups[-1], seg])
        else:
            groups.append(seg)
    takeoff = np.full(len(v), np.nan)
    flights = []
    for idx in groups:
        fixed = idx[np.isfinite(v[idx])]
        if not len(fixed):  # no GPS altitude in the whole flight: the one before's take-off, or none
            if flights:
                takeoff[idx] = takeoff[flights[-1][0][0]]
            continue
        fit = fit_drift(t[fixed], v[fixed], min_change, value_sigma=q[fixed])
        takeoff[idx] = fit.reference
        flights.append((idx, fit))  # in capture order: idx[0] is the flight's first image
    return takeoff, flights
