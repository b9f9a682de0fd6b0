"""Associate two landmark maps (`sosmatch match A B --out DIR`): the windowed CLIPPER search of SOS-Match,
then its verification on the full maps.

`run(params, a, b, out_dir)` loads both maps (session directory, .sosmap file or COLMAP model; see
`sosmatch.database.map_loading`), computes the match's answer (`sosmatch.plugin.match_answer.match_maps`: the
search, then, unless `verify` is off, the verification of its hypotheses on the full maps) and writes, atomically:
    match.json          every solved window pair (hypothesis), the best accepted one, the consensus, the
                        verification, which search mode ran, timings (schema in README.md, "Matching maps")
    associations.csv    the answer's associations (the verified alignment's, or the consensus'), else none
    match.png           both maps in A's frame (B moved by the answer's transform), associations drawn, the best
                        hypothesis highlighted
Transforms map B into A's frame: x_A = scale * R @ x_B + t, in the maps' world coordinates.

Modules: result (MatchResult and the printed summary), record (match.json and associations.csv as documents),
figure (match.png), answer_warnings (what is said about an accepted answer), workflow (`run`).
"""

from .answer_warnings import MAX_DATUM_DIFFERENCE_M
from .figure import alignment_png
from .record import (
    associations_csv,
    hypothesis_to_json,
    match_to_json,
    search_mode_json,
    transform_to_json,
    verification_json,
)
from .result import MatchResult
from .workflow import run

__all__ = ["MAX_DATUM_DIFFERENCE_M", "MatchResult", "alignment_png", "associations_csv", "hypothesis_to_json",
           "match_to_json", "run", "search_mode_json", "transform_to_json", "verification_json"]
