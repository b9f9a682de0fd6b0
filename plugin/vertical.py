"""The world's vertical in a structure-from-motion frame (pure numpy): what `plugin.georegistration` levels a block
on, and what every pose source that decides the attitudes of untagged images says of it.

Per image R_sfm_from_cam R_prior_from_cam^T e_z from the prior attitude (the IMU's gravity; a yaw error does not
change it), averaged robustly (`vertical_in_frame`). Without attitude tags the prior is a level nadir camera, the
survey assumption, with a systematic uncertainty of `NADIR_ASSUMPTION_SIGMA_DEG`. The GPS heights' plane over the
block levelled by it (`_gps_slopes`: its slopes are the vertical's tangent-plane coordinates about the prior's, with
their information, none across a single straight line; fitted with a drift in capture time, and a jump where the
heights against the prior-levelled block show one, both marginalised, since a survey flown line after line
confounds a drift or a jump between lines with a tilt across its lines) is compared with it: when they agree within
their uncertainties the two are combined (information-weighted, rebuilt exactly), otherwise the GPS altitudes are
inconsistent with the block and are not followed. Without tags, a tilt the heights fix worse than the nadir
assumption (a single line's roll, the axis a drift hides) rests on the assumption, said in a warning
(`nadir_tilt_warning`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .height_drift import MIN_HEIGHT_DRIFT_M, DriftFit, _robust_sigma, fit_drift
from .refinement import fit_yaw_translation
from .robust_fit import CHI2_1DOF_9973, CHI2_2DOF_9973, CHI2_2DOF_9999

# A level nadir camera is what survey flights aim for; fixed-wing airframes fly a few degrees nose-up and
# multirotor gimbals hold nadir to a degree: the uncertainty of the mean view direction as the vertical.
NADIR_ASSUMPTION_SIGMA_DEG = 3.0
# `Vertical.source` of a vertical resting on that assumption alone (no attitude tags; " + GPS altitudes" when the
# heights' plane joins it): what poses.json records, and what a map of those poses reads (`plugin.map_quality`)
NADIR_SOURCE = "nadir assumption"
# Gimbal/IMU tilt calibration: an error common to all images that averaging does not remove. A camera fixed to an
# airframe adds its unknown mounting and the airframe's flying attitude (a fixed wing's few degrees nose-up), as
# uncertain as the nadir assumption.
ATTITUDE_SYSTEMATIC_SIGMA_DEG = 0.5
AIRFRAME_SYSTEMATIC_SIGMA_DEG = NADIR_ASSUMPTION_SIGMA_DEG
# fewer fixes measure no noise: a fit of 4 unknowns (the horizontal similarity) or 3 (the heights' plane) on them
# has too few degrees of freedom left (rev49 D7: 3 fixes, "noise 0.00 m", an ordinary fix called an outlier, the
# GPS heights' plane through 3 points taken as exact and the block tilted 10 deg); `pose_check.gps` reads it too
MIN_FIXES = 5


def _mean_direction(vectors: np.ndarray, iterations: int = 5) -> tuple[np.ndarray, np.ndarray, float]:
    """Robust mean of unit vectors (N,3): (mean, inlier mask, per-vector angular sigma in degrees). Vectors
    further than 3 robust sigmas (at least 2 degrees) from the mean are left out, the mean recomputed."""
    v = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    keep = np.ones(len(v), bool)
    mean = v.mean(0)
    sigma = 0.0
    for _ in range(iterations):
        mean = v[keep].mean(0)
        mean /= np.linalg.norm(mean)
        ang = np.degrees(np.arccos(np.clip(v @ mean, -1.0, 1.0)))
        # angles of a 2-D isotropic spread: their median is 1.1774 sigma
        sigma = float(np.median(ang[keep]) / 1.1774) if keep.any() else 0.0
        new = ang <= max(3.0 * sigma, 2.0)
        if not new.any() or np.array_equal(new, keep):
            break
        keep = new
    return mean, keep, sigma


@dataclass
class Vertical:
    """The world's up direction in the SfM frame and where it came from."""

    up: np.ndarray  # unit vector, SfM frame
    source: str  # "attitude tags", "nadir assumption", "... + GPS altitudes"
    sigma_deg: float  # uncertainty of `up`
    prior_up: np.ndarray  # from the attitude priors (tags or nadir) alone
    prior_sigma_deg: float
    gps_up: np.ndarray | None  # from a 3-D similarity to the GPS positions (None without >= 3 spread fixes)
    gps_sigma_deg: float
    gps_tilt_deg: float  # angle between prior_up and gps_up (nan without gps_up)
    gps_consistent: bool
    images_used: int
    images_rejected: list[int] = field(default_factory=list)  # left out of the mean (beyond 3 robust sigmas)
    # of those, the ones whose tags contradict the others' vertical: beyond the 1-in-10^4 radius of the spread
    images_contradicting: list[int] = field(default_factory=list)
    # the horizontal axis (SfM frame) about which the GPS heights know the tilt least (`gps_sigma_deg` is about
    # it): across a single straight line, its roll; None without GPS heights
    gps_weakest_axis: np.ndarray | None = None
    # `gps_sigma_deg` if the GPS altitude did not drift over the flight (the heights' plane without its drift term):
    # far below it, the drift is what the heights cannot tell from a tilt (a survey flown line after line)
    gps_sigma_without_drift_deg: float = math.inf


