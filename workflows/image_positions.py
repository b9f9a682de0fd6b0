"""Where a folder's images were taken, as one flight in one frame (pure numpy + pyproj; `image_priors` reads the
tags): the flight's middle (`median_position`, antimeridian-safe), fixes outside the CRS they are projected into
(`check_one_place`: a CRS of another place, or images of two places in one folder), heights of two sources in
one vertical datum (`one_vertical_datum`), what the track and the attitude tags say that no aircraft does
(`track_checks`), which EXIF fixes a telemetry file's track shows to be no measurement (`doubtful_fixes`), and
whether a telemetry file's positions mend the EXIF fixes or are another flight's (`telemetry_against_exif`), or
its rows are joined to the images a whole number of images off (`rows_shifted`), whether DJI's XMP position
and the EXIF GPS of the same images part (`xmp_against_exif`), and whether capture times that jump back by days
split the folder into flights of one place (`flights_of_one_place`)."""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..database.exif import ImageMetadata
from ..plugin.errors import InputError
from ..plugin.geodesy import METRES_PER_DEGREE, geographic_to_grid, utm_epsg
from ..plugin.gps_track import (
    FROZEN_SPREAD_M,
    MOVING_STEP_M,
    OFF_NADIR_LIMIT_DEG,
    QUANTISATION_WARN_SIGMA_M,
    frozen_fix,
    gps_jumps,
    off_nadir_deg,
    quantisation,
    repeated_fixes,
)
from ..plugin.keyframes import reads_as_flight
from ..plugin.pose_check.gps import GNSS_WANDER_M, fix_jitter_m, fresh_fixes, stale_fixes

log = logging.getLogger(__name__)


