"""Pose refinement statistics and the plausibility judgement of a refinement against its priors."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ...plugin.errors import InputError
from ...plugin.geometry import rotation_angle_deg


@dataclass
class RefinementStats:
    """What the refinement did. Errors in pixels, metres and degrees; 'prior' = the given poses."""

    images: int
    points: int
    observations: int
    reprojection_rmse_before_px: float
    reprojection_rmse_after_px: float
    reprojection_median_before_px: float
    reprojection_median_after_px: float
    position_change_mean_m: float
    position_change_max_m: float
    rotation_change_mean_deg: float
    rotation_change_max_deg: float
    iterations: int
    seconds: float
    converged: bool
    position_change_median_m: float = float("nan")
    block_tilt_change_deg: float = float("nan")  # the rotation all poses share, its tilt off the vertical
    # per camera |change of the optical axis' angle off the vertical|, median: a heading turn leaves it unchanged
    tilt_change_median_deg: float = float("nan")
    # share of ALL the tie-point observations the refined poses explain (`tie_points.explained_share`), not only
    # those of the points the starting poses could triangulate and the adjustment kept
    explained_share: float = float("nan")
    explained_share_by_image: tuple[float, ...] = ()  # the same per image, of its own observations (NaN: none)
    # per image: how far the refined poses turned the direction of gravity in the camera frame (`tilt_changes_deg`);
    # judged against gimbal tags (`judge_refinement`)
    tilt_change_by_image_deg: tuple[float, ...] = ()
    observations_by_image: tuple[int, ...] = ()  # how many tie-point observations each image has
    heading_turns_deg: tuple[float, ...] = ()  # per image: heading turned from the course by the image motion
    # regions fixed in the image frame (burned-in text, a logo, drone parts) whose tie points were left out: boxes
    # (x0, x1, y0, y1) in full-size pixels (`plugin.fixed_in_frame`)
    fixed_in_frame_px: tuple[tuple[int, int, int, int], ...] = ()
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["warnings"] = list(self.warnings)
        d["observations_by_image"] = [int(n) for n in self.observations_by_image]
        for key in ("heading_turns_deg", "explained_share_by_image", "tilt_change_by_image_deg"):
            d[key] = [round(t, 3) if np.isfinite(t) else None for t in getattr(self, key)]
        return d


def pose_changes(before_r: np.ndarray, before_c: np.ndarray, after_r: np.ndarray, after_c: np.ndarray) -> dict:
    """How far the poses moved: per-image position and rotation changes, and the tilt of the rotation they share
    (the chordal mean of R_after R_before^T): a block that tilts as a whole moves every camera the same way."""
    dpos = np.linalg.norm(after_c - before_c, axis=1)
    drot = np.atleast_1d(rotation_angle_deg(before_r, after_r))
    mean = np.einsum("nij,nkj->ik", after_r, before_r)  # sum of R_after R_before^T
    u, _, vt = np.linalg.svd(mean)
    shared = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    tilt = float(np.degrees(np.arccos(np.clip(shared[2, 2], -1.0, 1.0))))
    return {"tilt_change_median_deg": float(np.median(np.abs(off_vertical_deg(after_r) - off_vertical_deg(before_r)))),
            "position_change_mean_m": float(dpos.mean()), "position_change_max_m": float(dpos.max()),
            "position_change_median_m": float(np.median(dpos)), "rotation_change_mean_deg": float(drot.mean()),
            "rotation_change_max_deg": float(drot.max()), "block_tilt_change_deg": tilt}


def tilt_changes_deg(before_r: np.ndarray, after_r: np.ndarray) -> np.ndarray:
    """(N,) per camera, degrees: how far the direction of gravity in the camera frame turned from `before_r` to
    `after_r` (world_from_camera, z up), i.e. the turn of the camera less its turn about the vertical: what a
    gimbal's pitch and roll tags give and its compass heading does not (0 for any heading turn, whatever the
    camera's tilt)."""
    up = np.einsum("nji,j->ni", np.asarray(after_r), [0.0, 0.0, 1.0])  # the world's up in each camera, after
    up0 = np.einsum("nji,j->ni", np.asarray(before_r), [0.0, 0.0, 1.0])
    return np.degrees(np.arccos(np.clip(np.sum(up * up0, axis=1), -1.0, 1.0)))


def off_vertical_deg(rotations: np.ndarray) -> np.ndarray:
    """(N,) angle in degrees of each camera's optical axis (world_from_camera, z up) from straight down."""
    return np.degrees(np.arccos(np.clip(-np.asarray(rotations)[:, 2, 2], -1.0, 1.0)))


