"""The poses against the images' own GPS fixes: the poses' unit and georeference (pure numpy).

The images fix every length of a map only up to the poses' unit: a flight's images look the same whether its
poses are in metres, feet or the arbitrary unit of an unscaled reconstruction, and so do its epipolar geometry and
its flying height in "metres" (a 100 m flight in feet is a plausible 328 m one). Most drone images carry their own
GPS fix, which measures lengths in metres independently of the poses. So the camera centres are fitted to the
fixes by a horizontal similarity (`georegistration.robust_horizontal_similarity`: least median of squares, then
least squares on the 99 % inliers of the measured noise):

- **unit**: the similarity's scale is the poses' length per GPS metre. Feet give 3.28, centimetres 100, an
  unscaled structure-from-motion model whatever its first baseline was. Its uncertainty is taken as if the GPS
  errors were fully correlated along the flight (a slowly wandering receiver): the noise over the track's
  extent, not over its square root of images, so a noisy receiver over a short flight never proves a scale.
- **georeference** (poses in a projected CRS): the median horizontal distance of the camera centres from their
  own fixes in that CRS, without any fit. GPS puts a camera within metres; another UTM zone or hemisphere puts
  it hundreds to thousands of kilometres off, another datum (NAD27, ED50) 100-200 m.
- **agreement**: how many fixes the similarity explains, and how much of their spread; a path that follows few of
  them is not this flight's (poses of another flight, names paired with the wrong images), and its "scale" is no
  measurement of a unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..georegistration import robust_horizontal_similarity
from ..gps_track import frozen_fix

MIN_FIXES = 5  # fewer images with a fix: no comparison (the fit needs a few more points than its 4 unknowns)


@dataclass(frozen=True)
class GpsComparison:
    """The camera centres against the images' GPS fixes (module doc). Lengths in metres are the GPS's."""

    fixes: int  # images with a fix that were compared
    inliers: int  # fixes the similarity explains (within the 99 % radius of the measured noise)
    scale: float  # the poses' length per GPS metre (1 for poses in metres)
    scale_sigma: float  # the standard deviation of log(scale), fully correlated GPS errors (module doc)
    yaw_deg: float  # rotation of the poses' horizontal axes from the fixes' grid (meaningful for georeferenced poses)
    sigma_m: float  # per-axis noise of the fixes about the fitted path
    extent_m: float  # root mean square distance of the fixes from their centre
    offset_m: float = float("nan")  # georeferenced poses: median distance of the centres from their own fixes

    @property
    def explained(self) -> float:
        """The share of the fixes' spread the similarity explains, 1 - residual variance / variance (2-D): near 1
        for a camera path that follows the fixes, near 0 for one that does not (whose scale is no measurement)."""
        return 1.0 - 2.0 * self.sigma_m**2 / self.extent_m**2 if self.extent_m > 0 else float("nan")

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
                "extent_m": num(self.extent_m), "explained": num(self.explained), "offset_m": num(self.offset_m)}


def compare_with_gps(centers: np.ndarray, fixes: np.ndarray, georeferenced: bool) -> GpsComparison | None:
    """Camera `centers` (N,3, the poses' frame and unit) against the same images' GPS `fixes` (N,2, metres: in the
    poses' projected CRS when `georeferenced`, else in any metric grid, e.g. their UTM zone). None when there is
    nothing to compare: fewer than MIN_FIXES finite fixes, a frozen receiver, or no horizontal spread."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    fixes = np.asarray(fixes, np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(fixes), axis=1) & np.all(np.isfinite(centers), axis=1)
    centers, fixes = centers[ok], fixes[ok]
    if len(fixes) < MIN_FIXES or frozen_fix(fixes[:, 0], fixes[:, 1]):
        return None
    # the fit maps the poses onto the fixes: fixes = s R centres + t, s in GPS metres per pose unit
    src = np.column_stack([centers[:, :2], np.zeros(len(centers))])
    dst = np.column_stack([fixes, np.zeros(len(fixes))])
    try:
        fit = robust_horizontal_similarity(src, dst)
    except ValueError:  # every centre at one place: nothing to measure a length with
        return None
    inl = fit.inliers
    extent = float(np.sqrt(np.mean(np.sum((fixes[inl] - fixes[inl].mean(axis=0)) ** 2, axis=1))))
    if not (fit.transform.scale > 0 and extent > 0):
        return None
    rot = fit.transform.rotation
    offset = float(np.median(np.linalg.norm(centers[:, :2] - fixes, axis=1))) if georeferenced else float("nan")
    return GpsComparison(
        fixes=len(fixes), inliers=int(inl.sum()), scale=1.0 / fit.transform.scale,
        scale_sigma=fit.sigma_m / extent, yaw_deg=math.degrees(math.atan2(rot[1, 0], rot[0, 0])),
        sigma_m=fit.sigma_m, extent_m=extent, offset_m=offset)
