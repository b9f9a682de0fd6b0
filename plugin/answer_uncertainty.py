"""How precisely an accepted alignment places map B: its associations' residuals propagated to B's landmarks (ours).

A verified answer claims that B's landmarks lie within the association gate (theta_eps) of their partners in A.
Its transform is fitted on a few pairs whose residuals scatter by metres; the yaw it fits is uncertain by about
sigma / (the pairs' horizontal spread), and that turns into metres at B's landmarks far from the pairs' centroid.
When the transform's own uncertainty at B's landmarks reaches the gate, the answer cannot deliver what it claims:
B's landmarks may lie a gate or more from their true partners although every associated pair is within the gate
(NAIP 2009 vs 2015 at 65 % overlap: 10 pairs with 2.5-8.1 m residuals at an 8.24 m gate; the fit's yaw is 0.68 deg
off and moves B's landmarks a median 8.8 m, at most 23 m, from the truth).

The residual scatter is measured on pairs that were chosen because they lie within the gate under this very
transform, so it is truncated at the gate: residuals that fill the gate as evenly as chance pairs would are what
noise as large as the gate (or wrong pairs) leaves, not a sign of a tight fit. The per-axis noise sigma is
therefore the maximum-likelihood sigma of an isotropic 2D Gaussian truncated at the gate (a truncated Rayleigh
law for the horizontal residual distances), with the residuals first scaled by 2n / (2n - 3) for the three
horizontal parameters the fit used. For residuals well inside the gate this is the ordinary estimate; on the
NAIP pair above it is 15 m instead of 4 m.

The horizontal placement error at a point p of B (placed in A's frame) is then delta_t + delta_yaw x (p - c), c
the pairs' centroid: covariance sigma^2 / n I + sigma^2 / sum |x_i - c|^2 |p - c|^2 u u^T (u perpendicular to
p - c), the least-squares covariance of a yaw + translation fit. Its 95 % radius (chi-square with 2 degrees of
freedom on the larger eigenvalue, conservative) at B's landmarks in the common area (placed inside A's convex
hull) is the answer's predicted error; when its largest value exceeds the gate the answer is `imprecise`.
Measured on the sweeps' accepted synthetic pairs (summer/winter, crossings, other cameras, 50-200 landmarks): at
most 0.6 x the gate; the NAIP pairs at 0 and 600 m offset: 4 x and more.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

CHI2_2D_95 = 5.991  # the 95 % quantile of chi-square with 2 degrees of freedom
MAX_SIGMA_GATES = 10.0  # the truncated fit's sigma is searched up to this many gates (beyond: residuals uniform)


@dataclass(frozen=True)
class AnswerUncertainty:
    """The predicted placement error of an accepted alignment at B's landmarks (module doc)."""

    sigma_m: float  # per-axis horizontal noise of one pair, corrected for the gate's truncation
    yaw_sd_deg: float  # standard deviation of the fitted yaw
    predicted_median_m: float  # 95 % error radius at B's landmarks in the common area: median
    predicted_max_m: float  # and largest
    landmarks: int  # B's landmarks it was evaluated at (those in the common area; all of B when none)
    gate_m: float  # what the answer claims: its associations' gate (theta_eps)
    imprecise: bool  # predicted_max_m > gate_m: the answer cannot place B within its own gate

    def to_dict(self) -> dict[str, Any]:
        """match.json `verification.uncertainty`."""
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    def warning(self) -> str:
        """The sentence `match` prints when the answer is imprecise."""
        return (f"imprecise answer: B's {self.landmarks} landmarks in the common area may lie up to "
                f"{self.predicted_max_m:.1f} m (median {self.predicted_median_m:.1f} m, 95 %) from where it puts "
                f"them, beyond its {self.gate_m:g} m gate (pair noise {self.sigma_m:.1f} m, yaw +- "
                f"{self.yaw_sd_deg:.2f} deg)")


def truncated_sigma(distances: np.ndarray, gate_m: float) -> float:
    """Per-axis sigma of an isotropic 2D Gaussian whose horizontal residual distances were kept only within
    `gate_m` (maximum likelihood of the truncated Rayleigh law; module doc). At most MAX_SIGMA_GATES gates."""
    from scipy.optimize import minimize_scalar

    r2 = np.asarray(distances, np.float64) ** 2
    n = len(r2)
    plain = float(np.sqrt(max(r2.mean() / 2.0, 1e-12)))
    if gate_m <= 0 or not np.isfinite(gate_m):
        return plain
    upper = MAX_SIGMA_GATES * gate_m
    if plain >= upper:
        return upper

    def nll(log_s: float) -> float:
        s2 = np.exp(2.0 * log_s)
        return float(n * np.log(s2) + r2.sum() / (2.0 * s2) + n * np.log(-np.expm1(-gate_m**2 / (2.0 * s2))))

    res = minimize_scalar(nll, bounds=(np.log(plain) - 1.0, np.log(upper)), method="bounded",
                          options={"xatol": 1e-4})
    return float(max(np.exp(res.x), plain))


def common_area(placed_b: np.ndarray, points_a: np.ndarray) -> np.ndarray:
    """Which of B's placed landmarks lie within A's horizontal convex hull (all when A spans no area)."""
    from scipy.spatial import Delaunay, QhullError

    pa = np.asarray(points_a, np.float64).reshape(-1, 3)[:, :2]
    try:
        inside = Delaunay(pa).find_simplex(np.asarray(placed_b, np.float64)[:, :2]) >= 0
    except (QhullError, ValueError):
        return np.ones(len(placed_b), bool)
    return inside if inside.any() else np.ones(len(placed_b), bool)


def answer_uncertainty(points_a: np.ndarray, points_b: np.ndarray, transform: Any, associations: np.ndarray,
                       gate_m: float) -> AnswerUncertainty | None:
    """The predicted placement error of the alignment `transform` (A_from_B, `apply`) fitted on `associations`
    ((K, 2) index pairs A, B) at B's landmarks in the common area, against its `gate_m` (module doc). None with
    fewer than 3 pairs or pairs without horizontal spread (nothing to propagate)."""
    pairs = np.asarray(associations, np.int64).reshape(-1, 2)
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    n = len(pairs)
    if n < 3:
        return None
    placed_pairs = transform.apply(pb[pairs[:, 1]])[:, :2]
    resid = np.linalg.norm(pa[pairs[:, 0], :2] - placed_pairs, axis=1) * np.sqrt(2 * n / (2 * n - 3))
    centre = placed_pairs.mean(axis=0)
    spread = float(np.sum((placed_pairs - centre) ** 2))
    if spread <= 0.0:
        return None
    sigma = truncated_sigma(resid, gate_m)
    placed = transform.apply(pb)
    inside = common_area(placed, pa)
    lever2 = np.sum((placed[inside, :2] - centre) ** 2, axis=1)
    # the larger eigenvalue of sigma^2 / n I + sigma^2 lever^2 / spread u u^T
    radius = np.sqrt(CHI2_2D_95 * sigma**2 * (1.0 / n + lever2 / spread))
    worst = float(radius.max())
    return AnswerUncertainty(sigma, float(np.degrees(sigma / np.sqrt(spread))), float(np.median(radius)), worst,
                             int(inside.sum()), float(gate_m), bool(worst > gate_m))
