"""Batch stage 3's choice of session pairs: every pair, or with --nearest K the pairs of nearby sessions plus each
flight's neighbours in time, each with why it was chosen (`pairs_chosen_by`)."""

from __future__ import annotations

import logging
import statistics
import time
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.multisession import nearest_pairs
from ...plugin.sampling import evenly_spaced

log = logging.getLogger(__name__)


# Dates a camera's clock falls back to when it loses power (the Unix, DOS/FAT and GPS epochs, and 2000-01-01 of
# many cameras' real-time clocks): a capture time within a month after one is a reset clock, not when it flew
CLOCK_RESET_DATES = {"1970-01-01": 0.0, "1980-01-01": 315532800.0, "1980-01-06": 315964800.0,
                     "2000-01-01": 946684800.0}
CLOCK_RESET_WINDOW_S = 31 * 86400.0
# one flight's images are taken within hours: one further from the flight's median than this has a wrong clock
FLIGHT_SPAN_S = 12 * 3600.0
FLIGHT_TIME_SAMPLES = 9  # images read per flight, spread evenly over it by name
ZONE_STEP_S = 900.0  # time zones are whole quarter hours from UTC
MAX_ZONE_S = 14 * 3600.0  # and within 14 h of it (UTC+14, Line Islands)


@dataclass(frozen=True)
class FlightTime:
    """When a flight was flown (`seconds`, since 1970: UTC when its images say their zone, `utc`; else the
    camera's clock), or why not (`seconds` None, `why`)."""

    seconds: float | None
    utc: bool = False
    why: str = ""


def _reset_date(t: float) -> str | None:
    return next((name for name, epoch in CLOCK_RESET_DATES.items() if epoch <= t < epoch + CLOCK_RESET_WINDOW_S),
                None)


def read_flight_time(images: Path | None) -> FlightTime:
    """When a flight was flown, from the capture times of up to 9 of its images spread over it (headers only):
    each image's time in UTC where it says how (GPSDateStamp/GPSTimeStamp, else DateTimeOriginal and its
    OffsetTimeOriginal; a flight whose images carry both GPS and camera times whole quarter hours apart takes that
    difference as its camera's zone for the images with the camera time only), else its camera clock. Times a
    reset clock gives (`CLOCK_RESET_DATES`) are left out, and so are those more than 12 h from the median of the
    rest; the flight's time is the median of the remaining ones if they are a majority of its timed images.
    Otherwise, or without images (an adopted mapped session), `seconds` is None and `why` says why."""
    from ...database.exif import read_capture_time
    from ...database.images import image_files
    from ...plugin.errors import InputError

    if images is None:
        return FlightTime(None, why="a mapped session, no images to read")
    metas = []
    files = sorted(image_files(images))
    for path in (files[i] for i in evenly_spaced(len(files), FLIGHT_TIME_SAMPLES)):
        try:
            metas.append(read_capture_time(path))
        except InputError:  # the map stage reports an image it cannot read
            continue
    # the camera's zone, from images carrying both its clock and the receiver's UTC (off by whole quarter hours)
    # (a zone is within 14 h: a reset camera clock can lie whole quarter hours, years, from the GPS time)
    zones = [z for m in metas if m.gps_time_utc_s is not None and m.capture_time_s is not None
             and _reset_date(m.gps_time_utc_s) is None
             and abs(z := round((d := m.capture_time_s - m.gps_time_utc_s) / ZONE_STEP_S) * ZONE_STEP_S) <= MAX_ZONE_S
             and abs(d - z) <= 120.0]
    zone = statistics.median_low(zones) if zones else None
    utc, local, resets = [], [], []
    for m in metas:
        # this image's times, best first: the receiver's UTC, the camera's clock in its zone, the clock alone
        # (time, in UTC, the clock's own reading: a reset is judged on that, before any zone moves it out of the
        # reset date's window: 2000-01-01 00:12 at +09:00 is 1999-12-31 in UTC, rev25)
        stamps = [(m.gps_time_utc_s, True, m.gps_time_utc_s)] if m.gps_time_utc_s is not None else []
        if (t := m.capture_time_s) is not None:
            offset = m.capture_offset_s if m.capture_offset_s is not None else zone
            stamps.append((t - offset, True, t) if offset is not None else (t, False, t))
        good = [(t, is_utc) for t, is_utc, clock in stamps if _reset_date(clock) is None]
        if good:
            (utc if good[0][1] else local).append(good[0][0])
        else:
            resets += [r for _, _, clock in stamps if (r := _reset_date(clock)) is not None]
    # UTC times where a flight has them: its camera-clock-only times are off by the unknown zone
    stamps, is_utc = (utc, True) if utc else (local, False)
    if not stamps:
        if resets:
            return FlightTime(None, why=f"its images' clocks were reset (dated {', '.join(sorted(set(resets)))})")
        return FlightTime(None, why="no image carries a capture time (EXIF DateTimeOriginal)" if metas
                          else "no readable images")
    median = statistics.median(stamps)
    kept = [t for t in stamps if abs(t - median) <= FLIGHT_SPAN_S]
    if 2 * len(kept) <= len(stamps):
        dates = sorted({time.strftime("%Y-%m-%d", time.gmtime(t)) for t in stamps})
        return FlightTime(None, why=f"its images' clocks disagree ({', '.join(dates)}, no majority within 12 h)")
    return FlightTime(statistics.median(kept), utc=is_utc)


