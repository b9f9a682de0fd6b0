"""Verification of a match on the full maps: the search's window hypotheses refined on every landmark the two maps
share (`plugin.refinement`), the best supported alignment chosen and accepted only when it clearly beats what
chance alignments of these maps reach (pure numpy; a stage of `plugin.match_answer.match_maps`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from .association.rigid import tilt_deg
from .chance import (
    ChanceModel,
    chance_pairs,
    chance_supports,
    chance_test,
    converged_to_winner,
    placed_map_is_a,
    sequential_chance,
    transforms_agree,
    within_prior,
)
from .layout_rivals import LayoutRival, layout_starts
from .multisession import Sim3
from .refinement import (
    Alignment,
    mutual_nearest,
    pairing_distance,
    pairing_tree,
    refine_alignment,
    tilt_of,
    yaw_matrix,
)
from .row_placements import row_chance, with_rows


@dataclass(frozen=True)
class Verification:
    """The outcome of `verify_alignments`: the best-supported refined alignment and how clearly it won."""

    best: Alignment | None  # None when no candidate could be refined
    runner_up_support: int  # support of the best alignment that disagrees with `best` (0 if none)
    num_refined: int  # candidates refined (the others agreed with an alignment already refined)
    accepted: bool  # support > theta_S and `clear`
    support: int = 0  # the winner's support in the `dof` search (the figure the tests compare)
    clear: bool = False  # it beats every rival by min_ratio and chance (p_value <= false_alarm)
    chance: ChanceModel | None = None  # None: no winner, or the chance test off (chance_starts 0)
    tilt_p: float | None = None  # the F test of a tilt in the winner's pairs (`tilt_significance`; None: not run)
    # with a position prior: the winner lies beyond it (`chance.within_prior`), where its chance test does not
    # reach, so it is not accepted
    beyond_prior: bool = False
    # the best rival the maps' own layout offered (`plugin.layout_rivals`) when it is the runner-up and beyond
    # chance: B moved by a displacement that repeats in A's layout or turned by one of its symmetries (None: another
    # rival is, or chance reaches it)
    layout_rival: LayoutRival | None = None
    # the answer is the free 6-DOF fit because the maps are tilted against each other (`maps_tilted`): the angle
    # between their vertical axes, deg (None: the level fit, as for gravity-aligned maps)
    tilted_deg: float | None = None


class _NearTried:
    """Which candidates (transform, indices of its B landmarks) agree with a transform tried before them
    (`transforms_agree` at gate_m on their own B landmarks), all later candidates at once for each tried
    transform. The batched products round differently from one candidate's own, so a candidate within
    AGREE_MARGIN of the gate is decided by `transforms_agree` itself: the same decisions as testing every
    candidate against every tried transform."""

    def __init__(self, candidates: Sequence[tuple[Any, np.ndarray]], points_b: np.ndarray, gate_m: float) -> None:
        idx = [np.asarray(i, dtype=np.int64).reshape(-1) for _, i in candidates]
        self.candidates, self.points_b, self.gate_m = candidates, points_b, gate_m
        self.done = np.zeros(len(candidates), bool)
        n = np.array([len(i) for i in idx], np.int64)
        self.start = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
        self.empty = n == 0  # no landmarks to compare: never agrees (`transforms_agree`)
        self.probe = points_b[np.concatenate(idx)] if len(idx) else np.zeros((0, 3))
        self.owner = owner = np.repeat(np.arange(len(candidates)), n)
        if len(candidates):
            rot = np.stack([t.scale * t.rotation for t, _ in candidates])
            tr = np.stack([t.translation for t, _ in candidates])
            self.own = np.einsum("nij,nj->ni", rot[owner], self.probe) + tr[owner]
        else:
            self.own = np.zeros((0, 3))
        scale = float(np.abs(self.own).max(initial=0.0)) + float(np.abs(self.probe).max(initial=0.0))
        self.margin = AGREE_MARGIN * (1.0 + scale)

    def tried(self, c: int, transform: Sim3) -> None:
        """Mark the candidates after c that agree with `transform`."""
        later = np.flatnonzero(~self.done[c + 1:] & ~self.empty[c + 1:]) + c + 1
        if not len(later):
            return
        pick = np.zeros(len(self.done), bool)
        pick[later] = True
        rows = np.flatnonzero(pick[self.owner])
        moved = transform.scale * self.probe[rows] @ transform.rotation.T + transform.translation
        dist = np.sqrt(np.sum((self.own[rows] - moved) ** 2, axis=1))
        bounds = np.concatenate([[0], np.cumsum(np.diff(self.start)[later])[:-1]]).astype(np.int64)
        worst = np.maximum.reduceat(dist, bounds)
        self.done[later[worst <= self.gate_m - self.margin]] = True
        for k in later[np.abs(worst - self.gate_m) <= self.margin]:  # too close to call: the exact test
            t, i = self.candidates[k]
            own = self.points_b[np.asarray(i, dtype=np.int64).reshape(-1)]
            self.done[k] = transforms_agree(t, transform, own, self.gate_m)


AGREE_MARGIN = 1e-9  # relative to the coordinates' magnitude: far above the rounding of a 3 x 3 product


def verify_alignments(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    candidates: Sequence[tuple[Any, np.ndarray]], gate_m: float, max_size_difference: float,
    min_support: int, min_ratio: float = 1.2, dof: int = 4, z_weight: float = 0.5, final_dof: int | None = 6,
    chance_starts: int = 512, false_alarm: float = 1e-2, prior_m: float = 0.0, coarse_factor: float = 2.0,
    tilt_prior_deg: float = 1.0, with_scale: bool = False,
) -> Verification:
    """Choose among a pair's window hypotheses by their support on the FULL maps, and refine the winner.

    One window pair sees 50 x 50 landmarks; across seasons a true hypothesis there has |S| ~ 5-9, and so do
    chance-consistent wrong ones, so |S| cannot tell them apart. Over the full maps it can: a correct transform
    brings many more landmarks of B onto landmarks of A than a wrong one. Every candidate (transform: a `Sim3`,
    or any object with its rotation, translation and scale; (K,) indices of its B landmarks), largest first, is
    refined by `refine_alignment` unless it already agrees with a candidate tried before or its refined result
    (its B landmarks land within gate_m of where that one puts them). The alignment with
    the most mutual-nearest-neighbour support wins; it is accepted when that support exceeds
    `min_support` and is at least `min_ratio` times the support of the best rival (an alignment that moves some
    of the winner's supporting B landmarks more than 2 gate_m away from where the winner puts them: the search's
    other candidates, and B deliberately displaced and turned (`_displaced_starts`), refined like the winner).
    `final_dof` 6: the winner's transform is finally tilted by what its supporting pairs' heights show, shrunk
    towards level by a Gaussian prior of `tilt_prior_deg` per axis (`tilted_fit`), and its support is the mutual
    nearest neighbours under that transform. The 4-DOF search finds the pairs robustly; with tens to hundreds of
    pairs over the whole overlap the small tilt between two EKF frames (~1 deg on the synthetic winter flights)
    is then observable, which one window's 8-20 inliers could not resolve, and the landmarks that the tilt kept
    out of the 4-DOF pairs join; with few or noisy heights the prior keeps the maps near level (a free 6-DOF
    refit fitted the EKF frames' local distortion: 1.5 deg of tilt between maps that agree within 0.4 deg).
    None: keep the `dof` fit. `tilt_significance` (the F test of a tilt in those heights) is reported. Maps tilted
    against each other beyond what the prior lets through (`maps_tilted`: the test sees the tilt and the free 6-DOF
    refit pairs clearly more landmarks) get that free fit as the answer (`Verification.tilted_deg`), and the rivals
    and chance below judge it, with its freedom, as `with_scale` does for a scale.
    Chance (`sequential_chance`, `chance_test`): up to `chance_starts` refinements from random placements of B over A
    (the map of the smaller footprint over the other, `chance.placed_map_is_a`; within `prior_m` of where it is
    when both maps share one frame, 0: anywhere) measure the support chance
    reaches; the winner must be improbable as the best of the N_eff alignments the search had
    (`effective_trials`): p_value <= `false_alarm`. Those chance alignments are rivals too. 0 starts: no chance
    test (the ratio alone, as before).
    The candidates and the displaced rivals are refined coarse to fine (`refine_alignment`'s `coarse_factor`, 2:
    first at 2 gates, the distance below which `converged_to_winner` calls two alignments one), so each settles
    in the best alignment of its neighbourhood, not in the first local optimum a fragment offers. The chance
    placements are not: the null hypothesis is the best of N_eff chance alignments, one per cell of 2 gates
    (`effective_trials`), and a one-gate refinement from a random placement is what one cell offers (its
    capture radius is half a cell). A coarse first stage would make each sample the best of ~8 cells while
    N_eff still counts cells (chance means 1.4 -> 3.0-3.7 on world 97's crossing flights). Polishing the winner
    selects among alignments the null already counts, so it keeps the test valid.
    `with_scale` (`association.transform` "similarity"): every refinement here, the winner's, its rivals' and the
    chance placements', fits a scale too (`refine_alignment`'s `dof` 5 / 7), so the answer is the similarity its
    pairs show (a rigid refit dropped the search's scale: nu49, B scaled by 1.10 was placed 15 m off with the
    window consensus' 0.909 at hand) and chance is judged with the same freedom.
    """
    fit_dof = dof + 1 if with_scale else dof  # `refine_alignment`: 5 / 7 add the scale to 4 / 6
    pb_all = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    pa_all = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    tree_a = pairing_tree(pa_all, z_weight)  # every refinement below pairs B, placed somewhere, with this A
    refined: list[Alignment] = []
    # the starting transforms and where they converged: a later candidate near either is done
    near_tried = _NearTried(candidates, pb_all, gate_m)
    for c, (transform, _) in enumerate(candidates):
        if near_tried.done[c]:
            continue
        start = transform if isinstance(transform, Sim3) else Sim3(transform.rotation, transform.translation,
                                                                   transform.scale)
        refined.append(refine_alignment(pa_all, sizes_a, pb_all, sizes_b, start, gate_m,
                                        max_size_difference, dof=fit_dof, z_weight=z_weight, tree_a=tree_a,
                                        coarse_factor=coarse_factor))
        near_tried.tried(c, start)
        near_tried.tried(c, refined[-1].transform)
    if not refined:
        return Verification(None, 0, 0, False)
    order = sorted(range(len(refined)), key=lambda k: (-len(refined[k].associations), refined[k].rms_m, k))
    best = refined[order[0]]
    probe = pb_all[best.associations[:, 1]]
    # A rival puts B somewhere else: more than 2 gates away. Refinements that converged within that distance
    # are the same alignment caught on a slightly different set of chance pairs (seen across seasons: 2-3 m
    # apart with |support| within 1), i.e. its uncertainty, not a contradiction.
    support = len(best.associations)
    rigid, winner_pairs, tilt_p, tilted_deg = None, None, None, None
    if final_dof == 6 and dof != 6 and support >= 3:
        tilt_p = tilt_significance(pa_all, pb_all, best)
        rigid = tilted_alignment(pa_all, sizes_a, pb_all, sizes_b, best, gate_m, max_size_difference,
                                 tilt_prior_deg, z_weight, tree_a)
        # the rigid alignment the winner belongs to, over the whole overlap: its pairs judge which other
        # refinements found the winner again; the answer keeps the fit above unless the maps are tilted
        free = refine_alignment(pa_all, sizes_a, pb_all, sizes_b, rigid.transform, gate_m, max_size_difference,
                                dof=7 if with_scale else 6, z_weight=z_weight, tree_a=tree_a)
        winner_pairs = free.associations
        if maps_tilted(tilt_p, free, rigid, min_ratio, false_alarm):
            # the maps' vertical axes differ (frames not both gravity-aligned): the level fit with its 1 deg prior
            # kept only the pairs near the centroid (rev42: roll 18 deg, 34 of 140 pairs, 15.9 m off at the far
            # end). The answer is the free fit, and the rivals and chance below judge it, with its freedom.
            best, rigid, fit_dof = free, None, 7 if with_scale else 6
            support, probe = len(best.associations), pb_all[best.associations[:, 1]]
            tilted_deg = tilt_deg(best.transform.rotation)
    # A rival counts the pairs the winner does not explain (`chance_pairs`), as the chance placements and the
    # displaced controls below do: a candidate refined to the edge of the winner's basin (turned a few degrees
    # about the winner's pairs) holds many of them and is no evidence that B lies elsewhere (a held-out world's
    # summer vs winter at 130 m: the true winner, 27 pairs, refused by the ratio test against 26 of a 3.4 deg turn
    # of it, 21 of whose pairs the winner puts within 2 gates)
    rivals = [chance_pairs(pa_all, pb_all, best.transform, refined[k].associations, gate_m) for k in order[1:]
              if not converged_to_winner(best.transform, probe, gate_m, winner_pairs, refined[k])]
    # The rivals the search offered are not enough: with one candidate there is none, and a chance alignment of
    # two unrelated maps then won by default (3 of 8 pairs of different synthetic worlds were "verified" with
    # 8-15 pairs). B deliberately put elsewhere and refined like the winner is the chance level at this map
    # density and these gates: the winner must beat it by min_ratio too.
    displaced = _displaced_starts(best.transform, pb_all, gate_m)
    rivals.extend(int(s) for s in chance_supports(pa_all, sizes_a, pb_all, sizes_b, best.transform, probe, gate_m,
                                                  max_size_difference, displaced, fit_dof, z_weight,
                                                  winner_pairs=winner_pairs, tree_a=tree_a,
                                                  coarse_factor=coarse_factor))
    # the placements the layout itself offers: on a grid, B a period further or a quarter turn round explains
    # about as many pairs as the winner, and the controls above do not aim there (a plantation's maps were verified
    # 40 m = two periods off, 25 pairs against a runner-up of 1)
    layout_best = None
    for start in layout_starts(best.transform, pa_all, pb_all, best.associations, gate_m):
        got = chance_supports(pa_all, sizes_a, pb_all, sizes_b, best.transform, probe, gate_m, max_size_difference,
                              [start.transform], fit_dof, z_weight, winner_pairs=winner_pairs, tree_a=tree_a,
                              coarse_factor=coarse_factor)
        if len(got) and (layout_best is None or int(got[0]) > layout_best.support):
            layout_best = LayoutRival(int(got[0]), start.shift_m, start.turn_deg)
    if layout_best is not None:
        rivals.append(layout_best.support)
    chance = None
    if chance_starts > 0:
        # chance places B level (random yaw and position); a tilted answer's chance is that of B in the answer's
        # tilt, so B is judged turned by it (its transform then level): placed level, the chance refinements, local,
        # never reached a 10-20 deg tilt and more freedom counted as less chance (rev43: two unrelated rows, B
        # rolled 14 deg, p 1.7e-75 where the level pair's is 1.0)
        chance_b, chance_probe, chance_winner = pb_all, probe, best.transform
        if tilted_deg is not None:
            tilt = tilt_of(best.transform.rotation)
            chance_b, chance_probe = pb_all @ tilt.T, probe @ tilt.T
            chance_winner = Sim3(best.transform.rotation @ tilt.T, best.transform.translation, best.transform.scale)
        chance, samples, opportunities = winner_chance(
            pa_all, sizes_a, chance_b, sizes_b, chance_winner, chance_probe, support, gate_m, max_size_difference,
            chance_starts, false_alarm, prior_m, fit_dof, z_weight, winner_pairs=winner_pairs, tree_a=tree_a)
        rivals.extend(int(s) for s in samples)
    runner_up = max(rivals, default=0)
    if rigid is not None:
        best = rigid
    clear = bool(support >= min_ratio * runner_up and (chance is None or chance.p_value <= false_alarm))
    pairs = np.asarray(best.associations, np.int64).reshape(-1, 2)
    beyond = not within_prior(best.transform, pb_all[pairs[:, 1]], prior_m, gate_m)
    # named as the layout's repeat only when the winner is not clear, the repeat is the runner-up and it is more
    # than chance reaches, judged as the winner is, with the placements' opportunities (on a random layout the
    # layout's starts are chance placements like the others, and a real pair refused at 17 against 17 is refused
    # by chance, not by a repeat; a clear winner refused beyond the position prior was said to "repeat": rev21)
    layout_rival = None
    if layout_best is not None and not clear and layout_best.support >= max(runner_up, 1) and (
            chance is None
            or chance_test(samples, layout_best.support, chance.trials, opportunities).p_value <= false_alarm):
        layout_rival = layout_best
    return Verification(best, runner_up, len(refined), bool(support > min_support and clear and not beyond),
                        support, clear, chance, tilt_p, beyond, layout_rival, tilted_deg)


def maps_tilted(tilt_p: float, free: Alignment, level: Alignment, min_ratio: float, false_alarm: float) -> bool:
    """Whether the verification's answer is the free (6-DOF) refit rather than the level fit tilted within its prior
    (`tilted_alignment`): the level fit's heights show a tilt (`tilt_significance` p <= `false_alarm`) and the free
    fit pairs clearly more landmarks (at least `min_ratio` times as many, the verification's own "clearly beats").
    Evidence, as the scale's refit is kept only with more pairs: two gravity-aligned maps (EKF frames within 1-2 deg)
    pair about as many either way and keep the level fit; maps whose frames are tilted 10-22 deg against each other
    (SLAM / VIO local frames, a COLMAP model not registered to gravity) lose most pairs to the level fit. Near 10 deg
    the level fit still pairs nearly all (rev42: 139 of 140) but places the far ones beyond the gate (2.4 m): a free
    fit at least as well supported whose tilt is beyond any two gravity-aligned frames' (`FREE_TILT_DEG`) is taken
    too."""
    if tilt_p > false_alarm:
        return False
    n_free, n_level = len(free.associations), len(level.associations)
    return bool(n_free >= min_ratio * max(n_level, 1)
                or (n_free >= n_level and tilt_deg(free.transform.rotation) >= FREE_TILT_DEG))


# a relative tilt no two gravity-aligned maps show: EKF frames differ by 0.2-1.4 deg on the synthetic worlds, and a
# free refit of such maps found at most 1.5 deg (`tilted_fit`); 6 x the default tilt prior
FREE_TILT_DEG = 6.0


def winner_chance(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
                  winner: Sim3, probe: np.ndarray, support: int, gate_m: float, max_size_difference: float,
                  starts: int, false_alarm: float, prior_m: float = 0.0, dof: int = 4, z_weight: float = 0.5,
                  winner_pairs: np.ndarray | None = None,
                  tree_a: Any = None) -> tuple[ChanceModel, np.ndarray, np.ndarray]:
    """The chance test of a winner: `chance.sequential_chance`'s uniform placements, then rows of landmarks laid on
    rows (tree-lined field edges: placements the uniform samples do not reach, `plugin.row_placements`; nothing
    changes for maps without rows). Rows only raise p (`row_placements.with_rows`), so a winner the uniform
    placements already refuse is not judged on them (their work, seconds on an orchard, is saved). Returns the model
    and the uniform samples and opportunities, as `sequential_chance` (the benchmarks time this, the verification's
    whole chance test). Which map the chance samples place (`chance.placed_map_is_a`) is decided here, once, and
    both parts take it."""
    a_is_placed = placed_map_is_a(points_a, points_b)
    chance, samples, opportunities = sequential_chance(
        points_a, sizes_a, points_b, sizes_b, winner, probe, support, gate_m, max_size_difference, starts,
        false_alarm, prior_m, dof, z_weight, winner_pairs=winner_pairs, tree_a=tree_a, a_is_placed=a_is_placed)
    if chance.p_value <= false_alarm:
        chance = with_rows(chance, row_chance(points_a, sizes_a, points_b, sizes_b, winner, support, gate_m,
                                              max_size_difference, z_weight, samples, opportunities, chance,
                                              prior_m, a_is_placed=a_is_placed))
    return chance, samples, opportunities


CONTROL_SHIFT_GATES = 3.0  # the displaced controls: B moved this many gates (beyond any landmark scatter)
CONTROL_YAWS_DEG = (-10.0, 10.0, 180.0)  # and B turned about its centre (a flight's lines, its reverse)


def _displaced_starts(transform: Sim3, points_b: np.ndarray, gate_m: float) -> list[Sim3]:
    """The winner's transform with B moved CONTROL_SHIFT_GATES gates in 6 horizontal directions and turned by
    CONTROL_YAWS_DEG about B's centre (in A's frame): starts of alignments that put B elsewhere."""
    starts = []
    for k in range(6):
        ang = k * np.pi / 3.0
        shift = CONTROL_SHIFT_GATES * gate_m * np.array([np.cos(ang), np.sin(ang), 0.0])
        starts.append(Sim3(transform.rotation, transform.translation + shift, transform.scale))
    centre = transform.apply(points_b).mean(axis=0) if len(points_b) else np.zeros(3)
    for yaw in CONTROL_YAWS_DEG:
        turn = yaw_matrix(np.radians(yaw))
        starts.append(Sim3(turn @ transform.rotation, turn @ (transform.translation - centre) + centre,
                           transform.scale))
    return starts


def hypothesis_agrees(associations: np.ndarray, transform: Any, points_a: np.ndarray, points_b: np.ndarray,
                      tolerance_m: float) -> bool:
    """A window hypothesis agrees with an alignment when most of its associations fit it: the median distance
    between an associated A landmark and its B partner moved by the alignment is within `tolerance_m` (2
    theta_eps in match.json and the evaluation). Such a hypothesis is part of the verified answer: its
    associations, never its own transform (fitted on its 7-10 associations it can be metres off the verified
    one, which is fitted on all of them)."""
    assoc = np.asarray(associations, dtype=np.int64).reshape(-1, 2)
    if not len(assoc):
        return False
    moved = transform.apply(np.asarray(points_b, np.float64)[assoc[:, 1]])
    return bool(np.median(np.linalg.norm(moved - np.asarray(points_a, np.float64)[assoc[:, 0]], axis=1))
                <= tolerance_m)


def verification_candidates(hypotheses: Sequence[Any], max_gravity_angle_deg: float,
                            max_candidates: int = 400) -> list[tuple[Any, np.ndarray]]:
    """The candidates `verify_alignments` takes from a search's window hypotheses (objects with `size`,
    `transform` (rotation, translation, scale; None when degenerate), `tilt_deg`, `associations`): those that
    pass the gravity check, largest |S| first (stable), at most `max_candidates` (bounds the work on dense
    same-season maps), each as (a_from_b, indices of its B landmarks); a_from_b is the hypothesis's own transform
    (`verify_alignments` makes a `Sim3` of the few it refines, not of every candidate)."""
    usable = [h for h in hypotheses if h.transform is not None and h.tilt_deg <= max_gravity_angle_deg]
    usable.sort(key=lambda h: -h.size)
    return [(h.transform, np.asarray(h.associations, dtype=np.int64).reshape(-1, 2)[:, 1])
            for h in usable[:max_candidates]]


class _HeightTilt(NamedTuple):
    """The height residuals of an alignment's pairs regressed on the horizontal position (`_height_regression`)."""

    centre: np.ndarray  # (3,) centroid of B's placed landmarks: the regression's origin
    design: np.ndarray  # (n, 3) x, y about the centre, 1
    dz: np.ndarray  # (n,) height residuals: B's landmark placed by the alignment minus its partner in A
    coef: np.ndarray  # (3,) slope in x, slope in y, offset
    inverse: np.ndarray | None  # (design^T design)^-1; None when the pairs are collinear


def _height_regression(pa: np.ndarray, pb: np.ndarray, aligned: Alignment) -> _HeightTilt:
    """One regression for `tilt_significance` (its F test) and `tilted_fit` (its slopes and covariance)."""
    assoc = aligned.associations
    placed = aligned.transform.apply(pb[assoc[:, 1]])
    dz = placed[:, 2] - pa[assoc[:, 0], 2]
    centre = placed.mean(axis=0)
    design = np.column_stack([placed[:, :2] - centre[:2], np.ones(len(assoc))])
    coef, *_ = np.linalg.lstsq(design, dz, rcond=None)
    try:
        inverse = np.linalg.inv(design.T @ design)
    except np.linalg.LinAlgError:
        inverse = None
    return _HeightTilt(centre, design, dz, coef, inverse)


def tilt_significance(pa: np.ndarray, pb: np.ndarray, aligned: Alignment) -> float:
    """p of the F test that the pairs of a gravity-aligned (4-DOF) alignment show a tilt: their height residuals
    (B's landmark placed by the alignment minus its partner in A) regressed on the horizontal position, F(2, n-3)
    on the two slopes against the residuals' own scatter. Only heights carry a small tilt (1 deg is 1.7 m of height
    100 m away and millimetres horizontally), so horizontal noise, which is smaller, does not enter. 1 when there
    is nothing to test (fewer than 5 pairs, or no scatter left)."""
    from scipy.stats import f as f_dist

    n = len(aligned.associations)
    if n < 5:
        return 1.0
    h = _height_regression(pa, pb, aligned)
    rss_full = float(np.sum((h.dz - h.design @ h.coef) ** 2))
    rss_level = float(np.sum((h.dz - h.dz.mean()) ** 2))
    if rss_full <= 0.0:
        return 0.0 if rss_level > 0.0 else 1.0
    return float(f_dist.sf(((rss_level - rss_full) / 2.0) / (rss_full / (n - 3)), 2, n - 3))


def tilted_fit(pa: np.ndarray, pb: np.ndarray, aligned: Alignment, prior_deg: float, z_weight: float) -> Alignment:
    """A gravity-aligned (4-DOF) alignment tilted by what its pairs' heights show, shrunk towards level by a prior:
    the height residuals regressed on the horizontal position (as `tilt_significance`) give the two slopes and
    their covariance; a zero-mean Gaussian prior of `prior_deg` per axis on the relative tilt of two gravity-aligned
    maps (EKF frames differ by 0.2-1.4 deg on the synthetic worlds) weighs them (the posterior mean). Few or noisy
    heights then leave the maps level instead of fitting the frames' local distortion; many pairs over a wide
    overlap measure the tilt. The tilt turns B about the pairs' centroid. Fewer than 5 pairs, or no prior: as is."""
    assoc = aligned.associations
    n = len(assoc)
    if n < 5 or prior_deg <= 0.0:
        return aligned
    h = _height_regression(pa, pb, aligned)
    if h.inverse is None:
        return aligned
    scatter = float(np.sum((h.dz - h.design @ h.coef) ** 2)) / (n - 3)
    slopes = h.coef[:2]
    if scatter > 0.0:
        prior_precision = np.eye(2) / np.tan(np.radians(prior_deg)) ** 2
        data_precision = np.linalg.inv(scatter * h.inverse[:2, :2])
        slopes = np.linalg.solve(data_precision + prior_precision, data_precision @ slopes)
    # heights fall by slope . (x, y) after turning B by -slope_y about x and +slope_x about y
    tx, ty = -float(np.arctan(slopes[1])), float(np.arctan(slopes[0]))
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tx), -np.sin(tx)], [0.0, np.sin(tx), np.cos(tx)]])
    ry = np.array([[np.cos(ty), 0.0, np.sin(ty)], [0.0, 1.0, 0.0], [-np.sin(ty), 0.0, np.cos(ty)]])
    turn = rx @ ry
    transform = Sim3(turn, h.centre - turn @ h.centre, 1.0).compose(aligned.transform)
    res = pairing_distance(transform.apply(pb[assoc[:, 1]]), pa[assoc[:, 0]], z_weight)
    return Alignment(transform, assoc, float(np.sqrt(np.mean(res**2))), aligned.iterations)


