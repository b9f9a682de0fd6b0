"""The answer of a match between two landmark maps: the windowed search, then its verification on the full maps.

One function computes it (`match_maps`), and every consumer reads it (through match.json and
`database.match_io.read_match`: merge, evaluate, batch, changes), so there is one notion of "the alignment":
- verification on (`verification.enabled`, the default): the search's hypotheses checked and refined on the full
  maps (`verification.verify_search`); the answer is the verified alignment, accepted or not;
- verification off (`match --no-verify`): the search's consensus of agreeing accepted window hypotheses.

Tolerances in two steps (`first_try`, ours): tolerances derived from the maps' noise allow for what changes
between sessions (season, growth), which two sessions of one season do not need; looser tolerances make many more
chance-consistent pairs, and past a density nothing is pruned any more (evaluation suite, summer vs summer: 0.26 s
-> 6.4 s of CPU, BENCHMARKS.md "Derived tolerances and search time"). So the search runs first with the tighter
tolerances (`map_noise.first_search_params`) and its hypotheses are verified on the full maps with the derived
ones (whose gate decides the associations of the answer); only when that verification refuses, the search runs
again with the derived tolerances. Maps whose derived windows were grown (`association.window_chance`: few
chance-consistent associations per transform) get a last search at the next doubled window when that one is
refused too (`wider_try`: a window that long detects a smaller fraction of repeating landmarks). `tolerances`
says which search gave the answer.

Maps georeferenced in one EPSG (ours, `association.georeference_prior_m`): one more search, with the derived
tolerances, only among landmarks within that distance of each other where the georeferences put them, verified
with the chance model of the alignments that near (`plugin.chance`: far fewer than over the whole maps, so a
smaller support is significant). The searches above still run: an answer they accept stands (it assumes nothing
about the georeference), and the one near the georeference is the answer only when they accept nothing and their
best candidate elsewhere holds fewer pairs (`reconcile_near`): a georeference wrong by more than the radius
leaves near it only partial alignments of a regular site, which can pass the chance test made for near ones.
A configured `position_prior_m` is a hard limit instead (every search within it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .answer_uncertainty import AnswerUncertainty, answer_uncertainty
from .association import SearchResult, Transform, kernel_cache, search, search_reference
from .chance import median_horizontal_move, transforms_agree
from .params import AssociationParams, Params
from .verification import Verification, verify_search


@dataclass
class MatchAnswer:
    search: SearchResult
    verification: Verification | None  # None: verification off
    accepted: bool
    transform: Transform | None  # A_from_B of the answer (x_A = s R x_B + t); None when there is none
    associations: np.ndarray  # (K, 2) landmark index pairs (A, B) supporting it
    source: str  # "verified" (the verification's alignment) or "consensus" (the search's, unverified)
    # how the position prior was used: "off", "applied", or why it was ignored; with the georeference prior
    # "georeference R m" (its search answered) or "georeference R m refused: searched everywhere"
    prior: str
    # the search's: "georeference" (near the georeference), "configured" (one search), "first" or "derived" (two
    # steps), "wider" (the last, wider windows)
    tolerances: str = "configured"
    # the association parameters of the search whose hypotheses `search` holds (the first of two searches keeps
    # the configured windows and theta_S: its hypotheses are judged at its own theta_S); None: params.association
    searched: AssociationParams | None = None
    # search_s, verify_s, total_s: wall time without the time spent compiling or loading numba kernels, which is
    # kernel_compile_s (minutes on the first match of an install: not the search's; `kernel_cache.search_clock`)
    timings: dict[str, float] = field(default_factory=dict)
    # maps in one frame with an accepted answer: how far it moves B from where B's georeference puts it (m,
    # horizontal, the median over B's paired landmarks: `chance.median_horizontal_move`); None otherwise. Beyond
    # GPS-level error the two maps' georeferences disagree (a datum, an origin), whichever search answered
    georeference_off_m: float | None = None
    # an accepted answer: its transform's predicted placement error at B's landmarks against its gate
    # (`answer_uncertainty`; `imprecise` when it exceeds the gate); None otherwise
    uncertainty: AnswerUncertainty | None = None


def match_maps(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
               params: Params, common_frame: bool = False, exhaustive: bool = False,
               verify: bool | None = None, first_try: AssociationParams | None = None,
               wider_try: AssociationParams | None = None, near_try: AssociationParams | None = None) -> MatchAnswer:
    """Search the two maps and verify the result (see the module docstring).

    common_frame: the two maps are expressed in one world frame (both georeferenced in one EPSG), the condition
    of the position prior and of the search near the georeference; when False (the default: the caller must know)
    a prior in `params` is ignored (and `prior` says so). exhaustive: the
    straightforward reference search (same hypotheses, slow). verify: overrides `params.verification.enabled`.
    first_try: tighter association parameters for a first search whose hypotheses are verified with
    `params.association` (module doc); used only with the verification on; None: one search. wider_try: the
    association parameters of a last search when the verification refuses `params.association`'s (module doc);
    used only with the verification on. near_try: the association parameters of the search near the
    georeference (its theta_S from the chance model within the prior, `DerivedSearch.near_try`); None:
    `params.association`'s.
    """
    compiling = kernel_cache.announce_compile()  # a fresh install compiles the kernels first (minutes): say so
    answer = _match_maps(points_a, sizes_a, points_b, sizes_b, params, common_frame, exhaustive, verify, first_try,
                         wider_try, near_try)
    if compiling:  # the next process starts without the notice
        kernel_cache.mark_compiled()
    return answer


def _match_maps(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
                params: Params, common_frame: bool = False, exhaustive: bool = False,
                verify: bool | None = None, first_try: AssociationParams | None = None,
                wider_try: AssociationParams | None = None, near_try: AssociationParams | None = None) -> MatchAnswer:
    """`match_maps` after its compile notice."""
    t0, k0 = kernel_cache.search_clock(), kernel_cache.kernel_seconds()
    prior = "off"
    if params.association.position_prior_m > 0:
        prior = "applied" if common_frame else "ignored: the maps are not georeferenced in one EPSG"
    verify = params.verification.enabled if verify is None else verify
    near = georeference_prior_m(params.association, common_frame, verify)

    def usable(ap: AssociationParams) -> AssociationParams:
        return ap if common_frame else dataclasses.replace(ap, position_prior_m=0.0)

    ap = usable(params.association)
    fn = search_reference if exhaustive else search
    clock = {"search_s": 0.0, "verify_s": 0.0}

    def timed(stage: str, f: Callable[..., Any], *args: Any) -> Any:
        t = kernel_cache.search_clock()
        out = f(*args)
        clock[stage] += kernel_cache.search_clock() - t
        return out

    def run(step: AssociationParams) -> tuple[SearchResult, Verification | None]:
        """One search and, with the verification on, its verification with the derived gate and the chance model
        of the alignments this search could find (within its position prior, if any)."""
        res = timed("search_s", fn, points_a, sizes_a, points_b, sizes_b, step)
        gate = dataclasses.replace(ap, position_prior_m=step.position_prior_m)
        return res, (timed("verify_s", verify_search, points_a, sizes_a, points_b, sizes_b, res.hypotheses, gate,
                           params.verification) if verify else None)

    # near the georeference first (module doc), with the derived tolerances and its own theta_S
    near_search = None
    if near > 0:
        near_params = dataclasses.replace(near_try or params.association, position_prior_m=near)
        near_search = (near_params, *run(near_params))
    # the searches in order, each verified with the derived gate (`ap`) until one is accepted (module doc): the
    # first and the wider one only with the verification on, which is what decides whether the next one runs
    steps = [("first", first_try)] if verify and first_try is not None else []
    steps.append(("derived" if steps else "configured", params.association))
    if verify and wider_try is not None:
        steps.append(("wider", wider_try))
    for label, step in steps:
        tolerances, searched = label, usable(step)  # of the last search that ran: the one whose answer this is
        res, ver = run(searched)
        if ver is None or ver.accepted:
            break
    if near_search is not None:
        near_params, near_res, near_ver = near_search
        prior, use_near = reconcile_near(near, near_ver, ver, points_b, ap.distance_tolerance_m)
        if use_near:
            tolerances, searched, res, ver = "georeference", near_params, near_res, near_ver
    if verify:
        best = ver.best
        transform = None if best is None else Transform(best.transform.rotation, best.transform.translation,
                                                         best.transform.scale)
        assoc = np.zeros((0, 2), np.int64) if best is None else best.associations
        answer = MatchAnswer(res, ver, bool(ver.accepted), transform, assoc, "verified", prior, tolerances, searched)
    elif res.consensus is not None:
        answer = MatchAnswer(res, None, res.consensus.accepted, res.consensus.transform, res.consensus.associations,
                             "consensus", prior, searched=ap)
    else:
        answer = MatchAnswer(res, None, False, None, np.zeros((0, 2), np.int64), "consensus", prior, searched=ap)
    answer.timings = {**clock, "total_s": kernel_cache.search_clock() - t0,
                      "kernel_compile_s": kernel_cache.kernel_seconds() - k0}
    if common_frame and answer.accepted and answer.transform is not None and len(answer.associations):
        paired_b = np.asarray(points_b, np.float64)[np.asarray(answer.associations, np.int64)[:, 1]]
        answer.georeference_off_m = median_horizontal_move(answer.transform, paired_b)
    if answer.accepted and answer.transform is not None:
        # the gate the answer's associations passed: the verification's derived one, or the consensus' own search's
        gate = (ap if answer.source == "verified" else answer.searched or ap).distance_tolerance_m
        answer.uncertainty = answer_uncertainty(points_a, points_b, answer.transform, answer.associations, gate)
    return answer


def georeference_disagreement(off_m: float | None, radius_m: float | None, prior: str | None = None) -> str | None:
    """What is said when an accepted alignment of two georeferenced maps puts B's paired landmarks `off_m`
    horizontally from where B's georeference does (`MatchAnswer.georeference_off_m`, or across two EPSG codes
    `database.landmark_map.georeference_offset_m`; match.json `search_mode.georeference_off_m`) farther than the
    radius the georeference is trusted to (`association.georeference_prior_m`, the radius of the search near it
    and of `chance.within_prior`; GPS puts a camera within metres): the images agree (the answer was found over
    every placement of B, or near the georeference and confirmed there), the georeferences do not, so one of them
    is wrong, and a merge or a GIS layer of either inherits that (`merge` refuses it without --trust-images,
    `batch` keeps the two flights apart). None: they agree, or there is no such figure or radius. The one rule of
    `match`, `merge` and `batch`; the text says "it" for B, whom the caller names; `prior` is how the search used
    the georeference (`MatchAnswer.prior`; "off": not said)."""
    if off_m is None or radius_m is None or not radius_m > 0 or not off_m > radius_m:
        return None
    how = f"; {prior}" if prior and prior != "off" else ""
    return (f"images agree, georeferences disagree by {ground_distance_text(off_m)}: one georeference is wrong (the "
            f"answer puts it that far from where its own does, beyond the {radius_m:g} m one is trusted to{how}; a "
            "datum, an origin, a UTM zone or hemisphere?)")


def ground_distance_text(metres: float) -> str:
    """'428 m', or '16,684 km' from 10 km on."""
    return f"{metres:.0f} m" if metres < 10_000 else f"{metres / 1000:,.0f} km"


def reconcile_near(radius_m: float, near: Verification, everywhere: Verification, points_b: np.ndarray,
                   gate_m: float) -> tuple[str, bool]:
    """The answer of two verified searches, one near the georeference and one everywhere (module doc): (what
    `MatchAnswer.prior` says, whether the answer is the search near the georeference's).

    The search everywhere needs no assumption about the georeference, so its accepted answer stands. The search
    near it is answered only when the search everywhere accepted nothing, and its best candidate elsewhere holds
    fewer pairs: a georeference wrong by more than the radius leaves near it only a partial alignment (rows of a
    site one spacing apart; world 241 with B's georeference 80 m off: 32 pairs 53 m from the truth, p 6e-4 among
    the alignments near it), which the true alignment's support elsewhere (91 pairs) shows to be none."""
    head = f"georeference {radius_m:g} m"
    if near.best is None or not near.accepted:
        return f"{head}: refused there", False
    pairs = np.asarray(near.best.associations, np.int64).reshape(-1, 2)
    probe = np.asarray(points_b, np.float64)[pairs[:, 1]] if len(pairs) else np.asarray(points_b, np.float64)
    other = everywhere.best
    agree = other is not None and transforms_agree(near.best.transform, other.transform, probe, 2.0 * gate_m)
    if everywhere.accepted:
        if agree:
            return f"{head}: the same answer as everywhere", False
        # how far it moves B is the answer's `georeference_off_m` (one computation, named by `match`'s warning)
        return f"{head}: overruled by the alignment found everywhere", False
    if other is not None and not agree and len(other.associations) >= len(pairs):
        return (f"{head}: not answered, an alignment elsewhere holds as many pairs ({len(other.associations)} "
                f"against {len(pairs)})"), False
    return f"{head}: answered there, nothing accepted everywhere", True


def georeference_prior_m(params: AssociationParams, common_frame: bool, verify: bool) -> float:
    """The radius of the first search near the maps' georeference (`association.georeference_prior_m`, module doc),
    0 when there is none: maps not in one frame, a (hard) position prior configured, or the verification off."""
    if not common_frame or not verify or params.position_prior_m > 0:
        return 0.0
    return float(params.georeference_prior_m)
