"""Rows of landmarks in one map (trees along a hedge, a field edge, an avenue): the straight rows found in it
(`find_rows`), the landmarks on a row's strip (`on_rows`) and the rows another map's landmarks make when laid on
them (`laid_rows`). The chance test lays such rows on rows (`plugin.row_placements`): a coincidence its uniform
placements do not sample. Pure numpy + scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chance import OPPORTUNITY_GATES

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


def offsets_across(rel: np.ndarray, d: np.ndarray) -> np.ndarray:
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
    perp = np.abs(offsets_across(rel, d))
    inside = (along >= along[members].min()) & (along <= along[members].max())
    width = ROW_FLANK_GATES * gate_m
    flank = int(np.sum(inside & (perp >= tol) & (perp < tol + width)))
    return len(members) >= ROW_CONTRAST * (flank + 1) / (2.0 * width) * 2.0 * tol


def _proposals(xy: np.ndarray, tol: float, gap: float) -> np.ndarray:
    """The pairs (i < j, sorted) of landmarks within `gap` of each other whose line can hold a row: a chain of at
    least ROW_MIN landmarks within `tol` of it, gaps <= `gap`, through i. Such a chain holds ROW_MIN consecutive
    members with i among them, all within (ROW_MIN - 1) gaps along the line and `tol` across, so within that
    radius of i, and contiguous there too: the chain through i among i's neighbours in that radius alone is at
    least ROW_MIN long. Testing that (a few hundred neighbours, not the whole map, for every pair) keeps the same
    proposals `find_rows` would find a row from and bounds the work by the map's density, not its size (a 20,000-
    landmark map: 27 s of CPU before)."""
    from scipy.spatial import cKDTree

    if len(xy) < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(xy)
    pairs = tree.query_pairs(gap, output_type="ndarray").astype(np.int64)
    if not len(pairs):
        return np.zeros((0, 2), np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    radius = (ROW_MIN - 1) * gap + 2.0 * tol
    firsts, starts = np.unique(pairs[:, 0], return_index=True)
    ends = np.r_[starts[1:], len(pairs)]
    keep = np.zeros(len(pairs), bool)
    for i, lo, hi in zip(firsts, starts, ends):
        near = np.asarray(tree.query_ball_point(xy[i], radius), np.int64)
        rel = xy[near] - xy[i]
        v = xy[pairs[lo:hi, 1]] - xy[i]
        d = v / (np.linalg.norm(v, axis=1) + 1e-12)[:, None]  # as `find_rows` computes it
        perp = np.abs(np.outer(d[:, 1], rel[:, 0]) - np.outer(d[:, 0], rel[:, 1]))
        along = d @ rel.T
        inl = perp < tol
        length = np.ones(len(d), np.int64)
        for side in (1.0, -1.0):  # the chain from i outwards, each way: its leading run of gaps <= gap
            s = np.sort(np.where(inl & (side * along > 0), side * along, np.inf), axis=1)
            with np.errstate(invalid="ignore"):  # inf - inf past the inliers: NaN, no step
                steps = np.diff(np.column_stack([np.zeros(len(d)), s]), axis=1)
            length += np.cumprod(steps <= gap, axis=1).sum(axis=1)
        keep[lo:hi] = length >= ROW_MIN
    return pairs[keep]


def find_rows(points: np.ndarray, gate_m: float) -> list[Row]:
    """The straight rows of a map's landmarks (horizontal positions), deterministic: every pair of landmarks
    within ROW_GAP_GATES gates whose line can hold a row (`_proposals`) proposes it; its landmarks within
    ROW_TOL_GATES gates of it form chains with gaps of at most ROW_GAP_GATES gates; the longest chain through the
    pair that passes the contrast test is a row, refitted (principal axis, the chain taken again, twice) and
    removed; repeated until none is left."""
    xy = np.asarray(points, np.float64).reshape(-1, 3)[:, :2]
    tol, gap = ROW_TOL_GATES * gate_m, ROW_GAP_GATES * gate_m
    left = np.arange(len(xy))
    rows: list[Row] = []
    proposals = _proposals(xy, tol, gap)
    # what each proposal's chain is known to be: an upper bound of its length (`most`: its inliers or an earlier
    # chain; removing landmarks never lengthens a chain) and, while `exact`, the chain (`chains`: landmark indices)
    # and its verdict, kept until a removed row takes a landmark of its band (the chain, or its flanks within the
    # chain's extent: all its chain and contrast depend on). The choice is the scan's own (the first of the longest
    # that passes); rescanning every proposal against the whole map per row found made an orchard quadratic
    most = np.full(len(proposals), np.iinfo(np.int64).max)
    exact = np.zeros(len(proposals), bool)
    passes = np.zeros(len(proposals), bool)
    chains: dict[int, np.ndarray] = {}
    band_of, band_at = np.zeros(0, np.int64), np.zeros(0, np.int64)  # (proposal, landmark) of the exact ones' bands
    flank = ROW_FLANK_GATES * gate_m
    while len(left) >= ROW_MIN:
        pts = xy[left]
        alive = np.zeros(len(xy), bool)
        alive[left] = True
        best, longest, new_of, new_at = None, -1, [band_of], [band_at]
        for k in np.flatnonzero(alive[proposals[:, 0]] & alive[proposals[:, 1]]):  # a removed landmark proposes none
            if most[k] <= longest:  # its chain cannot be longer than the best's
                continue
            if not exact[k]:
                i, j = np.searchsorted(left, proposals[k])
                d = (pts[j] - pts[i]) / (np.linalg.norm(pts[j] - pts[i]) + 1e-12)
                rel = pts - pts[i]
                perp = np.abs(offsets_across(rel, d))
                inl = np.flatnonzero(perp < tol)
                most[k] = len(inl)
                if len(inl) <= longest:  # its chain (a part of inl) cannot be longer
                    continue
                chain = inl[_chain(rel[inl] @ d, 0.0, gap)]
                along = rel @ d
                band = left[(along >= along[chain].min()) & (along <= along[chain].max()) & (perp < tol + flank)]
                chains[int(k)], most[k], exact[k] = left[chain], len(chain), True
                passes[k] = _contrast_ok(rel, d, chain, tol, gate_m)
                new_of.append(np.full(len(band), k))
                new_at.append(band)
            if passes[k] and most[k] > longest:
                best, longest = np.searchsorted(left, chains[int(k)]), int(most[k])
        band_of, band_at = np.concatenate(new_of), np.concatenate(new_at)
        if best is None:
            break
        for _ in range(2):  # the principal axis of the chain, and the chain along it again
            centre = pts[best].mean(axis=0)
            d = np.linalg.svd(pts[best] - centre)[2][0]
            rel = pts - centre
            inl = np.flatnonzero(np.abs(offsets_across(rel, d)) < tol)
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
        gone = np.zeros(len(xy), bool)
        gone[left[best]] = True
        exact[band_of[gone[band_at]]] = False  # their chains are bounds now, recomputed when they could win
        kept = exact[band_of]
        band_of, band_at = band_of[kept], band_at[kept]
        left = np.delete(left, best)
    return rows


def fit_row(xy: np.ndarray, members: np.ndarray) -> Row:
    """The row through landmarks `members` of positions xy: their mean, principal axis and extent along it."""
    centre = xy[members].mean(axis=0)
    d = np.linalg.svd(xy[members] - centre)[2][0]
    s = (xy[members] - centre) @ d
    return Row(np.asarray(members, np.int64), centre, d, float(s.min()), float(s.max()))


def on_rows(rows: list[Row], xy: np.ndarray, gate_m: float) -> list[np.ndarray]:
    """For each row, the landmarks at xy on its strip: within a gate of its line (where a tree laid on the line
    finds the line's trees within the gate), from a gap (ROW_GAP_GATES) before its start to a gap after its end
    (as far as its chain would have reached): its members and the landmarks beside them, part of the same 1-D
    structure to a map laid on it (members alone left a corner overlay's pairs with trees 1.5-2 m off the fitted
    line to the isotropic rate, and nu44's LA/LB verified at p 0.008)."""
    out = []
    reach = ROW_GAP_GATES * gate_m
    for row in rows:
        rel = xy[:, :2] - row.centre
        perp, along = offsets_across(rel, row.direction), rel @ row.direction
        out.append(np.flatnonzero((np.abs(perp) <= gate_m) & (along >= row.start - reach)
                                  & (along <= row.end + reach)))
    return out


def laid_rows(rows: list[Row], placed: np.ndarray, own_rows: list[Row], gate_m: float) -> list[np.ndarray]:
    """Rows of another map made of its landmarks `placed` (in this map's frame) on the strips of `rows`
    (`on_rows`), at least LAID_ROW_MIN of them, unless they are mostly a row of their map already found
    (`own_rows`): a line by construction, though their map alone may be too sparse for `find_rows` (a map seen at
    50-70 % detection often is). Their line is fitted in their own map's frame by the caller."""
    found = [set(int(k) for k in r.members) for r in own_rows]
    return [on for on in on_rows(rows, placed, gate_m)
            if len(on) >= LAID_ROW_MIN and all(2 * len(set(on.tolist()) & m) < len(on) for m in found)]
