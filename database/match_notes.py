"""What a consumer of a match says of it (`merge`, `changes`, `batch`, `match` itself): an imprecise or
unverified answer, georeferences that disagree with what the images say, and why no answer was accepted, in the
same words wherever it is said. Split from `database.match_io`, which reads and validates match.json.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from ..plugin.layout_rivals import LayoutRival
from ..plugin.multisession import PRECISE_GEOREFERENCE_FACTOR
from .landmark_map import LandmarkMap, georeference_offset_m
from .match_io import MatchSummary
from .session_io import SessionFiles, georeference_sigma_m


def imprecise_note(match: MatchSummary) -> str | None:
    """What a consumer of `match` (merge, changes) says when its accepted answer is imprecise (None when it is
    not): the transform may place B's landmarks farther from their true partners than the gate its pairs passed."""
    if not match.accepted or not match.imprecise:
        return None
    why = match.imprecise_reason or "few pairs, noisy against the gate, far from much of B"
    if match.gate_m is not None and match.predicted_max_m <= match.gate_m:  # its heights only (flipped)
        return f"the match's answer is imprecise: {why}"
    return (f"the match's answer is imprecise: its transform may place B's landmarks up to "
            f"{match.predicted_max_m:.1f} m from where they belong (95 %), beyond its {match.gate_m or 0:g} m gate "
            f"({why})")


def unverified_note(match: MatchSummary) -> str | None:
    """What a consumer of `match` (merge, changes) says when its answer was not verified on the full maps (None
    when it was): across seasons one window's consensus can be a chance alignment."""
    if match.source == "verified":
        return None
    return ("the match was not verified on the full maps (written by a sosmatch before the verification stage, or "
            "with --no-verify / verification.enabled = false)")


def georeference_note(match: MatchSummary, map_a: LandmarkMap | None = None,
                       map_b: LandmarkMap | None = None) -> str | None:
    """What `match` said of an accepted answer that moves B farther from its georeference than the radius it is
    trusted to: the images agree, the two maps' georeferences do not (`plugin.match_answer.
    georeference_disagreement`, the one rule, on what match.json records), for merge to refuse and batch to keep
    apart; None when they agree. A file that does not record the radius: the configured default. A file that
    does not record the offset (a sosmatch before it was measured across two EPSG codes, or at all): measured
    here from the two maps, when given (`landmark_map.georeference_offset_m`, as `match` measures it)."""
    from ..plugin.match_answer import georeference_disagreement  # (the search's modules: only when asked)
    from ..plugin.params import AssociationParams

    if not match.accepted:
        return None
    radius = match.georeference_radius_m
    off = match.georeference_off_m
    if off is None and map_a is not None and map_b is not None and match.transform is not None:
        off = georeference_offset_m(map_a, map_b, match.transform, match.associations)
    return georeference_disagreement(off, AssociationParams().georeference_prior_m if radius is None else radius,
                                     match.position_prior)


def check_georeferences(match: MatchSummary, map_a: LandmarkMap, map_b: LandmarkMap, match_json: str | Path,
                        trust_images: bool, done: str, doing: str) -> str | None:
    """The rule of `merge` and `changes` for an answer whose images agree and whose maps' georeferences do not
    (`georeference_note`): InputError naming `match_json` unless `trust_images` ("B: ...; nothing `done`
    (--trust-images `doing` all the same, in A's frame and georeference)"): which georeference stands, or whether
    the images do, is the user's call. Returns the note when trusted (for the caller's warning), else None."""
    note = georeference_note(match, map_a, map_b)
    if note is not None and not trust_images:
        raise InputError(f"B: {note}; nothing {done} (--trust-images {doing} all the same, in A's frame and "
                         "georeference)", match_json)
    return note


