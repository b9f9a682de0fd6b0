"""The chance of laying one map's rows of landmarks (`plugin.rows`) on another's: the structured coincidence the
chance model's uniform placements do not sample.

Two maps of different places, each with a field corner lined by trees, were verified with the corners laid on
each other (BENCHMARKS.md, "Tree-lined corners"): a B tree laid on an A row finds a partner within the gate with
probability 1 - exp(-lambda x chord) (lambda the row's trees per metre), 0.3-0.5 on those maps, eight times what
the isotropic density of `chance.chance_opportunity` predicts, and a uniform placement lays a row along a row
almost never (~rows / N_eff), so the chance samples never see it. Here the rows are found in each map
(`rows.find_rows`), the winner's support is judged as a row-on-row placement would reach it (`row_chance`: a 1-D model
of the rows at the winner plus the chance model's own rate for the rest), and the count of such placements the
two maps' rows offer is N_s; `with_rows` puts both into the best-of-N_eff. Maps without rows are unchanged.
Pure numpy + scipy; a part of `plugin.verification`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .association.gates import size_ratio
from .chance import (
    ChanceModel,
    _horizontal_radius,
    chance_rate,
    horizontal_tree,
    landmark_opportunities,
    placed_map_is_a,
    placed_over_b,
)
from .multisession import Sim3
from .refinement import mutual_nearest, pairing_tree, yaw_matrix
from .rows import Row, find_rows, fit_row, laid_rows, offsets_across, on_rows

# Row-on-row cells whose tail, bounded from above (`row_chance`), stays below ROW_NEGLIGIBLE / N_s are given that
# bound without pairing their landmarks one by one: together they add at most this to p, a hundredth of the
# default false alarm (0.01), and only ever raise it.
ROW_NEGLIGIBLE = 1e-4
# log P(no row-on-row cell reaches the support) below which p = 1 - exp(that) is 1 in double precision (exp(-40)
# = 4e-18): the cells left are not computed (most of a corner overlay's hundreds, each at q ~ 1)
SURE_LOG = -40.0
# The work `row_chance` counts its cells with, in units of (row landmark of A) x (row landmark of B) x turn x (1 +
# slides / 64), at most this much (~20 ns a unit: 1-2 s of CPU); the cells beyond it get a bound instead
# (`row_chance`). Tied to the work, not to a map: a bocage of 20 hedgerows a map (N_s 37,798) took 75 s counted in
# full, two 300-landmark orchards 5 s (fix78).
ROW_WORK_BUDGET = 7.5e7


def _scaled(points: np.ndarray, z_weight: float) -> np.ndarray:
    """Positions in the metric of the gate: (x, y, z_weight z), within gate_m of each other = within the gate."""
    return np.column_stack([points[:, :2], z_weight * points[:, 2]])


def _slide_pairs(row_a: np.ndarray, sizes_a: np.ndarray | None, row_b: np.ndarray, sizes_b: np.ndarray | None,
                 direction: np.ndarray, slides: np.ndarray, gate_m: float, max_size_difference: float) -> np.ndarray:
    """For B's row landmarks `row_b` (gate metric, placed at slide 0) moved by each of `slides` (m) along
    `direction`: the pairs of A's row landmarks `row_a` within the gate (sizes gated), as min(B landmarks with a
    partner, A landmarks with one), the one-to-one count bounded. Each (a, b) pair is within the gate over one
    interval of slides (a quadratic in the slide), so all slides are counted at once."""
    step = np.array([direction[0], direction[1], 0.0])
    rel = row_b[None, :, :] - row_a[:, None, :]  # (A, B, 3)
    c1 = rel @ step
    c0 = np.sum(rel**2, axis=2) - gate_m**2
    disc = c1**2 - c0  # |rel + u step|^2 <= g^2  <=>  u in -c1 +- sqrt(disc)
    ok = disc > 0
    if sizes_a is not None and sizes_b is not None:
        ratio = size_ratio(np.repeat(np.asarray(sizes_a, np.float64), len(row_b)),
                           np.tile(np.asarray(sizes_b, np.float64), len(row_a))).reshape(ok.shape)
        ok &= ratio <= max_size_difference
    ia, ib = np.nonzero(ok)
    if not len(ia):
        return np.zeros(len(slides), np.int64)
    root = np.sqrt(disc[ia, ib])
    lo, hi = -c1[ia, ib] - root, -c1[ia, ib] + root
    active = (slides[None, :] >= lo[:, None]) & (slides[None, :] <= hi[:, None])  # (pairs, slides)
    return np.minimum(_partnered(ib, active), _partnered(ia, active))


def _partnered(owner: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Per slide (column of `active`, pairs x slides), how many distinct landmarks `owner` (one per pair) have an
    active pair: the pairs grouped by owner and or-ed with one `reduceat` (a scatter-or, `np.logical_or.at`, did the
    same at 4x the CPU: 85 % of `row_chance` on an orchard pair, rev29)."""
    order = np.argsort(owner, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(owner[order]) != 0])
    return np.logical_or.reduceat(active[order], starts, axis=0).sum(axis=0)


