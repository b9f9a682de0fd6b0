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

The fit's own model can be wrong too, which its noise does not show: two maps whose scales differ (a GPS-less flight
scaled from a nominal height, a COLMAP model) leave residuals that grow with the distance from the pairs' centre,
and the pairs found are only those near it (nu49: B scaled by 1.10, 85 of 274 landmarks paired, B's far landmarks 15
m off against 1.75 m predicted). So the same pairs are fitted with a scale too (`scale_check`: a yaw + translation +
scale fit against the yaw + translation one, an F test on the horizontal residuals); where the scale is significant
(p <= SCALE_FALSE_ALARM) its systematic error |s - 1| |p - c| joins the radius at every landmark, and the answer is
imprecise when that reaches the gate, so a 1-2 % disagreement of EKF frames, which moves B's landmarks less than the
gate, is no flag. The pairs a rigid answer keeps lie where the scale moved B least, and include wrong pairs beyond
that, so their ratio understates a large disagreement (B scaled by 1.10: the pairs fit 1.024, 3.2 m of a true 15 m):
flagged, at least that far off. A similarity answer (`association.transform` "similarity") fits its scale already:
the test finds none left, and `scale_sd` states the uncertainty of its scale. And heights that anti-correlate
(`height_flip`: B's placed heights fall where A's rise, one-sided p <= HEIGHT_FALSE_ALARM) are one map upside down
(a NED / ENU mix-up): horizontally right, its heights tens of metres off; imprecise too. They are compared on B's
landmarks paired with A's by horizontal position alone under the answer (the answer's own pairs passed a height
gate, which keeps only the heights a flip happens to leave in place).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from .refinement import fit_yaw_translation, mutual_nearest

CHI2_2D_95 = 5.991  # the 95 % quantile of chi-square with 2 degrees of freedom
MAX_SIGMA_GATES = 10.0  # the truncated fit's sigma is searched up to this many gates (beyond: residuals uniform)
SCALE_FALSE_ALARM = 1e-3  # p of the scale test below which a scale disagreement is measured, not noise
HEIGHT_FALSE_ALARM = 1e-3  # p of anti-correlated heights below which one map is upside down
# what an imprecise answer whose scales disagree advises; after a similarity was tried and its scale not kept
# (`workflows.match.transform_choice`), `without_similarity_advice` advises the rest alone
SIMILARITY_ADVICE = "match with --set association.transform=similarity, or check the poses' scale"


@dataclass(frozen=True)
class AnswerUncertainty:
    """The predicted placement error of an accepted alignment at B's landmarks (module doc)."""

    sigma_m: float  # per-axis horizontal noise of one pair, corrected for the gate's truncation
    yaw_sd_deg: float  # standard deviation of the fitted yaw
    predicted_median_m: float  # 95 % error radius at B's landmarks in the common area: median
    predicted_max_m: float  # and largest
    landmarks: int  # B's landmarks it was evaluated at (those in the common area; all of B when none)
    gate_m: float  # what the answer claims: its associations' gate (theta_eps)
    imprecise: bool  # predicted_max_m > gate_m (with a significant scale's error), or heights flipped
    # the pairs' own scale relative to the answer's (a similarity fit of them after the answer; 1: none) and its
    # standard deviation and the F test's p (`scale_check`); the answer's scale (`transform.scale`) and its
    # standard deviation (relative sd x scale)
    scale_ratio: float = 1.0
    scale_p: float = 1.0
    scale: float = 1.0
    scale_sd: float = 0.0
    scale_error_max_m: float = 0.0  # the significant scale's systematic error at B's landmarks (0: not significant)
    height_r: float = 0.0  # rank correlation of the pairs' heights, A against B placed (`height_flip`)
    height_flip: bool = False  # significantly negative: one map upside down
    reason: str = ""  # what makes it imprecise, in words (consumers repeat it); "" when precise

    def to_dict(self) -> dict[str, Any]:
        """match.json `answer_uncertainty`."""
        return {k: (round(v, 4) if isinstance(v, float) and k not in ("scale_p", "scale", "scale_sd", "scale_ratio")
                    else v) for k, v in asdict(self).items()}

    def warning(self) -> str:
        """The sentence `match` prints when the answer is imprecise."""
        if self.predicted_max_m <= self.gate_m:  # only the heights are wrong
            return f"imprecise answer: {self.reason}"
        return (f"imprecise answer: B's {self.landmarks} landmarks in the common area may lie up to "
                f"{self.predicted_max_m:.1f} m (median {self.predicted_median_m:.1f} m, 95 %) from where it puts "
                f"them, beyond its {self.gate_m:g} m gate ({self.reason})")


