"""The rivals a map's own layout offers a verified alignment (a stage of `plugin.verification.verify_alignments`):
B moved by the displacements that carry A's landmarks near the winner's pairs onto other landmarks of A, and
turned about a landmark at the pairs' centre by the angles that carry those displacements onto each other.

On a random layout these are ordinary chance placements (no displacement carries many landmarks onto landmarks).
On a repetitive one (trees on a grid, lamps of a car park) they are the layout's own symmetries: a shift by the
period or a quarter turn explains about as many pairs as the true alignment, and an alignment that wins against
them only by one or two pairs is not told apart from them by the geometry at all. The verification's other
controls (the search's candidates, B displaced a fixed 3 gates or turned +-10 / 180 deg, random placements) do
not aim at these, so two maps of a plantation were "verified" a period or a quarter turn off (the 27th sweep:
11 pairs against a runner-up of 1, 1 pair correct). Pure numpy / scipy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .multisession import Sim3
from .refinement import yaw_matrix

LAYOUT_PROBES = 16  # the winner's A landmarks nearest the pairs' centroid whose neighbours give the displacements
LAYOUT_NEIGHBOURS = 8  # neighbours of each probe in A (horizontal): the candidate displacements
LAYOUT_SHIFTS = 6  # moved placements kept (those that land most of B on A): one refinement each
LAYOUT_TURNS = 3  # turned placements kept (likewise): one refinement each
QUARTER_TURNS_DEG = (90.0, 180.0, 270.0)  # always candidate turns: the symmetries of a square grid and a row
TURN_MERGE_DEG = 5.0  # candidate turns closer than this are one
TURN_MOVES = 12  # the best-landing moves that give the turns' angles and the moves tried with each turn


@dataclass(frozen=True)
class LayoutStart:
    """A rival start the layout offers: the winner's transform with B moved by `shift` (A's frame, metres) after
    turning it by `turn_deg` about a landmark of A at the winner's pairs; `landed`: how many of B's landmarks it
    puts within a gate of one of A (horizontally, before any refinement: how the starts are ranked)."""

    transform: Sim3
    shift_m: float
    turn_deg: float
    landed: int


@dataclass(frozen=True)
class LayoutRival:
    """The best rival a layout start converged to: `support` pairs the winner does not explain, B moved `shift_m`
    and turned `turn_deg` from the winner at its start."""

    support: int
    shift_m: float
    turn_deg: float

    def text(self) -> str:
        """'B moved 20 m' / 'B turned 90 deg' / 'B moved 20 m and turned 90 deg'."""
        parts = ([f"moved {self.shift_m:.0f} m"] if self.shift_m > 0 else []) + (
            [f"turned {self.turn_deg:.0f} deg"] if self.turn_deg != 0 else [])
        return "B " + " and ".join(parts or ["placed so"])

    def to_dict(self) -> dict[str, Any]:
        return {"support": int(self.support), "shift_m": float(self.shift_m), "turn_deg": float(self.turn_deg)}


def _on_a(tree_xy: Any, xy: np.ndarray, gate_m: float) -> int:
    """How many of the points `xy` have a landmark of A (its horizontal tree) within one gate."""
    if not len(xy):
        return 0
    d, _ = tree_xy.query(xy, k=1, distance_upper_bound=gate_m)
    return int(np.sum(np.isfinite(d)))


def layout_starts(winner: Sim3, points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray,
                  gate_m: float) -> list[LayoutStart]:
    """The starts of the layout's rivals of `winner` (a_from_b) with `pairs` ((K, 2) indices A, B): at most
    LAYOUT_SHIFTS placements of B moved and LAYOUT_TURNS turned (and moved), those that put the most of B's
    landmarks within a gate of one of A (`LayoutStart.landed`; ties: the shorter move first, then as found;
    deterministic), no two within 2 gates of each other at the winner's pairs.

    Moves: from the LAYOUT_PROBES paired A landmarks nearest the pairs' centroid to their LAYOUT_NEIGHBOURS nearest
    landmarks of A, one per cell of 2 gates; without a turn only those beyond 2 gates (nearer is the winner's own
    basin, `chance.converged_to_winner`). Turns: QUARTER_TURNS_DEG and the angles between two moves of about equal
    length among the TURN_MOVES best-landing moves (a lattice's rotations), about the paired A landmark nearest the
    centroid (a lattice point on a lattice: a turn about it maps the lattice onto itself), each with no move or one
    of those moves (a turned B's footprint lands on another part of the lattice, which a refinement does not reach
    from a period away)."""
    from scipy.spatial import cKDTree

    pa = np.asarray(points_a, np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, np.float64).reshape(-1, 3)
    ij = np.asarray(pairs, np.int64).reshape(-1, 2)
    if len(ij) < 2 or len(pa) < 3 or not len(pb):
        return []
    tree = cKDTree(pa[:, :2])
    mine = pa[ij[:, 0], :2]
    centre = mine.mean(axis=0)
    probes = mine[np.argsort(np.linalg.norm(mine - centre, axis=1), kind="stable")[:LAYOUT_PROBES]]
    _, nb = tree.query(probes, k=min(LAYOUT_NEIGHBOURS + 1, len(pa)))
    vecs = (pa[np.asarray(nb).reshape(len(probes), -1), :2] - probes[:, None, :]).reshape(-1, 2)
    cells: dict[tuple[int, int], np.ndarray] = {}
    for v in vecs[np.linalg.norm(vecs, axis=1) > 0.5 * gate_m]:
        cells.setdefault((int(np.floor(v[0] / (2 * gate_m))), int(np.floor(v[1] / (2 * gate_m)))), v)
    moves = list(cells.values())
    placed = winner.apply(pb)[:, :2]
    probe_b = winner.apply(pb[ij[:, 1]])[:, :2]
    pivot = probes[0]
    Row = tuple[int, float, int, np.ndarray, float, np.ndarray]

    def rows(ang: float, vs: list[np.ndarray]) -> list[Row]:
        rot = yaw_matrix(np.radians(ang))[:2, :2]
        base, base_probe = (placed - pivot) @ rot.T + pivot, (probe_b - pivot) @ rot.T + pivot
        return [(_on_a(tree, base + v, gate_m), float(np.linalg.norm(v)), k, v, ang, base_probe + v)
                for k, v in enumerate(vs) if ang or np.linalg.norm(v) > 2.0 * gate_m]

    shifted = sorted(rows(0.0, moves), key=lambda r: (-r[0], r[1], r[2]))
    # the turns and their moves come from the best-landing moves only: a lattice's period vectors are among them,
    # and on a random layout (128 distinct moves, thousands of angles between them) the cost stays bounded
    top = [r[3] for r in shifted[:TURN_MOVES]]
    angles = list(QUARTER_TURNS_DEG)
    for i, vi in enumerate(top):
        for vj in top[i + 1:]:
            if abs(np.linalg.norm(vi) - np.linalg.norm(vj)) <= gate_m:
                angles.append(float(np.degrees(np.arctan2(vj[1], vj[0]) - np.arctan2(vi[1], vi[0]))) % 360.0)
    turns: list[float] = []
    for ang in angles:
        if min(ang, 360.0 - ang) >= TURN_MERGE_DEG and all(
                abs((ang - t + 180.0) % 360.0 - 180.0) >= TURN_MERGE_DEG for t in turns):
            turns.append(ang)
    turned = sorted((r for ang in turns for r in rows(ang, [np.zeros(2), *top])),
                    key=lambda r: (-r[0], r[1], min(r[4], 360.0 - r[4]), r[2]))
    out: list[LayoutStart] = []
    for ranked, limit in ((shifted, LAYOUT_SHIFTS), (turned, LAYOUT_TURNS)):
        kept: list[Row] = []
        for r in ranked:
            if len(kept) == limit:
                break
            if all(np.max(np.linalg.norm(r[5] - q[5], axis=1)) > 2.0 * gate_m for q in kept):
                kept.append(r)
        for landed, length, _, v, ang, _ in kept:
            turn = yaw_matrix(np.radians(ang))
            at = np.array([pivot[0], pivot[1], 0.0])
            move = np.array([v[0], v[1], 0.0])
            out.append(LayoutStart(Sim3(turn @ winner.rotation, turn @ (winner.translation - at) + at + move,
                                        winner.scale), length, float(ang if ang <= 180.0 else ang - 360.0), landed))
    return out
