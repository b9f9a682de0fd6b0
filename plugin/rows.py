"""Rows of landmarks (trees along a hedge, a field edge, an avenue) and the chance of laying one map's rows on
another's: the structured coincidence the chance model's uniform placements do not sample.

Two maps of different places, each with a field corner lined by trees, were verified with the corners laid on
each other (BENCHMARKS.md, "Tree-lined corners"): a B tree laid on an A row finds a partner within the gate with
probability 1 - exp(-lambda x chord) (lambda the row's trees per metre), 0.3-0.5 on those maps, eight times what
the isotropic density of `chance.chance_opportunity` predicts, and a uniform placement lays a row along a row
almost never (~rows / N_eff), so the chance samples never see it. Here the rows are found in each map
(`find_rows`), the winner's support is judged as a row-on-row placement would reach it (`row_chance`: a 1-D model
of the rows at the winner plus the chance model's own rate for the rest), and the count of such placements the
two maps' rows offer is N_s; `with_rows` puts both into the best-of-N_eff. Maps without rows are unchanged.
Pure numpy + scipy; a part of `plugin.verification`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .association.gates import size_ratio
from .chance import OPPORTUNITY_GATES, ChanceModel, chance_opportunity, chance_rate, horizontal_tree
from .multisession import Sim3

# A row's landmarks lie within this many gates of its line: a tree of one row laid on another row's line then
# stays within the gate of the line's trees (3/4 gate of scatter leaves a quarter for the other row's).
ROW_TOL_GATES = 0.75
# The largest gap along a row: the outer radius of the annulus in which the chance model counts the density
# around a landmark (`chance.OPPORTUNITY_GATES`); pieces further apart are separate rows to it as well.
ROW_GAP_GATES = OPPORTUNITY_GATES[1]
# The largest gap bridged along the line of a row already found: the annulus's diameter. The strip of such a gap
# (1.5 x 12 gates) holds what the flanks' density puts there, below one landmark in a map sparse enough for rows to
# matter, and the whole row must still pass the contrast test.
ROW_BRIDGE_GATES = 2.0 * OPPORTUNITY_GATES[1]
# The flanks whose density a row is judged against: as wide as that annulus (4 gates), either side of the strip.
ROW_FLANK_GATES = OPPORTUNITY_GATES[1] - OPPORTUNITY_GATES[0]
# A row holds at least ROW_MIN landmarks, ROW_CONTRAST times what the density beside it (its flanks') puts in its
# strip. Together: where the flanks put at most one landmark in the strip, a chain of 8 is a Poisson(1) count
# reaching 8, P = 1e-5 per proposed line, so a uniform map (a few thousand proposals) rarely shows one and a
# dense patch or grove (its flanks as dense as the strip) never; a row that passes gives a laid-on landmark a
# partner rate of about ROW_TOL_GATES x ROW_CONTRAST = 6 times the isotropic density's, the excess the chance
# model does not sample. A spurious row only adds structured placements: p rises (power), it never accepts.
ROW_MIN = 8
ROW_CONTRAST = 8.0
# Landmarks of one map the winner lays within a gate of the other's row, at least this many: a row of their map
# too (a line by construction, though their map alone may be too sparse for `find_rows`, as a map seen at 50-70 %
# detection often is). Fewer than 4 cannot be told from the rest's chance pairs near a row.
LAID_ROW_MIN = 4


@dataclass(frozen=True)
class Row:
    """A straight row of one map's landmarks: `members` (indices), a point and unit direction of its line (x, y),
    and its extent along the line (`start` <= `end`, metres from `centre`)."""

    members: np.ndarray
    centre: np.ndarray
    direction: np.ndarray
    start: float
    end: float

    @property
    def length(self) -> float:
        """Its extent along the line (m)."""
        return self.end - self.start


def _perp(rel: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Signed distance of 2-D offsets `rel` from the line through 0 along unit `d`."""
    return rel[:, 0] * d[1] - rel[:, 1] * d[0]