def without_similarity_advice(uncertainty: AnswerUncertainty) -> AnswerUncertainty:
    """`uncertainty` whose reason does not advise a similarity: the answer of a rigid match made after a
    similarity's answer was not kept (its scale no dome's), where that advice names the transform just rejected
    (rev51 D6)."""
    reason = uncertainty.reason.replace(SIMILARITY_ADVICE, "check the poses' scale (a similarity's answer was not "
                                        "kept: its scale is more than an SfM block's dome makes)")
    return replace(uncertainty, reason=reason)


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
    """The predicted placement error of the alignment `transform` (A_from_B, `apply`; a `Sim3`) fitted on
    `associations` ((K, 2) index pairs A, B) at B's landmarks in the common area, against its `gate_m`, with the
    scale and height checks of its pairs (module doc). None with fewer than 3 pairs or pairs without horizontal
    spread (nothing to propagate)."""
    pairs = np.asarray(associations, np.int64).reshape(-1, 2)
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    n = len(pairs)
    if n < 3:
        return None
    placed_3d = transform.apply(pb[pairs[:, 1]])
    placed_pairs = placed_3d[:, :2]
    resid = np.linalg.norm(pa[pairs[:, 0], :2] - placed_pairs, axis=1) * np.sqrt(2 * n / (2 * n - 3))
    centre = placed_pairs.mean(axis=0)
    spread = float(np.sum((placed_pairs - centre) ** 2))
    if spread <= 0.0:
        return None
    sigma = truncated_sigma(resid, gate_m)
    placed = transform.apply(pb)
    inside = common_area(placed, pa)
    lever2 = np.sum((placed[inside, :2] - centre) ** 2, axis=1)
    # the larger eigenvalue of sigma^2 / n I + sigma^2 lever^2 / spread u u^T (a similarity's scale adds the same
    # variance along p - c, so the larger eigenvalue is the same)
    radius = np.sqrt(CHI2_2D_95 * sigma**2 * (1.0 / n + lever2 / spread))
    ratio, ratio_sd, scale_p = scale_check(placed_3d, pa[pairs[:, 0]])
    bias = abs(ratio - 1.0) * np.sqrt(lever2) if scale_p <= SCALE_FALSE_ALARM else np.zeros(len(lever2))
    radius = radius + bias  # a measured scale disagreement moves B's far landmarks by this, whatever the noise
    worst = float(radius.max())
    # heights are compared on pairs made by horizontal position alone: the answer's own pairs passed a gate on
    # their heights too, which keeps only the landmarks where a flipped map's heights happen to agree (nu49: r 0.03
    # on 184 pairs of an upside-down B; r -0.99 on 274 pairs by position)
    flat, _ = mutual_nearest(pa, None, placed, None, gate_m, np.inf, 0.0)
    height_r, flip_p = height_flip(placed[flat[:, 1], 2], pa[flat[:, 0], 2])
    flipped = flip_p <= HEIGHT_FALSE_ALARM
    scale = float(getattr(transform, "scale", 1.0))
    scale_error = float(bias.max(initial=0.0))
    reasons = []
    if scale_error > 0.0 and worst > gate_m:
        reasons.append(f"the maps' scales disagree: B's pairs fit x {ratio:.4f} +- {ratio_sd:.2g} of the answer's "
                       f"scale (p {scale_p:.1g}), at least {scale_error:.1f} m at B's far landmarks; "
                       + SIMILARITY_ADVICE)
    elif worst > gate_m:
        reasons.append(f"pair noise {sigma:.1f} m, yaw +- {np.degrees(sigma / np.sqrt(spread)):.2f} deg")
    if flipped:
        reasons.append(f"B's heights anti-correlate with A's on landmarks paired by position (r {height_r:.2f}, p "
                       f"{flip_p:.1g}): one map is upside down (z down against z up: NED / ENU?), its heights wrong "
                       "by up to twice their spread")
    return AnswerUncertainty(sigma, float(np.degrees(sigma / np.sqrt(spread))), float(np.median(radius)), worst,
                             int(inside.sum()), float(gate_m), bool(worst > gate_m or flipped), ratio, scale_p,
                             scale, scale * ratio_sd, scale_error, height_r, flipped, "; ".join(reasons))