def flight_times(images: dict[str, Path | None], warnings: list[str] | None = None) -> dict[str, float | None]:
    """Each flight's time (`read_flight_time`) by name; the flights without one are said in one warning line
    with why (their neighbours in time are not chosen), and when some flights' times are UTC and others' only
    their cameras' clocks (zone unknown), so is that their order within 14 h is uncertain. Each warning is also
    appended to `warnings` (batch's report.json `warnings`: a run that warned is not "ok", nu54)."""
    found = {name: read_flight_time(path) for name, path in images.items()}
    said = []
    untimed = [f"{name} ({ft.why})" for name, ft in sorted(found.items()) if ft.seconds is None]
    if untimed:
        said.append(f"--nearest: no usable capture time for {'; '.join(untimed)}; no flight is chosen for them as "
                    "their neighbour in time")
    timed = {name: ft for name, ft in found.items() if ft.seconds is not None}
    if any(ft.utc for ft in timed.values()) and (clock := sorted(n for n, ft in timed.items() if not ft.utc)):
        said.append(f"--nearest: {', '.join(clock)} carry their cameras' clock times without a zone (no "
                    "OffsetTimeOriginal, no GPS time), taken as UTC: their order against the other flights within "
                    "14 h is uncertain")
    for text in said:
        log.warning("%s", text)
    if warnings is not None:
        warnings.extend(said)
    return {name: ft.seconds for name, ft in found.items()}


def _footprint(session: str) -> tuple[float, float, float, float] | None:
    """The ground box (x0, y0, x1, y1) of a mapped session's landmarks, or None when it cannot be read."""
    from ...database.landmark_map import read_landmark_map
    from ...plugin.errors import InputError

    try:
        xy = read_landmark_map(Path(session) / "landmarks.sosmap").positions[:, :2]
    except (InputError, OSError, ValueError):
        return None
    if not len(xy):
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _overlap(a: tuple[float, ...] | None, b: tuple[float, ...] | None) -> bool:
    return a is not None and b is not None and min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1])


def time_neighbour_pairs(names: list[str], times: dict[str, float | None],
                         footprints: dict[str, tuple[float, float, float, float] | None]) -> list[tuple[str, str]]:
    """For each flight with a capture time, the pair with the flight flown last before it and the one flown first
    after it among those whose landmarks' ground boxes overlap its own: at most 2 pairs per flight, the pairs of
    consecutive surveys of one site ("what changed since the last flight"). Pairs (a, b) in the order of `names`."""
    order = sorted((n for n in names if times.get(n) is not None), key=lambda n: (times[n], n))
    rank = {n: k for k, n in enumerate(names)}
    chosen = set()
    for k, n in enumerate(order):
        before = next((m for m in reversed(order[:k]) if _overlap(footprints.get(n), footprints.get(m))), None)
        after = next((m for m in order[k + 1:] if _overlap(footprints.get(n), footprints.get(m))), None)
        for m in (before, after):
            if m is not None:
                chosen.add(tuple(sorted((n, m), key=rank.__getitem__)))
    return sorted(chosen, key=lambda p: (rank[p[0]], rank[p[1]]))


# why a pair was matched (report.json's `chosen_by` of every pair)
CHOSEN_ALL = "every pair"
CHOSEN_ALL_NO_FRAME = "every pair (--nearest needs every session's position in one frame)"
CHOSEN_NEAREST = "nearest by camera position"
CHOSEN_BY_TIME = "consecutive flights by capture time"
CHOSEN_OWN_FRAME = "every pair of a session in a local frame of its own (--nearest cannot place it)"


