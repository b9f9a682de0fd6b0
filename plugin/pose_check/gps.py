"""The poses against the images' own GPS fixes: the poses' unit and georeference (pure numpy).

The images fix every length of a map only up to the poses' unit: a flight's images look the same whether its
poses are in metres, feet or the arbitrary unit of an unscaled reconstruction, and so do its epipolar geometry and
its flying height in "metres" (a 100 m flight in feet is a plausible 328 m one). Most drone images carry their own
GPS fix, which measures lengths in metres independently of the poses. So the camera centres are fitted to the
fixes by a horizontal similarity (`georegistration.robust_horizontal_similarity`: least median of squares, then
least squares on the 99 % inliers of the measured noise):

- **unit**: the similarity's scale is the poses' length per GPS metre, measured against the fixes in their own
  UTM zone (a grid whose lengths are ground metres to 0.1 %, whatever the poses' CRS says; a CRS that stretches
  distances is refused where the poses are read, `database.poses`). Feet give 3.28, centimetres 100, an unscaled
  structure-from-motion model whatever its first baseline was. Its uncertainty is the
  noise about the fit over the track's extent, and never less than GNSS_WANDER_M over it: an uncorrected
  receiver's error wanders by metres over a flight, and a wander along the track reads as scale without leaving
  any residual, so a short flight never proves a scale its GPS cannot.
- **georeference** (poses in a projected CRS): the median horizontal distance of the camera centres from their
  own fixes in that CRS, without any fit. GPS puts a camera within metres; another UTM zone or hemisphere puts
  it hundreds to thousands of kilometres off, another datum (NAD27, ED50) 100-200 m.
- **agreement**: how many fixes the similarity explains, and how much of their spread; a path that follows few of
  them is not this flight's (poses of another flight, names paired with the wrong images), and its "scale" is no
  measurement of a unit. Three things can make a true path look so and are told apart: a flight whose extent is
  within a few times its receiver's own jitter (measured from the fixes alone: their departures from the line
  through their neighbours, `fix_jitter_m`); fixes that jump (a receiver switching solutions), where the path
  explains the fixes' spread but fewer of them lie within its noise; and a mirrored frame (north-east-down
  poses: a proper rotation of east-north-up whose horizontal plane is mirrored), which a similarity with a
  reflection fits.
- **stale fixes**: fixes that stay within a metre while their cameras move are the receiver holding its last
  position (lost lock, a cold start), no measurement: left out (`stale_fixes`). They made a true path look like
  another flight's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..georegistration import MIN_FIXES, HorizontalFit, robust_horizontal_similarity
from ..gps_track import FROZEN_SPREAD_M, frozen_fix

# the least error an uncorrected GNSS receiver's fixes wander by over a flight, per axis (consumer receivers
# state 2-5 m CEP; RTK/PPK fixes do better, and then only a scale error of a few tens of percent on a small site
# goes unproven): the floor of the scale's uncertainty (module doc)
GNSS_WANDER_M = 2.5
# a flight whose extent is within this many times its receiver's jitter cannot show that its path follows the
# fixes (explained share 1 - 2/k^2 at best: 0.78 at 3)
SMALL_FLIGHT_NOISE_RATIO = 3.0
# consecutive fixes are stale when they move less than this share of what their cameras do (relative to each
# track's extent): a frozen receiver's fixes barely move (centimetres of jitter), a noisy one's move with the
# aircraft
STALE_MOVE_RATIO = 0.2
# inliers the fit needs before its noise bounds the receiver's jitter (`GpsComparison.fit_noise_bound_m`; the
# verdict's MIN_FIXES_TO_REFUSE for a unit refusal)
MIN_FIT_INLIERS = 10
# poses in a projected CRS whose centres lie farther from their own fixes (median) than this many times the GPS
# noise (`GpsComparison.offset_limit_m`: the larger of the fit's bound on it, never below GNSS_WANDER_M, as an
# uncorrected receiver's bias over a flight is no noise any fit measures, and the fixes' own jitter) are off their
# georeference: 10 m at the least, where correct poses lie a
# median 1.2 noises from their fixes. A one-row shift of a telemetry log (nu53 H1: 32.5 m, 19 noises) was said only
# beyond the fixed `pose_check.warn_gps_offset_m` (50 m), which stays the bound for any noise
OFFSET_NOISES = 4.0
# consecutive fixes closer than this are one fix repeated (a GNSS fix is given to a millimetre or coarser), not a
# second measurement of the receiver's jitter
REPEATED_FIX_M = 1e-3


@dataclass(frozen=True)
class GpsComparison:
    """The camera centres against the images' GPS fixes (module doc). Lengths in metres are the GPS's."""

    fixes: int  # images with a fresh fix that were compared
    inliers: int  # fixes the similarity explains (within the 99 % radius of the noise, at least GNSS_WANDER_M)
    scale: float  # the poses' length per ground metre (1 for poses in metres)
    scale_sigma: float  # the standard deviation of log(scale) (module doc)
    yaw_deg: float  # rotation of the poses' horizontal axes from the fixes' grid (meaningful for georeferenced poses)
    sigma_m: float  # per-axis noise of the fixes about the fitted path, measured on its inliers
    extent_m: float  # root mean square distance of the fixes from their centre
    offset_m: float = float("nan")  # georeferenced poses: median distance of the centres from their own fixes
    fix_noise_m: float = float("nan")  # the receiver's jitter per axis, from the fixes alone (`fix_jitter_m`)
    mirrored_explained: float = float("nan")  # `explained` of the best similarity with a reflection
    stale: int = 0  # fixes left out as held by the receiver while the cameras moved (`stale_fixes`)

    @property
    def explained(self) -> float:
        """The share of the fixes' spread the similarity explains, 1 - residual variance / variance (2-D): near 1
        for a camera path that follows the fixes, near 0 for one that does not (whose scale is no measurement)."""
        return _explained(self.sigma_m, self.extent_m)

    def follows(self, min_agreement: float) -> bool:
        """Whether the camera path follows the fixes: at least `min_agreement` of them are inliers and of their
        spread is explained (`PoseCheckParams.min_gps_agreement`), over a flight not `too_small` for its
        receiver's jitter (where a share explained by chance is no agreement: a receiver that jittered in place
        while the cameras flew "followed" 1 % of the time); only then is its scale a measurement."""
        return (self.inliers >= min_agreement * self.fixes and self.explained >= min_agreement
                and not self.too_small)

    @property
    def too_small(self) -> bool:
        """Whether the flight spans too little against its receiver's jitter for a path to show it follows the
        fixes (SMALL_FLIGHT_NOISE_RATIO). The jitter is the smaller of the fixes' own (`fix_jitter_m`) and what
        the fitted path bounds it by (`fit_noise_bound_m`): a flight of few images per line (every fifth image
        of a survey) turns at most of its fixes, which the fixes alone read as 80 m of jitter, while a path that
        fits them to a few metres bounds the receiver's noise by that (a path that does not fit leaves the
        fixes' own figure)."""
        return self.extent_m < SMALL_FLIGHT_NOISE_RATIO * min(self.fix_noise_m, self.fit_noise_bound_m)

    @property
    def fit_noise_bound_m(self) -> float:
        """What the fit says of the receiver's noise, as an upper bound: its noise about the path, never below
        GNSS_WANDER_M, inflated by the share of fixes it left out; none (inf) on fewer than MIN_FIT_INLIERS
        inliers, where a robust fit keeps the few fixes that agree and measures half the receiver's noise
        (review rev18: 5-12 fixes of a 5 m receiver on a 10 m site then judged a meaningless scale)."""
        if self.inliers < MIN_FIT_INLIERS:
            return math.inf
        return max(self.sigma_m, GNSS_WANDER_M) * math.sqrt(self.fixes / self.inliers)

    @property
    def offset_limit_m(self) -> float:
        """How far the camera centres may lie from their own fixes (median) for GPS noise to explain it:
        OFFSET_NOISES x the larger of what the fit bounds the noise by (`fit_noise_bound_m`: never below
        GNSS_WANDER_M; none on fewer than MIN_FIT_INLIERS inliers, whose fit measures a 5 m receiver's noise at
        2.3 m: then inf, and only `pose_check.warn_gps_offset_m` bounds the offset) and the fixes' own jitter."""
        jitter = self.fix_noise_m if np.isfinite(self.fix_noise_m) else 0.0
        return OFFSET_NOISES * max(self.fit_noise_bound_m, jitter)

    @property
    def scale_text(self) -> str:
        return f"{self.scale:.2f}" if 0.1 <= self.scale < 100 else f"{self.scale:.3g}"

    @property
    def unit_factor(self) -> str:
        """The length unit the scale looks like, or "" (feet, centimetres, ...; none for an arbitrary scale)."""
        for factor, name in ((3.28084, "feet"), (100.0, "centimetres"), (1000.0, "millimetres"),
                             (39.3701, "inches"), (0.001, "kilometres"), (1.09361, "yards")):
            if abs(math.log(self.scale / factor)) <= 3.0 * self.scale_sigma + 0.01:
                return name
        return ""

    def to_dict(self) -> dict:
        def num(v: float) -> float | None:
            return round(float(v), 5) if np.isfinite(v) else None

        return {"fixes": self.fixes, "inliers": self.inliers, "scale": num(self.scale),
                "scale_log_sigma": num(self.scale_sigma), "yaw_deg": num(self.yaw_deg), "sigma_m": num(self.sigma_m),
                "extent_m": num(self.extent_m), "explained": num(self.explained), "offset_m": num(self.offset_m),
                "fix_noise_m": num(self.fix_noise_m), "mirrored_explained": num(self.mirrored_explained),
                "stale_fixes": self.stale}


