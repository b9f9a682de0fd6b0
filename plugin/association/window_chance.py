"""How large a consistent set chance alone makes in the windows of two maps, and the windows that follow (ours).

A window pair holds n_A x n_B landmark pairs, of which a fraction q passes the size gate theta_r (measured on the
two maps' sizes). Under one rigid upright transform (yaw + translation), a putative association of the pair is
consistent by chance when B's landmark lands within about theta_eps of its partner in A: a window of ground area
W_A holds n_A landmarks, so for each of B's landmarks over the common ground the expected number of size-compatible
partners within theta_eps is n_A q pi eps^2 / W_A, and per transform

    lambda = n_A n_B q pi eps^2 / max(W_A, W_B)           (chance-consistent associations per transform)

The search looks at every transform a window pair allows (the look-elsewhere effect): translations over the window
in cells of pi eps^2, and yaws in steps of eps / R (R the window's radius) - N_T = W / (pi eps^2) x 2 pi R / eps -
over every pair of disjoint windows. The largest chance set is then the largest k that at least one of those
N trials reaches: N x P(Poisson(lambda) >= k) >= 1 (`window_chance`).

The tolerance radius is theta_eps itself, not eps / 2 (what pairwise length agreement within eps guarantees for
one transform): the solver finds the largest pairwise-consistent set, which uses all the slack of the pairwise
test and of the yaw slice. So measured, with the search itself on a map against its mirror image (which no rigid
transform explains, `tools/benchmarks/bench_windows.py`) and on maps of two different synthetic worlds: synthetic
survey maps of worlds 5, 11, 42 at the derived theta_eps 2.7-4.1 m and 50-landmark windows reach 6-10 (model
7-13: it overestimates where lambda > 1, where it decides nothing); NAIP 2009 vs 2015 at 10.2 m reaches 5 (model
6); different worlds at 300 / 3000 landmarks per km^2, theta_eps 2 m: 4 / 5 (model 4 / 7). BENCHMARKS.md,
"Windows from the maps".

Windows from the maps (`derived_windows`): a window pair separates a true set from chance while lambda is below
one: above it, chance sets grow in proportion to the window, as the true set does (lambda and the common
landmarks are both proportional to the window's landmarks), so a longer window no longer helps and costs
quadratically. Below it, a longer window holds proportionally more common landmarks and the chance level grows
only slowly. Survey maps of 0.3-2 m landmarks at a derived theta_eps of 2.7-4 m reach lambda ~1 at the paper's 50
landmarks; 2.5 m/px orthophoto maps of 20 m objects at 10 m reach only ~0.2 there, their windows may hold five
times as many landmarks at the same chance per transform. theta_S of such windows exceeds their largest chance set.
Configured windows that are kept keep the configured theta_S: there lambda is near or above one, where the model
overestimates the largest chance set (above), and raising theta_S to it would drop true hypotheses of sparse map
pairs (world 97 at 130 m: true sets of 6 against a model's 7) while chance hypotheses over theta_S are refused by
the verification's chance test on the full maps anyway (`plugin.chance`).

Wider windows after a refusal (`DerivedWindows.wider_params`, ours): lambda <= 1 is the cheapest window that
separates maps whose landmarks repeat often, not a limit of what a window can separate. A window of n landmarks
holds r n true associations (r: the fraction of landmarks with a counterpart, which the maps cannot measure) and a
largest chance set of about lambda + sqrt(2 lambda ln N) with lambda proportional to n, so the smallest repeat
rate a window detects, theta_S / n, still falls as the window doubles past lambda = 1. Hence, when the search at
the grown windows is refused by the verification, the matcher searches once more at the next doubled window (its
theta_S again its largest chance set) if its window pair stays within MAX_PUTATIVE_PER_WINDOW_PAIR. NAIP 2009 vs
2015 with both orthophotos sharpened (906 / 786 landmarks instead of 698 / 617, as sharper rasters of other dates
give): lambda 0.53 at 100 landmarks, 1.07 at 200, so the grown windows were 100 and found nothing; at 200 the
verified answer is 62 associations against 21, 1.7 m off (BENCHMARKS.md, "Sharper rasters"). Only grown windows
get the wider search: there chance is sparse (lambda <= 1/2 at the configured window), so the doubled window
lies at lambda 1-2, where the theta_S-core still prunes. Survey maps whose configured windows already hold lambda
~1 would pay for it on every pair that has no answer (maps of two different synthetic worlds, 337 x 318
landmarks: 9 s of CPU at 50-landmark windows, 31 s at 100, 105 s at 200) and keep one search.

Near the georeference (`DerivedWindows.near_params`, ours): maps in one georeferenced frame are searched first
only among landmarks within `association.georeference_prior_m` of each other (`match_answer`). That search looks at
far fewer transforms (translations within a disc of the prior's radius, turns that move a landmark at most that
far) in far fewer window pairs (those within the prior of each other), so its largest chance set is smaller and
grown windows get theta_S from it: NAIP 2009 vs 2015 at 200-landmark windows, 1.2e8 trials and a largest chance set
of 10 over every alignment, ~1e4 and 6 within 50 m. Windows that were not grown keep the configured theta_S there
too (the model does not decide anything at lambda ~1, above).

Windows of equal ground area (`area_factors`, ours): the paper's windows hold theta_WL landmarks in both maps, so
in maps of unequal density (a winter map holds a third of the summer map's landmarks, a map flown higher fewer
small ones) one window of the sparser map spans several of the denser map's, and a window pair holds only that
fraction of their common objects (world 97 summer vs winter at 130 m: 9 400 against 30 400 m^2, no true set over
theta_S). The denser map's window therefore holds theta_WL x f landmarks (stride theta_SL x f), f the largest
power of two whose window spans no more ground than the sparser map's window of theta_WL: maps whose densities
differ by less than a factor of two keep f = 1 (the paper's windows), and a window pair never covers more ground
than the sparser window (so lambda, over the larger window area, grows only with the denser window's landmarks).
A power of two keeps the denser map's windows on the strides of the doubling rule above, which then doubles both
maps' windows together.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..geometry import hull_area
from ..params import AssociationParams
from .windows import hilbert_order

SIZE_SAMPLE = 800  # landmarks of each map the size-gate fraction q is measured on (evenly spaced, deterministic)
MAX_CHANCE_PER_TRANSFORM = 1.0  # lambda up to which longer windows separate true sets from chance (module doc)
# putative associations of one window pair beyond which windows are not grown: the solver's affinity matrix grows
# with their square (NAIP's 200-landmark windows hold ~11 600; a 50-landmark survey window pair ~700)
MAX_PUTATIVE_PER_WINDOW_PAIR = 25_000


@dataclass(frozen=True)
class WindowChance:
    """The chance model of one window length (module doc); areas in m^2."""

    length: int  # theta_WL (the window of a map whose factor is 1)
    lengths: tuple[int, int]  # landmarks per window of A and of B: theta_WL x each map's window factor
    landmarks: tuple[int, int]  # per window in A and B (fewer when a map is shorter than the window)
    window_area_m2: tuple[float, float]  # median horizontal area (convex hull) of disjoint windows of A and B
    size_pass: float  # q: fraction of landmark pairs that pass the size gate theta_r
    per_transform: float  # lambda: chance-consistent associations expected under one transform
    trials: float  # N: transforms x disjoint window pairs the search looks at
    largest: int  # the largest chance-consistent set size N trials reach (expected)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}


def _ordered(points: np.ndarray, params: AssociationParams) -> np.ndarray:
    xy = np.asarray(points, np.float64)[:, :2]
    return xy[hilbert_order(points)] if params.windows == "spatial" else xy


def _disjoint_windows(xy: np.ndarray, length: int) -> list[np.ndarray]:
    """The disjoint windows of `length` consecutive landmarks (the whole map if shorter; a remainder shorter than a
    window is left out): what `_window_area` and `_boxes` measure."""
    return [xy[s:s + length] for s in range(0, max(1, len(xy) - length + 1), length)]


def _window_area(xy: np.ndarray, length: int) -> float:
    """Median convex-hull area of the disjoint windows (`_disjoint_windows`); 0 for degenerate (collinear)
    windows."""
    areas = [hull_area(part) for part in _disjoint_windows(xy, length) if len(part) >= 3]
    return float(np.median(areas)) if areas else 0.0


def size_pass_fraction(sizes_a: np.ndarray | None, sizes_b: np.ndarray | None, theta_r: float) -> float:
    """q: the fraction of landmark pairs (A, B) whose sizes pass the gate r <= theta_r (1 without sizes)."""
    if sizes_a is None or sizes_b is None or len(sizes_a) == 0 or len(sizes_b) == 0:
        return 1.0

    def sample(h: np.ndarray) -> np.ndarray:
        h = np.asarray(h, np.float64)
        return h if len(h) <= SIZE_SAMPLE else h[np.linspace(0, len(h) - 1, SIZE_SAMPLE).astype(np.int64)]

    from .kernels_graph import size_pass_count

    a, b = sample(sizes_a), sample(sizes_b)
    return size_pass_count(a, b, float(theta_r)) / (len(a) * len(b))


def window_chance(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                  sizes_b: np.ndarray | None, params: AssociationParams, length: int | None = None,
                  prior_m: float = 0.0) -> WindowChance:
    """The chance model (module doc) for windows of `length` landmarks (default `params.window_length`) times each
    map's window factor (`params.window_factor_a`, `_b`) at the tolerances of `params` (theta_eps, theta_r), over the
    windows' order (`params.windows`); with `prior_m`, of a search with that position prior (maps in one frame)."""
    q = size_pass_fraction(sizes_a, sizes_b, params.max_size_difference)
    return _chance(_ordered(points_a, params), _ordered(points_b, params), q, params,
                   int(params.window_length if length is None else length), prior_m)