# The tilt off the vertical a stabilised gimbal holds and reports (DJI XMP Gimbal*Degree: gravity-referenced,
# nadir to a degree, `georegistration.NADIR_ASSUMPTION_SIGMA_DEG`'s note), as one sigma with margin. Its heading is
# the compass's and may be degrees off, which a refinement rightly corrects; the tilt it may not change by much:
# a lens taken as distortion-free (a barrel lens, k1 -0.2, from PINHOLE tags) was absorbed by cameras tilted 4-19 deg
# towards the block's centre over a ground lifted 26 m (the 26th new-user sweep, 0.39 px after the adjustment).
GIMBAL_TILT_SIGMA_DEG = 2.0


# A camera is turned against its own tie points when its pose explains fewer than half of them and that few is
# unlikely (one-sided binomial tail below this) for a pose that explains at least half: one unexplained observation
# of one image is no evidence (Seneca's IMG_0506, at the end of a line, had a single tie point, and the whole
# refinement of 167 images, 99.7 % explained, was refused for it); 0 of 7 is.
CONTRADICTION_P = 0.01
# A camera's own tie points constrain its 6 unknowns when they give at least 1.5 measured coordinates per unknown
# (the block-level rule of `judge_refinement`): 5 observations; with fewer one wrong tie point decides its turn
# (such a camera keeps its starting pose, `tie_points.turned_images`) and its share is not judged.
WEAK_OBSERVATIONS = 5


# A camera tilted beyond this many tilt sigmas off its gimbal tags is a gross error of the adjustment or of that
# tag. The tags' pitch and roll are a 2-D Gaussian, so a good camera lands beyond it with probability exp(-k^2 / 2)
# (1.1 % at 3): more such cameras than that rate explains (`CONTRADICTION_P`) say the adjustment turned them (rev49
# D3: a non-converged refinement turned 17 of 40 well-held cameras 6-59 deg off tags good to 0.5 deg, published);
# fewer are named and kept: one wrong tag the tie points correct (a tag 12 deg off on a plane's views: back within
# 1 deg, its tie points 99.6 % explained; given its tag back, its own and its neighbour's tie points refused it).
GROSS_TILT_SIGMAS = 3.0


def tilted_beyond_chance(tilted: int, images: int) -> bool:
    """Whether `tilted` of `images` cameras beyond GROSS_TILT_SIGMAS is more than good tags' noise explains:
    P(at least that many | binomial at the rate exp(-k^2 / 2)) < CONTRADICTION_P."""
    from scipy.stats import binom

    rate = float(np.exp(-0.5 * GROSS_TILT_SIGMAS**2))
    return tilted > 0 and float(binom.sf(tilted - 1, images, rate)) < CONTRADICTION_P


def contradicted_images(share_by_image: tuple[float, ...] | np.ndarray,
                        observations_by_image: tuple[int, ...] | np.ndarray = ()) -> np.ndarray:
    """Indices of the images whose refined poses explain, beyond chance, less than half of their own tie points:
    share < 0.5 and P(at most that many explained | n observations, rate 0.5) < CONTRADICTION_P. Without the
    counts every image below half counts. NaN (an image without tie points) is not judged here."""
    from scipy.stats import binom

    share = np.asarray(share_by_image, dtype=np.float64)
    below = share < 0.5
    if len(observations_by_image) != len(share):
        return np.flatnonzero(below)
    n = np.asarray(observations_by_image, dtype=np.int64)
    explained = np.round(np.nan_to_num(share) * n).astype(np.int64)
    return np.flatnonzero(below & (binom.cdf(explained, n, 0.5) < CONTRADICTION_P))


def unexplained_images(share_by_image: tuple[float, ...] | np.ndarray,
                       observations_by_image: tuple[int, ...] | np.ndarray = ()) -> np.ndarray:
    """Indices of the images whose refined poses explain less than half of their own tie points, on at least
    WEAK_OBSERVATIONS of them (fewer: the image keeps its starting pose and is named for that), beyond chance
    (`contradicted_images`, an error) or not. Such a pose is not used to build anything (README: less than half of
    an image's own is not a pose): nu58 D2's two Seneca cameras ~140 deg off their heading explained 7 of 17 / 7 of
    18 and were mapped. Without the counts every image below half counts; NaN (no tie points) is not judged."""
    share = np.asarray(share_by_image, dtype=np.float64)
    counted = np.asarray(observations_by_image, dtype=np.int64)
    enough = counted >= WEAK_OBSERVATIONS if len(counted) == len(share) else np.ones(len(share), bool)
    return np.flatnonzero((share < 0.5) & enough)