def _chain(s: np.ndarray, seed: float, max_gap: float) -> np.ndarray:
    """Mask of the contiguous chain (gaps <= max_gap) of positions s that holds the position nearest `seed`."""
    order = np.argsort(s, kind="stable")
    ss = s[order]
    k = min(int(np.searchsorted(ss, seed)), len(ss) - 1)
    lo = hi = k
    while lo > 0 and ss[lo] - ss[lo - 1] <= max_gap:
        lo -= 1
    while hi < len(ss) - 1 and ss[hi + 1] - ss[hi] <= max_gap:
        hi += 1
    mask = np.zeros(len(s), bool)
    mask[order[lo:hi + 1]] = True
    return mask


def _contrast_ok(rel: np.ndarray, d: np.ndarray, members: np.ndarray, tol: float, gate_m: float) -> bool:
    """Whether a chain is a row, not a chance chain through a dense patch: at least ROW_MIN members and
    ROW_CONTRAST times what the density of its flanks (ROW_FLANK_GATES wide either side of the strip +-tol, over
    the chain's extent) puts in the strip (+1 flank landmark: an empty flank is no density 0)."""
    if len(members) < ROW_MIN:
        return False
    along = rel @ d
    perp = np.abs(_perp(rel, d))
    inside = (along >= along[members].min()) & (along <= along[members].max())
    width = ROW_FLANK_GATES * gate_m
    flank = int(np.sum(inside & (perp >= tol) & (perp < tol + width)))
    return len(members) >= ROW_CONTRAST * (flank + 1) / (2.0 * width) * 2.0 * tol


def find_rows(points: np.ndarray, gate_m: float) -> list[Row]:
    """The straight rows of a map's landmarks (horizontal positions), deterministic: every pair of landmarks
    within ROW_GAP_GATES gates proposes a line; its landmarks within ROW_TOL_GATES gates of it form chains with gaps
    of at most ROW_GAP_GATES gates; the longest chain through the pair that passes the contrast test is a row,
    refitted (principal axis, the chain taken again, twice) and removed; repeated until none is left."""
    from scipy.spatial import cKDTree

    xy = np.asarray(points, np.float64).reshape(-1, 3)[:, :2]
    tol, gap = ROW_TOL_GATES * gate_m, ROW_GAP_GATES * gate_m
    left = np.arange(len(xy))
    rows: list[Row] = []
    while len(left) >= ROW_MIN:
        pts = xy[left]
        best = None
        for i, j in sorted(cKDTree(pts).query_pairs(gap)):
            d = (pts[j] - pts[i]) / (np.linalg.norm(pts[j] - pts[i]) + 1e-12)
            rel = pts - pts[i]
            inl = np.flatnonzero(np.abs(_perp(rel, d)) < tol)
            if best is not None and len(inl) <= len(best):  # its chain (a part of inl) cannot be longer
                continue
            chain = inl[_chain(rel[inl] @ d, 0.0, gap)]
            if (best is None or len(chain) > len(best)) and _contrast_ok(rel, d, chain, tol, gate_m):
                best = chain
        if best is None:
            break
        for _ in range(2):  # the principal axis of the chain, and the chain along it again
            centre = pts[best].mean(axis=0)
            d = np.linalg.svd(pts[best] - centre)[2][0]
            rel = pts - centre
            inl = np.flatnonzero(np.abs(_perp(rel, d)) < tol)
            best = inl[_chain(rel[inl] @ d, float(np.median(rel[best] @ d)), gap)]
            if len(best) < ROW_MIN:
                break
        if not _contrast_ok(rel, d, best, tol, gate_m):
            break
        # along an established row's line a gap of up to ROW_BRIDGE_GATES is a gateway or trees not detected, not
        # the row's end: the pieces beyond it, too short to be found alone, are the same row to a map laid on it
        # (fragments left the laid-on trees to the isotropic rate: a corner overlay of nu44's at p 0.009)
        wide = inl[_chain(rel[inl] @ d, float(np.median(rel[best] @ d)), ROW_BRIDGE_GATES * gate_m)]
        if len(wide) > len(best) and _contrast_ok(rel, d, wide, tol, gate_m):
            best = wide
            centre = pts[best].mean(axis=0)
            d = np.linalg.svd(pts[best] - centre)[2][0]
            rel = pts - centre
        s = rel[best] @ d
        rows.append(Row(left[best], centre, d, float(s.min()), float(s.max())))
        left = np.delete(left, best)
    return rows