def level_rotation(up: np.ndarray) -> np.ndarray:
    """The smallest rotation R with R @ up = e_z."""
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    s, c = float(np.linalg.norm(axis)), float(u @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * kx + (1.0 - c) * kx @ kx


@dataclass
class _HeightsPlane:
    """The GPS heights' plane against a levelled block (`_gps_slopes`)."""

    slopes: np.ndarray  # (a, b): z = a x + b y (+ c + d t) in the levelled GPS-aligned frame
    info: np.ndarray  # (2,2) information of (a, b), a drift in time marginalised out (when times are given)
    info_without_drift: np.ndarray  # (2,2) the information (a, b) would have if the heights did not drift
    to_sfm: np.ndarray  # (3,3) rotation from the levelled GPS-aligned frame to the SfM frame


def _gps_slopes(centers: np.ndarray, gps: np.ndarray, prior_up: np.ndarray,
                times: np.ndarray | None = None) -> _HeightsPlane | None:
    """The GPS heights' measure of the vertical against `prior_up`: the block levelled by it and turned and scaled
    onto the GPS positions on x, y (`fit_yaw_translation`), the heights' offset from it fitted as a plane z = a x +
    b y + c, plus a drift d t when capture `times` (seconds, or the capture order) are given, and a jump e [t >= t_j]
    where `fit_drift` of the heights against the levelled block finds one (rev56 D2). Returns the slopes
    (a, b) (least squares, the least-norm solution where the positions do not determine them), their information
    matrix with d marginalised out (the Schur complement, X^T X - X^T t t^T X / t^T t, over sigma^2: sigma of the
    heights about the fit, measured), the information without the drift term, and the rotation from that levelled
    GPS-aligned frame to the SfM frame. World up is the height's gradient, so in the SfM frame it is along
    rotation @ (a, b, 1). None when the positions have no horizontal spread.

    Why the drift: a GPS altitude drifts over a flight (the module doc), and a survey flown line after line puts
    its capture time along its cross-track position, so a drift reads exactly as a tilt across the lines (rev53 D2:
    6 m over a two-line flight tilted the block 4.6 deg about its lines while 1.2 deg was claimed). Marginalised,
    the heights know the tilt only as far as time and position differ (the lines flown back and forth, the time
    along each line); about the rest the attitude priors decide."""
    level = level_rotation(prior_up)
    levelled = centers @ level.T
    try:
        fit = fit_yaw_translation(levelled, gps, with_scale=True)
    except ValueError:
        return None
    q = fit.apply(levelled)
    xy = q[:, :2] - q[:, :2].mean(0)
    dz = gps[:, 2] - q[:, 2]
    dz = dz - dz.mean()
    n = len(dz)
    t = None if times is None else np.asarray(times, np.float64)
    if t is not None and np.all(np.isfinite(t)) and float(np.ptp(t)) > 0:
        t = t - t.mean()
    else:
        t = None
    nuisance = [] if t is None else [t]
    if t is not None and (jump := fit_drift(times, dz, MIN_HEIGHT_DRIFT_M)).kind == "step":
        # a jump of the GPS altitude (another datum) between lines is half a tilt across them for the plane: its
        # level is a nuisance too, else the rest tilts the block (rev56 D2: +8 m at a line change, 3.6 deg off
        # "+-1.8", no word); found against the prior-levelled block, where a jump stands out of a line
        after = (np.asarray(times, np.float64) >= jump.step_time).astype(np.float64)
        nuisance.append(after - after.mean())
    unknowns = 3 + len(nuisance)  # (with the offset c)
    # the drift (and a jump) marginalised: x, y and z with their part in the span of those taken out, (a, b) by least
    # squares on those (the least-norm solution where time and position are collinear: one line flown one way,
    # lines all flown the same way, whose heights then say nothing of that tilt)
    if nuisance:
        basis = np.linalg.qr(np.column_stack(nuisance))[0]
        xp, zp = xy - basis @ (basis.T @ xy), dz - basis @ (basis.T @ dz)
    else:
        xp, zp = xy, dz
    slopes = np.linalg.lstsq(xp, zp, rcond=1e-9)[0]
    # the MAD of the residuals, widened for the fit's unknowns
    sigma_v = max(_robust_sigma(zp - xp @ slopes) * math.sqrt(n / max(n - unknowns, 1)), 1e-3)
    ev, vecs = np.linalg.eigh(xp.T @ xp)
    ev[ev <= 1e-9 * max(float(ev.max()), 1e-300)] = 0.0  # (collinear: rounding, not information)
    info = (vecs * ev) @ vecs.T
    return _HeightsPlane(slopes, info / sigma_v**2, xy.T @ xy / sigma_v**2, level.T @ fit.rotation.T)


def vertical_in_frame(
    sfm_from_cam: np.ndarray,
    prior_world_from_cam: np.ndarray,
    attitude_from_tags: np.ndarray,
    sfm_centers: np.ndarray | None = None,
    gps: np.ndarray | None = None,
    tag_systematic_deg: float = ATTITUDE_SYSTEMATIC_SIGMA_DEG,
    times: np.ndarray | None = None,
) -> Vertical:
    """World up in the SfM frame from the prior attitudes, checked against (and combined with) the GPS positions.

    `sfm_from_cam` (N,3,3) are the SfM rotations, `prior_world_from_cam` the tags' (or a level nadir camera's),
    `attitude_from_tags` (N,) which priors came from tags: when at least 3 did, only those are used, with a
    systematic uncertainty of `tag_systematic_deg` (a gimbal's; `AIRFRAME_SYSTEMATIC_SIGMA_DEG` for a fixed camera).
    `gps` (N,3) may hold NaN rows (no fix); fewer than MIN_FIXES full fixes do not check the vertical. `times` (N,)
    capture times (seconds, or the capture order): the heights' plane is fitted with a drift in time, which the
    heights then do not take for a tilt (`_gps_slopes`); None: no drift term."""
    tags = np.asarray(attitude_from_tags, bool)
    use = tags if tags.sum() >= 3 else np.ones(len(tags), bool)
    e_z = np.array([0.0, 0.0, 1.0])
    per_image = np.einsum("nij,nkj,k->ni", sfm_from_cam[use], prior_world_from_cam[use], e_z)
    prior_up, keep, spread = _mean_direction(per_image)
    rejected = [int(i) for i in np.flatnonzero(use)[~keep]]
    # Leaving out beyond 3 sigmas protects the mean, but 3 sigmas of a 2-D spread is its 98.9 % radius: one image
    # in 90 of a sound flight lies beyond it (nu32: 2.1 deg at a spread of 0.58 deg, 1 of 60). Only beyond the
    # 1-in-10^4 radius, as for the GPS fixes, is a tag wrong rather than noisy.
    unit = per_image / np.linalg.norm(per_image, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(unit @ prior_up, -1.0, 1.0)))
    beyond = angle > max(math.sqrt(CHI2_2DOF_9999) * spread, 2.0)
    contradicting = [int(i) for i in np.flatnonzero(use)[beyond]]
    systematic = tag_systematic_deg if tags.sum() >= 3 else NADIR_ASSUMPTION_SIGMA_DEG
    prior_sigma = math.hypot(spread / math.sqrt(max(int(keep.sum()), 1)), systematic)
    source = "attitude tags" if tags.sum() >= 3 else NADIR_SOURCE

    gps_up, gps_sigma, tilt, consistent, still = None, math.inf, math.nan, False, math.inf
    up, sigma, weakest = prior_up, prior_sigma, None
    if gps is not None and sfm_centers is not None:
        ok = np.all(np.isfinite(gps), axis=1)
        when = None if times is None else np.asarray(times, np.float64)[ok]
        plane = _gps_slopes(sfm_centers[ok], gps[ok], prior_up, when) if ok.sum() >= MIN_FIXES else None
        if plane is not None:
            # Everything in the gnomonic chart centred on the prior's up (in the GPS-aligned levelled frame): a
            # direction u is (u_x / u_z, u_y / u_z), exactly the slopes of the plane it is the normal of, the prior
            # is at 0 with its isotropic sigma (exact at the chart's centre), and the GPS heights measure the slopes
            # linearly with the information `info_g` -- rank-deficient for a straight line, whose heights say
            # nothing of the roll about it (rev49 D1: an SVD fit's arbitrary roll about a line, combined in a
            # small-angle rebuild, turned a line's cameras 126 deg; information form needs no inverse of it).
            g, info_g, to_sfm = plane.slopes, plane.info, plane.to_sfm
            gps_up = to_sfm @ np.r_[g, 1.0]
            gps_up /= np.linalg.norm(gps_up)
            tilt = float(np.degrees(np.arccos(np.clip(gps_up @ prior_up, -1.0, 1.0))))
            ev, vecs = np.linalg.eigh(info_g)
            gps_sigma = _weakest_sigma_deg(ev[0])
            still = _weakest_sigma_deg(float(np.linalg.eigvalsh(plane.info_without_drift)[0]))
            weakest = to_sfm @ np.r_[vecs[:, 0], 0.0]  # the direction of tilt the GPS heights know least
            info_p = np.eye(2) / math.radians(prior_sigma) ** 2
            info = info_p + info_g
            # the GPS slopes against the prior (0) in the directions the heights determine: chi-square with as
            # many degrees of freedom (3 sigma: the 99.73 % quantile); (cov_p + cov_g)^-1 = I_g (I_p + I_g)^-1 I_p
            eta = info_g @ g
            chi2 = float(eta @ np.linalg.solve(info, info_p @ g))
            # degrees of freedom the heights add: the trace of their share of the information (2 for a block, 1
            # for a line, whose roll the heights know far less than the prior does)
            known = float(np.trace(np.linalg.solve(info, info_g)))
            consistent = chi2 <= (CHI2_2DOF_9973 if known >= 1.5 else CHI2_1DOF_9973)
            if consistent:  # the information-weighted mean, rebuilt exactly from the chart
                t = np.linalg.solve(info, eta)
                up = to_sfm @ np.r_[t, 1.0]
                up /= np.linalg.norm(up)
                sigma = math.degrees(math.atan(1.0 / math.sqrt(float(np.linalg.eigvalsh(info)[0]))))
                source += " + GPS altitudes"
    return Vertical(up, source, sigma, prior_up, prior_sigma, gps_up, gps_sigma, tilt, consistent,
                    int(keep.sum()), rejected, contradicting, weakest, still)