def tilted_alignment(pa: np.ndarray, sizes_a: np.ndarray | None, pb: np.ndarray, sizes_b: np.ndarray | None,
                     aligned: Alignment, gate_m: float, max_size_difference: float, prior_deg: float,
                     z_weight: float, tree_a: Any = None) -> Alignment:
    """The last stage of the verification's fit (`verify_alignments`' `final_dof` 6) of a gravity-aligned (4-DOF)
    alignment on the full maps: tilted by its pairs' heights (`tilted_fit`, shrunk towards level by `prior_deg`),
    then its support the mutual nearest neighbours under that transform (`mutual_nearest`), when they are at
    least as many: landmarks the 4-DOF fit could not reach because the frames are tilted (1-2 deg between EKF
    frames is metres of height at the far end of a map) join it. Also `merge --refine`'s for an unverified
    answer (`workflows.merge_refine.refined_answer`): one refinement of an alignment on the full maps."""
    first = tilted_fit(pa, pb, aligned, prior_deg, z_weight)
    assoc, dist = mutual_nearest(pa, sizes_a, first.transform.apply(pb), sizes_b, gate_m, max_size_difference,
                                 z_weight, tree_a)
    if len(assoc) >= len(first.associations):
        return Alignment(first.transform, assoc, float(np.sqrt(np.mean(dist**2))), first.iterations)
    return first


