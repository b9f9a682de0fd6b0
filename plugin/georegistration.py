"""Georegistration of a structure-from-motion block: world_from_sfm from camera centres against GPS (pure numpy).

An SfM reconstruction is right up to a similarity; GPS is right to metres horizontally, its altitude may drift
by tens of metres within a flight, a fix may be wrong, and attitude tags may be off (a whole flight line's yaw
by 180 degrees). A plain 7-DOF fit of the centres to GPS follows all of that: a drifting altitude tilts the
block (measured on a real flight: 40 degrees). So the similarity is put together from the sources that know
each part:

1. **Vertical** (`plugin.vertical.vertical_in_frame`, split from here): the world's up direction in the SfM
   frame from the prior attitudes (attitude tags, else the nadir assumption), checked against and combined with
   the GPS heights' plane (fitted with a drift and a jump in capture time, marginalised); a tilt the heights fix
   worse than the nadir assumption rests on it, said in a warning.
2. **Horizontal** (`robust_horizontal_similarity`): scale, yaw and east/north offset of the levelled block on
   the GPS positions, by least median of squares over 2-point samples (no threshold needed), then the noise
   sigma measured from the median residual, inliers within the 99 % chi-square(2) radius, least squares on
   them, repeated until the inliers settle. GPS fixes outside are listed.
3. **Height** (`fit_drift`): the offset between reference heights (DJI RelativeAltitude + take-off altitude,
   else the GPS altitude) and the levelled block, fitted as a line in capture time. A significant slope is the
   reference drifting against the reconstruction: it is reported, and the heights are referenced to the start
   of the flight (drift accumulates from take-off), not bent to follow it. A step (a receiver changing its height
   datum) is fitted as a step: the block is held to one side's level, and the jump is said as one.

Then `plugin.flight_lines.compare_with_priors` measures every image's orientation against its tags and finds
flight lines whose tags contradict the images (a 180 degree yaw).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .gps_lag import LagFit, TrackVelocity, corrected, fit_lag, track_velocity
from .height_drift import MIN_HEIGHT_DRIFT_M, DriftFit, _robust_sigma, fit_drift  # noqa: F401 (also read from here)
from .multisession import Sim3
from .refinement import fit_yaw_translation
from .robust_fit import (  # noqa: F401 (the constants are also read from here)
    CHI2_1DOF_9973,
    CHI2_2DOF_99,
    CHI2_2DOF_9973,
    CHI2_2DOF_9999,
    CHI2_2DOF_MEDIAN,
    lmeds_then_least_squares,
)
from .vertical import (  # noqa: F401 (split from here; also read from here)
    AIRFRAME_SYSTEMATIC_SIGMA_DEG,
    ATTITUDE_SYSTEMATIC_SIGMA_DEG,
    MIN_FIXES,
    NADIR_ASSUMPTION_SIGMA_DEG,
    NADIR_SOURCE,
    Vertical,
    _gps_slopes,
    _HeightsPlane,
    _mean_direction,
    _tilt_widened,
    _weak_heights_warning,
    _weakest_sigma_deg,
    level_rotation,
    nadir_tilt_warning,
    vertical_in_frame,
)

# more than this share of the fixes off the block by more than their noise's 1-in-10^4 radius makes the
# registration unusable (`_refusals`); below, they are wrong fixes, left out and listed
MAX_WRONG_FIX_SHARE = 0.25
# the fewest fixes whose measured noise can refuse a registration (`_refusals`)
REFUSE_FROM_FIXES = 2 * MIN_FIXES
# a GPS lag is corrected only when the corrected positions fit the block materially better (`_lag_decision`): a
# per-axis sigma this much lower, or this fraction of the positions more among the inliers (at least 2)
LAG_MIN_SIGMA_GAIN = 0.10
LAG_MIN_INLIER_GAIN = 0.03
# the largest plausible lag when the capture interval is unknown: a trigger latency is a fraction of a second
LAG_MAX_S = 2.0


@dataclass
class HorizontalFit:
    transform: Sim3  # target ≈ s Rz src + t (z of t meaningless)
    inliers: np.ndarray  # bool (N,)
    sigma_m: float  # per-axis noise of the target positions, measured
    residuals_m: np.ndarray  # horizontal distance per point
    measured: bool = True  # False: fewer than MIN_FIXES points; sigma_m is the floor, every point an inlier


def robust_horizontal_similarity(src: np.ndarray, dst: np.ndarray, seed: int = 0,
                                 samples: int = 500, min_sigma_m: float = 1e-3) -> HorizontalFit:
    """Scale, yaw and translation of levelled points `src` (N,3) onto `dst` (N,3) on x, y: least median of
    squares over 2-point samples, then least squares on the 99 % inliers of the measured sigma, iterated. With fewer
    than MIN_FIXES points, least squares on all of them and the noise not measured (`HorizontalFit.measured`)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    n = len(src)
    if n < 2:
        raise ValueError(f"need >= 2 positions, got {n}")
    rng = np.random.default_rng(seed)
    if n * (n - 1) // 2 <= samples:
        pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])
    else:
        pairs = np.array([rng.choice(n, 2, replace=False) for _ in range(samples)])

    def residuals(t: Sim3) -> np.ndarray:
        return np.linalg.norm((t.apply(src) - dst)[:, :2], axis=1)

    def candidate(i: int, j: int) -> Sim3 | None:
        if np.linalg.norm(src[i, :2] - src[j, :2]) < 1e-9:
            return None
        try:
            cand = fit_yaw_translation(src[[i, j]], dst[[i, j]], with_scale=True)
        except ValueError:
            return None
        return cand if cand.scale > 0 else None

    if n < MIN_FIXES:
        # a fit of 4 unknowns on 2-4 points: its residuals measure no noise (3 points left 2 degrees of freedom:
        # "noise 0.00 m", and an ordinary fix an outlier), so all are used and the noise is the receiver's wander
        from .pose_check.gps import GNSS_WANDER_M

        try:
            fit = fit_yaw_translation(src, dst, with_scale=True)
        except ValueError:
            raise ValueError("the positions have no horizontal spread") from None
        return HorizontalFit(fit, np.ones(n, bool), max(GNSS_WANDER_M, min_sigma_m), residuals(fit), False)
    fitted = lmeds_then_least_squares(
        (candidate(i, j) for i, j in pairs),
        lambda inl: fit_yaw_translation(src[inl], dst[inl], with_scale=True),
        residuals, n, unknowns=4, min_points=2, min_sigma=min_sigma_m)
    if fitted is None:
        raise ValueError("the positions have no horizontal spread")
    fit, inliers, sigma = fitted
    return HorizontalFit(fit, inliers, sigma, residuals(fit))


