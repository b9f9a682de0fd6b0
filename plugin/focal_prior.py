"""A focal length from structure from motion weighed against the EXIF one (pure arithmetic).

Over flat ground a nadir block's focal length trades against its depths: f and every camera-to-ground distance
scaled together reproject the same, so the images say little about f and a bundle adjustment that frees it
lets it wander (a 40-frame synthetic flight: +5.7 % off the true focal length, the ground 4-6 m too low, for
0.36 px^2 of squared reprojection error in 12,000 observations). Relief, tilted views and lens distortion break
the trade, and then the images know f far better than any EXIF tag (166 real Seneca frames: +2.1 % off
FocalLength, and holding the EXIF value costs 5,000 chi-square units). COLMAP's bundle adjustment has no prior
on intrinsics (OpenSfM's has one, `exif_focal_sd`), so the prior is applied to its profile instead:

- the images' information on f comes from the misfit profile: the sum of squared reprojection errors with f
  free (SSE_free at f_free) and held at the EXIF value (SSE_exif); near its minimum the profile is a parabola,
  so the images alone know f to sigma_free = |f_exif - f_free| / sqrt(delta chi^2), with
  delta chi^2 = (SSE_exif - SSE_free) / sigma_px^2 and sigma_px^2 the fit's own variance per coordinate;
- that curvature counts every observation as independent, and they are not: a flight's errors are correlated
  along it (the same ground, the same attitude episode, the tracker's biases on one patch), so where the
  images barely know f the curvature claims several times what they know (nu32's wind flights and nu26's wide
  cameras: 0.8-2 % claimed, 3-6 % off). The images' sigma is therefore the larger of it and a grouped jackknife
  of the free focal length over contiguous blocks of the flight (`contiguous_blocks`, `robust_fit.jackknife_sigma`): the
  scatter of f with one stretch of the flight left out at a time, which carries the correlation in it;
- the EXIF focal length is a Gaussian prior of its own relative uncertainty (`exif_focal_uncertainty`);
- the focal length taken is the two combined by their inverse variances (the maximum a posteriori of the
  parabola times the prior), unless the two contradict each other beyond what their uncertainties allow: an
  EXIF value is then more probably not about these pixels at all (the files resized or cropped after capture:
  a focal length in pixels scales with a resize, and a crop changes the frame a 35 mm equivalent refers to) and
  the images' own value is taken (`exif_unrelated_probability`). Averaging two estimates 10-20 sigmas apart
  gives a value both sources exclude (nu42: photos resized by half, EXIF's width updated: 502 px against the
  images' 247 +- 6 px, 315 px taken and the landmarks 22 m low);
- a camera of too few images for the jackknife (`checkable` false) has no honest sigma: the curvature's alone
  is the overconfident figure the jackknife exists to correct, so such a measurement may neither set EXIF aside
  nor pull it: the EXIF value is held and the images' optimum only reported (nu53: 3 frames exported at 800x600
  measured 629 px +-1.2 % by the curvature against EXIF's right 555 px, EXIF set aside and the poses 5 m high;
  one 12000x9000 frame 2299 px against EXIF's right 8326, its pose 45 m low).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np


def residual_variance(sse_px2: float, observations: int, parameters: int) -> float:
    """The fit's variance per image coordinate (px^2): the squared reprojection errors of `observations` 2-D
    observations over their degrees of freedom (2 per observation less the `parameters` estimated; at least one
    degree is left). NaN without a finite, positive sum."""
    if not (math.isfinite(sse_px2) and sse_px2 > 0):
        return float("nan")
    return sse_px2 / max(2 * int(observations) - int(parameters), 1)


def images_focal_sigma(f_free: float, sse_free: float, f_fixed: float, sse_fixed: float,
                       variance_px2: float) -> float:
    """The standard deviation (px) with which the images alone know the focal length: from the misfit rise
    between the free optimum (`f_free`, `sse_free`) and the fit held at `f_fixed` (`sse_fixed`), a parabola's
    curvature in units of the fit's variance per coordinate. Infinite when holding it costs nothing (a flat
    profile: the images carry no information on f); 0 when the two focal lengths are equal and holding costs
    something (cannot happen at an optimum; treated as fully determined)."""
    rise = (sse_fixed - sse_free) / variance_px2 if variance_px2 > 0 else float("nan")
    if not math.isfinite(rise) or rise <= 0:
        return math.inf
    return abs(f_fixed - f_free) / math.sqrt(rise)


# The prior probability that a focal length read from EXIF does not describe the pixels of the files at all
# (resized or cropped after capture, the tag of another lens or zoom setting), and the ratios to the true
# focal length such a value leaves equally likely (a factor of this either way, uniform in log f). The images'
# value is taken where this hypothesis explains their optimum better than EXIF's Gaussian error does: at 4.0
# sigmas of the two together for images and EXIF known to +-2.4 % and 2 % (3.7-4.3 for a spread of 10-1 %; 3.4
# at a prior of 10 %, 4.6 at 0.1 %: the switch barely depends on either figure). Every s47 case lies within 2.4
# sigmas (nu26 D_wide80, whose images are 4 % off claiming 1.2 %): their EXIF prior holds as before.
EXIF_UNRELATED_PRIOR = 0.01
UNRELATED_RATIO = 4.0


def exif_unrelated_probability(exif_px: float, images_px: float, spread_px: float) -> float:
    """The posterior probability that the EXIF focal length `exif_px` does not describe the images at all,
    given the images' own optimum `images_px` and `spread_px`, the standard deviation of their difference when
    EXIF is right (the images' and EXIF's sigmas together). Two hypotheses: EXIF right within its Gaussian error
    (prior 1 - `EXIF_UNRELATED_PRIOR`), or unrelated, the true focal length anywhere within `UNRELATED_RATIO`
    of it, uniformly in log f. In log f (relative units) both are densities of the same difference. 0 where the
    images know nothing of f (an infinite or NaN spread) or a value is not positive."""
    if not (exif_px > 0 and images_px > 0 and math.isfinite(spread_px) and spread_px > 0):
        return 0.0
    d = math.log(images_px / exif_px)
    s = spread_px / exif_px
    right = (1.0 - EXIF_UNRELATED_PRIOR) * math.exp(-0.5 * (d / s) ** 2) / (math.sqrt(2.0 * math.pi) * s)
    unrelated = EXIF_UNRELATED_PRIOR / (2.0 * math.log(UNRELATED_RATIO))
    return unrelated / (unrelated + right)


def contiguous_blocks(count: int, blocks: int) -> np.ndarray:
    """Block id (0 .. blocks-1) per position 0 .. count-1: `blocks` runs of consecutive positions of nearly
    equal length (fewer blocks when there are fewer positions)."""
    blocks = max(1, min(int(blocks), int(count)))
    return np.arange(int(count)) * blocks // max(int(count), 1)


@dataclass(frozen=True)
class FocalEstimate:
    """One camera's focal length: the EXIF prior, what the images alone say, and the one taken (all px)."""

    camera_id: int
    exif_px: float
    exif_sigma_px: float
    images_px: float  # the bundle adjustment's optimum with f free
    images_sigma_px: float  # inf: the images know nothing of f
    taken_px: float
    taken_sigma_px: float
    chi2_of_exif: float  # the misfit rise of holding f at the EXIF value, in units of the fit's variance
    curvature_sigma_px: float = math.nan  # the misfit curvature's sigma (every observation independent)
    blocks_sigma_px: float = math.nan  # the jackknife's over contiguous blocks (NaN: not needed, not run)
    blocks: int = 0  # the blocks of that jackknife
    exif_unrelated: float = 0.0  # the probability that EXIF's value is not about these pixels at all
    exif_set_aside: bool = False  # it was the more probable: the images' value taken alone
    exif_unchecked: bool = False  # too few images to know how well they know f: EXIF's value held, not checked

    @property
    def disagreement_sigmas(self) -> float:
        """How far the images' optimum and the EXIF value lie apart in units of what the two know together (the
        standard deviation of their difference): beyond 2, one of them is wrong by more than it admits, and
        the focal length taken (and every depth) is a compromise between contradicting sources. 0 where the
        images carry no information on f."""
        if not math.isfinite(self.images_sigma_px):
            return 0.0
        spread = math.hypot(self.images_sigma_px, self.exif_sigma_px)
        return abs(self.images_px - self.exif_px) / spread if spread > 0 else math.inf

    @property
    def images_weight(self) -> float:
        """The share of the images in the focal length taken (0: the EXIF value, 1: the images' optimum)."""
        if self.exif_unchecked:
            return 0.0
        if self.exif_set_aside:
            return 1.0
        if not math.isfinite(self.images_sigma_px):
            return 0.0
        if self.images_sigma_px <= 0:
            return 1.0
        w_img, w_exif = 1.0 / self.images_sigma_px**2, 1.0 / self.exif_sigma_px**2
        return w_img / (w_img + w_exif)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["images_weight"] = self.images_weight
        out["disagreement_sigmas"] = self.disagreement_sigmas
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}