def _laid_on(rows: list[Row], row_points: np.ndarray, row_sizes: np.ndarray | None, placed: np.ndarray,
             placed_sizes: np.ndarray | None, gate_m: float, max_size_difference: float,
             z_weight: float) -> tuple[dict[int, float], list[tuple[frozenset, float]]]:
    """The landmarks `placed` (another map, in this map's frame) that lie on `rows` (within a gate of a row's line
    and its extent): for each, the probability that chance gives it a partner on the row, and per row the group of
    them with its extent. A row is a 1-D process of lambda landmarks per metre, so the expected partners within
    the 3-D gate are lambda x the mean over the row's own landmarks (their offset from the line, height, size) of
    the chord 2 sqrt(g^2 - dperp^2 - (z_w dz)^2) the gate cuts from the line, size-gated; p = 1 - exp(-that)."""
    p: dict[int, float] = {}
    groups = []
    for row in rows:
        mem = row.members
        lam = (len(mem) - 1) / max(row.length, 1e-9)
        perp_row = _perp(row_points[mem, :2] - row.centre, row.direction)
        rel = placed[:, :2] - row.centre
        perp, along = _perp(rel, row.direction), rel @ row.direction
        on = np.flatnonzero((np.abs(perp) <= gate_m) & (along >= row.start - gate_m) & (along <= row.end + gate_m))
        for k in on:
            h2 = gate_m**2 - (perp[k] - perp_row) ** 2 - (z_weight * (placed[k, 2] - row_points[mem, 2])) ** 2
            sized = np.ones(len(mem), bool)
            if row_sizes is not None and placed_sizes is not None:
                ratio = size_ratio(np.asarray(row_sizes)[mem], np.full(len(mem), placed_sizes[k]))
                sized = ratio <= max_size_difference
            chord = np.where((h2 > 0) & sized, 2.0 * np.sqrt(np.maximum(h2, 0.0)), 0.0)
            p[int(k)] = max(p.get(int(k), 0.0), float(-np.expm1(-lam * chord.mean())))
        if len(on) >= LAID_ROW_MIN:
            groups.append((frozenset(int(k) for k in on), float(np.ptp(along[on]))))
    return p, groups


def _lengths(rows: list[Row], laid: list[tuple[frozenset, float]]) -> list[float]:
    """The lengths of a map's rows: those `find_rows` found, and the groups the winner lays along the other map's
    rows (`_laid_on`) that are not mostly one of those."""
    found = [frozenset(int(k) for k in r.members) for r in rows]
    return [r.length for r in rows] + [ext for grp, ext in laid if all(2 * len(grp & m) < len(grp) for m in found)]


def _cell_tail(p_on: dict[int, float], support: int, rest_mean: float, dispersion: float) -> float:
    """q_s: the probability that a row-on-row placement like the winner's reaches `support`: the laid-on
    landmarks' partners (Poisson binomial of their `p_on`) plus the rest's chance pairs (a negative binomial of
    mean `rest_mean` and variance (1 + dispersion) x that, as `chance._opportunity_tails`; 0: Poisson)."""
    from scipy import stats

    pmf = np.array([1.0])
    for p in p_on.values():
        pmf = np.convolve(pmf, [1.0 - p, p])
    need = support - np.arange(len(pmf))  # what the rest must reach beside r row pairs
    mu = max(rest_mean, 1e-9)
    if dispersion > 0:
        rest = stats.nbinom.sf(need - 1, mu / dispersion, 1.0 / (1.0 + dispersion))
    else:
        rest = stats.poisson.sf(need - 1, mu)
    return float(min(1.0, np.sum(pmf * np.where(need <= 0, 1.0, rest))))


def _row_pair_placements(length_a: float, length_b: float, gate_m: float, prior_m: float) -> float:
    """Row-on-row placements of two rows: 2 orientations x their slides one along the other, one per cell of 2
    gates ((L_A + L_B) / (2 gate)); with a position prior one orientation and at most prior_m / gate slides."""
    slides = (length_a + length_b) / (2.0 * gate_m)
    if prior_m > 0:
        return min(slides, prior_m / gate_m)
    return 2.0 * slides