def judge_refinement(stats: RefinementStats, position_sigma_m: float | tuple[float, float, float],
                     attitude_sigma_deg: float, names: list[str] | None = None,
                     tilt_sigma_deg: float | None = None) -> tuple[list[str], list[str]]:
    """(errors, warnings) of a refinement: the priors say how far the poses may move.

    Errors (the refined poses are not used): a median position change beyond 3 prior sigmas (a Gaussian prior
    puts 3 sigma in the tail of every axis: half the cameras beyond it means the tie points pulled the block away
    from the GPS, e.g. folded it); a tilt of the whole block (the rotation all poses share) beyond 3 attitude
    sigmas. Warnings: no convergence within the solver's iterations (Seneca's good refinement ends so: 0.52 px,
    poses 1.2 sigma from their priors, block tilt 2 deg; the figures above judge the result); single images moved
    beyond 5 sigmas (a wrong GPS fix, or a wrong tie point); a mean rotation change beyond 3 attitude sigmas; tie
    points that barely constrain the poses (fewer than 1.5 measured coordinates per unknown: 6 per pose, 3 per
    point).
    Errors: the refined poses explain less than half of the images' tie-point observations (`explained_share`), or,
    beyond chance, less than half of one image's own (`contradicted_images`; `names` name it). The reprojection
    error after the adjustment is measured on the points it kept, so it cannot see this: cameras 90 degrees off
    their true headings triangulate a third of the tracks, and the adjustment fits those to 0.4 px (Seneca's first
    30 frames turned to portrait: 57 of 171 tracks kept, the rest dropped unseen; 33 % of the observations
    explained), and a camera left 180 degrees off explains none of its own (a synthetic flight turned to portrait: 3
    such images among 24, 95 % of all observations explained). Good refinements explain 92-100 % of every image's
    own where it has more than a few.
    `tilt_sigma_deg` (None: not judged): how well the priors give each camera's tilt off the vertical (a gimbal's,
    GIMBAL_TILT_SIGMA_DEG); a median change of that tilt beyond 3 of it is an error, the tie points bending the
    block (a bowl or a dome: an unmodelled lens distortion) rather than correcting the tags; so are more cameras
    tilted beyond GROSS_TILT_SIGMAS of it than chance explains (`stats.tilt_change_by_image_deg`: a warning naming
    fewer, and one when the tilts together lie beyond what the tags allow, `_judge_tilts`)."""
    sigma = float(np.max(np.atleast_1d(position_sigma_m)))
    errors: list[str] = []
    warnings: list[str] = []
    if stats.points == 0:
        if not np.isfinite(stats.explained_share):  # no tie-point observation at all: nothing to judge with
            return errors, ["no tie points between the images: the poses are the priors, unrefined"]
        # tie points were there and the starting poses triangulated none of them (the thirteenth sweep: Seneca's
        # telemetry headings turned by 180 deg, 281 tracks, exit 0 with "no tie points"): what the poses explain
        # of them says whether the orientations contradict the images
        warnings.append("the starting poses triangulate none of the tie points: the poses are the priors, "
                        "unrefined")
    elif not stats.converged:
        warnings.append(f"the bundle adjustment did not converge ({stats.iterations} solve(s))")
    if np.isfinite(stats.position_change_median_m) and stats.position_change_median_m > 3.0 * sigma:
        errors.append(f"it moved the cameras {stats.position_change_median_m:.1f} m (median) against a "
                      f"{sigma:g} m GPS prior (at most 3 sigma)")
    if np.isfinite(stats.explained_share) and stats.explained_share < 0.5:
        errors.append(f"the refined poses explain only {stats.explained_share:.0%} of the images' tie points "
                      "(within 2 pixel sigmas; at least half): the orientations contradict what the images show")
    odd = contradicted_images(stats.explained_share_by_image, stats.observations_by_image)
    share = np.asarray(stats.explained_share_by_image, dtype=np.float64)
    if len(odd):
        first = names[int(odd[0])] if names is not None else f"image {int(odd[0]) + 1}"
        errors.append(f"the refined poses of {len(odd)} of {len(share)} images explain less than half of their own "
                      f"tie points (e.g. {first}, {share[odd[0]]:.0%}): those cameras are turned against what the "
                      "images show")
    # below half but within chance (7 of 17 explained: p 0.31): not refused, but named -- nu58 D2's two Seneca
    # cameras ~140 deg off their heading explained 41 % / 39 % of their tie points and were named nowhere
    weak = np.setdiff1d(unexplained_images(share, stats.observations_by_image), odd)
    if len(weak):
        listed = ", ".join((names[int(i)] if names is not None else f"image {int(i) + 1}") + f" {share[i]:.0%}"
                           for i in weak[:8]) + (", ..." if len(weak) > 8 else "")
        warnings.append(f"the refined poses of {len(weak)} image(s) explain less than half of their own tie points "
                        f"({listed}; too few observations to call it beyond chance): those cameras may be turned "
                        "against what the images show; check their headings")
    if np.isfinite(stats.block_tilt_change_deg) and stats.block_tilt_change_deg > 3.0 * attitude_sigma_deg:
        errors.append(f"it tilted the whole block by {stats.block_tilt_change_deg:.1f} deg against a "
                      f"{attitude_sigma_deg:g} deg attitude prior (at most 3 sigma)")
    if (tilt_sigma_deg is not None and np.isfinite(stats.tilt_change_median_deg)
            and stats.tilt_change_median_deg > 3.0 * tilt_sigma_deg):
        errors.append(f"it tilted the cameras {stats.tilt_change_median_deg:.1f} deg (median) off the tilt their "
                      f"gimbal tags give (held to {tilt_sigma_deg:g} deg; at most 3 sigma): the tie points bend the "
                      "block, e.g. a lens distortion the camera does not model (structure from motion estimates it: "
                      "`map --pose-source sfm`)")
    if tilt_sigma_deg is not None and len(stats.tilt_change_by_image_deg):
        errors_, warnings_ = _judge_tilts(np.asarray(stats.tilt_change_by_image_deg, np.float64), tilt_sigma_deg,
                                          names)
        errors += errors_
        warnings += warnings_
    if stats.position_change_max_m > 5.0 * sigma:
        warnings.append(f"some cameras moved up to {stats.position_change_max_m:.1f} m (more than 5 x the "
                        f"{sigma:g} m prior): a wrong GPS fix or wrong tie points")
    if stats.rotation_change_mean_deg > 3.0 * attitude_sigma_deg:
        warnings.append(f"the cameras turned {stats.rotation_change_mean_deg:.1f} deg on average (more than 3 x the "
                        f"{attitude_sigma_deg:g} deg attitude prior)")
    unknowns = 6 * stats.images + 3 * stats.points
    if stats.points and 2 * stats.observations < 1.5 * unknowns:
        warnings.append(f"only {stats.points} tie points ({stats.observations} observations) for {stats.images} "
                        "images: the poses are barely constrained")
    return errors, warnings


