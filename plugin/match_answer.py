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

Maps georeferenced in one EPSG (ours, `association.georeference_prior_m`): before those searches, one search with
the derived tolerances only among landmarks within that distance of each other where the georeferences put them,
verified with the chance model of the alignments that near (`plugin.chance`: far fewer than over the whole maps,
so a smaller support is significant, and the search is local, so it is fast whatever the maps' size). Only its
refusal runs the searches above, which look everywhere: a georeference that is wrong by more than the radius
costs one search, never the answer. A configured `position_prior_m` is a hard limit instead (every search within it).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .association import SearchResult, Transform, kernel_cache, search, search_reference
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
    timings: dict[str, float] = field(default_factory=dict)  # search_s, verify_s, total_s (wall)


def match_maps(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
               params: Params, common_frame: bool = False, exhaustive: bool = False,
               verify: bool | None = None, first_try: AssociationParams | None = None,
               wider_try: AssociationParams | None = None) -> MatchAnswer:
    """Search the two maps and verify the result (see the module docstring).

    common_frame: the two maps are expressed in one world frame (both georeferenced in one EPSG), the condition
    of the position prior and of the search near the georeference; when False (the default: the caller must know)
    a prior in `params` is ignored (and `prior` says so). exhaustive: the
    straightforward reference search (same hypotheses, slow). verify: overrides `params.verification.enabled`.
    first_try: tighter association parameters for a first search whose hypotheses are verified with
    `params.association` (module doc); used only with the verification on; None: one search. wider_try: the
    association parameters of a last search when the verification refuses `params.association`'s (module doc);
    used only with the verification on.
    """
    compiling = kernel_cache.announce_compile()  # a fresh install compiles the kernels first (minutes): say so
    t0 = time.perf_counter()
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
        t = time.perf_counter()
        out = f(*args)
        clock[stage] += time.perf_counter() - t
        return out

    # the searches in order, each verified with the derived gate (`ap`) until one is accepted (module doc): the
    # first and the wider one only with the verification on, which is what decides whether the next one runs
    steps = [("first", first_try)] if verify and first_try is not None else []
    steps.append(("derived" if steps else "configured", params.association))
    if verify and wider_try is not None:
        steps.append(("wider", wider_try))
    if near > 0:  # first near the georeference, with the derived tolerances (module doc)
        steps.insert(0, ("georeference", dataclasses.replace(params.association, position_prior_m=near)))
    for label, step in steps:
        tolerances, searched = label, usable(step)  # of the last search that ran: the one whose answer this is
        res = timed("search_s", fn, points_a, sizes_a, points_b, sizes_b, searched)
        # verified with the derived gate and the chance model of the alignments this search could find
        gate = dataclasses.replace(ap, position_prior_m=searched.position_prior_m)
        ver = timed("verify_s", verify_search, points_a, sizes_a, points_b, sizes_b, res.hypotheses, gate,
                    params.verification) if verify else None
        if ver is None or ver.accepted:
            break
    if near > 0:
        prior = (f"georeference {near:g} m" if tolerances == "georeference" else
                 f"georeference {near:g} m refused: searched everywhere")
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
    answer.timings = {**clock, "total_s": time.perf_counter() - t0}
    if compiling:
        kernel_cache.mark_compiled()
    return answer


def georeference_prior_m(params: AssociationParams, common_frame: bool, verify: bool) -> float:
    """The radius of the first search near the maps' georeference (`association.georeference_prior_m`, module doc),
    0 when there is none: maps not in one frame, a (hard) position prior configured, or the verification off."""
    if not common_frame or not verify or params.position_prior_m > 0:
        return 0.0
    return float(params.georeference_prior_m)