@dataclass
class Georegistration:
    """world_from_sfm and everything measured on the way (see the module doc)."""

    transform: Sim3
    vertical: Vertical
    horizontal: HorizontalFit
    height_offset: DriftFit  # of reference heights - levelled block heights
    gps_altitude: DriftFit | None  # of GPS altitude - registered heights (the GPS altitude drift)
    gps_indices: np.ndarray  # the images (indices into the inputs) with a GPS fix used
    warnings: list[str] = field(default_factory=list)
    lag: LagFit | None = None  # the GPS lag measured (`plugin.gps_lag`; None: not measurable)
    # per image (N,3): what was added to its GPS x, y and reference height (the lag, where significant), for the
    # users of the same positions downstream; None: nothing
    position_shift: np.ndarray | None = None
    lag_applied: bool = False  # the lag was significant, plausible and improved the fit: corrected
    # the lag was significant and beyond one capture interval (`_lag_decision`): no trigger latency but a clock or
    # log offset (a log joined to the images one row off), not corrected; the centres lie up to `lag.metres` off
    # along the track, which makes a map of these poses unusable (`workflows.poses.result.registration_refusals`)
    lag_beyond_interval: bool = False
    # what makes these poses unusable (one line each; `workflows.poses.checks._register` refuses with them): the
    # vertical resting on the nadir assumption alone about an axis the GPS heights do not fix (a single line), or
    # a share of the fixes off the block that no receiver's wrong fixes explain (a mirrored or deformed block)
    refusals: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        h, v = self.horizontal, self.vertical
        return {
            "transform": self.transform.to_dict(),
            "images_with_gps": int(len(self.gps_indices)),
            "gps_inliers": int(h.inliers.sum()),
            "gps_horizontal_sigma_m": h.sigma_m, "gps_noise_measured": h.measured,
            "gps_horizontal_residual_median_m": float(np.median(h.residuals_m[h.inliers])),
            "vertical_source": v.source, "vertical_sigma_deg": v.sigma_deg,
            "gps_block_tilt_deg": None if math.isnan(v.gps_tilt_deg) else v.gps_tilt_deg,
            "gps_altitudes_consistent": v.gps_consistent,
            "height_offset": self.height_offset.to_dict(),
            "gps_altitude_drift": None if self.gps_altitude is None else self.gps_altitude.to_dict(),
            "gps_lag": None if self.lag is None else {**self.lag.to_dict(), "applied": self.lag_applied,
                                                      "beyond_interval": self.lag_beyond_interval},
            "warnings": list(self.warnings),
        }