def own_frame(session: dict[str, Any]) -> bool:
    """Whether a mapped session (its batch record) is in a local frame of its own, which no other session shares:
    poses by structure from motion without GPS (its poses/poses.json in the session, EPSG 0: "origin on the
    ground under the flight"), or an OpenSfM reconstruction without reference_lla. Its position says nothing of
    where it lies against the others (rev48 D5: such sessions were "nearest" to whichever centre was nearest their
    own origin). A local frame given with the poses (a synth world, a poses.csv in `crs: local`) is taken as
    shared, as the user gave it."""
    if session.get("epsg"):
        return False
    if session.get("kind") in ("images", "opensfm"):
        return True
    return bool(session.get("session")) and (Path(session["session"]) / "poses" / "poses.json").is_file()


def frame_of(session: dict[str, Any]) -> int | None:
    """The frame a mapped session (its batch record) lies in, as both the choice of pairs by position and the
    session graph's map read it: its EPSG code, 0 for a local frame shared with the other sessions in one (a synth
    world, a poses.csv in `crs: local`), None for a local frame of its own (`own_frame`), which it shares with
    none."""
    return None if own_frame(session) else int(session.get("epsg") or 0)


def pairs_chosen_by(names: list[str], sessions: dict[str, dict[str, Any]], nearest: int | None,
                    times: dict[str, float | None] | None = None) -> dict[tuple[str, str], str]:
    """The session pairs to match, in the order of `combinations(names, 2)`, each with why it was chosen (one of
    the CHOSEN_* reasons). Every pair, or with `nearest` the pairs where one session is among the k nearest of the
    other by mean camera position, plus each flight's neighbours in time (`time_neighbour_pairs`; `times`: each
    flight's capture time, `flight_times`): the flights of one site all overlap, so the nearest by position are
    arbitrary among them (nu40, 6 flights, --nearest 2: 1-2..1-6, 2-6, 3-5, 3-6, 4-6 kept and 2-3, 3-4, 4-5, the
    consecutive surveys, dropped). A session in a local frame of its own (`own_frame`) is matched with every other
    one."""
    all_pairs = list(combinations(names, 2))
    if nearest is None:
        return dict.fromkeys(all_pairs, CHOSEN_ALL)
    # sessions in a local frame of their own are matched with every other one: nearness by position is no
    # nearness for them (`own_frame`)
    alone = [n for n in names if own_frame(sessions[n])]
    placed = [n for n in names if n not in alone]
    centres = [sessions[n].get("center") for n in placed]
    if any(c is None for c in centres) or len({frame_of(sessions[n]) for n in placed}) > 1:
        log.warning("--nearest needs every session's position in one frame; matching all %d pairs", len(all_pairs))
        return dict.fromkeys(all_pairs, CHOSEN_ALL_NO_FRAME)
    reasons = dict.fromkeys([(placed[i], placed[j]) for i, j in nearest_pairs(np.asarray(centres), nearest)]
                            if len(placed) > 1 else [], f"{CHOSEN_NEAREST} (--nearest {nearest})")
    if alone:
        log.warning("--nearest: %s %s in a local frame of its own (poses by structure from motion, not georeferenced): "
                    "its position says nothing of where it lies against the others, so it is matched with every other "
                    "session",
                    ", ".join(alone), "is" if len(alone) == 1 else "are each")
        reasons.update(dict.fromkeys([p for p in all_pairs if set(p) & set(alone)], CHOSEN_OWN_FRAME))
    timed = [n for n in names if (times or {}).get(n) is not None]
    if len(timed) >= 2:
        footprints = {n: _footprint(sessions[n]["session"]) for n in timed if sessions[n].get("session")}
        added = [p for p in time_neighbour_pairs(names, times or {}, footprints) if p not in reasons]
        if added:
            log.info("--nearest %d: %d pair(s) of flights consecutive in capture time (EXIF) among overlapping "
                     "ones matched too: %s", nearest, len(added), ", ".join(f"{a}-{b}" for a, b in added))
        reasons.update(dict.fromkeys(added, CHOSEN_BY_TIME))
    rank = {p: k for k, p in enumerate(all_pairs)}
    return {p: reasons[p] for p in sorted(reasons, key=rank.__getitem__)}