@dataclass(frozen=True)
class RowChance:
    """What the two maps' rows contribute to the chance test (`row_chance`)."""

    placements: float  # N_s: row-on-row placements (each row pair, 2 orientations, slides of a gate pair apart)
    tail: float  # q_s: the probability that one of them reaches the winner's support


def row_chance(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
               winner: Sim3, support: int, gate_m: float, max_size_difference: float, z_weight: float,
               samples: np.ndarray, opportunities: np.ndarray, chance: ChanceModel,
               prior_m: float = 0.0) -> RowChance | None:
    """The row-on-row placements of two maps and their tail at the winner (None: no row pair, nothing changes).

    Rows: `find_rows` in each map, and the landmarks of each map the winner lays along the other's rows (at least
    LAID_ROW_MIN, `_laid_on`): symmetric in A and B. N_s: for every row of A and row of B, 2 orientations x the
    slides of one along the other, one per 2 gates (the cell of `chance.effective_trials`): (L_A + L_B) / gate.
    q_s: the winner's own placement modelled as a row-on-row one (`_cell_tail`), from either map's side (B's
    landmarks on A's rows, A's on B's; the larger), the rest at the chance model's rate (`chance.chance_rate` of
    its samples, its overdispersion). Every structured placement is given the winner's q_s: an upper bound (most
    align one arm, not a corner), which is what refuses a corner overlay that one cell's model leaves at
    p <= 0.01 (8 of 24 of nu44's pairs). With a position prior of `prior_m` (both maps in one frame) a row slides
    along another by at most the prior's diameter (prior_m / gate cells) and is not reversed (the search's turns
    are then small): the placements the prior lets the search find, as `chance.effective_trials` counts them."""
    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    rows_a, rows_b = find_rows(pa, gate_m), find_rows(pb, gate_m)
    if not rows_a and not rows_b:
        return None
    placed_b, placed_a = winner.apply(pb), winner.inverse().apply(pa)
    on_a, laid_b = _laid_on(rows_a, pa, sizes_a, placed_b, sizes_b, gate_m, max_size_difference, z_weight)
    on_b, laid_a = _laid_on(rows_b, pb, sizes_b, placed_a, sizes_a, gate_m, max_size_difference, z_weight)
    lengths_a, lengths_b = _lengths(rows_a, laid_a), _lengths(rows_b, laid_b)
    n_s = float(sum(_row_pair_placements(la, lb, gate_m, prior_m) for la in lengths_a for lb in lengths_b))
    if n_s <= 0:
        return None
    rate = chance_rate(samples, opportunities)
    dispersion = 0.0 if np.isnan(chance.overdispersion) else chance.overdispersion
    tails = []
    for p_on, placed, tree, n in ((on_a, placed_b, horizontal_tree(pa), len(pb)),
                                  (on_b, placed_a, horizontal_tree(pb), len(pa))):
        rest = np.setdiff1d(np.arange(n), np.fromiter(p_on, np.int64, len(p_on)))
        if np.isnan(rate):  # no opportunity measured: the model's mean, for the share of landmarks off the rows
            rest_mean = chance.mean * len(rest) / max(n, 1)
        else:
            rest_mean = rate * chance_opportunity(tree, placed[rest], gate_m)
        tails.append(_cell_tail(p_on, support, rest_mean, dispersion))
    return RowChance(n_s, max(tails))


def with_rows(chance: ChanceModel, rows: RowChance | None) -> ChanceModel:
    """The chance model with the row-on-row placements in its best-of-N_eff: p = 1 - (1 - q_u)^(N_eff - N_s)
    (1 - q_s)^N_s (N_s at most N_eff: they are some of the alignments the search chooses from). None: as is."""
    if rows is None:
        return chance
    n_s = min(rows.placements, chance.trials)
    log_keep = ((chance.trials - n_s) * np.log1p(-min(chance.tail, 1.0 - 1e-16))
                + n_s * np.log1p(-min(rows.tail, 1.0 - 1e-16)))
    return replace(chance, p_value=float(-np.expm1(log_keep)), row_placements=n_s, row_tail=rows.tail)