def _chance(xa: np.ndarray, xb: np.ndarray, q: float, params: AssociationParams, length: int,
            prior_m: float = 0.0) -> WindowChance:
    """`window_chance` of the two maps' horizontal positions in window order and their size-gate fraction q
    (neither depends on the window length: `derived_windows` computes them once for all lengths it tries). With
    `prior_m` (maps in one frame, putative associations within that distance): the translations of a disc of
    that radius, the turns that move a landmark at most that far, and only the window pairs that lie within it
    of each other (`_near_window_pairs`)."""
    la, lb = length * params.window_factor_a, length * params.window_factor_b
    na, nb = min(la, len(xa)), min(lb, len(xb))
    wa, wb = _window_area(xa, la), _window_area(xb, lb)
    cell = math.pi * params.distance_tolerance_m ** 2
    if min(wa, wb) <= 0 or na < 3 or nb < 3:  # no extent to place landmarks by chance: no trials
        return WindowChance(length, (la, lb), (na, nb), (wa, wb), q, 0.0, 0.0, 0)
    lam = na * nb * q * cell / max(wa, wb)
    common = min(wa, wb)
    radius = math.sqrt(common / math.pi)
    if prior_m > 0:
        transforms = (max(1.0, min(common, math.pi * prior_m ** 2) / cell)
                      * max(1.0, min(2.0 * math.pi * radius, 2.0 * prior_m) / params.distance_tolerance_m))
        pairs = float(_near_window_pairs(xa, xb, la, lb, prior_m))
    else:
        transforms = max(1.0, common / cell) * max(1.0, 2.0 * math.pi * radius / params.distance_tolerance_m)
        pairs = max(1.0, len(xa) / la) * max(1.0, len(xb) / lb)
    trials = transforms * pairs
    return WindowChance(length, (la, lb), (na, nb), (wa, wb), q, lam, trials,
                        _largest_chance_set(lam, trials, na * nb))