def no_match_text(best_support: int | None, runner_up: int, chance_p: float | None = None,
                  chance_mean: float | None = None, beyond_prior: bool = False, layout: str | None = None,
                  min_associations: int | None = None, tested_support: int | None = None,
                  row_placements: float | None = None, min_ratio: float | None = None) -> str:
    """What `sosmatch match` says of a verification that found no match: "verification: no match (the best
    candidate holds 13 associations, B placed elsewhere 13, chance p 1 (mean 12.3))"; `best_support` None: no
    candidate, because no window hypothesis held more than theta_S (`min_associations`, when known) associations.
    The runner-up is the best alignment that puts B elsewhere, chance placements included: it may hold more pairs
    than the best candidate ("best support 6, runner-up 8" read as a contradiction). `layout`: how the maps' own
    layout placed that runner-up ("B moved 20 m", `plugin.layout_rivals.LayoutRival.text`), said first: a site
    that repeats (trees on a grid) is why, not chance. `tested_support`: the support the ratio and chance tests
    compared (match.json `support_dof`, the `dof` fit's, before the winner's tilt refit), said beside the refit's
    when they differ: "holds 10 associations, B placed elsewhere 8, chance p 0.002" passes both documented tests
    on its face, and the ratio test refused 9 < 1.2 x 8 (nu44). `row_placements`: the chance test's placements laying
    a row of landmarks on a row (`plugin.row_placements`; match.json's `row_placements`), said when there were any:
    "chance p 1 (mean 0.8)" of 22 pairs reads as a contradiction when rows laid on rows are what reach them.
    `min_ratio`: the verification's ratio test (match.json `method.min_ratio`); when the tested support beats the
    runner-up by it, the layout did not refuse the candidate, so the refusal is not said to be the layout's."""
    if best_support is None:
        # said, not left bare: a user saw "no match" on maps of 3-6 landmarks and could not tell why (nu27)
        theta = "" if min_associations is None else f" = {min_associations}"
        return ("verification: no match (no candidate: no window hypothesis holds more than "
                f"theta_S{theta} associations)")
    rows = f"; {row_placements:.0f} placements laying rows on rows" if row_placements else ""
    chance = "" if chance_p is None else f", chance p {chance_p:.1g} (mean {chance_mean or 0:.1f}{rows})"
    prior = ", beyond the position prior" if beyond_prior else ""
    tested = (f" ({tested_support} as tested, before its tilt refit)"
              if tested_support is not None and tested_support != best_support else "")
    compared = best_support if tested_support is None else tested_support
    if min_ratio is not None and compared >= min_ratio * runner_up:
        # the ratio test passed: the chance test (or the prior) refused it. A tree line of 70 true pairs was said
        # to repeat at "40 pairs against 70" while rows laid on rows had made its chance p 1 (rev42)
        layout = None
    if layout and runner_up <= 2 * best_support:  # about as good: the site repeats itself
        return (f"verification: no match (the layout repeats: {layout} explains {runner_up} pairs against the best "
                f"candidate's {best_support}{tested}{chance}{prior})")
    if layout:  # far better: the search missed it (a wrong candidate on a sparse or repetitive site)
        return (f"verification: no match (the best candidate holds {best_support} associations{tested}, {layout} "
                f"{runner_up}: a placement the maps' layout offers, which the search missed{chance}{prior})")
    return (f"verification: no match (the best candidate holds {best_support} associations{tested}, B placed "
            f"elsewhere {runner_up}{chance}{prior})")


def refusal_note(doc: dict[str, Any], match: MatchSummary) -> str | None:
    """Why a match.json holds no accepted answer, in `match`'s words (`no_match_text` for a verified one), for a
    consumer's report (batch's `refused` column); None when it holds one. `doc`: the file as read
    (`read_match_json`), `match`: as parsed from it (`parse_match`)."""
    if match.accepted:
        return None
    ver = doc.get("verification")
    if match.source != "verified" or not isinstance(ver, dict):
        theta = "" if match.min_associations is None else f", no more than theta_S {match.min_associations}"
        return f"no match, not verified (its best candidate holds {len(match.associations)} associations{theta})"
    chance = ver.get("chance") if isinstance(ver.get("chance"), dict) else {}
    p, mean = chance.get("p_value"), chance.get("mean")
    numeric = all(isinstance(x, (int, float)) and math.isfinite(x) for x in (p, mean))
    # a verification without a best candidate records support 0 and no rms (`workflows.match.verification_json`)
    best = None if ver.get("rms_m") is None and not len(match.associations) else len(match.associations)
    tested = ver.get("support_dof")  # absent from files written before it was recorded
    rows = chance.get("row_placements")  # absent from files written before rows entered the chance test
    return no_match_text(best, match.runner_up_support or 0, p if numeric else None, mean if numeric else None,
                         bool(ver.get("beyond_prior", False)), _layout_text(ver.get("layout_rival")),
                         match.min_associations,
                         tested if isinstance(tested, int) and not isinstance(tested, bool) else None,
                         rows if isinstance(rows, (int, float)) and math.isfinite(rows) else None,
                         _number(ver.get("method"), "min_ratio"))


def _layout_text(rival: Any) -> str | None:
    """'B moved 20 m and turned 90 deg' from match.json's verification.layout_rival (None: absent or malformed;
    files written before it existed have none)."""
    if not isinstance(rival, dict):
        return None
    shift, turn = rival.get("shift_m"), rival.get("turn_deg")
    if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in (shift, turn)):
        return None
    return LayoutRival(0, float(shift), float(turn)).text()


def _number(table: Any, key: str) -> float | None:
    """table[key] when `table` is a dict and the value a finite number, else None (absent or malformed)."""
    value = table.get(key) if isinstance(table, dict) else None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else None


def precision_note(a: SessionFiles, b: SessionFiles, label_a: str, label_b: str) -> str | None:
    """What to say when B's georeference is much more precise than A's (`PRECISE_GEOREFERENCE_FACTOR`, measured
    GPS noise of each, `session_io.georeference_sigma_m`): the merged model is in A's frame and keeps A's (nu34: an
    RTK session merged into a 1.4 m GPS one, its landmarks 0.56 m off instead of 0.26, nothing said)."""
    if not (a.landmarks.epsg and b.landmarks.epsg):
        return None
    sa, sb = georeference_sigma_m(a.path), georeference_sigma_m(b.path)
    if sa is None or sb is None or sb * PRECISE_GEOREFERENCE_FACTOR > sa:
        return None
    return (f"{label_b}'s georeference is more precise (GPS noise {sb:.2f} m measured) than {label_a}'s "
            f"({sa:.2f} m): the merged model keeps {label_a}'s; match and merge with {label_b} as the first session "
            "to keep its georeference")