def verify_search(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                  sizes_b: np.ndarray | None, hypotheses: Sequence, association: object,
                  verification: object) -> Verification:
    """The verified answer of a windowed search: its hypotheses checked and refined on the full maps.

    `hypotheses`: the search's `WindowHypothesis` list; every one with a transform that passes the gravity check
    is a candidate, largest |S| first (at most `verification.max_candidates`), and `verify_alignments` chooses
    among them with the search's theta_eps, the verification's size gate and support > theta_S, fitting a scale when
    `association.transform` is "similarity". `association`, `verification`: `AssociationParams`,
    `VerificationParams`.
    """
    sims = verification_candidates(hypotheses, association.max_gravity_angle_deg, verification.max_candidates)
    return verify_alignments(np.asarray(points_a, np.float64), sizes_a, np.asarray(points_b, np.float64), sizes_b,
                             sims, association.distance_tolerance_m, verification.max_size_difference,
                             association.min_associations, min_ratio=verification.min_ratio, dof=verification.dof,
                             z_weight=verification.z_weight, final_dof=verification.final_dof or None,
                             chance_starts=verification.chance_starts, false_alarm=verification.false_alarm,
                             prior_m=association.position_prior_m, coarse_factor=verification.coarse_factor,
                             tilt_prior_deg=verification.tilt_prior_deg,
                             with_scale=association.transform == "similarity")