def _boxes(xy: np.ndarray, length: int) -> np.ndarray:
    """(n, 4) horizontal bounding boxes (x0, y0, x1, y1) of the disjoint windows of `length` consecutive landmarks
    (`_disjoint_windows`)."""
    return np.array([[*p.min(axis=0), *p.max(axis=0)] for p in _disjoint_windows(xy, length) if len(p)]).reshape(-1, 4)


def _near_window_pairs(xa: np.ndarray, xb: np.ndarray, la: int, lb: int, prior_m: float) -> int:
    """How many pairs of disjoint windows (A's of la landmarks, B's of lb) lie within prior_m of each other: the
    window pairs a search with that position prior can find anything in (at least 1)."""
    ba, bb = _boxes(xa, la), _boxes(xb, lb)
    if not len(ba) or not len(bb):
        return 1
    gap_x = np.maximum(0.0, np.maximum(ba[:, None, 0] - bb[None, :, 2], bb[None, :, 0] - ba[:, None, 2]))
    gap_y = np.maximum(0.0, np.maximum(ba[:, None, 1] - bb[None, :, 3], bb[None, :, 1] - ba[:, None, 3]))
    return max(1, int(np.count_nonzero(gap_x**2 + gap_y**2 <= prior_m**2)))


def area_factors(xa: np.ndarray, xb: np.ndarray, length: int) -> tuple[int, int]:
    """The window factors (f_A, f_B) of equal-area windows (module doc) for maps whose horizontal positions in
    window order are xa and xb: 1 for the sparser map; for the denser one the largest power of two f whose windows
    of length x f landmarks span at most the median ground area of the sparser map's windows of `length` (and
    stop at the first that holds the whole map). (1, 1) when a map has no window area (fewer than 3 landmarks,
    collinear)."""
    wa, wb = _window_area(xa, length), _window_area(xb, length)
    if min(wa, wb) <= 0 or wa == wb:
        return 1, 1
    dense, target = (xa, wb) if wa < wb else (xb, wa)
    f = 1
    while length * f < len(dense) and _window_area(dense, 2 * length * f) <= target:
        f *= 2
    return (f, 1) if wa < wb else (1, f)