def georegister(
    sfm_centers: np.ndarray,
    sfm_from_cam: np.ndarray,
    gps: np.ndarray,
    prior_world_from_cam: np.ndarray,
    attitude_from_tags: np.ndarray,
    times_s: np.ndarray,
    reference_heights: np.ndarray | None = None,
    seed: int = 0,
    tag_systematic_deg: float = ATTITUDE_SYSTEMATIC_SIGMA_DEG,
    times_known: bool = True,
) -> Georegistration:
    """world_from_sfm for registered images: SfM centres (N,3) and rotations sfm_from_cam (N,3,3), GPS (N,3)
    as the receiver gave it (NaN: no fix, or no altitude; needs >= 2 horizontal fixes), prior rotations and
    which came from tags, capture times (s), and `reference_heights` (N,) to register the height on instead of
    the GPS altitude (DJI RelativeAltitude + take-off altitude). The GPS altitude's drift against the result is
    measured either way. A significant GPS lag (`plugin.gps_lag`) is corrected in the GPS positions and the
    heights before anything else is fitted on them (`position_shift`) when it improves the fit and is plausible
    (`_lag_decision`). `times_known` False: `times_s` is only the capture order (no EXIF time), and a lag is
    said in image intervals. ValueError when fewer than 2 images have a fix."""
    c = np.asarray(sfm_centers, float)
    gps = np.asarray(gps, float)
    has = np.all(np.isfinite(gps[:, :2]), axis=1)  # a horizontal fix (the altitude may be missing)
    idx = np.flatnonzero(has)
    if len(idx) < 2:
        raise ValueError(f"{len(idx)} registered image(s) with a GPS position; georegistration needs 2")
    warnings: list[str] = []
    # the GPS fixes that fit horizontally (block levelled by the priors alone) check the vertical
    first = vertical_in_frame(sfm_from_cam, prior_world_from_cam, attitude_from_tags,
                              tag_systematic_deg=tag_systematic_deg)
    levelled_first = c[idx] @ level_rotation(first.up).T  # (the lag's fits and the first horizontal fit)
    # the lag first: uncorrected, the lines flown one way would be taken as outliers of the others
    track = track_velocity(gps[idx], np.asarray(times_s, float)[idx], times_known)
    lag = fit_lag(levelled_first, gps[idx], track, seed)
    shift = None
    lag_applied, lag_note = _lag_decision(lag, track, levelled_first, gps[idx], seed)
    if lag_note:
        warnings.append(lag_note)
    if lag is not None and lag_applied:
        vel = np.full_like(gps, np.nan)
        vel[idx] = track.velocity
        shift = np.zeros_like(gps)
        shift[idx, :2] = lag.dt * np.nan_to_num(vel[idx, :2])
        gps = corrected(gps, vel, lag.dt)
        if reference_heights is not None:  # their own rate of climb (a relative altitude is not the GPS's)
            ref = np.asarray(reference_heights, float)
            vz = track_velocity(np.column_stack([gps[idx, :2], ref[idx]]), np.asarray(times_s, float)[idx],
                                times_known)
            shift[idx, 2] = lag.dt * np.nan_to_num(vz.velocity[:, 2])
            reference_heights = ref + shift[:, 2]
        else:
            shift[idx, 2] = lag.dt * np.nan_to_num(vel[idx, 2])
        warnings.append(f"the GPS positions {lag.shift()}: corrected (camera trigger latency or a time offset)")
    hfit = robust_horizontal_similarity(levelled_first, gps[idx], seed)
    checked = np.full_like(gps, np.nan)
    checked[idx[hfit.inliers]] = gps[idx[hfit.inliers]]
    # (the capture times, or order, let the heights' plane tell a drift of the GPS altitude from a tilt)
    vert = vertical_in_frame(sfm_from_cam, prior_world_from_cam, attitude_from_tags, c, checked, tag_systematic_deg,
                             np.asarray(times_s, float))
    level = level_rotation(vert.up)
    levelled = c @ level.T
    hfit = robust_horizontal_similarity(levelled[idx], gps[idx], seed)
    s = hfit.transform.scale
    r = hfit.transform.rotation @ level
    block_z = s * levelled[:, 2]
    heights = gps[:, 2] if reference_heights is None else np.asarray(reference_heights, float)
    inl = idx[hfit.inliers]
    use = inl[np.isfinite(heights[inl])]
    if len(use) == 0:
        offset = DriftFit(0.0, 0.0, 0.0, 0.0, math.inf, False, 0.0)
        warnings.append("no image has a height reference: heights are relative to the SfM origin")
    else:
        offset = fit_drift(times_s[use], heights[use] - block_z[use], MIN_HEIGHT_DRIFT_M)
        if reference_heights is None:  # the GPS altitude: the drift `gps_alt` measures below, one answer
            offset = _tilt_widened(offset, times_s[use], (c[use] @ r.T)[:, :2] * s, vert, r)
    transform = Sim3(r, np.array([hfit.transform.translation[0], hfit.transform.translation[1],
                                  offset.reference]), s)
    registered_z = transform.apply(c)[:, 2]
    alt = inl[np.isfinite(gps[inl, 2])]
    gps_alt = _tilt_widened(fit_drift(times_s[alt], gps[alt, 2] - registered_z[alt], MIN_HEIGHT_DRIFT_M),
                            times_s[alt], (c[alt] @ r.T)[:, :2] * s, vert, r) if len(alt) else None
    tilt_unfollowed = not vert.gps_consistent and vert.gps_up is not None
    if tilt_unfollowed:
        # what was measured: a plane through the GPS heights against the block's camera centres, fitted with a drift
        # in time (`_gps_slopes`), so a linear drift cannot be its cause (rev56 D6): the GPS altitude jumps, or the
        # reconstruction is bent (its centres against its orientations)
        warnings.append(f"the GPS altitudes, fitted to the block's camera centres, tilt it by {vert.gps_tilt_deg:.1f} "
                        f"deg against the vertical of the {vert.source}, beyond both uncertainties (GPS heights "
                        f"+-{vert.gps_sigma_deg:.1f} deg across the block, {vert.prior_sigma_deg:.1f} deg): not "
                        "followed; the GPS altitude jumps or the reconstruction is bent")
    source = "GPS altitude jumps" if reference_heights is None else "reference heights (RelativeAltitude-based) jump"
    if offset.kind == "step":
        # one datum for the block: the kept segment's level, not a line through the step (nu34 mAmix2)
        with_gps = (reference_heights is not None and gps_alt is not None and gps_alt.kind == "step"
                    and abs(gps_alt.change - offset.change) < 0.5 * abs(offset.change))
        warnings.append(f"the {source} by {offset.change:+.1f} m at image {_image_at(times_s, use, offset)} "
                        f"against the reconstruction: the block is held to the {_kept_count(offset)} images "
                        f"{offset.kept} the jump (one datum)"
                        + ("; the GPS altitude jumps with them: its height datum changed, not the take-off height"
                           if with_gps else ""))
    elif len(every := idx[np.isfinite(heights[idx])]) > len(use) and (whole := fit_drift(
            times_s[every], heights[every] - registered_z[every], MIN_HEIGHT_DRIFT_M)).kind == "step":
        # the images whose horizontal fixes were left out carry a jump of the heights too (nu34 mAmix2: a second
        # battery's single fixes, another datum, read as another take-off height): the block does not follow it
        warnings.append(f"the {source} by {whole.change:+.1f} m at image {_image_at(times_s, every, whole)} "
                        "against the reconstruction, in images whose GPS positions are left out of the fit: the "
                        f"block is held to the {len(use)} others' heights (another height datum of those fixes?)")
    elif offset.significant and reference_heights is not None and not (gps_alt is not None and gps_alt.significant):
        warnings.append(f"the relative altitude (barometric) drifts by {offset.change:+.1f} m over the flight against "
                        "the reconstruction, the GPS altitude does not: heights referenced to the start of the flight")
    if gps_alt is not None and gps_alt.kind == "step":
        if not (offset.kind == "step" and reference_heights is None):  # (else said just above)
            at = _image_at(times_s, alt, gps_alt)
            warnings.append(f"the GPS altitude jumps by {gps_alt.change:+.1f} m at image {at} against the "
                            "reconstruction (another height datum of the receiver?): measured, not followed"
                            + ("" if reference_heights is None else "; heights from the relative altitude"))
    elif gps_alt is not None and gps_alt.significant and not tilt_unfollowed:
        # (a tilt not followed, above, reads along time as a drift over a survey flown line after line: one cause,
        # said once, rev56 D6; without capture times `times_s` is the image order: the change only, no rate, D5)
        rate = f" ({gps_alt.slope_per_s * 60:+.2f} m/min)" if times_known else ""
        warnings.append(f"the GPS altitude drifts by {gps_alt.change:+.1f} m over the flight against the "
                        f"reconstruction{rate}: measured, not followed"
                        + ("" if reference_heights is None else "; heights from the relative altitude")
                        + ("; heights referenced to the start of the flight" if offset.significant else ""))
    far = idx[hfit.residuals_m[np.arange(len(idx))] ** 2 > CHI2_2DOF_9999 * hfit.sigma_m**2]
    if not hfit.measured:
        warnings.append(f"only {len(idx)} image(s) have a GPS fix: too few to measure the GPS noise (taken as "
                        f"{hfit.sigma_m:g} m) or to call a fix wrong, and the GPS heights do not check the vertical")
    elif len(far):  # beyond the 99 % radius are left out; beyond 1 in 10^4 they are wrong fixes, not noise
        warnings.append(f"{len(far)} GPS position(s) are off the reconstruction by more than 4.3 sigma of the "
                        f"measured {hfit.sigma_m:.2f} m noise (left out of the fit)")
    refusals = _refusals(vert, hfit, levelled[idx], gps[idx], seed)
    if (nadir := nadir_tilt_warning(vert)) is not None:
        warnings.append(nadir)
    if vert.source == NADIR_SOURCE and vert.gps_up is None:
        # nothing measured the vertical: no attitude tags and no GPS heights that could check it (heights that
        # contradict the assumption have their own warning above); a fixed-wing
        # camera is often not nadir on average (Seneca: 6.6 deg nose-up; nu58 D1: the block 4.8 deg off, landmarks
        # 4 m off, heights tilted 5 deg, said nowhere), so the user is told what the vertical rests on and its sigma
        warnings.append(f"no attitude tags and no GPS heights: the vertical (the block's tilt) rests on the camera "
                        f"looking straight down on average, +-{vert.sigma_deg:.1f} deg, unchecked (a camera tilted "
                        "on average, e.g. a fixed-wing's pitch, tilts the whole block: positions off by about the "
                        "flying height x tan(tilt), heights on a tilted plane); give attitude tags (--telemetry) "
                        "or the GPS altitudes")
    if hfit.inliers.sum() < 0.5 * len(idx):
        warnings.append(f"only {int(hfit.inliers.sum())} of {len(idx)} GPS positions fit the reconstruction: "
                        "the georegistration is doubtful")
    if vert.images_contradicting and vert.source.startswith("attitude tags"):  # (off-nadir views are no fault)
        warnings.append(f"{len(vert.images_contradicting)} image(s) have attitude tags whose vertical contradicts "
                        "the others'")
    # the map is refused only for a lag beyond one interval by more than its error (LAG_BEYOND_SIGMAS x sigma_dt):
    # a true lag of one interval, measured 0.97-1.04 +- 0.01-0.05, was refused on every other seed (rev47); between,
    # it is not corrected and said (`_lag_decision`)
    beyond = lag is not None and lag.significant and _beyond_interval(lag, track) and \
        abs(lag.dt) - LAG_BEYOND_SIGMAS * lag.sigma_dt > _interval(lag, track)
    return Georegistration(transform, vert, hfit, offset, gps_alt, idx, warnings, lag, shift, lag_applied, beyond,
                           refusals)


