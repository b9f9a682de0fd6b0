"""The verdict on the figures of `check.check_poses`: refusals (the poses contradict the images) and warnings."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..map_verdict import Verdict
from ..params import PoseCheckParams
from .check import PoseCheck, beyond
from .gps import GNSS_WANDER_M, GpsComparison

# a mirrored similarity that explains this much of the fixes' spread (where the proper one does not) names the
# poses mirrored: NED poses give 100 %, shuffled ones under 20 %
MIRRORED_EXPLAINED = 0.9
MIN_FIXES_TO_REFUSE = 10  # inliers a unit refusal needs (simulated: 0.5-2 % false refusals at 8-10, none from 15)
# A shared attitude error is a pitch when its axis lies within ~25 deg of the cameras' x axis (the axis a gimbal
# pitches the camera about), and the images tell it from a lag along the track when the fitted error takes the
# consecutive pairs' median misfit to at most CONSECUTIVE_EXPLAINED of what the poses give: a lag moves both
# cameras of a pair on one straight pass alike and leaves their relative pose as it was, a pitch turns their
# baseline in the camera frame. Measured (40-frame synthetic lawnmowers, nadir and 35 deg oblique; nu51's relief
# runs): lags of 5-60 m 1.17-1.32 (the fit makes them worse), exact poses 0.97-1.03, pitch errors of 5 / 10 deg
# 0.86 / 0.81, 12-70 deg 0.21-0.54 (the oblique camera recorded as nadir: 0.25 and 0.50; BENCHMARKS.md)
PITCH_AXIS_SHARE = 0.9
CONSECUTIVE_EXPLAINED = 0.75
MIN_CONSECUTIVE = 6  # consecutive pairs the comparison needs (the systematic fit's own minimum)


def median_loose(check: PoseCheck, limits: PoseCheckParams) -> bool:
    """The flight's matches fit the poses loosely: more than `warn_matches_beyond_gate` of the checked pairs' true
    matches lie beyond the tracker's gate (the tracks it would lose; the gate keeps >99 % of them on the EKF poses
    it was made for, so a median at a fixed fraction of it sits at their noise); the median beyond
    `warn_epipolar_gate_fraction` of the gate where that share is unknown."""
    share = check.matches_beyond_gate
    if np.isfinite(share):
        return bool(share > limits.warn_matches_beyond_gate)
    return bool(check.epipolar_p50_px > limits.warn_epipolar_gate_fraction * check.gate_px)


def poses_loose(check: PoseCheck, limits: PoseCheckParams) -> bool:
    """The check saw enough to say that the poses fit the images loosely or not at all: the flight's matches
    loose (`median_loose`), a pair beyond its warning limit, a camera whose pose misses its pairs
    (`wrong_cameras`) or two whose poses fit exchanged (`PoseCheck.exchanges`)."""
    if check.pairs_checked < limits.min_pairs or not np.isfinite(check.epipolar_p50_px):
        return False
    gate = check.gate_px
    return bool(median_loose(check, limits)
                or any(p.epipolar_px > limits.warn_pair_gate_fraction * gate for p in check.pairs)
                or wrong_cameras(check) or bool(check.exchanges))


def judge_poses(check: PoseCheck, limits: PoseCheckParams, names: Sequence[str] | None = None,
                remedy: str = "") -> Verdict:
    """Refusals (the poses contradict the images) and warnings (they fit them loosely); limits: PoseCheckParams.
    `names`: the images' names (capture order), to name the pairs whose poses do not fit them. `remedy`: what
    would give better poses (the map of EXIF tags: `--refine`), added to the first words on a loose or wrong fit.

    A systematic error is refused only when it exceeds its limit by more than two of its standard deviations
    (the evidence must be clear, not a noisy fit)."""
    v = judge_gps(check.gps, limits)
    if 0 < check.pairs_checked < limits.min_pairs and check.pairs_checked == check.pairs_tried:
        # every pair matched: the flight is short, not its images or poses bad (nu49: 4 of 4 pairs of a 5-frame flight
        # were blamed on "little texture, or poses far off")
        v.warnings.append(f"poses vs images: only {check.pairs_checked} image pairs to check in a flight of "
                          f"{check.images} images, all matched (fewer than {limits.min_pairs}): too few to check the "
                          "poses")
    elif check.pairs_checked < limits.min_pairs:
        v.warnings.append(f"poses vs images: only {check.pairs_checked} of {check.pairs_tried} image pairs matched "
                          "(too few to check the poses: little texture, or poses far off where the images are)")
        if not check.pairs_checked:
            return v
    elif check.pairs_tried and check.pairs_checked < limits.min_pair_share * check.pairs_tried:
        v.warnings.append(f"poses vs images: only {check.pairs_checked} of {check.pairs_tried} image pairs could be "
                          f"checked (fewer than {limits.min_pair_share:.0%}: dark, noisy, blurred or featureless "
                          "images?): misfitting poses among the others may go unseen")
    gate = check.gate_px
    unsaid = [remedy] if remedy else []

    def then() -> str:  # the remedy, once
        return f"; {unsaid.pop()}" if unsaid else ""

    if not np.isfinite(check.epipolar_p50_px):
        # no pair has a baseline in the poses (E = 0, the Sampson distance undefined): the epipolar test cannot run,
        # so "ok" would be a verdict on nothing
        flow = float(np.median([p.flow_px for p in check.pairs])) if check.pairs else float("nan")
        if np.isfinite(flow) and flow > gate:
            v.refusals.append(f"poses vs images: the poses put the cameras of all {check.pairs_checked} matched pairs "
                              f"at one position, but the images move by {flow:.1f} px between them (median): the "
                              "poses do not describe this flight (one position given to every image?)")
        else:
            v.warnings.append(f"poses vs images: the cameras of all {check.pairs_checked} matched pairs stand at one "
                              "position (no baseline): the poses are not checked")
        return v
    for rp in check.reversed_passes:
        v.refusals.append(f"poses vs images: on the pass {rp['first']} .. {rp['last']} ({rp['reversed']} of "
                          f"{rp['pairs']} pairs) the images move the other way than the poses say (a heading "
                          "180 deg off?)")
    if check.epipolar_p50_px > limits.max_epipolar_gate_fraction * gate:
        v.refusals.append(f"poses vs images: the poses' epipolar geometry misses the images' matches by "
                          f"{check.epipolar_p50_px:.1f} px (median of {check.pairs_checked} pairs; the tracker's gate "
                          f"is {gate:.1f} px): wrong relative rotations or directions of motion{then()}")
    elif median_loose(check, limits):
        # said by what trips it: the share of matches beyond the gate where it is known (a median of 0.3 px is
        # an excellent fit, and "fit only to 0.3 px" read as praise for two swapped cameras, rev55 D5)
        if np.isfinite(check.matches_beyond_gate):
            what = (f"{check.matches_beyond_gate:.0%} of the checked pairs' matches lie beyond the tracker's "
                    f"{gate:.1f} px gate (the median pair fits to {check.epipolar_p50_px:.1f} px, "
                    f"{check.pairs_checked} pairs): the poses fit some images loosely or not at all")
        else:
            what = (f"the poses fit the images' matches only to {check.epipolar_p50_px:.1f} px (median of "
                    f"{check.pairs_checked} pairs; gate {gate:.1f} px)")
        v.warnings.append(f"poses vs images: {what}: expect a sparse map, or one metres off if the poses are wrong "
                          "(each image given its neighbour's pose, or another flight's poses, fit like this too)"
                          f"{then()}")
    # the median speaks for the flight; a few images whose poses are far off hide behind it (EXIF poses whose
    # attitudes the tie points could not solve: 25 deg off, one pair 271 px beyond a 24 px gate, the rest 0.5 px)
    pair_limit = limits.warn_pair_gate_fraction * gate
    far = sorted((p for p in check.pairs if p.epipolar_px > pair_limit), key=lambda p: -p.epipolar_px)

    def name(i: int) -> str:
        return names[i] if names is not None and i < len(names) else f"#{i}"

    refused_before = bool(v.refusals)
    if not refused_before:
        # cameras whose pose misses every pair they are in, though their partners fit elsewhere: named and refused
        # (rev55 D1: two swapped cameras and one yawed 90 deg passed as "ok", the median deciding alone)
        if check.exchanges:
            # the epipolar error is blind to the sign of a baseline: two consecutive cameras exchanged passed "ok"
            # (fix155); the images were asked whether the poses fit better exchanged (`swaps`), and they do
            shown = ", ".join(f"{name(e.a)} and {name(e.b)} ({e.pairs} pairs: {e.given_px:.1f} px as given, "
                              f"{e.exchanged_px:.1f} px exchanged)" for e in check.exchanges[:3])
            more = f" and {len(check.exchanges) - 3} more" if len(check.exchanges) > 3 else ""
            v.refusals.append(f"poses vs images: the poses of {shown}{more} fit the images exchanged (the flight's "
                              f"median pair error is {check.epipolar_p50_px:.1f} px): those rows are swapped (a pose "
                              "table joined to its images out of order?); fix them or leave those images out")
        exchanged = {c for e in check.exchanges for c in (e.a, e.b)}
        wrong = [w for w in wrong_cameras(check) if w[0] not in exchanged]  # named above already
        if wrong:
            limit = check.camera_limit_px
            shown = ", ".join(f"{name(c)} ({len(m)} of {n} pairs, {min(m):.0f}-{max(m):.0f} px)"
                              for c, n, m in wrong[:5])
            more = f" and {len(wrong) - 5} more" if len(wrong) > 5 else ""
            # the names first: a refusal is cut at 400 characters (`plugin.errors.one_line`)
            v.refusals.append(
                f"poses vs images: the poses of {shown}{more} miss the matches of every pair they are in by more "
                f"than {limit:.0f} px ({check.camera_median_factor:g} x the flight's median pair error of "
                f"{check.epipolar_p50_px:.1f} px, at least {check.camera_gate_fraction:g} x the tracker's "
                f"{gate:.0f} px gate), while their partners fit their other pairs: those poses are wrong (swapped "
                "with another image's, or a wrong attitude?); fix them or leave those images out")
    if not v.refusals:  # the flight-level count: the poses fit too few pairs, whichever images are at fault
        v.refusals.extend(misfit_pairs_refusal(check))
    if far and not refused_before:
        shown = ", ".join(f"{name(p.a)} / {name(p.b)} {p.epipolar_px:.0f} px" for p in far[:3])
        more = ", ..." if len(far) > 3 else ""
        v.warnings.append(f"poses vs images: {len(far)} of {check.pairs_checked} checked pairs miss their matches by "
                          f"more than {pair_limit:.0f} px, {limits.warn_pair_gate_fraction:g} x the gate ({shown}"
                          f"{more}): those images' poses do not fit them{then()}")
    s, h = check.systematic, check.flying_height_m
    if not check.systematic_separable:
        v.warnings.append(f"poses vs images: the flight's geometry cannot tell a height drift, a tilt of the heights "
                          f"and an attitude error shared by all cameras apart (condition index "
                          f"{s.condition_text}; a single straight line?): they are not checked")
        return v
    consecutive = sum(p.kind == "next" for p in check.pairs)
    # the likely reason only where the pairs show it (most of them consecutive images); otherwise just the fact
    # (rev41: Seneca's wrong telemetry poses, 42 of 97 consecutive, were told "an oblique camera or a low flight?")
    why = (": an oblique camera, whose other flight lines look at other ground, or a low flight where few other "
           "pairs match?" if 2 * consecutive > check.pairs_checked else "")
    # the reading only from a fit that measured something (`systematic_significant`): a reading of one no better
    # than the random errors read as a measured gimbal error (nu57: "18.8 deg" at F 1.3, p 0.27)
    read = (f" (they read {s.attitude_bias_deg:.1f} deg)" if check.systematic_significant else
            f" (the fit is no better than the poses' random errors: F {s.explained_f:.1f}, p {s.explained_p:.2f})")
    unchecked = (f"poses vs images: the checked pairs pin an attitude error shared by all cameras only to "
                 f"+-{s.attitude_bias_sigma_deg:.1f} deg{read}, too loosely to "
                 f"judge one of a few degrees ({consecutive} of {check.pairs_checked} are consecutive images, whose "
                 f"short baselines show little of it{why}): the cameras' attitude is not checked")
    if not check.systematic_explains:
        # the poses' random errors, not a systematic one: the fit's parameters are no measurement (silent, as on
        # exact poses, where there is nothing to explain either), unless the pairs cannot see the attitude at all:
        # silence would read as "checked and found right" (nu51: a 10 deg pitch error of an oblique flight). Not
        # where the poses are refused already: they are wrong, and what was not checked of them is noise (rev41)
        if not check.attitude_checked and not v.refusals:
            v.warnings.append(unchecked)
        return v
    pitch = pitch_shown(check)
    systematic = [  # value, its sigma, refusal limit, warning limit, what, the refusal limit in words, likely cause
        (s.height_drift_m, s.height_drift_sigma_m, limits.max_height_drift * h, limits.warn_height_drift * h,
         f"the cameras' heights drift by {s.height_drift_m:+.1f} m (+-{s.height_drift_sigma_m:.1f}) over the flight",
         f"{limits.max_height_drift * h:.0f} m, {limits.max_height_drift:.0%} of the {h:.0f} m flying height",
         "a drifting GPS altitude?"),
        (s.height_tilt_deg, s.height_tilt_sigma_deg, limits.max_height_tilt_deg, limits.warn_height_tilt_deg,
         f"the cameras' heights tilt {s.height_tilt_deg:.1f} deg (+-{s.height_tilt_sigma_deg:.1f}) over the ground",
         f"{limits.max_height_tilt_deg:g} deg", "the camera centres lie on a tilted plane"),
        (s.attitude_bias_deg, s.attitude_bias_sigma_deg, limits.max_attitude_bias_deg, limits.warn_attitude_bias_deg,
         f"the cameras share an attitude error of {s.attitude_bias_deg:.1f} deg (+-{s.attitude_bias_sigma_deg:.1f})",
         f"{limits.max_attitude_bias_deg:g} deg", _attitude_cause(check, pitch)),
    ]
    for k, (value, sigma, limit, warn, what, at_most, cause) in enumerate(systematic):
        # the attitude bias (last) may be a lag along the track as well: both named, unless the consecutive pairs
        # show a pitch (`pitch_shown`), which a lag cannot give
        alternative = ("" if k < len(systematic) - 1 else _as_pitch(pitch) if pitch is not None
                       else _or_lag(check.lag_along_track_m))
        if beyond(value, sigma, limit):
            v.refusals.append(f"poses vs images: {what} against what the images show (at most {at_most})"
                              f"{alternative}: {cause}")
        elif beyond(value, sigma, warn):
            v.warnings.append(f"poses vs images: {what} against the images{alternative}")
        elif k == len(systematic) - 1 and not check.attitude_checked:
            v.warnings.append(unchecked)
    return v


# a camera's pose is wrong (`wrong_cameras`) when it misses its pairs' matches beyond the camera limit
# (`PoseCheck.camera_limit_px`: PoseCheckParams.camera_median_factor x the flight's median pair error, at least
# camera_gate_fraction of the tracker's gate) in at least CAMERA_MIN_PAIRS pairs and CAMERA_SHARE of the checked
# pairs it is in, where the partner fits its other pairs. Measured (BENCHMARKS.md, "Cameras whose poses miss
# their pairs"): a swapped pair of cameras 48-72 px and a 90 deg yaw 26-37 px at a median of 0.3 px
CAMERA_MIN_PAIRS = 2
CAMERA_SHARE = 2 / 3


def wrong_cameras(check: PoseCheck) -> list[tuple[int, int, list[float]]]:
    """The cameras whose poses contradict their images: (index, checked pairs it is in, the errors of its failing
    pairs whose partner fits), worst first. A pair fails beyond `PoseCheck.camera_limit_px`; it counts against
    camera c when its partner has other pairs and at most half of them fail (the partner's pose fits: the fault is
    c's). A camera is wrong with at least CAMERA_MIN_PAIRS such pairs and CAMERA_SHARE of its pairs failing. A
    single failing pair cannot be attributed (either camera may be off): it is only named among the pairs
    (`judge_poses`), or with its partner in an exchange (`swaps`)."""
    if check.pairs_checked < 2 or not np.isfinite(check.epipolar_p50_px):
        return []
    errors: dict[int, list[tuple[int, float]]] = {}
    for p in check.pairs:
        if np.isfinite(p.epipolar_px):
            errors.setdefault(p.a, []).append((p.b, p.epipolar_px))
            errors.setdefault(p.b, []).append((p.a, p.epipolar_px))
    if not errors:
        return []
    limit = check.camera_limit_px

    def partner_fits(partner: int, c: int) -> bool:
        other = [e for q, e in errors.get(partner, []) if q != c]
        return bool(other) and sum(e > limit for e in other) <= len(other) / 2

    out = []
    for c, pairs in errors.items():
        failing = [e for _, e in pairs if e > limit]
        attributed = [e for q, e in pairs if e > limit and partner_fits(q, c)]
        if len(attributed) >= CAMERA_MIN_PAIRS and len(failing) >= CAMERA_SHARE * len(pairs):
            out.append((c, len(pairs), attributed))
    return sorted(out, key=lambda t: -float(np.median(t[2])))


# A flight whose poses miss too many of its pairs is refused, whatever the median says (nu59 D1: each image given
# its neighbour's pose, a pose file one row off, fit the straight passes, whose consecutive pairs keep their
# relative pose, and missed only the turns and cross-line pairs: 33 % of the pairs beyond the gate, "ok"). The gate
# is the misfit sound poses may have, so the question is how many pairs beyond it a sound flight shows. Pairs that
# share an image are not independent (one bad pose spoils every pair of its image, a slow EKF error a run of them),
# so pairs count in clusters of the flight's pairs per image (the design effect). Measured (BENCHMARKS.md, "Pose
# files off by rows"): true and EKF poses of 11 synthetic flights (10 worlds; lawnmower and free-form, a k1 -0.15
# lens, a 35 deg oblique camera, 320-640 px) and Seneca's refined telemetry: 2 of 2567 pairs beyond the gate (1
# beyond twice it; both Seneca's: an image its refinement left at its prior, 62 px, and a pair at 24.7 on 24 px),
# 1.2 clusters of 649; the 95 % upper bound of that rate is 0.8 % (twice the gate: 0.6 %, no sharper test), taken
# as SOUND_MISS_RATE 1 %. A sound flight's cluster count then follows a binomial law of at most that rate, and a
# count whose tail is below MISFIT_TAIL_P (one sound flight in 10^4) is refused: ~20 % of a flight's pairs (16 of
# 84 on 39 images)
SOUND_MISS_RATE = 0.01
MISFIT_TAIL_P = 1e-4


def misfit_pairs_refusal(check: PoseCheck) -> list[str]:
    """The refusal (a list of at most one) of poses that miss more of their checked pairs beyond the tracker's
    gate than sound poses would with odds of MISFIT_TAIL_P (`SOUND_MISS_RATE`; the counts taken in clusters of the
    pairs per image). Empty when the count is within what sound poses show."""
    from scipy.special import betainc

    errors = np.array([p.epipolar_px for p in check.pairs], np.float64)
    errors = errors[np.isfinite(errors)]
    images = len({p.a for p in check.pairs} | {p.b for p in check.pairs})
    misses = int(np.sum(errors > check.gate_px))
    if not misses or not images:
        return []
    cluster = max(1.0, 2.0 * len(errors) / images)
    k, trials = misses / cluster, len(errors) / cluster
    # P(X >= k) of a binomial (trials, rate), continued to real k and trials by the regularized incomplete beta
    if float(betainc(k, trials - k + 1.0, SOUND_MISS_RATE)) >= MISFIT_TAIL_P:
        return []
    return [f"poses vs images: {misses} of {len(errors)} checked pairs ({misses / len(errors):.0%}) miss their "
            f"matches by more than the tracker's {check.gate_px:.0f} px gate, where sound poses miss at most "
            f"{SOUND_MISS_RATE:.0%} of their pairs (median pair {check.epipolar_p50_px:.1f} px): the poses do not "
            "belong to these images (a pose file shifted by a row, in reverse order, or of another flight?)"]


def poses_fit_images(check: PoseCheck, limits: PoseCheckParams) -> str:
    """A phrase saying that the check found the poses fitting the images ("" when it did not, or saw too little
    to say): at least `min_pairs` pairs checked, no pass reversed, the matches not loose (`median_loose`: few of
    them beyond the gate) and no single pair beyond its warning limit. The map's own warnings that would otherwise
    name the poses (passes without landmarks, few tracks triangulated, passes disagreeing) quote it, so that a map
    thinned by its images is not blamed on poses that were measured to fit (the 23rd new-user sweep: Gaussian noise
    on the images of unchanged EKF poses was reported as "a wrong heading")."""
    if check.pairs_checked < limits.min_pairs or not np.isfinite(check.epipolar_p50_px) or check.reversed_passes:
        return ""
    if poses_loose(check, limits):
        return ""
    return (f"the pose check found the poses fitting the images ({check.pairs_checked} of {check.pairs_tried} pairs "
            f"checked, median {check.epipolar_p50_px:.1f} px on a {check.gate_px:.0f} px gate)")


@dataclass(frozen=True)
class PitchShown:
    """A shared attitude error that is a pitch the consecutive pairs show (`pitch_shown`)."""

    pitch_deg: float  # about the cameras' x axis; > 0: the images see further towards the image top
    consecutive_px: float  # the consecutive pairs' median misfit on the poses as given
    consecutive_fit_px: float  # the same with the fitted errors taken off


def pitch_shown(check: PoseCheck) -> PitchShown | None:
    """The fitted attitude error as a pitch that a lag along the track cannot give (`PITCH_AXIS_SHARE`,
    `CONSECUTIVE_EXPLAINED`): its axis within ~25 deg of the cameras' x axis, and the fit taking the consecutive
    pairs (at least MIN_CONSECUTIVE) well below their misfit on the given poses. None otherwise (no fit, another
    axis, or the consecutive pairs fitting as they were: then a lag is as likely)."""
    w = np.asarray(check.systematic.parameters[3:6], np.float64)
    angle = float(np.linalg.norm(w)) if len(w) == 3 and np.all(np.isfinite(w)) else 0.0
    if not angle or abs(w[0]) < PITCH_AXIS_SHARE * angle:
        return None
    nexts = np.array([(p.epipolar_px, p.epipolar_fit_px) for p in check.pairs if p.kind == "next"
                      and np.isfinite(p.epipolar_px) and np.isfinite(p.epipolar_fit_px)]).reshape(-1, 2)
    if len(nexts) < MIN_CONSECUTIVE:
        return None
    given, fitted = (float(v) for v in np.median(nexts, axis=0))
    if not (given > 0 and fitted <= CONSECUTIVE_EXPLAINED * given):
        return None
    return PitchShown(float(np.degrees(w[0])), given, fitted)


def _attitude_cause(check: PoseCheck, pitch: PitchShown | None) -> str:
    """The likely causes of a refused attitude error, the one the evidence favours first."""
    if pitch is not None:  # a gimbal pitched away from nadir moves the view towards the image top
        return ("the camera's pitch (an oblique camera recorded as nadir, or a gimbal pitch left out or wrong)?"
                if pitch.pitch_deg > 0 else
                "the camera's pitch (a gimbal pitch recorded too far from nadir)?")
    if np.isfinite(check.lag_along_track_m):
        return "a camera trigger latency, a log time offset, or a wrong mounting?"
    return "a wrong mounting or heading convention?"


def _as_pitch(pitch: PitchShown) -> str:
    """The attitude error as the pitch the consecutive pairs show, in words (short: a refusal is cut at 400
    characters, `plugin.errors.one_line`, and the cause comes last)."""
    towards = "top" if pitch.pitch_deg > 0 else "bottom"
    return (f", a pitch of {abs(pitch.pitch_deg):.1f} deg towards the image {towards}"
            f" (the consecutive pairs show it, {pitch.consecutive_px:.1f} -> {pitch.consecutive_fit_px:.1f} px, as a "
            "lag along the track would not)")


def _or_lag(lag_m: float) -> str:
    """The lag along the track the images cannot tell from the attitude bias, in words ("" for none)."""
    if not np.isfinite(lag_m):
        return ""
    return (f", or positions {abs(lag_m):.1f} m {'behind' if lag_m > 0 else 'ahead'} along the track (a camera "
            "trigger latency or a log time offset: over flat ground the images cannot tell them apart)")


def judge_gps(gps: GpsComparison | None, limits: PoseCheckParams) -> Verdict:
    """The camera centres against the images' own GPS fixes (`gps.compare_with_gps`): a warning for a georeference
    far from the fixes (measured without any fit, so always judged); then, for a path that follows the fixes, a
    refusal when the poses' lengths are not ground metres (beyond `max_gps_scale_error` by more than two of the
    scale's standard deviations); for one that does not, a warning naming why (a mirrored frame, unsteady
    fixes, or poses of another flight), or nothing for a flight too small against its receiver's jitter to tell.
    Nothing without fixes."""
    v = Verdict()
    if gps is None:
        return v
    limit = min(limits.warn_gps_offset_m, gps.offset_limit_m)
    if np.isfinite(gps.offset_m) and gps.offset_m > limit:
        v.warnings.append(f"poses vs images' GPS: the camera centres lie {_distance(gps.offset_m)} from the images' "
                          f"own GPS fixes in the poses' CRS (median of {gps.fixes}; their noise explains up to "
                          f"{limit:.0f} m): the map's georeference is that far off (another UTM zone or hemisphere, "
                          "another datum, a shifted origin, or positions from a log joined to the images one row "
                          "off?)")
    agreement = limits.min_gps_agreement
    if not gps.follows(agreement):
        # only a mirror that fits clearly better than the proper fit names the frame (a straight corridor fits both
        # equally, and a receiver's jumps then failed the inlier share: good poses were refused, review rev16)
        if (not gps.too_small and gps.explained < agreement
                and gps.mirrored_explained >= max(agreement, MIRRORED_EXPLAINED, gps.explained + 0.3)):
            # a mirrored map matches no other session and misplaces its georeference: unusable, when clear
            (v.refusals if gps.fixes >= MIN_FIXES_TO_REFUSE else v.warnings).append(
                f"poses vs images' GPS: the camera path is the mirror image of the images' own GPS track (mirrored, "
                f"a similarity explains {gps.mirrored_explained:.0%} of its spread, {gps.fixes} fixes): x and y "
                "swapped or one axis reversed (north-east-down poses?), so the map would be mirrored too")
        elif not gps.too_small and gps.explained >= agreement:
            # the path explains the fixes' spread, but most fixes lie outside its noise: unsteady fixes (a receiver
            # jumping between solutions, multipath), not the poses of another flight (review rev16)
            v.warnings.append(f"poses vs images' GPS: the camera path follows the images' own GPS track (a "
                              f"similarity explains {gps.explained:.0%} of its spread), but only {gps.inliers} of "
                              f"{gps.fixes} fixes lie within its {max(gps.sigma_m, GNSS_WANDER_M):.1f} m noise: "
                              "unsteady fixes (a receiver jumping between solutions, multipath?), so the poses' unit "
                              "is not checked")
        elif not gps.too_small:
            v.warnings.append(f"poses vs images' GPS: the camera path does not follow the images' own GPS track (a "
                              f"similarity explains {max(gps.explained, 0.0):.0%} of its spread, {gps.inliers} of "
                              f"{gps.fixes} fixes): poses of another flight, or names paired with the wrong images?")
        return v  # its scale is no measurement of the poses' unit
    # a few fixes measure their own noise too small (3 of 5 agreeing by chance: 0.5 m for a 3 m receiver refused
    # true poses 19 % of the time, the diff review): a refusal needs MIN_FIXES_TO_REFUSE inliers, fewer warn
    off_scale = beyond(float(np.log(gps.scale)), gps.scale_sigma, float(np.log1p(limits.max_gps_scale_error)))
    if off_scale and gps.inliers < MIN_FIXES_TO_REFUSE:
        v.warnings.append(f"poses vs images' GPS: the camera path is {gps.scale_text} x as long as the images' own "
                          f"GPS track, but only {gps.inliers} fixes agree: too few to prove the poses' unit")
    elif off_scale:
        unit = gps.unit_factor
        cause = (f"poses in {unit}?" if unit else
                 "an unscaled reconstruction? georeference it (COLMAP's model_aligner) or let `sosmatch poses` make "
                 "the poses")
        v.refusals.append(f"poses vs images' GPS: the camera path is {gps.scale_text} x as long as the images' own "
                          f"GPS track ({gps.fixes} fixes, {gps.extent_m:.0f} m rms from their centre): the poses "
                          f"are not in metres, so neither would the map be ({cause})")
    return v


def _distance(metres: float) -> str:
    return f"{metres / 1000:,.0f} km" if metres >= 10_000 else f"{metres:,.0f} m"