def _largest_chance_set(lam: float, trials: float, most: int) -> int:
    """The smallest k (at most `most`) with trials x P(Poisson(lam) >= k + 1) < 1: the largest set size that at
    least one of `trials` trials reaches. P(X >= k + 1) = sf(k), evaluated for a block of k at a time (the same
    values one call per k gives)."""
    from scipy.stats import poisson

    start, block = 0, 16
    while start < most:
        ks = np.arange(start, min(start + block, most))
        below = np.flatnonzero(trials * poisson.sf(ks, lam) < 1.0)
        if len(below):
            return int(ks[below[0]])
        start += block
    return most


@dataclass(frozen=True)
class DerivedWindows:
    """The windows `derived_windows` chose, and the chance model that chose them (recorded in match.json)."""

    params: AssociationParams  # theta_WL, theta_SL and theta_S derived (the configured ones when `derived` is None)
    configured: WindowChance  # the chance model at the configured window length
    derived: WindowChance | None  # ... at the derived one; None: the configured windows are kept
    # the wider windows of a last search when the derived one is refused (module doc, "Wider windows"); None: no
    # wider search (windows not grown, the maps no longer than the window, or too many putative associations)
    wider_params: AssociationParams | None = None
    wider: WindowChance | None = None
    # the search near the maps' georeference (`match_answer`, `association.georeference_prior_m`): the derived
    # windows with theta_S from the chance model of the alignments within that prior (module doc, "Near the
    # georeference"); None: the derived theta_S (windows not grown, or no lower under the prior)
    near_params: AssociationParams | None = None
    near: WindowChance | None = None

    def to_dict(self) -> dict:
        p = self.params
        return {"derived": self.derived is not None, **_window_fields(p),
                "window_factors": [p.window_factor_a, p.window_factor_b],
                "equal_area": p.equal_area_windows,
                "rule": ("denser map's window x the largest power of two within the sparser's area; "
                         if p.equal_area_windows
                         else "") +
                        f"longest doubled window with lambda <= {MAX_CHANCE_PER_TRANSFORM:g} and at most "
                        f"{MAX_PUTATIVE_PER_WINDOW_PAIR} putative associations; theta_S >= its largest chance set",
                "configured_chance": self.configured.to_dict(),
                "derived_chance": None if self.derived is None else self.derived.to_dict(),
                "wider": None if self.wider_params is None else {
                    **_window_fields(self.wider_params),
                    "chance": None if self.wider is None else self.wider.to_dict()},
                "near_georeference": None if self.near_params is None else {
                    **_window_fields(self.near_params), "prior_m": self.near_params.georeference_prior_m,
                    "chance": None if self.near is None else self.near.to_dict()}}


