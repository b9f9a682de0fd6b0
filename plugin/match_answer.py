"""The answer of a match between two landmark maps: the windowed search, then its verification on the full maps.

One function computes it (`match_maps`), and every consumer reads it (through match.json and
`database.match_io.read_match`: merge, evaluate, batch, changes), so there is one notion of "the alignment":
- verification on (`verification.enabled`, the default): the search's hypotheses checked and refined on the full
  maps (`multisession.verify_search`); the answer is the verified alignment, accepted or not;
- verification off (`match --no-verify`): the search's consensus of agreeing accepted window hypotheses.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .association import SearchResult, Transform, search, search_reference
from .multisession import Verification, verify_search
from .params import Params


@dataclass
class MatchAnswer:
    search: SearchResult
    verification: Verification | None  # None: verification off
    accepted: bool
    transform: Transform | None  # A_from_B of the answer (x_A = s R x_B + t); None when there is none
    associations: np.ndarray  # (K, 2) landmark index pairs (A, B) supporting it
    source: str  # "verified" (the verification's alignment) or "consensus" (the search's, unverified)
    prior: str  # how the position prior was used: "off", "applied", or why it was ignored
    timings: dict[str, float] = field(default_factory=dict)  # search_s, verify_s, total_s (wall)


def match_maps(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
               params: Params, common_frame: bool = True, exhaustive: bool = False,
               verify: bool | None = None) -> MatchAnswer:
    """Search the two maps and verify the result (see the module docstring).

    common_frame: the two maps are expressed in one world frame (both georeferenced in one EPSG), the condition
    of the position prior; when False a prior in `params` is ignored (and `prior` says so). exhaustive: the
    straightforward reference search (same hypotheses, slow). verify: overrides `params.verification.enabled`.
    """
    t0 = time.perf_counter()
    ap = params.association
    prior = "off"
    if ap.position_prior_m > 0:
        prior = "applied" if common_frame else "ignored: the maps are not georeferenced in one EPSG"
        if not common_frame:
            ap = dataclasses.replace(ap, position_prior_m=0.0)
    fn = search_reference if exhaustive else search
    res = fn(points_a, sizes_a, points_b, sizes_b, ap)
    t1 = time.perf_counter()
    verify = params.verification.enabled if verify is None else verify
    ver = None
    if verify:
        ver = verify_search(points_a, sizes_a, points_b, sizes_b, res.hypotheses, ap, params.verification)
        best = ver.best
        transform = None if best is None else Transform(best.transform.rotation, best.transform.translation,
                                                         best.transform.scale)
        assoc = np.zeros((0, 2), np.int64) if best is None else best.associations
        answer = MatchAnswer(res, ver, bool(ver.accepted), transform, assoc, "verified", prior)
    elif res.consensus is not None:
        answer = MatchAnswer(res, None, True, res.consensus.transform, res.consensus.associations, "consensus", prior)
    else:
        answer = MatchAnswer(res, None, False, None, np.zeros((0, 2), np.int64), "consensus", prior)
    t2 = time.perf_counter()
    answer.timings = {"search_s": t1 - t0, "verify_s": t2 - t1, "total_s": t2 - t0}
    return answer