def compare_with_gps(centers: np.ndarray, fixes: np.ndarray, crs_fixes: np.ndarray | None = None,
                     index: np.ndarray | None = None) -> GpsComparison | None:
    """Camera `centers` (N,3, the poses' frame and unit, capture order) against the same images' GPS `fixes` (N,2,
    metres in their UTM zone, NaN where an image has none). `crs_fixes`: for georeferenced poses, the same fixes in
    the poses' CRS (the georeference is measured there). `index`: the images' places in the flight (N,; default
    0..N-1) when they are a sample of it (`fix_jitter_m`). None when there is nothing to
    compare: fewer than MIN_FIXES fresh finite fixes, a frozen receiver, or no horizontal spread."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    fixes = np.asarray(fixes, np.float64).reshape(-1, 2)
    in_crs = None if crs_fixes is None else np.asarray(crs_fixes, np.float64).reshape(-1, 2)
    places = np.arange(len(fixes)) if index is None else np.asarray(index).reshape(-1)
    ok = np.all(np.isfinite(fixes), axis=1) & np.all(np.isfinite(centers), axis=1)
    stale = np.zeros(len(fixes), bool)
    stale[ok] = stale_fixes(centers[ok, :2], fixes[ok])
    ok &= ~stale
    centers, fixes = centers[ok], fixes[ok]
    in_crs = in_crs[ok] if in_crs is not None else None
    if len(fixes) < MIN_FIXES or frozen_fix(fixes[:, 0], fixes[:, 1]):
        return None
    # the fit maps the poses onto the fixes: fixes = s R centres + t, s in GPS metres per pose unit
    dst = np.column_stack([fixes, np.zeros(len(fixes))])
    # the fit's noise is floored at GNSS_WANDER_M, the least a receiver's fixes wander by: poses that sit exactly
    # on some of their fixes (EXIF poses a refinement left at their priors) measured a noise of 1 mm, and every
    # camera the refinement moved by a metre was an "outlier" of a path that follows the fixes (nu53 M4)
    try:
        fit = robust_horizontal_similarity(np.column_stack([centers[:, :2], np.zeros(len(centers))]), dst,
                                           min_sigma_m=GNSS_WANDER_M)
        mirrored = robust_horizontal_similarity(np.column_stack([centers[:, 0], -centers[:, 1],
                                                                 np.zeros(len(centers))]), dst,
                                                min_sigma_m=GNSS_WANDER_M)
    except ValueError:  # every centre at one place: nothing to measure a length with
        return None
    inl = fit.inliers
    extent = _rms_extent(fixes[inl])
    if not (fit.transform.scale > 0 and extent > 0):
        return None
    rot = fit.transform.rotation
    offset = float("nan")
    if in_crs is not None:
        offset = float(np.median(np.linalg.norm(centers[:, :2] - in_crs, axis=1)))
    return GpsComparison(
        fixes=len(fixes), inliers=int(inl.sum()), scale=1.0 / fit.transform.scale,
        scale_sigma=max(fit.sigma_m, GNSS_WANDER_M) / extent,
        yaw_deg=math.degrees(math.atan2(rot[1, 0], rot[0, 0])), sigma_m=_measured_sigma(fit), extent_m=extent,
        offset_m=offset, fix_noise_m=fix_jitter_m(fixes, places[ok]),
        mirrored_explained=_explained(_measured_sigma(mirrored), _rms_extent(fixes[mirrored.inliers])),
        stale=int(stale.sum()))


def stale_fixes(centers: np.ndarray, fixes: np.ndarray) -> np.ndarray:
    """(K,) True for the fixes of a receiver that held its position while the cameras moved: every fix after the
    first of a run of consecutive fixes within FROZEN_SPREAD_M of it, when the run's fixes span less than
    STALE_MOVE_RATIO of what its cameras do (both relative to their whole track, so the poses' unit does not
    matter; a hovering drone's fixes and cameras are both still, and kept)."""
    c = np.asarray(centers, np.float64).reshape(-1, 2)
    f = np.asarray(fixes, np.float64).reshape(-1, 2)
    stale = np.zeros(len(f), bool)
    fix_extent, cam_extent = _rms_extent(f), _rms_extent(c)
    if not (fix_extent > 0 and cam_extent > 0):
        return stale
    start = 0
    while start < len(f):
        end = start + 1
        while end < len(f) and np.linalg.norm(f[end] - f[start]) <= FROZEN_SPREAD_M:
            end += 1
        if end - start >= 2:
            fix_span = float(np.max(np.linalg.norm(f[start:end] - f[start], axis=1)))
            cam_span = float(np.max(np.linalg.norm(c[start:end] - c[start], axis=1)))
            if fix_span / fix_extent < STALE_MOVE_RATIO * cam_span / cam_extent:
                stale[start + 1:end] = True
        start = end
    return stale


def fresh_fixes(fixes: np.ndarray) -> np.ndarray:
    """(K,) True where a fix (K,2, capture order) is a measurement of its own, False where it repeats its
    predecessor to REPEATED_FIX_M (a receiver logging slower than the camera shoots, a held fix); the first is
    fresh."""
    f = np.asarray(fixes, np.float64).reshape(-1, 2)
    return np.r_[True, np.any(np.abs(np.diff(f, axis=0)) > REPEATED_FIX_M, axis=1)] if len(f) else np.zeros(0, bool)


def fix_jitter_m(fixes: np.ndarray, index: np.ndarray | None = None) -> float:
    """A receiver's per-axis jitter from its fixes alone (K,2, capture order): the robust spread of each fix's
    departure from the line through its two neighbours, which a steady flight leaves near zero and white noise
    of sigma makes sigma sqrt(1 + a^2 + b^2) (a, b the neighbours' interpolation weights; the median ignores the
    turns). `index`: the fixes' places in the flight (K,; default 0..K-1), so images left out (no fix, stale)
    weigh their neighbours by the real spacing. A fix repeating its predecessor exactly (a bracketed exposure,
    a receiver logging slower than the camera shoots) is no second measurement and is left out: the steps
    between repeats read as jitter and a straight pass was called too small to check (review rev16). NaN for
    fewer than 3 distinct fixes."""
    f = np.asarray(fixes, np.float64).reshape(-1, 2)
    at = np.arange(len(f), dtype=np.float64) if index is None else np.asarray(index, np.float64).reshape(-1)
    fresh = fresh_fixes(f)
    f, at = f[fresh], at[fresh]
    if len(f) < 3:
        return float("nan")
    before, after = at[1:-1] - at[:-2], at[2:] - at[1:-1]
    a, b = (after / (before + after))[:, None], (before / (before + after))[:, None]  # weights of f[:-2], f[2:]
    departure = (f[1:-1] - a * f[:-2] - b * f[2:]) / np.sqrt(1.0 + a**2 + b**2)
    return float(1.4826 * np.median(np.abs(departure.ravel())))


def _measured_sigma(fit: HorizontalFit) -> float:
    """The per-axis noise of a fit's inliers about it as measured (the fit's own `sigma_m` is floored at
    GNSS_WANDER_M, the radius its inliers were chosen in): the share of the fixes' spread a path explains
    (`_explained`) is judged on what the fixes scatter by, or a true 15 m pass of a 1 m receiver "did not follow"."""
    r = fit.residuals_m[fit.inliers]
    return max(math.sqrt(float(np.sum(r**2)) / max(2 * len(r) - 4, 1)), REPEATED_FIX_M)


def _rms_extent(xy: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1)))) if len(xy) else 0.0


def _explained(sigma_m: float, extent_m: float) -> float:
    return 1.0 - 2.0 * sigma_m**2 / extent_m**2 if extent_m > 0 else float("nan")
