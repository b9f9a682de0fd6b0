"""`merge --refine` and `batch --refine`: a match's unverified answer refined on the full maps as the match's
verification refines its winner (`refined_answer`), and the pairs a merge then fuses under the refined transform
(`Refinement.fuse`). Split from `workflows.merge` (which re-exports `Refinement` and `refined_answer`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..database.landmark_map import LandmarkMap
from ..database.match_io import MatchSummary, answer_gate
from ..plugin.multisession import Sim3
from ..plugin.params import Params
from ..plugin.refinement import Alignment, mutual_nearest, refine_alignment, tilt_of
from ..plugin.verification import tilted_alignment
from .merge_pairs import FusePair, match_fuse_pair


@dataclass(frozen=True)
class Refinement:
    """An answer's transform refined on the full maps (`refined_answer`)."""

    transform: Sim3  # a_from_b: the refined one, or the answer's own when it was kept
    used: int  # the mutual nearest neighbours that support the refined transform (0: the answer's kept)
    dof: int  # 4: yaw + translation (then tilted by the pairs' heights), 6: rigid / similarity, 0: not refitted
    note: str | None = None  # why the answer's own transform was kept
    # what a merge fuses under the refined transform (None: the answer's kept, its own associations are fused): the
    # pairs it supports, by the pairing the refinement and the verification use (`mutual_nearest`, at the gate,
    # size gate and height weight the refinement ran with); rev45 D1: the consensus' pairs re-judged against it
    # fused 11 where the refinement found 27, and left 6 pairs of one object twice in the model
    fuse: FusePair | None = None

    def record(self) -> dict[str, Any]:
        """What the fit used, as batch records it (the pair's `refine`, merge.json's `refine` of a batch's group):
        the supporting pairs, the degrees of freedom, and why the answer was kept, if it was."""
        return {"associations_used": self.used, "dof": self.dof, **({"kept": self.note} if self.note else {})}


def refined_answer(a: LandmarkMap, b: LandmarkMap, match: MatchSummary, params: Params) -> Refinement:
    """`merge --refine` and `batch --refine`: the match's answer a_from_b refined on every landmark the two maps
    share, by the match's own recorded settings. One answer for both (rev33: batch refitted once on the window
    associations at the configured 2 m, merge refined at another size gate, and batch's changes used neither).

    A verified answer is kept as it is: it is already the verification's fit on the full maps, and refitting it
    with other settings only made it worse (rev33: merge refitted it yaw-only, dropping its tilt, at the default
    size gate 0.2: 126 instead of 138 pairs, landmarks 2.03 -> 2.51 m from the truth). An unverified answer (the
    window consensus, `match --no-verify`) is refined as the verification refines its winner: at the answer's gate
    (`answer_gate`), with match.json's recorded verification settings (`MatchSummary.refinement`: size gate,
    dof, the final tilt and its prior, z_weight, coarse factor; the configured `params.verification` for any it
    does not record): `refinement.refine_alignment`, then for a 4-DOF fit `verification.tilted_alignment`; a
    similarity match a 6-DOF fit with scale. A 4-DOF fit runs from the answer levelled (as the verification's) and
    from B turned by the answer's tilt (`tilt_of`), each then tilted by what its pairs' heights show against the
    recorded prior of level maps; the one with more pairs stands. Fewer than 3 supporting pairs: the answer's own
    transform, kept."""
    if match.transform is None:
        raise ValueError("the match has no transform to refine")
    if match.source == "verified":
        return Refinement(match.transform, 0, 0, "the verified answer is already refined on the full maps (the "
                          "match's verification): --refine keeps it as it is")
    vp = dataclasses.replace(params.verification, **match.refinement)
    gate = answer_gate(match, params.association.distance_tolerance_m)
    with_scale = match.transform_kind == "similarity"
    dof = 6 if with_scale else vp.dof
    # the 4-DOF fit from the answer levelled (the verification's way) and from B turned by the answer's own tilt:
    # levelled, the fit paired fewer the farther the maps are tilted (rev33's A and B turned 3 / 8 / 15 deg about
    # x: 130 / 99 / 53 pairs against 132 held), held, it kept a tilt the window consensus had fitted wrongly (rev33's
    # B and C: consensus 2.8 deg, verified 0.8 deg; held 2.0 deg, 125 pairs, C's landmarks 2.3 m from the truth;
    # levelled 0.8 deg, 127 pairs, 1.6 m). The one with more pairs, as `refine_alignment`'s two stages (ties: level)
    helds = [np.eye(3)] + ([tilt_of(match.transform.rotation)] if dof == 4 else [])
    fits = [_fit(a, b, match.transform, held, gate, vp, dof, with_scale) for held in helds]
    best = max(fits, key=lambda f: len(f.associations))
    if len(best.associations) < 3:
        return Refinement(match.transform, 0, 0, f"the refinement found {len(best.associations)} supporting pairs: "
                          "the answer's transform is kept")
    # the pairs under the transform that stands (the tilted fit's may have kept the pairs of its level start)
    pairs, _ = mutual_nearest(a.positions, a.sizes, best.transform.apply(b.positions), b.sizes, gate,
                              vp.max_size_difference, vp.z_weight)
    return Refinement(best.transform, len(best.associations), dof, fuse=FusePair(0, 1, pairs, gate, vp.z_weight))


def _fit(a: LandmarkMap, b: LandmarkMap, start: Sim3, held: np.ndarray, gate: float, vp: Any, dof: int,
         with_scale: bool) -> Alignment:
    """One refinement of `refined_answer`: `refine_alignment` of B turned by `held` (3x3) from `start`, then, for
    a 4-DOF fit with the final tilt on, the tilt its pairs' heights show against the prior of level maps, from its
    level version (`_level`: the verification's `tilted_alignment`). a_from_b in B's own frame."""
    t = Sim3(start.rotation @ held.T, start.translation, start.scale)
    aligned = refine_alignment(a.positions, a.sizes, b.positions @ held.T, b.sizes, t, gate, vp.max_size_difference,
                               dof=dof, with_scale=with_scale, z_weight=vp.z_weight, coarse_factor=vp.coarse_factor)
    t, pairs = aligned.transform, aligned.associations
    refined = Sim3(t.rotation @ held, t.translation, t.scale)
    if dof != 4 or vp.final_dof != 6 or len(pairs) < 3:
        return Alignment(refined, pairs, aligned.rms_m, aligned.iterations)
    level = _level(refined, b.positions[pairs[:, 1]].mean(axis=0))
    return tilted_alignment(a.positions, a.sizes, b.positions, b.sizes,
                            Alignment(level, pairs, aligned.rms_m, aligned.iterations), gate, vp.max_size_difference,
                            vp.tilt_prior_deg, vp.z_weight)


def _level(transform: Sim3, centre: np.ndarray) -> Sim3:
    """`transform` without its roll and pitch (its yaw, `tilt_of`), placing `centre` (B's frame) where it does."""
    turn = transform.rotation @ tilt_of(transform.rotation).T
    return Sim3(turn, transform.apply(centre) - transform.scale * turn @ centre, transform.scale)


def fused_pair(a: int, b: int, match: MatchSummary, refinement: Refinement | None) -> FusePair:
    """What sessions a and b fuse, for `merge` and `batch` alike: under a refinement that found its own pairs
    (`Refinement.fuse`, the pairs its refined transform supports) those, else the match's answer
    (`match_fuse_pair`; a refinement that kept the answer, `Refinement.note`, has none)."""
    if refinement is None or refinement.fuse is None:
        return match_fuse_pair(a, b, match)
    return refinement.fuse._replace(a=a, b=b)