def _window_fields(p: AssociationParams) -> dict:
    """The windows and theta_S of one search, as match.json records them."""
    return {"window_length": p.window_length, "window_stride": p.window_stride,
            "min_associations": p.min_associations}


def derived_windows(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                    sizes_b: np.ndarray | None, params: AssociationParams) -> DerivedWindows:
    """Windows of equal ground area in both maps (with `params.equal_area_windows`: the window factors of
    `area_factors`, else the configured ones), then longer windows for maps whose windows hold far fewer
    chance-consistent associations per transform than one (module doc): the longest window (doubling theta_WL, in
    both maps, while a map is longer than its window) whose lambda stays <= MAX_CHANCE_PER_TRANSFORM and whose
    window pair holds at most MAX_PUTATIVE_PER_WINDOW_PAIR putative associations (the solver's cost grows with
    their square), overlapping by half, and theta_S the larger of the configured one and that window's largest
    chance set. The configured theta_WL, theta_SL and theta_S stay when even the doubled window exceeds one chance
    association per transform (or the maps are shorter than the configured window). Grown windows come with the
    next doubled window for a last search after a refusal (`wider_params`, module doc) when it is affordable."""
    xa, xb = _ordered(points_a, params), _ordered(points_b, params)
    if params.equal_area_windows:
        fa, fb = area_factors(xa, xb, params.window_length)
        params = dataclasses.replace(params, window_factor_a=fa, window_factor_b=fb)
    q = size_pass_fraction(sizes_a, sizes_b, params.max_size_difference)
    base = _chance(xa, xb, q, params, params.window_length)

    def doubled(chance: WindowChance) -> WindowChance | None:
        """The chance model of the next doubled window; None when both maps are no longer than the window."""
        length = chance.length
        if length * params.window_factor_a >= len(xa) and length * params.window_factor_b >= len(xb):
            return None
        return _chance(xa, xb, q, params, 2 * length)

    def affordable(chance: WindowChance | None) -> bool:
        if chance is None:
            return False
        putative = chance.landmarks[0] * chance.landmarks[1] * chance.size_pass
        return chance.trials > 0 and putative <= MAX_PUTATIVE_PER_WINDOW_PAIR

    def windows_of(chance: WindowChance) -> AssociationParams:
        # overlapping by half: every stretch of length / 2 consecutive landmarks lies whole in one window, at
        # least the configured windows' length - stride once grown to twice that, at a fraction of the pairs
        return dataclasses.replace(params, window_length=chance.length,
                                   window_stride=max(params.window_stride, chance.length // 2),
                                   min_associations=max(params.min_associations, chance.largest))

    best = None
    nxt = doubled(base)
    while affordable(nxt) and nxt.per_transform <= MAX_CHANCE_PER_TRANSFORM:
        best, nxt = nxt, doubled(nxt)
    if best is None:
        return DerivedWindows(params, base, None)
    wider = nxt if affordable(nxt) else None
    chosen = windows_of(best)
    near_params, near = None, None
    if params.georeference_prior_m > 0:
        near = _chance(xa, xb, q, params, best.length, params.georeference_prior_m)
        theta_s = max(params.min_associations, near.largest)
        if theta_s < chosen.min_associations:
            near_params = dataclasses.replace(chosen, min_associations=theta_s)
    return DerivedWindows(chosen, base, best, None if wider is None else windows_of(wider), wider,
                          near_params, near if near_params is not None else None)
