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
- the EXIF focal length is a Gaussian prior of its own relative uncertainty (`exif_focal_uncertainty`);
- the focal length taken is the two combined by their inverse variances (the maximum a posteriori of the
  parabola times the prior).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any


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

    @property
    def images_weight(self) -> float:
        """The share of the images in the focal length taken (0: the EXIF value, 1: the images' optimum)."""
        if not math.isfinite(self.images_sigma_px):
            return 0.0
        if self.images_sigma_px <= 0:
            return 1.0
        w_img, w_exif = 1.0 / self.images_sigma_px**2, 1.0 / self.exif_sigma_px**2
        return w_img / (w_img + w_exif)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["images_weight"] = self.images_weight
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}


def combine_focal(camera_id: int, exif_px: float, exif_sigma_rel: float, images_px: float,
                  images_sigma_px: float, chi2_of_exif: float) -> FocalEstimate:
    """The focal length taken: the EXIF value (relative sigma `exif_sigma_rel`) and the images' optimum
    (`images_sigma_px`, inf for none) combined by their inverse variances."""
    exif_sigma = abs(exif_px) * exif_sigma_rel
    if not math.isfinite(images_sigma_px):
        taken, sigma = exif_px, exif_sigma
    elif images_sigma_px <= 0 or exif_sigma <= 0:
        taken, sigma = images_px, max(images_sigma_px, 0.0)
    else:
        w_img, w_exif = 1.0 / images_sigma_px**2, 1.0 / exif_sigma**2
        taken = (w_img * images_px + w_exif * exif_px) / (w_img + w_exif)
        sigma = 1.0 / math.sqrt(w_img + w_exif)
    return FocalEstimate(int(camera_id), float(exif_px), float(exif_sigma), float(images_px),
                         float(images_sigma_px), float(taken), float(sigma), float(chi2_of_exif))