def _judge_tilts(tilts: np.ndarray, tilt_sigma_deg: float, names: list[str] | None) -> tuple[list[str], list[str]]:
    """(errors, warnings) of the refined cameras' tilt changes `tilts` (`tilt_changes_deg`) against gimbal tags of
    `tilt_sigma_deg`: more cameras beyond GROSS_TILT_SIGMAS than chance explains is an error; fewer are named (a
    wrong tag, or a wrong turn: the tie points decide); the others are a warning when their tilts together lie
    beyond what the tags allow (sum of (tilt / sigma)^2 beyond the 99 % quantile of chi-square with 2 per camera:
    each a small turn, all of them together a block bent off its gimbals)."""
    from scipy.stats import chi2

    errors: list[str] = []
    warnings: list[str] = []
    limit = GROSS_TILT_SIGMAS * tilt_sigma_deg
    beyond = np.flatnonzero(tilts > limit)
    worst = ", ".join(f"{names[i] if names is not None else f'image {i + 1}'} {tilts[i]:.0f} deg"
                      for i in beyond[np.argsort(-tilts[beyond], kind="stable")][:4]) + (
        ", ..." if len(beyond) > 4 else "")
    if tilted_beyond_chance(len(beyond), len(tilts)):
        errors.append(f"it tilted {len(beyond)} of {len(tilts)} cameras more than {limit:g} deg off the tilt their "
                      f"gimbal tags give (held to {tilt_sigma_deg:g} deg: {GROSS_TILT_SIGMAS:g} sigma; good tags put "
                      f"at most a few there by chance): {worst}")
        return errors, warnings
    if len(beyond):
        warnings.append(f"{len(beyond)} of {len(tilts)} cameras were tilted more than {limit:g} deg off the tilt "
                        f"their gimbal tags give ({GROSS_TILT_SIGMAS:g} x {tilt_sigma_deg:g} deg): {worst}; a wrong "
                        "tag the tie points correct, or a wrong tie point")
    kept = tilts[tilts <= limit]
    statistic = float(np.sum((kept / tilt_sigma_deg) ** 2))
    if len(kept) and statistic > chi2.ppf(0.99, 2 * len(kept)):
        warnings.append(f"it tilted the cameras {float(np.sqrt(np.mean(kept**2))):.1f} deg (RMS of {len(kept)}) off "
                        f"the tilt their gimbal tags give, more than tags of {tilt_sigma_deg:g} deg allow (chi-square "
                        "99 %): the tie points may hold the cameras' tilt less well than the tags do")
    return errors, warnings


class RefinementRejected(InputError):
    """The refined poses are implausible against their priors (`judge_refinement`); the message says why (one
    line; the command line prints it and exits 2, nothing is written)."""