@dataclass(frozen=True)
class RowChance:
    """What the two maps' rows contribute to the chance test (`row_chance`)."""

    placements: float  # N_s: row-on-row cells (each row pair, 2 orientations, slides 2 gates apart)
    tail: float  # the largest cell's tail: P(one placement of that cell reaches the winner's support) (of the cells
    # computed: once those make p 1 (SURE_LOG) the others are not)
    keep: float  # log of prod over the cells of (1 - q_c): P(no row-on-row cell reaches the support) = exp(keep)
    bounded: bool = False  # cells beyond ROW_WORK_BUDGET were given the conservative bound, not counted


def row_chance(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
               winner: Sim3, support: int, gate_m: float, max_size_difference: float, z_weight: float,
               samples: np.ndarray, opportunities: np.ndarray, chance: ChanceModel,
               prior_m: float = 0.0, a_is_placed: bool | None = None) -> RowChance | None:
    """The row-on-row placements of two maps and the chance that one reaches the winner's support (None: no row
    pair, nothing changes).

    Rows: `find_rows` in each map, and the landmarks of each map the winner lays along the other's rows
    (`laid_rows`): symmetric in A and B. Cells: for every row of A and row of B, 2 orientations x slides of one
    along the other 2 gates apart (the cell of `chance.effective_trials`): B turned so that its row lies on A's
    row's line. In each cell the pairs between the two maps' row landmarks (all rows: a cell that lays one corner on
    another lays both arms) are counted from the geometry itself at the best slide within the cell (+-1 gate,
    quarter-gate steps: the refinement's choice), R_c, not modelled: regular rows pair all or nothing by phase, and
    a binomial per laid tree left a third of nu44's corner overlays at p <= 0.01. The rest of B (its landmarks not
    so paired) gets the chance model's own negative binomial at that placement (rate `chance.chance_rate` x
    `chance_opportunity`, its dispersion), and q_c = P(rest >= support - R_c): rows that align give their pairs for
    free (structure both places have), so a winner laid row on row must show support beyond what the rows give.
    The winner's own cell is among them: a corner overlay, its support nearly all row pairs, gets q_c ~ 1; a true
    alignment whose pairs off the rows carry it keeps its p. With a position prior of `prior_m` (both maps in one
    frame) a row slides along another by at most the prior's reach and is not reversed (the search's turns are then
    small): the placements the prior lets the search find, as `chance.effective_trials` counts them.

    The roles are those `chance.sequential_chance` drew `samples` and `opportunities` in (the map of the smaller
    footprint placed, `chance.placed_map_is_a`; the winner then inverted): the rate, the dispersion, the turns at
    the placed map's radius and the rest's mean are all of that map, so the answer is one of the pair, not of the
    order its maps are given in (in the caller's roles the two orders of one corner pair gave p up to 10x apart:
    rev29). `a_is_placed`: the answer of `placed_map_is_a` when the caller has it (`verification.winner_chance`);
    None: decided here."""
    from scipy import stats

    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    if placed_map_is_a(pa, pb) if a_is_placed is None else a_is_placed:
        pa, sizes_a, pb, sizes_b, winner = placed_over_b(pa, sizes_a, pb, sizes_b, winner)[:5]
    rows_a, rows_b = find_rows(pa, gate_m), find_rows(pb, gate_m)
    if not rows_a and not rows_b:
        return None
    rows_a = rows_a + [fit_row(pa[:, :2], m) for m in laid_rows(rows_b, winner.inverse().apply(pa), rows_a, gate_m)]
    rows_b = rows_b + [fit_row(pb[:, :2], m) for m in laid_rows(rows_a, winner.apply(pb), rows_b, gate_m)]
    if not rows_a or not rows_b:
        return None
    rate = chance_rate(samples, opportunities)
    dispersion = 0.0 if np.isnan(chance.overdispersion) else chance.overdispersion
    # the landmarks of the rows: their members and the others on their strips (`on_rows`)
    mem_a = np.unique(np.concatenate([r.members for r in rows_a] + on_rows(rows_a, pa, gate_m)))
    mem_b = np.unique(np.concatenate([r.members for r in rows_b] + on_rows(rows_b, pb, gate_m)))
    row_a = _scaled(pa[mem_a], z_weight)
    sz_a = None if sizes_a is None else np.asarray(sizes_a, np.float64)[mem_a]
    sz_b = None if sizes_b is None else np.asarray(sizes_b, np.float64)[mem_b]
    tree_a = horizontal_tree(pa)
    pair_tree = pairing_tree(pa[mem_a], z_weight)
    layouts = _layouts(rows_a, rows_b, pb, winner, gate_m, prior_m)
    cells = sum(len(lay.slides) for lay in layouts)
    if cells == 0:
        return None

    def tail(need: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """P(rest >= need), the rest negative binomial of mean mu and the chance model's dispersion."""
        mu = np.maximum(mu, 1e-9)
        if dispersion > 0:
            q = stats.nbinom.sf(need - 1, mu / dispersion, 1.0 / (1.0 + dispersion))
        else:
            q = stats.poisson.sf(need - 1, mu)
        return np.where(need <= 0, 1.0, q)

    def rest_mean(each: np.ndarray, r_c: np.ndarray) -> np.ndarray:
        """The rest's mean: every landmark of B at the opportunity of `chance_opportunity` (`each`, per cell and
        landmark), less what the row pairs took (r_c of B's row landmarks' share, at most one each)."""
        opp = np.maximum(0.0, each.sum(axis=1) - r_c * each[:, mem_b].mean(axis=1))
        return (chance.mean * opp / max(len(pb), 1)) if np.isnan(rate) else rate * opp

    top, keep, work = 0.0, 0.0, 0.0
    for done, lay in enumerate(layouts):  # counted one at a time: once p is sure (SURE_LOG) the rest are never built
        work += len(CELL_TURNS_GATES) * len(mem_a) * len(mem_b) * (1.0 + lay.slides.size / 64.0)
        if work > ROW_WORK_BUDGET:
            # too many to count in the time a verification has (a hedgerow landscape's thousands): each cell left
            # gets what no cell can exceed, every row landmark paired and the rest of B all at an opportunity of
            # 1, so p only rises (a winner among many rows may then be refused; never a chance one accepted)
            q_max = tail(np.array([support - min(len(mem_a), len(mem_b))]),
                         rest_mean(np.ones((1, len(pb))), np.zeros(1)))[0]
            left = sum(len(rest.slides) for rest in layouts[done:])
            top, keep = max(top, float(q_max)), keep + left * float(np.log1p(-min(q_max, 1.0 - 1e-16)))
            return RowChance(float(cells), top, keep, bounded=True)
        g = _counted(lay, pb, winner.scale, row_a, sz_a, mem_b, sz_b, gate_m, max_size_difference, z_weight)
        n, f = g.slides.shape
        pick = g.counts.argmax(axis=1)
        t, s = np.divmod(pick, f)
        placed = np.stack([g.bases[t[c]] + np.r_[g.slides[c, s[c]] * g.direction, 0.0] for c in range(n)])
        each = landmark_opportunities(tree_a, placed.reshape(-1, 3), gate_m).reshape(n, -1)
        bound = g.counts[np.arange(n), pick]
        # the count of `_slide_pairs` bounds the pairs from above and the rest's mean without them is the larger:
        # a cell whose tail is negligible even so keeps that bound (all such cells together add at most
        # ROW_NEGLIGIBLE to p) and is not paired landmark by landmark
        q = tail(support - bound, rest_mean(each, np.zeros(n)))
        for c in np.flatnonzero(q > ROW_NEGLIGIBLE / cells):
            # the pairs themselves: the mutual nearest neighbours the verification counts, at the best of the
            # cell's slides and turns in the order of the bound (a bound at or below the best found cannot beat it)
            r_c = 0
            for k in np.argsort(-g.counts[c], kind="stable"):
                if g.counts[c, k] <= r_c:
                    break
                tk, sk = divmod(int(k), f)
                moved = g.bases[tk][mem_b] + np.r_[g.slides[c, sk] * g.direction, 0.0]
                got = len(mutual_nearest(pa[mem_a], sz_a, moved, sz_b, gate_m, max_size_difference, z_weight,
                                         tree_a=pair_tree)[0])
                r_c = max(r_c, got)
            # the rest's opportunity where the bound peaked: the same cell, within a gate of the pairs' best
            q[c] = tail(np.array([support - r_c]), rest_mean(each[c][None], np.array([float(r_c)])))[0]
        top, keep = max(top, float(q.max())), keep + float(np.sum(np.log1p(-np.minimum(q, 1.0 - 1e-16))))
        if keep < SURE_LOG:  # p is 1 to double precision whatever the other cells hold: refused, not counted on
            break
    return RowChance(float(cells), top, keep)


@dataclass(frozen=True)
class _Layout:
    """One row of A with one of B in one orientation, before any pair is counted: B's row's centre `cb` (B's
    frame, its height the members' mean), turned by `yaw` and put at A's row's centre `anchor` (height `z0`, where
    the winner places it), then slid along `direction` (A's row's) by `slides` (m, cells x slides within a cell)."""

    anchor: np.ndarray
    direction: np.ndarray
    yaw: float
    cb: np.ndarray
    z0: float
    slides: np.ndarray  # (cells, slides within a cell)


@dataclass(frozen=True)
class _Cells:
    """The cells of one `_Layout`, counted (`_counted`): B placed at slide 0 for each turn within the cell (`bases`),
    the slides (m along `direction`, A's row's) of each cell, and the bound of `_slide_pairs` for every
    cell x (turn, slide)."""

    bases: list
    direction: np.ndarray
    slides: np.ndarray  # (cells, slides within a cell)
    counts: np.ndarray  # (cells, turns x slides within a cell)


CELL_SLIDES_GATES = np.arange(-4, 5) / 4.0  # the slides within a cell (gates): +-1 gate in quarter gates
CELL_TURNS_GATES = np.arange(-2, 3) * 0.5  # and the turns (gates at B's radius): +-1 gate in half gates


def _layouts(rows_a: list[Row], rows_b: list[Row], pb: np.ndarray, winner: Sim3, gate_m: float,
             prior_m: float) -> list[_Layout]:
    """The row-on-row cells of `row_chance`, not yet counted: every row of A with every row of B, 2 orientations
    (with a position prior one, turned no further than the search turns within it), slides 2 gates apart over the
    rows' overlap (with a prior, as far as it reaches from where B's row lies unmoved); within each cell slides of
    +-1 gate in quarter gates and turns of +-1 gate at B's radius in half gates (the cells of
    `chance.effective_trials`: the refinement chooses within them; two arms of a corner are never both exactly
    parallel, and it turns to lay both). B is turned so that its row lies along A's row, its row's centre on A's
    row's line, heights as the winner places them. Cheap (no pairs): N_s is known before any cell is counted."""
    scale = winner.scale
    radius = _horizontal_radius(pb)
    max_turn = prior_m / radius if prior_m > 0 else np.pi  # `chance.effective_trials`' yaw range
    fine = CELL_SLIDES_GATES * gate_m
    out = []
    for ra in rows_a:
        for rb in rows_b:
            for sign in ((1.0,) if prior_m > 0 else (1.0, -1.0)):
                db = sign * rb.direction
                yaw = np.arctan2(ra.direction[1], ra.direction[0]) - np.arctan2(db[1], db[0])
                if prior_m > 0:  # not reversed, and turned no further than the search turns within the prior
                    yaw = np.arctan2(np.sin(yaw), np.cos(yaw))
                    if abs(yaw) > np.pi / 2:
                        yaw += np.pi
                        sign = -sign
                    if abs(np.arctan2(np.sin(yaw), np.cos(yaw))) > max_turn:
                        continue
                cb = np.r_[rb.centre, float(pb[rb.members, 2].mean())]
                z0 = float(winner.apply(cb)[2])
                ext = np.sort(sign * scale * np.array([rb.start, rb.end]))
                lo, hi = ra.start - ext[1], ra.end - ext[0]  # slides at which the rows overlap
                if prior_m > 0:  # only as far as the prior reaches from where B's row lies unmoved
                    rel = np.asarray(cb[:2]) - ra.centre
                    if abs(float(offsets_across(rel[None], ra.direction)[0])) > prior_m + gate_m:
                        continue
                    here = float(rel @ ra.direction)
                    lo, hi = max(lo, here - prior_m), min(hi, here + prior_m)
                    if hi < lo:
                        continue
                n = max(1, int(np.ceil((hi - lo) / (2.0 * gate_m))))
                centres = (lo + hi) / 2.0 + (np.arange(n) - (n - 1) / 2.0) * 2.0 * gate_m
                out.append(_Layout(ra.centre, ra.direction, float(yaw), cb, z0, centres[:, None] + fine[None, :]))
    return out


def _counted(lay: _Layout, pb: np.ndarray, scale: float, row_a: np.ndarray, sz_a: np.ndarray | None,
             mem_b: np.ndarray, sz_b: np.ndarray | None, gate_m: float, max_size_difference: float,
             z_weight: float) -> _Cells:
    """The cells of `lay` with the bound of `_slide_pairs` at every turn and slide within each."""
    n, f = lay.slides.shape
    radius = _horizontal_radius(pb)
    bases, counts = [], []
    for dyaw in CELL_TURNS_GATES * gate_m / radius:
        base = Sim3(yaw_matrix(float(lay.yaw + dyaw)), np.zeros(3), scale).apply(pb - lay.cb) + np.r_[lay.anchor,
                                                                                                     lay.z0]
        bases.append(base)
        counts.append(_slide_pairs(row_a, sz_a, _scaled(base[mem_b], z_weight), sz_b, lay.direction,
                                   lay.slides.reshape(-1), gate_m, max_size_difference).reshape(n, f))
    return _Cells(bases, lay.direction, lay.slides, np.stack(counts, axis=1).reshape(n, -1))


def with_rows(chance: ChanceModel, rows: RowChance | None) -> ChanceModel:
    """The chance model with the row-on-row cells in its best-of-N_eff: p = 1 - (1 - q_u)^(N_eff - N_s)
    prod_c (1 - q_c) (N_s at most N_eff: they are some of the alignments the search chooses from), and never below
    the uniform placements' p: a cell's q_c below q_u (B half off A in it) would otherwise lower p where rows were
    found, and a spurious row must only add placements (an orchard pair's 3,084 cells at q_c 1e-9 took p from 0.0101,
    refused, to 0.0098, accepted: rev29). None: as is."""
    if rows is None:
        return chance
    n_s = min(rows.placements, chance.trials)
    log_keep = (chance.trials - n_s) * np.log1p(-min(chance.tail, 1.0 - 1e-16)) + rows.keep
    p_value = max(chance.p_value, float(-np.expm1(log_keep)))
    return replace(chance, p_value=p_value, row_placements=n_s, row_tail=rows.tail, row_bounded=rows.bounded)
