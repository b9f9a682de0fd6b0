"""Verification of a match on the full maps: the search's window hypotheses refined on every landmark the two maps
share (`plugin.refinement`), the best supported alignment chosen and accepted only when it clearly beats what
chance alignments of these maps reach (pure numpy; a stage of `plugin.match_answer.match_maps`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .multisession import Sim3
from .refinement import Alignment, huber_weights, mutual_nearest, refine_alignment, weighted_umeyama


@dataclass(frozen=True)
class Verification:
    """The outcome of `verify_alignments`: the best-supported refined alignment and how clearly it won."""

    best: Alignment | None  # None when no candidate could be refined
    runner_up_support: int  # support of the best alignment that disagrees with `best` (0 if none)
    num_refined: int  # candidates refined (the others agreed with an alignment already refined)
    accepted: bool


def _agree(t1: Sim3, t2: Sim3, points: np.ndarray, tolerance_m: float) -> bool:
    return bool(len(points) and np.max(np.linalg.norm(t1.apply(points) - t2.apply(points), axis=1)) <= tolerance_m)


def verify_alignments(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    candidates: Sequence[tuple[Sim3, np.ndarray]], gate_m: float, max_size_difference: float,
    min_support: int, min_ratio: float = 1.2, dof: int = 4, z_weight: float = 0.5, final_dof: int | None = 6,
) -> Verification:
    """Choose among a pair's window hypotheses by their support on the FULL maps, and refine the winner.

    One window pair sees 50 x 50 landmarks; across seasons a true hypothesis there has |S| ~ 5-9, and so do
    chance-consistent wrong ones, so |S| cannot tell them apart. Over the full maps it can: a correct transform
    brings many more landmarks of B onto landmarks of A than a wrong one. Every candidate (transform, (K,)
    indices of its B landmarks), largest first, is refined by `refine_alignment` unless it already agrees with
    a candidate tried before or its refined result (its B landmarks land within gate_m of where that one puts
    them). The
    alignment with the most mutual-nearest-neighbour support wins; it is accepted when that support exceeds
    `min_support` and is at least `min_ratio` times the support of the best rival (an alignment that moves some
    of the winner's supporting B landmarks more than 2 gate_m away from where the winner puts them: the search's
    other candidates, and B deliberately displaced and turned (`_displaced_starts`), refined like the winner).
    `final_dof` 6: the winner's transform is finally refitted rigidly (6-DOF, Huber-weighted) on its supporting
    pairs, and its support is the mutual nearest neighbours under that transform. The 4-DOF search finds the
    pairs robustly; with tens to hundreds of pairs over the whole overlap the small tilt between two EKF frames
    (~1 deg on the synthetic winter flights) is then observable, which one window's 8-20 inliers could not
    resolve, and the landmarks that the tilt kept out of the 4-DOF pairs join. None: keep the `dof` fit.
    """
    pb_all = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    refined: list[Alignment] = []
    tried: list[Sim3] = []  # the starting transforms and where they converged: a candidate near either is done
    for transform, idx_b in candidates:
        probe = pb_all[np.asarray(idx_b, dtype=np.int64).reshape(-1)]
        if any(_agree(transform, t, probe, gate_m) for t in tried):
            continue
        tried.append(transform)
        refined.append(refine_alignment(points_a, sizes_a, points_b, sizes_b, transform, gate_m,
                                        max_size_difference, dof=dof, z_weight=z_weight))
        tried.append(refined[-1].transform)
    if not refined:
        return Verification(None, 0, 0, False)
    order = sorted(range(len(refined)), key=lambda k: (-len(refined[k].associations), refined[k].rms_m, k))
    best = refined[order[0]]
    probe = pb_all[best.associations[:, 1]]
    # A rival puts B somewhere else: more than 2 gates away. Refinements that converged within that distance
    # are the same alignment caught on a slightly different set of chance pairs (seen across seasons: 2-3 m
    # apart with |support| within 1), i.e. its uncertainty, not a contradiction.
    rivals = [len(refined[k].associations) for k in order[1:]
              if not _agree(best.transform, refined[k].transform, probe, 2.0 * gate_m)]
    # The rivals the search offered are not enough: with one candidate there is none, and a chance alignment of
    # two unrelated maps then won by default (3 of 8 pairs of different synthetic worlds were "verified" with
    # 8-15 pairs). B deliberately put elsewhere and refined like the winner is the chance level at this map
    # density and these gates: the winner must beat it by min_ratio too.
    pa_all = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    for start in _displaced_starts(best.transform, pb_all, gate_m):
        control = refine_alignment(pa_all, sizes_a, pb_all, sizes_b, start, gate_m, max_size_difference, dof=dof,
                                   z_weight=z_weight)
        if not _agree(best.transform, control.transform, probe, 2.0 * gate_m):
            rivals.append(len(control.associations))
    runner_up = max(rivals, default=0)
    support = len(best.associations)
    if final_dof == 6 and dof != 6 and support >= 3:
        first = _final_rigid_fit(pa_all, pb_all, best, gate_m, z_weight)
        # then the pairs under that transform: landmarks the 4-DOF fit could not reach because the frames are
        # tilted (1-2 deg between EKF frames is metres of height at the far end of a map) join its support
        assoc, dist = mutual_nearest(pa_all, sizes_a, first.transform.apply(pb_all), sizes_b, gate_m,
                                     max_size_difference, z_weight)
        best = first
        if len(assoc) >= len(first.associations):
            best = Alignment(first.transform, assoc, float(np.sqrt(np.mean(dist**2))), first.iterations)
    accepted = support > min_support and support >= min_ratio * runner_up
    return Verification(best, runner_up, len(refined), accepted)


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
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        starts.append(Sim3(turn @ transform.rotation, turn @ (transform.translation - centre) + centre,
                           transform.scale))
    return starts


def verification_candidates(hypotheses: Sequence[Any], max_gravity_angle_deg: float,
                            max_candidates: int = 400) -> list[tuple[Sim3, np.ndarray]]:
    """The candidates `verify_alignments` takes from a search's window hypotheses (objects with `size`,
    `transform` (rotation, translation, scale; None when degenerate), `tilt_deg`, `associations`): those that
    pass the gravity check, largest |S| first (stable), at most `max_candidates` (bounds the work on dense
    same-season maps), each as (a_from_b, indices of its B landmarks)."""
    usable = [h for h in hypotheses if h.transform is not None and h.tilt_deg <= max_gravity_angle_deg]
    usable.sort(key=lambda h: -h.size)
    return [(Sim3(h.transform.rotation, h.transform.translation, h.transform.scale),
             np.asarray(h.associations, dtype=np.int64).reshape(-1, 2)[:, 1]) for h in usable[:max_candidates]]


def _final_rigid_fit(pa: np.ndarray, pb: np.ndarray, aligned: Alignment, gate_m: float, z_weight: float) -> Alignment:
    """One Huber-weighted 6-DOF fit on an alignment's supporting pairs (kept as they are)."""
    assoc = aligned.associations
    src, dst = pb[assoc[:, 1]], pa[assoc[:, 0]]
    scale = np.array([1.0, 1.0, z_weight])  # the distance `mutual_nearest` pairs by
    w = huber_weights(np.linalg.norm((aligned.transform.apply(src) - dst) * scale, axis=1), gate_m)
    try:
        rigid = weighted_umeyama(src, dst, w, with_scale=False)
    except ValueError:
        return aligned
    res = np.linalg.norm((rigid.apply(src) - dst) * scale, axis=1)
    return Alignment(rigid, assoc, float(np.sqrt(np.mean(res**2))), aligned.iterations)


def verify_search(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                  sizes_b: np.ndarray | None, hypotheses: Sequence, association: object,
                  verification: object) -> Verification:
    """The verified answer of a windowed search: its hypotheses checked and refined on the full maps.

    `hypotheses`: the search's `WindowHypothesis` list; every one with a transform that passes the gravity check
    is a candidate, largest |S| first (at most `verification.max_candidates`), and `verify_alignments` chooses
    among them with the search's theta_eps, the verification's size gate and support > theta_S. `association`,
    `verification`: `AssociationParams`, `VerificationParams`.
    """
    sims = verification_candidates(hypotheses, association.max_gravity_angle_deg, verification.max_candidates)
    return verify_alignments(np.asarray(points_a, np.float64), sizes_a, np.asarray(points_b, np.float64), sizes_b,
                             sims, association.distance_tolerance_m, verification.max_size_difference,
                             association.min_associations, min_ratio=verification.min_ratio, dof=verification.dof,
                             z_weight=verification.z_weight, final_dof=verification.final_dof or None)
