"""Heights over a flight: a robust line through one value per image (`fit_drift`: how a GPS altitude drifts
against the barometer or the block, over capture time), and the take-off altitude each image's barometric height
is measured from when a folder holds several flights (`takeoff_altitudes`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .landmark_filters import MAD_TO_SIGMA

# A height drift smaller than this over a flight is within what the vertical of a block can explain (0.1 degree
# over 300 m is 0.5 m) and is not followed nor warned about (it is still measured and recorded).
MIN_HEIGHT_DRIFT_M = 1.0


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

    @property
    def reference(self) -> float:
        """The offset that applies to the block: at the start of the flight when the value drifts, else the median."""
        return self.offset if self.significant else self.median

    def to_dict(self) -> dict:
        return {"offset_at_start": self.offset, "median": self.median, "change_over_flight": self.change,
                "change_sigma": self.change_sigma, "slope_per_min": self.slope_per_s * 60.0, "sigma": self.sigma,
                "significant": self.significant}


def _robust_sigma(residuals: np.ndarray) -> float:
    return float(MAD_TO_SIGMA * np.median(np.abs(residuals - np.median(residuals)))) if len(residuals) else 0.0


def fit_drift(times: np.ndarray, values: np.ndarray, min_change: float = 0.0, iterations: int = 10) -> DriftFit:
    """Huber-weighted (k = 2 sigma) least-squares line of `values` over `times` (seconds), scale re-estimated
    from the residuals' MAD every round; the line's change over the time span with its standard error. The
    change is significant beyond 3 standard errors, 2 sigma and `min_change`."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
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


# A break in the capture times longer than this (and than 20 of the flight's own intervals) is a landing: a
# battery change takes minutes, survey images come every few seconds.
FLIGHT_BREAK_S = 60.0
# Two flights whose take-off altitudes (GPS altitude - RelativeAltitude) differ by less than this took off from
# one place: an uncorrected receiver's altitude wanders by a few metres between flights (2 x GNSS_WANDER_M of the
# pose check's horizontal floor), and a step that size is no evidence of another home point. Beyond it (and
# beyond the estimates' own noise) each flight keeps its own take-off altitude.
MIN_TAKEOFF_STEP_M = 5.0


def _value_at(fit: DriftFit, t0: float, t: float) -> float:
    """The fitted offset at time `t` (a line fitted from `t0`; the median when it does not drift)."""
    return fit.offset + fit.slope_per_s * (t - t0) if fit.significant else fit.median


def takeoff_altitudes(times: np.ndarray, offsets: np.ndarray, min_change: float = 0.0,
                      ) -> tuple[np.ndarray, list[tuple[np.ndarray, DriftFit]]]:
    """Per image, the altitude its barometric height (DJI RelativeAltitude, above the take-off point) is measured
    from, and the flights: [(image indices, their `fit_drift` of GPS altitude - RelativeAltitude)], in capture
    order. `offsets` (N,) is GPS altitude - RelativeAltitude (NaN without a GPS altitude), `times` (N,) seconds.

    A folder of two batteries taken off from two places has two: the barometer restarts at each take-off, and one
    line through both (the nu20 sweep: a second home 15 m higher, read as a GPS drift of +16 m) put the second
    flight's cameras 15 m low, landmarks 6 m low (some twice, 17 m apart), with the map's verdict "ok". So the
    images are split into flights at breaks in the capture times (`FLIGHT_BREAK_S`), and a flight joins the one
    before unless its take-off altitude (at its start) differs from that flight's line at its last image by more
    than `MIN_TAKEOFF_STEP_M` and 3 standard errors. One flight: the one fit of the whole folder, as before."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(offsets, dtype=np.float64)
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
                before, after = fit_drift(t[prev], v[prev], min_change), fit_drift(t[fixed], v[fixed], min_change)
                # each flight's line where it has images (not extended across the break: a drift that is noise,
                # stretched over a 5 min pause, made a step of 5 m in one flight; review rev19)
                jump = after.reference - _value_at(before, float(t[prev].min()), float(t[prev].max()))
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
        fit = fit_drift(t[fixed], v[fixed], min_change)
        takeoff[idx] = fit.reference
        flights.append((idx, fit))  # in capture order: idx[0] is the flight's first image
    return takeoff, flights