def _weakest_sigma_deg(eigenvalue: float) -> float:
    """The angle (deg) a slope information `eigenvalue` (1/rad^2, in the gnomonic chart) knows the tilt to."""
    return math.degrees(math.atan(1.0 / math.sqrt(eigenvalue))) if eigenvalue > 0 else 90.0


def _tilt_widened(fit: DriftFit, times_s: np.ndarray, plan: np.ndarray, vert: Vertical,
                  world_from_sfm: np.ndarray) -> DriftFit:
    """A `fit_drift` line of heights against the registered block, its change's standard error widened by the
    vertical's uncertainty: a tilt of the block about its weakest axis moves the heights in proportion to the
    position across that axis, which over a survey flown line after line grows with time, so an error of the
    vertical within its sigma reads as a drift (a sound six-line survey: -3.7 m "+-0.6", its vertical 1.4 deg off,
    claimed 1.6). `plan` (K,2): the images' registered horizontal positions (m). Steps are left as they are."""
    axis = vert.gps_weakest_axis
    t = np.asarray(times_s, float)
    if fit.kind == "step" or axis is None or len(t) < 3 or float(np.ptp(t)) <= 0:
        return fit
    # the horizontal direction along which the weakest tilt changes the heights (the chart's slope direction)
    d = (world_from_sfm @ axis)[:2]
    if float(np.linalg.norm(d)) < 1e-9:
        return fit
    across = plan @ (d / np.linalg.norm(d))
    tc = t - t.mean()
    rate = float(tc @ (across - across.mean()) / (tc @ tc))  # metres across per second, by least squares
    tilt = math.tan(math.radians(min(vert.sigma_deg, 89.0)))
    widened = math.hypot(fit.change_sigma, rate * float(np.ptp(t)) * tilt)
    significant = bool(abs(fit.change) > max(3.0 * widened, 2.0 * fit.sigma, MIN_HEIGHT_DRIFT_M))
    return dataclasses.replace(fit, change_sigma=widened, significant=significant)