def _refusals(vert: Vertical, hfit: HorizontalFit, levelled: np.ndarray, gps: np.ndarray, seed: int) -> list[str]:
    """What makes a registration unusable (`Georegistration.refusals`), from its vertical and horizontal fit of the
    `levelled` centres (K,3) on `gps` (K,3)."""
    from .pose_check.gps import GNSS_WANDER_M

    out: list[str] = []
    # Refused only on what the fixes measure, and only from enough of them: from 5-7 fixes of a correct block at
    # 3 m noise the two rules below refused 3-7 % (rev53 D3: the noise measured on so few is itself unsure), from
    # 10-16 at most 1 in 400
    if not hfit.measured or len(gps) < REFUSE_FROM_FIXES:
        return out
    # The handedness: a proper similarity is all the fit takes, but the images may be mirrored (a camera or a
    # converter set to flip them: the reconstruction is then the mirror world's); the best fit of the mirrored
    # block fitting clearly more fixes (within the 1-in-10^4 radius of the better one's noise, at least
    # GNSS_WANDER_M, what an uncorrected receiver wanders by) says so (rev49 D2: 22 of 40 fitted, 18 cameras up to
    # 61 m off, exit 0; a symmetric lawnmower fits none). A line is its own mirror image: never more.
    mirror = robust_horizontal_similarity(levelled * [1.0, -1.0, 1.0], gps, seed)
    radius = math.sqrt(CHI2_2DOF_9999) * max(min(hfit.sigma_m, mirror.sigma_m), GNSS_WANDER_M)
    fits, mirror_fits = int(np.sum(hfit.residuals_m <= radius)), int(np.sum(mirror.residuals_m <= radius))
    if mirror_fits >= fits + max(2, 0.1 * len(gps)):
        out.append(f"only {fits} of {len(gps)} GPS positions lie within {radius:.1f} m of the reconstruction, its "
                   f"mirror image fits {mirror_fits}: the images are mirrored (a camera or converter set to flip "
                   "them?); the poses are unusable")
        return out
    # Wrong fixes of a receiver are single glitches: noise puts 1 in 10^4 beyond 4.3 sigma (a block bent by a
    # decimetre under RTK fixes is no wrong fix: the noise at least GNSS_WANDER_M). A quarter of the flight that
    # far off is a block that is not the place the fixes say (another place, a folded reconstruction): least
    # median of squares follows the largest part up to half and places the rest wherever it lands.
    radius = math.sqrt(CHI2_2DOF_9999) * max(hfit.sigma_m, GNSS_WANDER_M)
    far = int(np.sum(hfit.residuals_m > radius))
    if far > MAX_WRONG_FIX_SHARE * len(gps):
        out.append(f"{far} of {len(gps)} GPS positions lie more than {radius:.1f} m off the reconstruction, more "
                   "than a receiver's wrong fixes explain (a deformed reconstruction, or images of another place "
                   "among them?): the poses are unusable")
    return out


