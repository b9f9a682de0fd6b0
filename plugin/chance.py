"""The chance model of the verification: what support alignments of two maps reach by chance alone.

The winner of a search is the best of very many distinct alignments, so it must be improbable as the best of that
many chance alignments, not only beat one rival (maps of different worlds were verified by the ratio test alone).
B is refined from random placements over A exactly like the winner (`chance_refinements`); their supports are
counts whose expected value depends on how much of A lies under B where it was placed (`chance_opportunity`), and
`chance_test` extrapolates their tail to the best of N_eff (`effective_trials`) chance alignments. Pure numpy +
scipy; a part of `plugin.verification`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .geometry import hull_area
from .multisession import Sim3
from .refinement import Alignment, pairing_tree, refine_alignment, yaw_matrix


def transforms_agree(t1: Sim3, t2: Sim3, points: np.ndarray, tolerance_m: float) -> bool:
    """Whether two transforms put every one of `points` within `tolerance_m` of each other (none: no)."""
    return bool(len(points) and np.max(np.linalg.norm(t1.apply(points) - t2.apply(points), axis=1)) <= tolerance_m)


@dataclass(frozen=True)
class ChanceModel:
    """How often chance alone reaches the winner's support (`chance_test`).

    Two maps of different places still pair up: at 300 landmarks in 220 m x 240 m and a 2.9 m gate, a refined
    alignment of two unrelated maps has 1-13 mutual nearest neighbours on average (BENCHMARKS.md, "Negative
    pairs"), and the search offers the best of a very large number of distinct alignments. So the winner's
    support is compared with the MAXIMUM chance support over that many trials (the look-elsewhere effect), not
    with one rival."""

    samples: int  # chance refinements measured (random starts that did not converge to the winner)
    mean: float  # their mean support
    variance: float  # and its variance (> mean: overdispersed; else Poisson)
    trials: float  # N_eff: effectively independent alignments the search could have found
    tail: float  # q: probability that one chance alignment reaches the winner's support
    p_value: float  # 1 - (1 - q)^N_eff: probability that the best of N_eff chance alignments reaches it
    # phi: the chance support at a placement of mean mu has variance (1 + phi) mu once its opportunity is
    # accounted for (a negative binomial of size mu / phi; 0: Poisson); NaN: no opportunities measured (the
    # unconditioned model, whose spread is in `variance`)
    overdispersion: float = float("nan")
    # N_s and the largest q_c of `row_placements.with_rows`: row-on-row placements of two maps' rows of landmarks,
    # counted in the best-of-N_eff each with its own tail (0, 0: no row pair; p_value is then the uniform
    # placements' alone)
    row_placements: float = 0.0
    row_tail: float = 0.0
    # True: more row-on-row cells than `row_placements.ROW_WORK_BUDGET` lets be counted; those beyond it were given
    # an upper bound of their tail (p only rises)
    row_bounded: bool = False

    def to_dict(self) -> dict[str, float]:
        return {"samples": self.samples, "mean": self.mean, "variance": self.variance, "trials": self.trials,
                "tail": self.tail, "p_value": self.p_value,
                "overdispersion": None if np.isnan(self.overdispersion) else self.overdispersion,
                "row_placements": self.row_placements, "row_tail": self.row_tail, "row_bounded": self.row_bounded}


def converged_to_winner(winner: Sim3, probe: np.ndarray, gate_m: float, winner_pairs: np.ndarray | None,
                        aligned: Alignment) -> bool:
    """Whether a refinement found the winner again rather than another alignment: its transform puts the winner's
    supporting B landmarks `probe` within 2 gates of where the winner puts them, or (with `winner_pairs`, the
    winner's pairs after its final rigid fit) most of its own pairs are the winner's. The latter is the same
    alignment fitted with yaw only on another part of two maps tilted against each other: 1 deg between two
    frames is 17 m of height 1 km away, so 4-DOF fits from different window hypotheses each hold a band of the
    map and disagree by more than 2 gates, though their pairs are those of one rigid alignment."""
    if transforms_agree(winner, aligned.transform, probe, 2.0 * gate_m):
        return True
    mine = np.asarray(aligned.associations, np.int64).reshape(-1, 2)
    return bool(2 * shared_with_winner(mine, winner_pairs) > len(mine))


def chance_pairs(points_a: np.ndarray, points_b: np.ndarray, winner: Sim3, pairs: np.ndarray, gate_m: float) -> int:
    """How many of an alignment's `pairs` the winner does not explain: pairs whose landmarks the winner puts more
    than 2 gates apart (the tolerance of `converged_to_winner`)."""
    ij = np.asarray(pairs, np.int64).reshape(-1, 2)
    if not len(ij):
        return 0
    gap = np.linalg.norm(points_a[ij[:, 0]] - winner.apply(points_b[ij[:, 1]]), axis=1)
    return int(np.sum(gap > 2.0 * gate_m))


def shared_with_winner(pairs: np.ndarray, winner_pairs: np.ndarray | None) -> int:
    """How many of `pairs` ((K, 2) landmark indices A, B) are pairs of the winner (`winner_pairs`; None: 0)."""
    mine = np.asarray(pairs, np.int64).reshape(-1, 2)
    if winner_pairs is None or not len(mine) or not len(winner_pairs):
        return 0
    base = int(max(mine[:, 1].max(), winner_pairs[:, 1].max())) + 1
    return int(np.isin(mine[:, 0] * base + mine[:, 1], winner_pairs[:, 0] * base + winner_pairs[:, 1]).sum())


CHANCE_SEED = 0  # the random placements of the chance model (fixed: the same maps give the same decision)


CHANCE_BATCH = 16  # chance placements refined per step of `sequential_chance`
# it stops early when p_value <= false_alarm x CHANCE_MARGIN or p_value >= CHANCE_CLEARLY_CHANCE, the interval with
# it. 1e-3 while the accepting stop's interval could not show a spread its samples lacked (it needed a margin of
# decades); with the dispersion the samples cannot exclude (`dispersion_bound`) a tenth is as safe on constructed
# near-threshold chance (0 of 210 accepted what their 512 samples refuse; 1e-3 without the bound: 4), at about the
# old cost on the clear pairs (1e-3 with the bound: 3-8x; BENCHMARKS.md, "the accepting early stop")
CHANCE_MARGIN = 1e-1
CHANCE_CLEARLY_CHANCE = 0.5


def chance_placements(points_a: np.ndarray, points_b: np.ndarray, starts: int, prior_m: float = 0.0) -> list[Sim3]:
    """`starts` random placements of B over A (a_from_b), deterministic (CHANCE_SEED). Without a prior a
    uniform yaw and B's centroid on a random landmark of A (over A's footprint, where the landmarks are, so the
    density chance works with is A's own); with `prior_m` (both maps in one frame, the search's putative
    associations within that radius) B moved by a uniform offset in the disc of that radius and turned by at
    most the angle that moves B's landmarks that far: the alignments the prior lets the search find (B's
    centroid at A's mean height in both cases)."""
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    if not len(pa) or not len(pb) or starts <= 0:
        return []
    rng = np.random.default_rng(CHANCE_SEED)
    centre_b = pb.mean(axis=0)
    radius_b = _horizontal_radius(pb)
    out = []
    for _ in range(starts):
        if prior_m > 0:
            yaw = rng.uniform(-1.0, 1.0) * min(np.pi, prior_m / radius_b)
            r, ang = prior_m * np.sqrt(rng.uniform()), rng.uniform(0.0, 2.0 * np.pi)
            # the prior is horizontal, and so is the search (it compares height differences, never heights):
            # B's heights are put at A's as without a prior, since two georeferences' altitudes may differ by
            # hundreds of metres (ellipsoid, AMSL, take-off heights) and a placement that far from A's heights
            # pairs with nothing (it measured no chance at all; the thirteenth sweep's maps 418 m apart: p 2e-24)
            target = np.array([centre_b[0] + r * np.cos(ang), centre_b[1] + r * np.sin(ang), pa[:, 2].mean()])
        else:
            yaw = rng.uniform(0.0, 2.0 * np.pi)
            target = np.array([*pa[rng.integers(len(pa)), :2], pa[:, 2].mean()])
        turn = yaw_matrix(yaw)
        out.append(Sim3(turn, target - turn @ centre_b))
    return out


def median_horizontal_move(transform: Sim3 | Any, points: np.ndarray) -> float:
    """How far `transform` (a Sim3, or any transform with `apply`) moves `points` horizontally, at the median (0 for
    no points)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    return float(np.median(np.linalg.norm((transform.apply(pts) - pts)[:, :2], axis=1))) if len(pts) else 0.0


def within_prior(transform: Sim3, points_b: np.ndarray, prior_m: float, gate_m: float) -> bool:
    """Whether an alignment (a_from_b) lies within a position prior of `prior_m`: it moves the B landmarks it pairs
    (`points_b`: the winner's supporting ones) by at most prior_m + one gate horizontally, at the median (heights are
    free: the prior and the search are horizontal; the gate: a refinement moves its start by about that much). A
    search with a prior still finds alignments beyond it (a turn and a shift that cancel near their fixed point
    leave the landmarks there within it, and the refinement then pairs the rest); the chance test with the prior
    does not measure those, so they are not answers of it. Judged on the pairs, not on B's centroid: a flight
    matched into a season map kilometres across turns the whole map's centroid far while its pairs stay within a
    few metres (bench_match's season case was refused so). True without a prior."""
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    if prior_m <= 0 or not len(pb):
        return True
    return median_horizontal_move(transform, pb) <= prior_m + gate_m


def chance_refinements(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                       sizes_b: np.ndarray | None, winner: Sim3, probe: np.ndarray, gate_m: float,
                       max_size_difference: float, placements: Sequence[Sim3], dof: int = 4,
                       z_weight: float = 0.5, winner_pairs: np.ndarray | None = None,
                       tree_a: Any = None, tree_a_xy: Any = None,
                       coarse_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Chance alignments of these two maps: B refined from each placement like the winner (`refine_alignment`:
    the same gate, size gate and fit; `coarse_factor` as there, 1 for the chance model's samples:
    `verification.verify_alignments` says why); the refinements that converge to the winner
    (`converged_to_winner`) are no chance and are left out. Returns their supports, counting only the pairs chance
    gave them (`chance_pairs`), and their opportunities (`chance_opportunity`; zeros without `tree_a_xy`).
    `tree_a`: `refinement.pairing_tree` of A, if built; `tree_a_xy`: `horizontal_tree` of A."""
    supports, opportunities = [], []
    for start in placements:
        aligned = refine_alignment(points_a, sizes_a, points_b, sizes_b, start, gate_m, max_size_difference,
                                   dof=dof, z_weight=z_weight, tree_a=tree_a, coarse_factor=coarse_factor)
        if converged_to_winner(winner, probe, gate_m, winner_pairs, aligned):
            continue
        # only the pairs chance gave it: a refinement caught on the edge of the winner's basin (turned a few
        # degrees about the winner's pairs) holds some of the winner's own pairs, no evidence of what chance
        # reaches elsewhere
        supports.append(chance_pairs(points_a, points_b, winner, aligned.associations, gate_m))
        opportunities.append(0.0 if tree_a_xy is None else
                             chance_opportunity(tree_a_xy, aligned.transform.apply(points_b), gate_m))
    return np.asarray(supports, np.int64), np.asarray(opportunities, np.float64)


def chance_supports(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                    sizes_b: np.ndarray | None, winner: Sim3, probe: np.ndarray, gate_m: float,
                    max_size_difference: float, placements: Sequence[Sim3], dof: int = 4,
                    z_weight: float = 0.5, winner_pairs: np.ndarray | None = None, tree_a: Any = None,
                    coarse_factor: float = 1.0) -> np.ndarray:
    """The supports of `chance_refinements` (for rivals, which need no opportunity)."""
    return chance_refinements(points_a, sizes_a, points_b, sizes_b, winner, probe, gate_m, max_size_difference,
                              placements, dof, z_weight, winner_pairs, tree_a, coarse_factor=coarse_factor)[0]


OPPORTUNITY_GATES = (2.0, 6.0)  # A's density around a placed B landmark: counted in this annulus (in gates)


def horizontal_tree(points: np.ndarray) -> Any:
    """The KD-tree of a map's horizontal positions (`chance_opportunity`)."""
    from scipy.spatial import cKDTree

    return cKDTree(np.asarray(points, np.float64).reshape(-1, 3)[:, :2])


def chance_opportunity(tree_a_xy: Any, placed_b: np.ndarray, gate_m: float) -> float:
    """How many chance partners B placed so can expect: the sum over B's landmarks of min(1, pi gate^2 rho), rho
    the density of A's landmarks around it. rho is counted in the annulus OPPORTUNITY_GATES (beyond the gate, so
    that the winner's own partners do not raise the winner's opportunity: the same measure for the winner and for
    chance). A placement with half of B off A, or over a sparse part of it, has a fraction of the opportunity of
    one over A's dense core."""
    return float(np.sum(landmark_opportunities(tree_a_xy, placed_b, gate_m)))


def landmark_opportunities(tree_a_xy: Any, placed_b: np.ndarray, gate_m: float) -> np.ndarray:
    """Each placed B landmark's term of `chance_opportunity`: min(1, pi gate^2 rho), rho A's density in the
    annulus OPPORTUNITY_GATES around it."""
    inner, outer = (g * gate_m for g in OPPORTUNITY_GATES)
    xy = np.asarray(placed_b, np.float64).reshape(-1, 3)[:, :2]
    if not len(xy):
        return np.zeros(0)
    counts = (tree_a_xy.query_ball_point(xy, outer, return_length=True)
              - tree_a_xy.query_ball_point(xy, inner, return_length=True))
    density = counts / (np.pi * (outer**2 - inner**2))
    return np.minimum(1.0, np.pi * gate_m**2 * density)


def sequential_chance(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                      sizes_b: np.ndarray | None, winner: Sim3, probe: np.ndarray, support: int, gate_m: float,
                      max_size_difference: float, starts: int, false_alarm: float, prior_m: float = 0.0,
                      dof: int = 4, z_weight: float = 0.5,
                      winner_pairs: np.ndarray | None = None, tree_a: Any = None,
                      a_is_placed: bool | None = None) -> tuple[ChanceModel, np.ndarray, np.ndarray]:
    """`chance_test` of the winner's support on up to `starts` chance placements, refined CHANCE_BATCH at a time:
    it stops once the answer cannot be in doubt (p_value and its interval <= false_alarm x CHANCE_MARGIN: a true
    alignment well above chance, as every dense map pair; or >= CHANCE_CLEARLY_CHANCE), which keeps the cost of a
    clear case at one to a few batches. The placements are fixed in advance, so the result is deterministic.
    Returns the model, the chance supports and their opportunities (`chance_opportunity`: another support is
    judged against the same placements with `chance_test`). `tree_a`: as `chance_refinements`. The accepting stop
    assumes the dispersion at its upper confidence bound (`dispersion_bound`), which shrinks as samples accrue, so
    a first batch whose spread happens to be small cannot end the test on a tail it does not support.
    The test is one of the pair, not of the order its maps are given in: the map of the smaller footprint is the
    one placed (`placed_map_is_a`), so `match A B` and `match B A` decide alike. `a_is_placed`: that answer when
    the caller has it (`verification.winner_chance` decides the roles once for the whole test); None: decided here."""
    if placed_map_is_a(points_a, points_b) if a_is_placed is None else a_is_placed:
        points_a, sizes_a, points_b, sizes_b, winner, probe, winner_pairs = placed_over_b(
            points_a, sizes_a, points_b, sizes_b, winner, probe, winner_pairs)
        tree_a = pairing_tree(points_a, z_weight)
    placements = chance_placements(points_a, points_b, starts, prior_m)
    trials = effective_trials(points_a, points_b, gate_m, prior_m, a_is_placed=False)  # B is the placed map now
    tree_a_xy = horizontal_tree(points_a)
    samples, opportunities = np.zeros(0, np.int64), np.zeros(0, np.float64)
    chance = chance_test(samples, support, trials, opportunities)
    for k in range(0, len(placements), CHANCE_BATCH):
        more, more_o = chance_refinements(points_a, sizes_a, points_b, sizes_b, winner, probe, gate_m,
                                          max_size_difference, placements[k:k + CHANCE_BATCH], dof, z_weight,
                                          winner_pairs, tree_a, tree_a_xy)
        samples, opportunities = np.concatenate([samples, more]), np.concatenate([opportunities, more_o])
        chance = chance_test(samples, support, trials, opportunities)
        if chance.p_value >= CHANCE_CLEARLY_CHANCE:
            # past the refusing stop; stop only if the whole interval is (a tail extrapolated from 16-64 samples
            # swings by decades: 1.8e-9 after 16 placements, 2.4e-4 after 256 on one pair)
            if chance_interval(samples, support, trials, opportunities)[0] >= CHANCE_CLEARLY_CHANCE:
                break
        elif chance.p_value <= false_alarm * CHANCE_MARGIN:
            # past the accepting stop: so must the interval be under the largest dispersion the samples so far do
            # not exclude (`dispersion_bound`). A bootstrap cannot show a spread its samples lack: a first batch
            # that happened to look Poisson ended the test at p 8.8e-13 where 512 samples give 2e-4 to 5e-3
            # (w229's crossing flight, chance seed 4; BENCHMARKS.md, "the accepting early stop")
            high = chance_interval(samples, support, trials, opportunities,
                                   dispersion_bound(samples, opportunities))[1]
            if high <= false_alarm * CHANCE_MARGIN:
                break
    return chance, samples, opportunities


def placed_map_is_a(points_a: np.ndarray, points_b: np.ndarray) -> bool:
    """Whether the chance model should place A over B rather than B over A: A's footprint (the convex hull of its
    landmarks' horizontal positions) is the smaller one (ties: A has fewer landmarks). The smaller map moved over
    the larger is what N_eff counts (`effective_trials`: translations over the fixed map's footprint, turns at
    the moved map's radius); the other way round the placements where a large moved map covers a small fixed one
    everywhere are left out, and the samples fall where the moved map hangs over the fixed one's edges. Measured
    on the suite's crossing pair (297 and 85 landmarks), the two orders gave p 0.003 and 1e-5."""
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    area_a, area_b = hull_area(pa[:, :2]), hull_area(pb[:, :2])
    return bool((area_a, len(pa)) < (area_b, len(pb)))


def placed_over_b(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                  sizes_b: np.ndarray | None, winner: Sim3, probe: np.ndarray | None = None,
                  winner_pairs: np.ndarray | None = None) -> tuple:
    """The chance model's arguments with the roles swapped, A the map placed over B (`placed_map_is_a`): the
    maps, the winner inverted, its probe and its pairs (B, A; None where not given). The winner maps B's supporting
    landmarks `probe` onto their A partners, so those partners are where it puts them, and a refinement that brings
    them back within 2 gates of `probe` found the winner again (`converged_to_winner`), as from the other side."""
    pairs = None if winner_pairs is None else np.ascontiguousarray(np.asarray(winner_pairs)[:, ::-1])
    moved = None if probe is None else winner.apply(probe)
    return points_b, sizes_b, points_a, sizes_a, winner.inverse(), moved, pairs


CHANCE_RESAMPLES = 100  # bootstrap resamples of `chance_interval`
CHANCE_INTERVAL = 0.9  # its two-sided level


def chance_interval(samples: np.ndarray, support: int, trials: float, opportunities: np.ndarray | None,
                    min_dispersion: float = 0.0) -> tuple[float, float]:
    """A bootstrap interval (level CHANCE_INTERVAL, CHANCE_RESAMPLES resamples of the (support, opportunity)
    pairs, seeded: deterministic) of `chance_test`'s p_value: how far it could move with other placements of the
    same kind. The early stops of `sequential_chance` decide on it, so a few dozen samples whose mean happens to
    be small cannot end the test on a tail they do not support. `min_dispersion`: each resample's phi at least
    this (`_opportunity_tails`; the accepting stop passes `dispersion_bound`, since resamples cannot show a spread
    the samples lack). Without opportunities: the point estimate."""
    x = np.asarray(samples, np.float64).reshape(-1)
    o = None if opportunities is None else np.asarray(opportunities, np.float64).reshape(-1)
    rows = np.zeros((0, len(x)), np.int64)
    if o is not None and len(o) == len(x) and len(x) >= 2 and o.sum() > 0:
        rows = np.random.default_rng(CHANCE_SEED).integers(0, len(x), (CHANCE_RESAMPLES, len(x)))
        # a resample of placements that all had no opportunity measures no rate (its beta 1 / 0): left out, as
        # the point estimate leaves out such a sample set (rev27: one NaN row made the whole interval NaN)
        rows = rows[o[rows].sum(axis=1) > 0]
    if not len(rows):
        p = chance_test(samples, support, trials, opportunities).p_value
        return p, p
    tails, _ = _opportunity_tails(x[rows], o[rows], support, min_dispersion)
    p = _best_of(tails, trials)
    low, high = np.quantile(p, [(1.0 - CHANCE_INTERVAL) / 2.0, (1.0 + CHANCE_INTERVAL) / 2.0])
    return float(low), float(high)


def _opportunity_tails(x: np.ndarray, o: np.ndarray, support: int, min_dispersion: float = 0.0) -> tuple:
    """q of `chance_test` with opportunities for each row of x (supports) and o (opportunities), and each row's
    overdispersion phi: at each placement a negative binomial with mean mu_i = beta o_i (`_placement_means`) and
    variance (1 + phi) mu_i, mixed over the row's placements (Poisson where phi is 0; phi at least
    `min_dispersion`). Rows with no opportunity are never passed.

    The variance grows in proportion to the mean, not with its square (the NB1 form, size mu_i / phi): chance
    pairs come in small clusters (a refinement that pairs one landmark pulls its neighbours in), a compound Poisson
    whose clusters are Poisson in the opportunity. Binned by opportunity, the chance supports of the seasons
    benchmark's sparse winter maps keep var / mean at 1.1-1.3 from means of 1 to 4 (the dense pairs' are
    Poisson); the form that fitted one 1/k for every mean (variance mu + mu^2 / k) read that spread of the small
    means as a gamma tail under the large ones, and over 4,096 placements of a crossing flight expected 2-5x the
    supports >= 10-15 observed (BENCHMARKS.md, "Issue 16: the chance test's tail"). phi is the moment estimate
    sum((x - mu)^2 - mu) / sum(mu): each placement weighted by its mean, so neither a few placements of large mean
    (the 1/k estimate divided by sum(mu^2)) nor one of near-zero opportunity that happened to pair (a likelihood
    would chase it) sets it."""
    from scipy import stats

    mu = _placement_means(x, o)
    extra = np.sum((x - mu) ** 2 - mu, axis=1)
    overdispersion = np.maximum(min_dispersion, extra / np.sum(mu, axis=1))
    # below MIN_OVERDISPERSION: Poisson. A phi left by rounding (1e-16 where the moments agree exactly) made
    # 1 / (1 + phi) exactly 1, and the negative binomial's tail 0: p 0, any support accepted (rev27)
    overdispersion = np.where(overdispersion > MIN_OVERDISPERSION, overdispersion, 0.0)
    phi = np.where(overdispersion > 0, overdispersion, 1.0)[:, None]
    tails = np.where(overdispersion > 0, np.mean(stats.nbinom.sf(support - 1, mu / phi, 1.0 / (1.0 + phi)), axis=1),
                     np.mean(stats.poisson.sf(support - 1, mu), axis=1))
    return tails, overdispersion


def chance_rate(samples: np.ndarray, opportunities: np.ndarray) -> Any:
    """beta: chance pairs per unit of opportunity (`chance_opportunity`), sum x / sum o over the last axis with one
    pseudo-sample of 1 at the mean opportunity (`chance_test` says why); NaN when no opportunity was measured."""
    x = np.asarray(samples, np.float64)
    o = np.asarray(opportunities, np.float64)
    if not x.shape[-1]:
        return float("nan")
    total = o.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        beta = (x.sum(axis=-1) + 1.0) / (total + total / x.shape[-1])
    return np.where(total > 0, beta, np.nan) if np.ndim(beta) else (float(beta) if total > 0 else float("nan"))


MIN_OVERDISPERSION = 1e-6  # phi of `_opportunity_tails` below which the chance supports are taken as Poisson


def _placement_means(x: np.ndarray, o: np.ndarray) -> np.ndarray:
    """mu_i = beta o_i for each row of x (supports) and o (opportunities): beta the rate per unit of opportunity
    (`chance_rate`)."""
    return np.maximum(np.asarray(chance_rate(x, o))[:, None] * o, 1e-9)


DISPERSION_LEVEL = 0.95  # one-sided level of `dispersion_bound`


def dispersion_bound(samples: np.ndarray, opportunities: np.ndarray | None) -> float:
    """The largest NB1 dispersion phi (`_opportunity_tails`) that the chance samples so far do not exclude: an
    upper confidence bound of level DISPERSION_LEVEL. The moment statistic S = sum((x - mu)^2) / sum(mu) estimates
    1 + phi; it is taken as (1 + phi) chi2_nu / nu, nu its effective degrees of freedom (Satterthwaite: 2 (sum
    k2)^2 / sum(k4 + 2 k2^2) with the negative binomial's cumulants k2, k4 at the estimate, one less for beta), so
    1 + phi <= S nu / chi2_nu(1 - level). The bound shrinks as samples accrue: 16 Poisson-looking samples of mean
    ~2 leave phi ~1.3 possible, 512 leave ~0.13; on simulated NB1 samples it lies below the true phi in 2-5 % of
    draws at 16-512 samples. 0 without opportunities or with fewer than 2 samples (`chance_interval` then decides
    on the point estimate)."""
    from scipy import stats

    x = np.asarray(samples, np.float64).reshape(1, -1)
    o = None if opportunities is None else np.asarray(opportunities, np.float64).reshape(1, -1)
    if o is None or o.shape != x.shape or x.shape[1] < 2 or o.sum() <= 0:
        return 0.0
    mu = _placement_means(x, o)[0]
    s = float(np.sum((x[0] - mu) ** 2) / np.sum(mu))
    phi = max(0.0, s - 1.0)
    k2 = (1.0 + phi) * mu
    k4 = (1.0 + phi) * (1.0 + 6.0 * phi + 6.0 * phi**2) * mu
    nu = max(0.5, 2.0 * np.sum(k2) ** 2 / np.sum(k4 + 2.0 * k2**2) - 1.0)
    return max(0.0, s * nu / float(stats.chi2.ppf(1.0 - DISPERSION_LEVEL, nu)) - 1.0)


def effective_trials(points_a: np.ndarray, points_b: np.ndarray, gate_m: float, prior_m: float = 0.0,
                     a_is_placed: bool | None = None) -> float:
    """N_eff: how many effectively independent alignments the search chooses its winner from.

    Two placements of B share no chance pair once B moved by more than a gate diameter (2 gate_m: every
    landmark's gate disc has left its old one), or turned by more than 2 gate_m / R_B (R_B: the RMS horizontal
    distance of B's landmarks from their centroid, so a typical landmark moved that far). So the translations
    over A's footprint (its horizontal bounding box; with a position prior the disc of radius `prior_m` that the
    chance samples cover) hold area / (2 gate_m)^2 independent cells, and the yaws (a full turn; with a prior at most
    +-prior_m / R_B) hold yaw range / (2 gate_m / R_B) of them. A 220 m x 240 m map at a 2.9 m gate and R_B
    ~90 m: ~1,600 x ~100 = 1.6e5. (Counting the search's 48 yaw slices instead would ignore that within one
    slice a turn of 7.5 degrees moves far landmarks by ten gates.) A count of the pair, whatever the order: the
    map of the smaller footprint is the one placed (`placed_map_is_a`; `a_is_placed`: that answer when the caller
    has it, None: decided here)."""
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    if placed_map_is_a(pa, pb) if a_is_placed is None else a_is_placed:
        pa, pb = pb, pa
    cell = 2.0 * gate_m
    span = np.ptp(pa[:, :2], axis=0) if len(pa) else np.zeros(2)
    area = float(span[0] * span[1])
    radius_b = _horizontal_radius(pb)
    yaw_range = 2.0 * np.pi
    if prior_m > 0:
        # the disc the samples cover (`chance_placements`: B moved anywhere within the prior), also where it
        # reaches past A's footprint: q is their mean over the whole disc, placements off A included, so N_eff
        # counts the same measure (min(box, disc) undercounted small maps' trials by up to disc / box: rev32 F3)
        area = np.pi * prior_m**2
        yaw_range = min(yaw_range, 2.0 * prior_m / radius_b)
    return float(max(1.0, area / cell**2) * max(1.0, yaw_range * radius_b / cell))


def chance_test(samples: np.ndarray, support: int, trials: float,
                opportunities: np.ndarray | None = None) -> ChanceModel:
    """The probability that the best of `trials` chance alignments reaches `support`.

    The chance supports (`chance_refinements`) are counts, overdispersed because placements differ in how much of
    B lies over A and how dense A is there. With each sample's `opportunity` (`chance_opportunity`) that part is
    measured, not guessed: sample i is negative binomial with mean beta o_i (beta = sum x / sum o, the Poisson
    estimate) and variance (1 + phi) times that, phi what the moments of the rest give (none left: Poisson;
    `_opportunity_tails`), and one chance alignment reaches the support with q = the mean over the samples of
    P(X_i >= support), the mixture over the placements chance actually makes. Without opportunities (or none
    measured) the whole spread is fitted by its moments as one negative binomial (a gamma mixture of Poissons),
    whose unbounded gamma tail overstates what a
    bounded overlap can reach: across seasons it refused true pairs (world 7: support 46 against a chance maximum
    of 31 in 512 placements, p 0.20; with opportunities 1e-7), because a few placements over A's dense core
    inflate the variance. The best of N_eff independent trials reaches it with 1 - (1 - q)^N_eff. The tail is
    extrapolated from a few dozen samples, so the mean carries one pseudo-sample of 1 (at the mean opportunity:
    a map pair whose every random start reached the winner measured no chance at all; that is not chance 0) and
    the variance is at least the mean."""
    from scipy import stats

    x = np.asarray(samples, np.float64).reshape(-1)
    mean = float((x.sum() + 1.0) / (len(x) + 1))
    var = float(np.var(x, ddof=1)) if len(x) > 1 else mean
    var = max(var, mean)
    o = None if opportunities is None else np.asarray(opportunities, np.float64).reshape(-1)
    overdispersion = float("nan")
    if o is not None and len(o) == len(x) and len(x) and o.sum() > 0:
        tails, dispersions = _opportunity_tails(x[None], o[None], support)
        tail, overdispersion = float(tails[0]), float(dispersions[0])
    elif var > mean * (1.0 + 1e-9):
        tail = float(stats.nbinom.sf(support - 1, mean**2 / (var - mean), mean / var))
    else:
        tail = float(stats.poisson.sf(support - 1, mean))
    p_value = float(_best_of(tail, trials))
    return ChanceModel(int(len(x)), mean, var, float(trials), tail, p_value, overdispersion)


def _best_of(tail: float | np.ndarray, trials: float) -> float | np.ndarray:
    """1 - (1 - q)^N_eff: the probability that the best of `trials` chance alignments, each reaching the support
    with probability `tail`, reaches it (q kept below 1 so that the log stays finite)."""
    return -np.expm1(trials * np.log1p(-np.minimum(tail, 1.0 - 1e-16)))


def _horizontal_radius(points: np.ndarray) -> float:
    """RMS horizontal distance of the points from their centroid (at least 1 m)."""
    if not len(points):
        return 1.0
    d = points[:, :2] - points[:, :2].mean(axis=0)
    return float(max(1.0, np.sqrt(np.mean(np.sum(d**2, axis=1)))))
