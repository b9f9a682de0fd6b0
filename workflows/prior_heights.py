"""The images' reference heights (`prior_heights`): which source to trust for them, the GPS altitude or DJI's
barometric RelativeAltitude + a take-off altitude, and what the one says of the other.

A barometer does not restart within a flight, a GPS altitude can: an RTK receiver that loses its fix falls
back to a single-point solution, often in another height datum (nu34: ellipsoidal -> orthometric, a 30 m
step). So GPS altitude - RelativeAltitude per flight is fitted as a line or a step (`fit_drift`), and the
take-off altitude is the level of one segment, never a line through the step. Which source moves is named
where it is known: an RTK fixed altitude (DJI RtkFlag 50, RtkStdHgt of centimetres) is better than any
barometer, so when every fix is one the heights are the GPS altitude and a drift between the two is the
barometer's. Without RTK tags which of the two moves is left to the reconstruction (the georegistration
measures each against the block)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..database.exif import ImageMetadata
from ..plugin.height_drift import MIN_HEIGHT_DRIFT_M, DriftFit, takeoff_altitudes

# DJI RtkFlag: 0 no position, 16 single point, 34 float, 50 fixed. Where RtkStdHgt is missing, the vertical
# standard deviation each status typically has (a single fix: metres; float: decimetres; fixed: centimetres).
RTK_FIXED = 50
FLAG_HEIGHT_SIGMA_M = {16: 3.0, 34: 0.5, 50: 0.05}
# a fixed solution whose own vertical sigma is above this is not the centimetre altitude it is trusted as
RTK_FIXED_MAX_SIGMA_M = 0.1


def rtk_tags(metas: Sequence[ImageMetadata]) -> tuple[np.ndarray, np.ndarray]:
    """Per image, DJI's RtkFlag (-1 without) and the altitude's a-priori standard deviation in metres
    (RtkStdHgt, else the flag's typical one, NaN when neither is tagged)."""
    flags = np.full(len(metas), -1, dtype=np.int64)
    sigma = np.full(len(metas), np.nan)
    for i, m in enumerate(metas):
        if (f := m.xmp_float("RtkFlag")) is not None:
            flags[i] = int(f[0])
        if (s := m.xmp_float("RtkStdHgt")) is not None and s[0] > 0:
            sigma[i] = s[0]
        elif flags[i] in FLAG_HEIGHT_SIGMA_M:
            sigma[i] = FLAG_HEIGHT_SIGMA_M[int(flags[i])]
    return flags, sigma


# How far a RelativeAltitude may move between two images before it is no flight: a survey drone climbs and sinks
# at under 10 m/s (twice that as the bound), and below SPIKE_MIN_M the barometer's own noise and a gust.
MAX_VERTICAL_SPEED_MPS = 20.0
SPIKE_MIN_M = 30.0


def _neighbours(ok: np.ndarray, i: int) -> list[int]:
    """The nearest images with a value before and after image `i` (in capture order); at an end, the two nearest
    on its one side, so that an end image is judged against two as well."""
    before, after = np.flatnonzero(ok[:i])[::-1], np.flatnonzero(ok[i + 1:]) + i + 1
    picked = [int(k) for k in (*before[:1], *after[:1])]
    return picked if len(picked) == 2 else [int(k) for k in (*before[:2], *after[:2])]


def _between(rel: np.ndarray, times: np.ndarray, i: int, around: list[int]) -> float:
    """Image `i`'s value from its neighbours `around` (`_neighbours`): interpolated in time where they lie on
    either side of it in time as in order, else their mean."""
    if len(around) == 2 and around[0] < i < around[1] and times[around[0]] < times[i] < times[around[1]]:
        a, b = around
        return float(rel[a] + (rel[b] - rel[a]) * (times[i] - times[a]) / (times[b] - times[a]))
    return float(np.mean(rel[around]))


def relative_altitude_spikes(rel: np.ndarray, alt: np.ndarray, times: np.ndarray,
                             names: Sequence[str]) -> tuple[np.ndarray, str | None]:
    """`rel` (RelativeAltitude, capture order) with the values of images that jump away from both neighbours by
    more than the drone could climb or sink in between (`MAX_VERTICAL_SPEED_MPS`), the same way on both sides,
    while their GPS altitude `alt` does not follow, replaced by their two neighbours' (interpolated in `times`); and a
    warning naming them (None when there are none). A barometer that resets moves every image after it, a
    step `prior_heights` keeps; one damaged value is no step (nu59 D4: -9999 put one camera at z -9581 m and
    the warning blamed the GPS for jumping there and back)."""
    rel = np.asarray(rel, np.float64).copy()
    ok = np.isfinite(rel)
    if ok.sum() < 3:
        return rel, None
    bad = []
    for i in np.flatnonzero(ok):
        jumps = []
        for k in _neighbours(ok, int(i)):
            jump, bound = rel[i] - rel[k], max(SPIKE_MIN_M, MAX_VERTICAL_SPEED_MPS * abs(times[i] - times[k]))
            gps = alt[i] - alt[k]  # NaN where either has no GPS altitude: the barometer alone judges
            jumps.append(jump if abs(jump) > bound and not abs(jump - gps) <= bound else 0.0)
        if len(jumps) == 2 and jumps[0] * jumps[1] > 0:
            bad.append(int(i))
    if not bad:
        return rel, None
    said = [f"{names[i]} ({rel[i]:g} m against {', '.join(f'{rel[k]:g}' for k in _neighbours(ok, i))} m)"
            for i in bad[:3]]
    good = ok.copy()
    good[bad] = False
    # each from its own two neighbours in capture order: `np.interp` over all of them needs increasing times, which
    # the capture order of interleaved flights (one flight after the other) does not have (rev59 D2: a value of the
    # other flight's was taken)
    rel[bad] = [_between(rel, times, i, _neighbours(good, i)) for i in bad]
    return rel, (f"{len(bad)} image(s) have an XMP RelativeAltitude (barometric) far off their neighbours' while "
                 f"their GPS altitude is not, a damaged value: {'; '.join(said)}"
                 + (f" ... ({len(bad)} in all)" if len(bad) > 3 else "")
                 + "; replaced by their neighbours' RelativeAltitude (interpolated in capture time)")


@dataclass
class PriorHeights:
    """What `prior_heights` decided."""

    heights: np.ndarray  # (N,) reference heights (NaN where none)
    source: str  # said in the summary's altitude_source
    consistent: bool  # one datum the block can be held to (RelativeAltitude-based, or an RTK fixed altitude)
    rel_drift: DriftFit | None  # GPS altitude - RelativeAltitude of the first flight
    flights: list[tuple[np.ndarray, DriftFit]]
    takeoff_altitude_m: float | None
    warnings: list[str]


def _flag_change(flags: np.ndarray, before: np.ndarray, after: np.ndarray) -> str:
    """'RtkFlag 50 -> 16' when the most frequent RTK status differs on the two sides, else ''."""
    fb, fa = flags[before][flags[before] >= 0], flags[after][flags[after] >= 0]
    if not len(fb) or not len(fa):
        return ""
    mb, ma = Counter(fb.tolist()).most_common(1)[0][0], Counter(fa.tolist()).most_common(1)[0][0]
    return f"RtkFlag {mb} -> {ma}" if mb != ma else ""


def prior_heights(alt: np.ndarray, rel: np.ndarray, has: np.ndarray, times: np.ndarray, names: Sequence[str],
                  flags: np.ndarray, sigma: np.ndarray, takeoff_altitude_m: float | None) -> PriorHeights:
    """The reference heights of images with GPS altitudes `alt`, RelativeAltitudes `rel` (NaN without), a fix
    `has`, capture `times` (s), RTK `flags` and altitude `sigma` (`rtk_tags`), and a given take-off altitude
    (None: from the GPS). See the module doc; the warnings name the source that moves and what was done."""
    n = len(alt)
    fixed_alt = has & np.isfinite(alt)
    out = PriorHeights(alt.copy(), "GPS altitude", False, None, [], takeoff_altitude_m, [])
    if not (has.any() and np.isfinite(rel[has]).all()):
        return out
    rtk = bool(fixed_alt.any() and np.all(flags[fixed_alt] == RTK_FIXED)
               and np.all(np.nan_to_num(sigma[fixed_alt], nan=0.0) <= RTK_FIXED_MAX_SIGMA_M))
    takeoff = np.full(n, np.nan if takeoff_altitude_m is None else float(takeoff_altitude_m))
    if takeoff_altitude_m is not None:
        out.source, out.consistent = "given take-off altitude + XMP RelativeAltitude", True
        out.heights = takeoff + rel
        return out
    if not fixed_alt.any():
        return out
    # one take-off altitude per flight: a folder of two batteries may hold two home points
    takeoff, flights = takeoff_altitudes(times, np.where(fixed_alt, alt - rel, np.nan), MIN_HEIGHT_DRIFT_M, sigma)
    out.flights, out.rel_drift = flights, flights[0][1]
    out.takeoff_altitude_m = out.rel_drift.reference
    out.consistent = True
    if rtk:
        # an RTK fixed altitude of centimetres over a barometer: what moves between the two is the barometer
        out.source = "GPS altitude (RTK fixed, RtkFlag 50)"
        # a fix without an altitude keeps the barometric height on its flight's take-off altitude (rev23: NaN)
        out.heights = np.where(np.isfinite(alt), alt, takeoff + rel)
        for idx, fit in flights:
            if fit.significant:
                what = (f"jumps by {-fit.change:+.1f} m at {names[fit.first_at_step(idx, times)]}"
                        if fit.kind == "step" else f"drifts by {-fit.change:+.1f} m over the flight")
                out.warnings.append(f"the XMP RelativeAltitude (barometric) {what} against the RTK fixed GPS "
                                    "altitude (RtkFlag 50): heights from the GPS altitude")
        return out
    out.source = "take-off altitude (GPS at the start of the flight) + XMP RelativeAltitude"
    for idx, fit in flights:
        where = "" if len(flights) == 1 else f" from {names[idx[0]]}"
        if fit.kind == "step":
            k = fit.first_at_step(idx, times)
            before, after = idx[times[idx] < fit.step_time], idx[times[idx] >= fit.step_time]
            change = _flag_change(flags, before, after)
            kept = before if fit.kept == "before" else after
            why = (f"{change}: the receiver changed its fix, another height datum?" if change
                   else "another height datum of the receiver, or a barometer reset?")
            good = (" (RTK fixed)" if np.all(flags[kept] == RTK_FIXED) else "")
            out.warnings.append(
                f"the GPS altitude jumps by {fit.change:+.1f} m at {names[k]}{where} against the XMP "
                f"RelativeAltitude (barometric; {why}): heights from the take-off altitude {fit.reference:.1f} m of "
                f"the {len(kept)} images {fit.kept} the jump{good} + RelativeAltitude, one datum for the flight")
        elif fit.significant:
            out.warnings.append(
                f"the GPS altitude and the XMP RelativeAltitude (barometric) drift apart by {fit.change:+.1f} m "
                f"over the flight{where} (which of them moves, the reconstruction shows): heights from the take-off "
                f"altitude {fit.reference:.1f} m (GPS at the start) + RelativeAltitude")
    if len(flights) > 1:
        out.source = "each flight's take-off altitude (GPS at its start) + XMP RelativeAltitude"
        changes = [c for (a, _), (b, _) in zip(flights, flights[1:]) if (c := _flag_change(flags, a, b))]
        out.warnings.append(
            f"the images are {len(flights)} flights whose take-off altitudes differ (take-off altitudes "
            + ", ".join(f"{fit.reference:.1f} m from {names[idx[0]]} on" for idx, fit in flights)
            + ", from the GPS against the XMP RelativeAltitude): another home point"
            + (f", or another height datum of the GPS ({'; '.join(changes)})" if changes else "")
            + "? heights from each flight's own take-off altitude")
    out.heights = takeoff + rel
    return out