def _kept_count(fit: DriftFit) -> int:
    """The number of values on the kept side of a step."""
    return (fit.counts or (0, 0))[0 if fit.kept == "before" else 1]


def _image_at(times_s: np.ndarray, used: np.ndarray, fit: DriftFit) -> str:
    """'k of N' (capture order, 1-based, of the images given) of the first image at or after a fit's step."""
    t = np.asarray(times_s, float)
    k = fit.first_at_step(used, t)
    return f"{int(np.sum(t < t[k])) + 1} of {len(t)}"


def _interval(lag: LagFit, track: TrackVelocity) -> float:
    """One capture interval in the lag's unit (LAG_MAX_S when the capture times do not tell it)."""
    return 1.0 if lag.unit == "image" else (track.interval_s if math.isfinite(track.interval_s) else LAG_MAX_S)


# how many of its standard errors a lag must lie beyond one capture interval to refuse the map of its poses
LAG_BEYOND_SIGMAS = 2.0


def _beyond_interval(lag: LagFit, track: TrackVelocity) -> bool:
    """Whether a lag exceeds one capture interval (`_interval`): no trigger latency, a clock or log offset."""
    return abs(lag.dt) > _interval(lag, track)


def _lag_decision(lag: LagFit | None, track: TrackVelocity, levelled: np.ndarray, gps: np.ndarray,
                  seed: int) -> tuple[bool, str]:
    """Whether a significant lag is applied, and a warning when it is not for being implausible. Applied only
    when the corrected positions fit the block materially better than the raw ones (the robust horizontal fit of
    each: more inliers, or on the raw fit's inliers a per-axis sigma lower by LAG_MIN_SIGMA_GAIN; a lag of the
    size `fit_lag` requires raises the raw sigma by 18 % or more, or drops the lines flown one way), and when |dt|
    is within one capture interval (LAG_MAX_S when no interval is known): beyond it the GPS log and the images
    disagree by more than a trigger latency can, e.g. a clock or log offset, which is said, not corrected. A lag
    measured on too few passes to verify it (`LagFit.unverified`) is said, never applied."""
    if lag is not None and lag.unverified:
        return False, (f"the GPS positions would {lag.shift()}, {abs(lag.dt) / lag.sigma_dt_formal:.0f} times its "
                       f"formal error and {abs(lag.metres) / lag.sigma_m:.0f} times the fixes' measured noise "
                       f"({lag.sigma_m:.2f} m), but only {lag.passes} pass(es) of the track measure it, too few to "
                       "tell a trigger latency from the GPS wandering between them: not corrected; camera centres "
                       "may lie that far off along the track")
    if lag is None or not lag.significant:
        return False, ""
    interval = _interval(lag, track)
    if _beyond_interval(lag, track):
        limit = "one image interval" if lag.unit == "image" else (
            f"one capture interval ({interval:.2f} s)" if math.isfinite(track.interval_s) else f"{LAG_MAX_S:.0f} s")
        return False, (f"the GPS positions and the images disagree along the track by {abs(lag.metres):.1f} m "
                       f"(the GPS positions would {lag.shift()}, more than {limit}): not corrected; a clock or log "
                       "offset between the GPS and the camera?")
    raw = robust_horizontal_similarity(levelled, gps, seed)
    moved = np.column_stack([corrected(gps[:, :2], track.velocity[:, :2], lag.dt), gps[:, 2]])
    fixed = robust_horizontal_similarity(levelled, moved, seed)
    if int(fixed.inliers.sum()) - int(raw.inliers.sum()) >= max(2, math.ceil(LAG_MIN_INLIER_GAIN * len(gps))):
        return True, ""  # the corrected positions bring in lines the raw fit had to leave out
    # else the sigmas on the same positions, the raw fit's inliers: each fit's own sigma is over its own inliers,
    # and a lower one bought by leaving positions out is no improvement (rev22 seed 5049, a clean flight with GPS
    # wander: the lag's fifth unknown fit 6 of 10 lines tighter, 104 of 190 inliers at 0.34 m against 126 at 0.45)
    keep = raw.inliers
    on_raw = fit_yaw_translation(levelled[keep], moved[keep], with_scale=True)
    r = np.linalg.norm((on_raw.apply(levelled[keep]) - moved[keep])[:, :2], axis=1)
    sigma_fixed = math.sqrt(float(np.sum(r**2)) / max(2 * int(keep.sum()) - 4, 1))
    return sigma_fixed <= (1.0 - LAG_MIN_SIGMA_GAIN) * raw.sigma_m, ""