def doubtful_fixes(fixes: np.ndarray, reference: np.ndarray, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of the images' own GPS fixes (K,2 metres, east-north) are no measurement of where they were, judged
    against another track of the same images (`reference`, K,2: a telemetry file's) and their capture times (K,;
    NaN where unknown, then name order and no speeds): (stale, jumped), two (K,) bool masks.
    - stale: the fixes of a receiver holding one position while the reference moves (`pose_check.gps.stale_fixes`,
      every fix after the first of such a run), or all of them when they lie at one point (`frozen_fix`);
    - jumped: the others' fixes on the far side of a jump the aircraft cannot fly between two captures
      (`gps_track.gps_jumps`, over the fixes that are not stale, whose zero speeds would lower the flight's):
      the track cut at its jumps, every part but the one holding the most fixes (none with two such parts of one
      size: no telling which is wrong). Without capture times no jump is judged."""
    f, ref = np.asarray(fixes, np.float64).reshape(-1, 2), np.asarray(reference, np.float64).reshape(-1, 2)
    t = np.asarray(times_s, np.float64).reshape(-1)
    timed = len(t) > 0 and bool(np.all(np.isfinite(t)))
    order = np.argsort(t, kind="stable") if timed else np.arange(len(f))
    stale, jumped = np.zeros(len(f), bool), np.zeros(len(f), bool)
    if frozen_fix(f[:, 0], f[:, 1]):
        return ~stale, jumped
    stale[order] = stale_fixes(ref[order], f[order])
    if timed:
        fresh = np.where(stale[order][:, None], np.nan, f[order])
        cuts = [j for _, j, _, _ in gps_jumps(fresh[:, 0], fresh[:, 1], t[order])]
        part = np.searchsorted(np.asarray(cuts, int), np.arange(len(f)), side="right")  # per ordered fix
        sizes = np.bincount(part[~stale[order]], minlength=len(cuts) + 1)
        if len(cuts) and np.sum(sizes == sizes.max()) == 1:
            jumped[order] = (part != int(np.argmax(sizes))) & ~stale[order]
    return stale, jumped

# telemetry and EXIF altitudes of the same images differing by more than this are said to be of two datums
HEIGHT_DATUM_NOTE_M = 1.0


def one_vertical_datum(alt: np.ndarray, from_telemetry: np.ndarray, tele_alt: np.ndarray, exif_alt: np.ndarray,
                        telemetry: Any) -> np.ndarray:
    """The images' altitudes (`alt`, NaN where none) in one vertical datum, the telemetry's, when some come from
    the telemetry CSV (`from_telemetry`) and others from their EXIF: a log of heights above the ellipsoid or
    the take-off point beside EXIF heights above sea level differ by tens of metres, and a flight whose heights
    jump by that between images makes a map of nothing. The offset is measured on the images that have both
    (median of telemetry - EXIF) and added to the EXIF heights; with no image to measure it on, a warning."""
    from_exif = np.isfinite(alt) & ~from_telemetry
    if not (from_telemetry.any() and from_exif.any()):
        return alt
    both = np.isfinite(tele_alt) & np.isfinite(exif_alt)
    if not both.any():
        log.warning("heights: %d images take their altitude from %s and %d from their EXIF GPS, and no image has "
                    "both to measure the offset between the two (above the ellipsoid, the sea or the take-off "
                    "point: tens of metres apart?): give every image an altitude in the telemetry",
                    int(from_telemetry.sum()), telemetry, int(from_exif.sum()))
        return alt
    offset = float(np.median(tele_alt[both] - exif_alt[both]))
    if abs(offset) > HEIGHT_DATUM_NOTE_M:
        log.info("heights: %d images without an altitude in %s take their EXIF altitude %+.1f m, the offset of the "
                 "telemetry's heights from the EXIF's (median of the %d images with both): one vertical datum",
                 int(from_exif.sum()), telemetry, offset, int(both.sum()))
    out = alt.copy()
    out[from_exif] += offset
    return out


def median_position(lat: np.ndarray, lon: np.ndarray) -> tuple[float, float]:
    """The median latitude and longitude of fixes (degrees); longitudes are taken relative to the first fix, so a
    flight across the antimeridian has its median there, not on the other side of the Earth."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    relative = (lon - lon[0] + 180.0) % 360.0 - 180.0
    middle = (float(np.median(relative)) + lon[0] + 180.0) % 360.0 - 180.0
    return float(np.median(lat)), float(middle)


def check_one_place(lat: np.ndarray, lon: np.ndarray, east: np.ndarray, north: np.ndarray, epsg: int,
                     names: list[str], images: Any) -> None:
    """InputError naming `images` when some fixes lie far outside where the poses' CRS is used (more than
    `database.geojson.CRS_AREA_MARGIN_M` beyond its area of use). Projected into a CRS not made for them, fixes
    get coordinates without any meaning, which later checks read as a mirrored or a wildly scaled flight. Two
    causes are told apart by the fixes' own spread: a flight at one place in a CRS of elsewhere (an --epsg of
    another zone), or images of two places in one folder."""
    from pyproj import CRS

    from ..database.geojson import CRS_AREA_MARGIN_M, outside_crs_area

    has = np.isfinite(east) & np.isfinite(north)
    far = np.flatnonzero(has & outside_crs_area(epsg, np.column_stack([east, north])))
    if not len(far):
        return
    k = int(far[0])
    where = (f"{len(far)} of {int(has.sum())} images' GPS fixes lie more than {CRS_AREA_MARGIN_M / 1000:.0f} km "
             f"outside where EPSG:{epsg} ({CRS.from_epsg(epsg).name}) is used (e.g. {names[k]} at {lat[k]:.4f}, "
             f"{lon[k]:.4f})")
    mid_lat, mid_lon = median_position(lat[has], lon[has])
    dlon = (lon[has] - mid_lon + 180.0) % 360.0 - 180.0
    spread_m = np.hypot((lat[has] - mid_lat) * METRES_PER_DEGREE,
                        dlon * METRES_PER_DEGREE * np.cos(np.radians(lat[has])))
    own = utm_epsg(mid_lat, mid_lon)
    if float(spread_m.max()) <= CRS_AREA_MARGIN_M and own != epsg:
        raise InputError(f"{where}: the flight is at one place, in a CRS made for another; give the --epsg of "
                         f"its place, e.g. EPSG:{own} ({CRS.from_epsg(own).name})", images)
    raise InputError(f"{where}: images of two places in one folder? map each flight on its own (a flight that "
                     "long: give --epsg of a CRS that holds it all)", images)


def coarse_fixes(lat: np.ndarray, lon: np.ndarray, east: np.ndarray, north: np.ndarray,
                 times: np.ndarray | None = None, exposures: np.ndarray | None = None) -> tuple[str | None,
                                                                                               dict | None]:
    """Fixes coarser than the receiver gives them (`plugin.gps_track.quantisation`): rounded to a grid of latitude
    and longitude, or repeated exactly while the aircraft flies on. Returns the one warning and the summary's
    `gps_quantisation` (its `sigma_m`, step / sqrt(12), is added to the GPS noise every consumer assumes:
    `gps_track.with_quantisation`), or (None, None). Capture `times` and `exposures` (s) tell a burst or a
    bracket at one place from a lagging receiver (`gps_track.repeated_fixes`)."""
    repeats, moving_m = repeated_fixes(east, north, times, exposures)
    q = quantisation(lat, lon)
    fixed = int(np.sum(np.isfinite(east) & np.isfinite(north)))
    if q is not None and q.sigma_m < QUANTISATION_WARN_SIGMA_M:
        log.info("the GPS positions lie on a grid of %.2g x %.2g deg latitude x longitude (%.1f m north x %.1f m "
                 "east): rounded by the tool that wrote them; counted as GPS noise of %.2f m more", q.step_lat_deg,
                 q.step_lon_deg, q.step_north_m, q.step_east_m, q.sigma_m)
        return None, {**q.to_dict(), "repeated_fixes": repeats}
    if q is not None:
        again = f"; {repeats} images repeat the previous image's fix" if repeats else ""
        return (f"the GPS positions of all {fixed} images with a fix lie on a grid of {q.step_lat_deg:.2g} x "
                f"{q.step_lon_deg:.2g} deg latitude x longitude ({q.step_north_m:.1f} m north x {q.step_east_m:.1f} "
                f"m east{again}): rounded or truncated by the tool that wrote them (a privacy tool, an export to few "
                f"decimals?), each fix up to a step off; counted as GPS noise of {q.sigma_m:.1f} m more (step / "
                "sqrt(12)); the originals' fixes are better", {**q.to_dict(), "repeated_fixes": repeats})
    if repeats >= 2 and np.isfinite(moving_m) and moving_m > MOVING_STEP_M:
        sigma = moving_m / math.sqrt(12.0)
        return (f"{repeats} of {fixed} images repeat the previous image's GPS fix exactly while the aircraft moves "
                f"{moving_m:.1f} m between captures (median): a receiver updating slower than the camera; their "
                f"positions lag by up to that, counted as GPS noise of {sigma:.1f} m more",
                {"repeated_fixes": repeats, "step_along_track_m": round(moving_m, 3), "sigma_m": round(sigma, 3)})
    return None, None


def track_checks(east: np.ndarray, north: np.ndarray, heights: np.ndarray, times: np.ndarray, timed: bool,
                  rotations: np.ndarray, tagged: np.ndarray, names: list[str],
                  lat: np.ndarray | None = None, lon: np.ndarray | None = None,
                  exposures: np.ndarray | None = None) -> tuple[list[str], dict[str, Any]]:
    """What the GPS track and the attitude tags say that no aircraft does (`plugin.gps_track`): warnings naming
    images, and the facts for the summary (`gps_frozen`, `gps_jumps`, `gps_quantisation` with `lat`/`lon`, the
    fixes in degrees, `tags_median_off_nadir_deg`; `exposures`, s, tell bracketing from a lagging receiver). Without
    capture times (`timed` False: `times` are one second per image) there is no speed, so no jump is judged: the
    step to the next line or battery is as long as a wrong fix."""
    out: list[str] = []
    frozen = frozen_fix(east, north)
    jumps = [] if frozen or not timed else gps_jumps(east, north, times, heights)
    if frozen:
        fixed = int(np.sum(np.isfinite(east)))
        out.append(f"the GPS fixes of all {fixed} images{'' if fixed == len(names) else ' with a fix'} lie within "
                   f"{FROZEN_SPREAD_M:g} m of one point: a receiver without a lock repeats its last fix; poses from "
                   "them have no baseline")
    elif jumps:
        said = ", ".join(f"{names[i]} -> {names[j]} {d:.0f} m" + (f" at {v:.0f} m/s" if timed else "")
                         for i, j, d, v in jumps[:4])
        out.append(f"the GPS jumps {len(jumps)} time(s) farther than the aircraft flies between two captures "
                   f"({said}{', ...' if len(jumps) > 4 else ''}): wrong fixes; their images' positions are wrong")
    coarse, quantised = (None, None) if frozen or lat is None or lon is None else coarse_fixes(
        lat, lon, east, north, times if timed else None, exposures)
    if coarse:
        out.append(coarse)
    off = off_nadir_deg(rotations[tagged]) if np.any(tagged) else np.zeros(0)
    median_off = float(np.median(off)) if len(off) else None
    if median_off is not None and median_off > OFF_NADIR_LIMIT_DEG:
        out.append(f"the attitude tags turn {int(np.sum(off > OFF_NADIR_LIMIT_DEG))} of {len(off)} cameras more "
                   f"than {OFF_NADIR_LIMIT_DEG:g} deg away from straight down (median {median_off:.0f} deg): a "
                   "survey camera looks at the ground; tags written in another pitch convention (DJI gimbal pitch "
                   "-90 = nadir, 0 = horizon; airframe tags: --mount, --pitch-sign)?")
    facts = {"gps_frozen": frozen, "gps_quantisation": quantised,
             "gps_jumps": [[names[i], names[j], round(d, 1)] for i, j, d, _ in jumps],
             "tags_median_off_nadir_deg": median_off}
    return out, facts


# A telemetry CSV's positions replace the EXIF GPS (module doc). A copy of the same receiver's agrees to
# centimetres (Seneca: < 1 mm), a PPK / RTK solution moves a consumer fix by metres: beyond TELEMETRY_NOTE_M
# (median) the log says by how much; beyond TELEMETRY_WARN_M, the distance another datum (100-200 m) or another
# flight's log with the same file names puts them, it warns (the pose check's `warn_gps_offset_m` for the same
# reason); below it, beyond what the GPS noise explains where it can be measured (ROW_SHIFT_NOISES)
TELEMETRY_NOTE_M = 1.0
TELEMETRY_WARN_M = 50.0
# Beyond this disagreement the telemetry's position is not the image's position corrected: no GPS error
# (metres; tens with multipath) or datum still met on a receiver or an autopilot's log (WGS84 against NAD27,
# ED50, Pulkovo 1942: 0.1-0.2 km; against the Tokyo datum, the largest: ~0.5 km) moves a fix by a kilometre.
# A whole flight moved further is a wrong file: another site's log under the same file names, coordinates without
# their sign (rev38: Seneca posed in China, 14,000 km off, exit 0). Refused when most plausible EXIF fixes are so
# far (`telemetry_against_exif`: wrong EXIF fixes are so far on a subset only); between the two bounds, a warning.
# Not relative to the flight's extent: neither a datum's shift nor a GPS error grows with the flight.
TELEMETRY_REFUSE_M = 1000.0


# A log joined to the images by order, one row off, gives each image the position of its neighbour: the offset
# is a whole number of capture steps along the track, and pairing each log row with the EXIF fix MAX_ROW_SHIFT
# images away or fewer explains it. Said when that pairing fits to within ROW_FIT_NOISES times the GPS noise
# and the rows as given lie beyond ROW_SHIFT_NOISES times it (the noise: the larger of either track's jitter and
# GNSS_WANDER_M; another receiver's log, a PPK solution beside a consumer fix, differs by its bias, which a
# neighbour's fix can match on a straight line only by chance). Any other offset beyond ROW_SHIFT_NOISES times
# the receivers' noise (at least 10 m; TELEMETRY_WARN_M before) is a warning: no receiver's error puts a log that
# far from the camera's own fixes (a time offset, another datum)
MAX_ROW_SHIFT = 3
ROW_SHIFT_NOISES = 4.0
# the shifted pairing explains the offset when it fits to within this many times the receivers' noise (a row shift
# fits to the two tracks' noise: 0.0-4.9 m on Seneca's fixes with 0-4 m of noise added, noise 2.5-6.8 m)
ROW_FIT_NOISES = 2.0
# a log whose positions match the EXIF fixes of other images to this (a fix written to 6 decimals: 0.1 m) copies
# them: one receiver's values, joined to the wrong images (two receivers' fixes differ by their noise, metres)
COPIED_FIX_M = 0.1
# fewer images with both positions: no shift is judged (the median of a handful of pairs is no measurement)
MIN_ROW_SHIFT_IMAGES = 6
# a flight whose steps along its axis go this share each way at least is flown both ways (`flown_both_ways`)
BOTH_WAYS_SHARE = 0.2


def rows_shifted(exif_xy: np.ndarray, tele_xy: np.ndarray, order: np.ndarray) -> tuple[int, float, float, float]:
    """Whether a telemetry log's rows are joined to the images a whole number of images off: the images' own EXIF
    fixes and the log's positions (K,2 metres, one frame), `order` the capture order. Returns (shift, as given,
    shifted, noise): the shift N (0: none; N > 0 means each image holds the row of the image N later), the median
    distance of the log's positions from the images' own fixes and from the fixes N images later (the nearest
    pairing), and the receivers' noise (`receivers_noise_m`). A shift of a log that copies the EXIF fixes (shifted
    within COPIED_FIX_M) is judged against COPIED_FIX_M instead (constants above)."""
    e, g = np.asarray(exif_xy, np.float64)[order], np.asarray(tele_xy, np.float64)[order]
    n = len(e)
    # a fix repeating its predecessor (a receiver logging slower than the camera shoots, a held fix) was measured
    # at another capture and cannot tell which image a row belongs to: a 1 Hz receiver under a 2 Hz camera matched
    # its neighbour's row at every other image, and a correct log was refused as shifted (rev47)
    fresh_e, fresh_g = fresh_fixes(e), fresh_fixes(g)
    by_shift: dict[int, float] = {}
    for k in range(-MAX_ROW_SHIFT, MAX_ROW_SHIFT + 1):
        rows, fixes = slice(max(0, -k), n - max(0, k)), slice(max(0, k), n + min(0, k))
        both = fresh_g[rows] & fresh_e[fixes]
        if both.sum() >= MIN_ROW_SHIFT_IMAGES:
            by_shift[k] = float(np.median(np.linalg.norm(g[rows][both] - e[fixes][both], axis=1)))
    if 0 not in by_shift:
        return 0, math.nan, math.nan, math.nan
    best = min(by_shift, key=by_shift.get)
    noise = receivers_noise_m(e, g)
    # a log that copies the EXIF fixes (the same receiver's values, to COPIED_FIX_M) has no noise between the two:
    # a shift of its rows is then judged against that, so short capture steps are seen too
    judged = COPIED_FIX_M if by_shift[best] <= COPIED_FIX_M else noise
    # the shifted pairing must fit to within the noise (a time offset of 2.5 captures is no shift of rows) and the
    # rows as given lie beyond ROW_SHIFT_NOISES x it
    if best == 0 or by_shift[best] > ROW_FIT_NOISES * judged or by_shift[0] <= ROW_SHIFT_NOISES * judged:
        return 0, by_shift[0], by_shift[best], noise
    return best, by_shift[0], by_shift[best], noise


def receivers_noise_m(exif_xy: np.ndarray, tele_xy: np.ndarray) -> float:
    """The noise two tracks of one flight (K,2 metres, capture order) are judged against: the larger of either
    track's jitter (`fix_jitter_m`) and GNSS_WANDER_M."""
    return max([GNSS_WANDER_M, *(v for v in (fix_jitter_m(exif_xy), fix_jitter_m(tele_xy)) if np.isfinite(v))])


def flown_both_ways(fixes: np.ndarray) -> bool:
    """Whether a flight's fixes (K,2 metres, capture order) hold steps flown both ways along its main axis (a
    lawnmower, a line flown out and back): at least BOTH_WAYS_SHARE of the steps longer than GNSS_WANDER_M and
    within 60 deg of the axis point each way. A constant offset along the track then cannot pass for a row shift,
    which moves the positions forward on every line (`judge_row_shift`)."""
    steps = np.diff(np.asarray(fixes, np.float64).reshape(-1, 2), axis=0)
    length = np.linalg.norm(steps, axis=1)
    steps = steps[length > GNSS_WANDER_M] / length[length > GNSS_WANDER_M, None]
    if len(steps) < 2:
        return False
    axis = np.linalg.eigh(steps.T @ steps)[1][:, -1]  # the steps' main direction, either sense
    along = steps @ axis
    forward, back = int((along > 0.5).sum()), int((along < -0.5).sum())
    return min(forward, back) >= BOTH_WAYS_SHARE * (forward + back)


def local_metres(ll: np.ndarray) -> np.ndarray:
    """(K,2) lat, lon (degrees) as east, north metres about their median (antimeridian-safe): tracks to compare."""
    lat0, lon0 = median_position(ll[:, 0], ll[:, 1])
    dlon = (ll[:, 1] - lon0 + 180.0) % 360.0 - 180.0
    return np.column_stack([dlon * METRES_PER_DEGREE * np.cos(np.radians(ll[:, 0])),
                            (ll[:, 0] - lat0) * METRES_PER_DEGREE])


def telemetry_against_exif(telemetry: str | Path | None, exif_ll: np.ndarray, tele_ll: np.ndarray,
                           times_s: np.ndarray) -> list[str]:
    """Judge how far a telemetry CSV's positions moved the images' own EXIF fixes (`exif_ll`, `tele_ll`: the lat,
    lon of each image with both; `times_s` the images' capture times, NaN where unknown; the horizontal distance in
    metres at the EXIF fix's latitude):
    logged beyond TELEMETRY_NOTE_M (median), a warning returned for the summary beyond TELEMETRY_WARN_M (it was in
    the log only: poses.json and run.json never said it) or where any image moved beyond TELEMETRY_REFUSE_M, an
    InputError when the telemetry lies beyond TELEMETRY_REFUSE_M from most of the EXIF fixes that are plausible.

    Why the majority of the plausible fixes (rev39: a receiver's stale fix 5 km off at 6 of 10 images put the
    median beyond the bound, and the log that mends them was refused, the remedy named keeping the wrong
    positions): a wrong file (another flight's log, coordinates without their sign) disagrees with the EXIF
    track everywhere, wrong EXIF fixes only on a subset. The fixes the telemetry's own track shows to be no
    measurement (`image_positions.doubtful_fixes`: held at one point while the telemetry moves, all at one point,
    beyond a jump the aircraft cannot fly) are left out; of the rest, the telemetry is refused when more than half
    lie beyond the bound, and taken with a warning counting the wrong EXIF fixes otherwise (none left: taken)."""
    moved = distances_from_fixes(exif_ll, tele_ll)
    far = moved > TELEMETRY_REFUSE_M
    if not len(moved) or ((median := float(np.median(moved))) <= TELEMETRY_NOTE_M and not far.any()):
        return []
    said = f"positions from {telemetry}, not the images' EXIF GPS: they differ by {median:.1f} m (median of " \
           f"{len(moved)} images)"
    # below TELEMETRY_WARN_M the offset is judged against the GPS noise (`judge_row_shift`): a log joined a whole
    # number of rows off is refused; another offset beyond what the noise explains is warned about
    limit = judge_row_shift(telemetry, exif_ll, tele_ll, times_s) if not far.any() else TELEMETRY_WARN_M
    if median <= min(limit, TELEMETRY_WARN_M) and not far.any():
        log.info("%s", said)
        return []
    stale, jumped = doubtful_fixes(local_metres(exif_ll), local_metres(tele_ll), times_s)
    plausible = ~(stale | jumped)
    disagree = far & plausible
    counts = [(int(stale.sum()), "stale"), (int(jumped.sum()), "beyond a jump")]
    if 2 * int(disagree.sum()) > int(plausible.sum()):
        swapped = swapped_columns(exif_ll[plausible], tele_ll[plausible])
        if swapped is not None:
            raise InputError(swapped, telemetry)
        # kept under errors.MAX_PROBLEM_CHARS (cut there): every remedy must reach the user
        skipped = ", ".join(f"{k} {what}" for k, what in counts if k)
        raise InputError(f"its positions lie {float(np.median(moved[plausible])):.0f} m from the images' own EXIF "
                         f"GPS (median) at {int(disagree.sum())} of {int(plausible.sum())} images"
                         + (f" (left out: {skipped})" if skipped else "")
                         + f", beyond GPS error or datum ({TELEMETRY_REFUSE_M:.0f} m): another flight's log, or "
                         "unsigned coordinates (add GPSLatitudeRef/GPSLongitudeRef columns)? Fix it, or drop its "
                         "lat/lon columns to keep the images' GPS; if that GPS is wrong, use copies of the images "
                         "without GPS tags", telemetry)
    left_out = "; ".join(f"{k} {what}" for k, what in zip(
        (k for k, _ in counts), ("stale, held at one point while the telemetry moves",
                                 "beyond a jump the aircraft cannot fly")) if k)
    if stale.all():
        said += ": the images' own fixes all lie at one point (a receiver without a lock), so the telemetry's are " \
                "taken"
    elif far.any():
        said += f": {int(far.sum())} of the images' own EXIF fixes lie more than {TELEMETRY_REFUSE_M:.0f} m from it" \
                f" and it agrees with {int(plausible.sum() - disagree.sum())} of the {int(plausible.sum())} " \
                f"plausible ones" + (f" (EXIF fixes {left_out})" if left_out else "") + ": wrong EXIF GPS, " \
                "mended by the telemetry's positions"
    else:
        said += (": the telemetry of another flight, or another datum?" if median > TELEMETRY_WARN_M else
                 f", beyond the {limit:.0f} m the GPS noise explains: a time offset between the log and the camera, "
                 "another datum, or another flight's log?")
    log.warning("%s", said)
    return [said]


def swapped_columns(exif_ll: np.ndarray, tele_ll: np.ndarray) -> str | None:
    """Why a telemetry file far from the images' own EXIF fixes (`exif_ll`, `tele_ll`: lat, lon of the images
    with both) is wrong, when its latitude and longitude read the other way round lie within TELEMETRY_REFUSE_M of
    most of them: its columns are swapped (rev56 D7: an ODM geo.txt in EPSG:4326 holds the longitude first, and a
    file written latitude first reads as a place on the other side of the globe whenever both are within +-90).
    Else None. The images' own GPS is the only evidence: a swapped flight's shape and spacing are as plausible."""
    if not len(exif_ll):
        return None
    turned = np.asarray(tele_ll, np.float64)[:, ::-1]
    if not (np.abs(turned[:, 0]) <= 90.0).all():
        return None
    gap = distances_from_fixes(exif_ll, turned)
    if 2 * int((gap <= TELEMETRY_REFUSE_M).sum()) <= len(gap):
        return None
    given_km = float(np.median(distances_from_fixes(exif_ll, tele_ll))) / 1000.0
    return (f"its latitude and longitude look swapped: read the other way round, its positions lie "
            f"{float(np.median(gap)):.0f} m from the images' own EXIF GPS (median of {len(gap)} images), as given "
            f"{given_km:.0f} km. Swap its columns (an ODM geo.txt in EPSG:4326 gives the longitude first: "
            "image_name lon lat [alt])")


def distances_from_fixes(exif_ll: np.ndarray, other_ll: np.ndarray) -> np.ndarray:
    """Horizontal distances (metres) of positions `other_ll` from the images' EXIF fixes `exif_ll` (lat, lon rows,
    degrees), at the EXIF fix's latitude: how far a telemetry file moves them."""
    return np.hypot((other_ll[:, 0] - exif_ll[:, 0]) * METRES_PER_DEGREE,
                    (other_ll[:, 1] - exif_ll[:, 1]) * METRES_PER_DEGREE * np.cos(np.radians(exif_ll[:, 0])))


def judge_row_shift(telemetry: str | Path | None, exif_ll: np.ndarray, tele_ll: np.ndarray,
                    times_s: np.ndarray) -> float:
    """InputError naming `telemetry` when its rows are joined to the images a whole number of images off
    (`rows_shifted`; arguments as `telemetry_against_exif`'s): every image would take its neighbour's position,
    the poses and the map a capture step off their place, while the flight looks as smooth as a correct one
    (nu53 H1: 32.7 m off, taken with an INFO line, the map's verdict "ok"). Capture order from `times_s` where
    every image has one, else the order given. Otherwise the offset the GPS noise explains (ROW_SHIFT_NOISES x
    `rows_shifted`'s noise; inf with too few images to measure it)."""
    both = np.column_stack([exif_ll, tele_ll]).reshape(-1, 2)
    xy = local_metres(both).reshape(-1, 4)  # one frame for the two tracks
    t = np.asarray(times_s, np.float64).reshape(-1)
    order = np.argsort(t, kind="stable") if len(t) and np.all(np.isfinite(t)) else np.arange(len(xy))
    shift, given, shifted, noise = rows_shifted(xy[:, :2], xy[:, 2:], order)
    # flown one way only (a corridor, lines all flown alike), a constant offset along the track (another datum, a
    # time offset) is a row shift to the positions: a shift is said where lines flown both ways agree on it, and
    # elsewhere the offset is only a warning beyond the noise (rev47: an RTK log 12 m north of a northbound
    # corridor of 12 m steps was refused)
    if shift and flown_both_ways(xy[order, :2]):
        way = "later" if shift > 0 else "earlier"
        raise InputError(f"its rows look shifted by {abs(shift)} image(s): each image gets the position of the image "
                         f"{abs(shift)} {way} in capture order (its positions lie {given:.1f} m from the images' own "
                         f"EXIF GPS, median; {shifted:.1f} m from those {way} images'"
                         + (": their fixes, copied" if shifted <= COPIED_FIX_M else f"; GPS noise {noise:.1f} m")
                         + "): "
                         "join its rows to the images by FileName, not by order, or drop its lat/lon columns (or, "
                         "if the log is right, the images' own EXIF fixes lag that many captures)", telemetry)
    return ROW_SHIFT_NOISES * noise if np.isfinite(noise) else math.inf


XMP_EXIF_TOLERANCE_M = 5.0  # two records of one fix; a consumer receiver's noise is metres, not tens


def xmp_against_exif(metas: list[ImageMetadata], east: np.ndarray, north: np.ndarray, epsg: int) -> str | None:
    """A warning when images hold a DJI XMP position (`ImageMetadata.xmp_position`) more than
    `XMP_EXIF_TOLERANCE_M` from their EXIF GPS position (`east`, `north`: the EXIF ones in `epsg`), else None: one
    of the two was edited (a geotagging tool rewrote the EXIF only) and the EXIF one is used."""
    idx = [i for i, m in enumerate(metas) if m.xmp_position is not None and np.isfinite(east[i])]
    if not idx:
        return None
    xe, xn, _ = geographic_to_grid(np.array([metas[i].xmp_position[0] for i in idx]),  # type: ignore[index]
                                   np.array([metas[i].xmp_position[1] for i in idx]), epsg)  # type: ignore[index]
    gap = np.hypot(xe - east[idx], xn - north[idx])
    far = gap > XMP_EXIF_TOLERANCE_M
    if not far.any():
        return None
    worst = int(np.argmax(gap))
    return (f"{int(far.sum())} of {len(idx)} images hold a DJI XMP position (drone-dji:GpsLatitude/GpsLongitude) "
            f"more than {XMP_EXIF_TOLERANCE_M:.0f} m from their EXIF GPS position (up to {gap[worst]:.1f} m, "
            f"{metas[idx[worst]].path.name}): the EXIF one is used; if a tool rewrote it, check which is right")


# Flights of one folder apart by at least this much (s) are separate flights, not a pause between batteries
SEPARATE_FLIGHTS_GAP_S = 3600.0


def flights_of_one_place(times: np.ndarray, centers: np.ndarray, names: list[str]) -> str | None:
    """A warning when the capture times (`times`, `centers` (N, >=2) and `names` in the listed order), sorted, fall
    into groups apart by SEPARATE_FLIGHTS_GAP_S or more (and by more than any group lasts) that are flights of one
    place: each group in its time order one flight (`plugin.keyframes.reads_as_flight`), and each later group's
    frames, at the median, within one flight step of the first group's (the same ground again). None otherwise,
    e.g. for a camera clock reset mid-flight, whose later frames carry on over new ground (`image_priors` names
    that as such). nu58 D6: the same place flown a day apart, in one folder, was called "a camera clock reset?",
    "fix the dates"; rev56 D3: the groups are cut where the sorted times part, whatever order the names list
    them in (they were cut only where the listed times went back, so the same folder named in time order was
    mapped as one flight without a word)."""
    t = np.asarray(times, dtype=np.float64)
    xy = np.asarray(centers, dtype=np.float64)[:, :2]
    if len(t) < 2 or not np.isfinite(t).all() or not np.isfinite(xy).all():
        return None
    timed = np.argsort(t, kind="stable")
    cuts = np.flatnonzero(np.diff(t[timed]) >= SEPARATE_FLIGHTS_GAP_S) + 1
    if not len(cuts):
        return None
    groups = np.split(timed, cuts)
    spans = [(float(t[g].min()), float(t[g].max())) for g in groups]
    gaps = [b[0] - a[1] for a, b in zip(spans, spans[1:])]
    if min(gaps) < max(e - s for s, e in spans):
        return None
    ordered = groups  # each in time order already
    if any(len(g) < 3 or not reads_as_flight(xy[g]) for g in ordered):
        return None
    steps = np.concatenate([np.linalg.norm(np.diff(xy[g], axis=0), axis=1) for g in ordered])
    step = float(np.median(steps))
    first = cKDTree(xy[ordered[0]])  # a tree, not a dense distance array: memory stays linear in the images
    for g in ordered[1:]:
        nearest = first.query(xy[g])[0]
        if not np.median(nearest) <= step:
            return None
    dates = ", ".join(time.strftime("%Y-%m-%d %H:%M", time.gmtime(s)) for s, _ in spans)
    sizes = " + ".join(str(len(g)) for g in groups)
    return (f"the folder holds {len(groups)} flights of one place ({dates}, camera clock; {sizes} images, e.g. "
            f"{names[int(ordered[0][0])]} and {names[int(ordered[1][0])]}): they are ordered by capture time and "
            "mapped as one flight; to map each on its own, or to compare them (changes between the dates), put "
            "each flight in its own folder (`sosmatch batch` takes a folder of such flight folders)")