def scale_check(placed_b: np.ndarray, partners_a: np.ndarray) -> tuple[float, float, float]:
    """Do an answer's pairs show a scale the answer lacks? (ratio, its standard deviation, p): the pairs' B
    landmarks as the answer placed them ((n, 3)) fitted to their partners in A ((n, 3)) by yaw + translation and by
    yaw + translation + scale (`refinement.fit_yaw_translation`), least squares on the horizontal coordinates; the
    F(1, 2n - 4) test of the scale on the residual sums. The ratio is the second fit's scale (1: the answer's
    own), its sd the residual noise over the pairs' horizontal spread. (1, 0, 1) when there is nothing to test
    (fewer than 5 pairs, no spread)."""
    from scipy.stats import f as f_dist

    n = len(placed_b)
    if n < 5:
        return 1.0, 0.0, 1.0
    try:
        rigid = fit_yaw_translation(placed_b, partners_a)
        similar = fit_yaw_translation(placed_b, partners_a, with_scale=True)
    except ValueError:
        return 1.0, 0.0, 1.0
    rss_r = float(np.sum((rigid.apply(placed_b) - partners_a)[:, :2] ** 2))
    rss_s = float(np.sum((similar.apply(placed_b) - partners_a)[:, :2] ** 2))
    spread = float(np.sum((placed_b[:, :2] - placed_b[:, :2].mean(axis=0)) ** 2))
    dof = 2 * n - 4
    if rss_s <= 0.0 or spread <= 0.0:
        return float(similar.scale), 0.0, (0.0 if abs(similar.scale - 1.0) > 1e-9 else 1.0)
    sd = float(np.sqrt(rss_s / dof / spread))
    return float(similar.scale), sd, float(f_dist.sf(max(rss_r - rss_s, 0.0) / (rss_s / dof), 1, dof))


def refused_scale_note(points_a: np.ndarray, points_b: np.ndarray, transform: Any,
                       associations: np.ndarray) -> str | None:
    """What a refused verification's best candidate says of the maps' scales: its pairs (`associations`, (K, 2)
    index pairs A, B, as `transform`, A_from_B, placed them) tested for a scale beyond the candidate's own
    (`scale_check`); the sentence when it is significant (p <= SCALE_FALSE_ALARM), else None. Two maps whose
    poses SfM computed from small images can each be domed, scaled by a few % about their centres (BENCHMARKS.md
    "Two SfM maps of one place refused": 4 % between nu54's two flights); a rigid search at their tight derived
    gate then finds too few pairs to verify, and the refusal alone did not say that a similarity would (nu54 M14)."""
    pairs = np.asarray(associations, np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return None
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    placed = transform.apply(np.asarray(points_b, np.float64).reshape(-1, 3)[pairs[:, 1]])
    ratio, ratio_sd, scale_p = scale_check(placed, pa[pairs[:, 0]])
    if scale_p > SCALE_FALSE_ALARM:
        return None
    return (f"the best candidate's {len(pairs)} pairs fit x {ratio:.4f} +- {ratio_sd:.2g} of its scale (p "
            f"{scale_p:.1g}): the maps' scales disagree, which the search's gate does not absorb (maps from SfM on "
            f"small images can be domed, README \"Poses from a folder of photos\"); {SIMILARITY_ADVICE}")


def height_flip(placed_z: np.ndarray, partner_z: np.ndarray) -> tuple[float, float]:
    """Are two maps' heights upside down? (Spearman's rank r of B's placed heights against their partners' in A,
    the one-sided p of a negative r, by the t approximation). Same-way heights correlate positively (crowns,
    terrain) or not at all (flat, heights within their noise); a map whose z axis points down gives r near -1.
    Ranks, not the heights: a map's heights have far outliers (wrong tracks tens of metres below the ground), and
    on flat ground one or two of them decided Pearson's r (rev37: two of 153 pairs of a true answer took it from
    0.09 to -0.27, p 3e-4; one pair of 60, -0.95), while their ranks weigh as one pair each. (0, 1) with fewer
    than 5 pairs or heights without spread."""
    from scipy.stats import rankdata
    from scipy.stats import t as t_dist

    n = len(placed_z)
    if n < 5 or np.std(placed_z) <= 0.0 or np.std(partner_z) <= 0.0:
        return 0.0, 1.0
    r = float(np.clip(np.corrcoef(rankdata(placed_z), rankdata(partner_z))[0, 1], -1.0, 1.0))
    if abs(r) >= 1.0:  # exactly (anti-)correlated: no scatter to test against
        return r, (0.0 if r < 0 else 1.0)
    return r, float(t_dist.cdf(r * np.sqrt((n - 2) / (1.0 - r * r)), n - 2))