def combine_focal(camera_id: int, exif_px: float, exif_sigma_rel: float, images_px: float,
                  images_sigma_px: float, chi2_of_exif: float, blocks_sigma_px: float = math.nan,
                  blocks: int = 0, checkable: bool = True) -> FocalEstimate:
    """The focal length taken: the EXIF value (relative sigma `exif_sigma_rel`) and the images' optimum
    combined by their inverse variances. The images' sigma is the larger of the misfit curvature's
    (`images_sigma_px`, inf for none) and the blocks' jackknife (`blocks_sigma_px` over `blocks` blocks; NaN
    when it was not run). Where the two contradict each other so far that EXIF's value is more probably not
    about these pixels at all (`exif_unrelated_probability` above one half), the images' value is taken alone.
    `checkable` false: the camera has too few images for the jackknife, so the images' sigma cannot be known
    (the curvature's understates it several times) and EXIF's value is held (`exif_unchecked`); the images'
    optimum and the curvature's sigma are kept for the record (`disagreement_sigmas` on them says how far apart
    the two lie if the curvature were honest) and EXIF's unrelated probability is not judged (NaN)."""
    curvature = images_sigma_px
    if not math.isnan(blocks_sigma_px):
        images_sigma_px = max(images_sigma_px, blocks_sigma_px)
    exif_sigma = abs(exif_px) * exif_sigma_rel
    if not checkable:
        return FocalEstimate(int(camera_id), float(exif_px), float(exif_sigma), float(images_px),
                             float(images_sigma_px), float(exif_px), float(exif_sigma), float(chi2_of_exif),
                             float(curvature), float(blocks_sigma_px), int(blocks), math.nan, False, True)
    unrelated = exif_unrelated_probability(exif_px, images_px, math.hypot(images_sigma_px, exif_sigma))
    set_aside = unrelated > 0.5
    if not math.isfinite(images_sigma_px):
        taken, sigma = exif_px, exif_sigma
    elif set_aside:
        # averaging would give a value both sources exclude: the images measure these pixels, EXIF may not
        taken, sigma = images_px, images_sigma_px
    elif images_sigma_px <= 0 or exif_sigma <= 0:
        taken, sigma = images_px, max(images_sigma_px, 0.0)
    else:
        w_img, w_exif = 1.0 / images_sigma_px**2, 1.0 / exif_sigma**2
        taken = (w_img * images_px + w_exif * exif_px) / (w_img + w_exif)
        sigma = 1.0 / math.sqrt(w_img + w_exif)
    return FocalEstimate(int(camera_id), float(exif_px), float(exif_sigma), float(images_px),
                         float(images_sigma_px), float(taken), float(sigma), float(chi2_of_exif), float(curvature),
                         float(blocks_sigma_px), int(blocks), float(unrelated), bool(set_aside))