def _weak_heights_warning(vert: Vertical) -> str:
    """The warning for a vertical the nadir assumption alone sets about one axis: a single line's roll, or the tilt
    a drift of the GPS altitude over the flight cannot be told from (`_gps_slopes`)."""
    rests = (f"(more than the {NADIR_ASSUMPTION_SIGMA_DEG:g} deg of the nadir assumption): that tilt rests on the "
             "camera looking straight down; for a tilted camera give attitude tags (--telemetry)")
    if vert.gps_sigma_without_drift_deg > NADIR_ASSUMPTION_SIGMA_DEG:
        return (f"no attitude tags, and the GPS heights fix the tilt about the flight's long axis only to "
                f"+-{vert.gps_sigma_deg:.1f} deg {rests}")
    return (f"no attitude tags, and the GPS heights fix the tilt about one horizontal axis only to "
            f"+-{vert.gps_sigma_deg:.1f} deg, their altitude allowed to drift over the flight (+-"
            f"{vert.gps_sigma_without_drift_deg:.1f} deg if it did not: a survey flown line after line advances "
            f"across its lines with time, so a drift reads as a tilt about them) {rests}")


def nadir_tilt_warning(vert: Vertical) -> str | None:
    """What to say when `vert` (no attitude tags) rests on the nadir assumption about an axis the GPS heights fix
    worse than it does (a single line's roll), else None: one rule for every pose source that decides the
    attitudes of untagged images (`georegister`, `poses-from-exif`'s refinement). Heights found inconsistent with
    the assumption leave it alone, so it rests on it as much (fix139: a corridor's noisy heights across a line of
    0.5 m cross-track spread, 39 deg off +-11, were not followed and nothing was said)."""
    if (vert.source.startswith(NADIR_SOURCE) and vert.gps_up is not None
            and vert.gps_sigma_deg > NADIR_ASSUMPTION_SIGMA_DEG):
        # the heights know the tilt about one axis (a single line's roll) worse than the assumption does: it alone
        # sets it, exactly (the information-weighted vertical), so said, not refused: rev53 found a two-line
        # survey 16 m apart refused whose poses were 0.9 deg right; rev49 D1's 126 deg roll was the small-angle
        # rebuild's, not the assumption's
        return _weak_heights_warning(vert)
    return None
