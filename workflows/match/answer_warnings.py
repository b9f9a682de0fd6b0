"""The warnings `sosmatch match` gives about an accepted answer: georeference, tilt and height datums."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.errors import InputError
from ...plugin.match_answer import georeference_disagreement

# Ellipsoidal and sea-level heights differ by the geoid's undulation, at most ~106 m anywhere on Earth: two
# georeferenced maps whose heights differ by more are not on one height datum (heights above take-off, feet)
MAX_DATUM_DIFFERENCE_M = 110.0


def _georeference_warning(ans: Any, path_b: str | Path, radius_m: float) -> str | None:
    """The warning when the answer moves B farther from its georeference than `radius_m`
    (`match_answer.georeference_disagreement`, the rule merge and batch repeat from match.json), else None."""
    if (said := georeference_disagreement(ans.georeference_off_m, radius_m, ans.prior)) is not None:
        return f"{path_b}: {said}"
    return None


def _tilt_warning(ans: Any, a: str | Path, b: str | Path) -> str | None:
    """The warning when an accepted answer is the verification's free 6-DOF fit because the maps are tilted against
    each other (`verification.maps_tilted`): a level fit would have lost most pairs. None otherwise."""
    v = ans.verification
    if not ans.accepted or v is None or v.tilted_deg is None:
        return None
    return (f"{b}: the maps' vertical axes differ by {v.tilted_deg:.1f} deg (not both gravity-aligned?): the answer "
            f"is the free 6-DOF fit ({v.support} pairs; a level fit kept far fewer); {a} and {b} are not in one "
            "gravity-aligned frame")


def _height_datum_warning(ans: Any, points_b: np.ndarray, path_b: str | Path) -> str | None:
    """The warning when an accepted alignment of two maps in one EPSG moves B's landmarks vertically by more than
    two height datums can differ (MAX_DATUM_DIFFERENCE_M): the search and the prior are horizontal, so it still
    finds the alignment, but the maps' heights are not comparable. None: within that."""
    pairs = np.asarray(ans.associations, np.int64).reshape(-1, 2)
    if not len(pairs) or ans.transform is None:
        return None
    pb = np.asarray(points_b, np.float64)[pairs[:, 1]]
    dz = float(np.median(ans.transform.apply(pb)[:, 2] - pb[:, 2]))
    if abs(dz) > MAX_DATUM_DIFFERENCE_M:
        return (f"{path_b}: its landmarks lie {abs(dz):.0f} m {'below' if dz > 0 else 'above'} those of A under the "
                "answer, more than ellipsoidal and sea-level heights differ anywhere: the two maps' altitudes are not "
                "on one datum (heights above take-off, or in feet?)")
    return None


def _takeoff_height_warning(ans: Any, points_b: np.ndarray, a: str | Path, b: str | Path) -> str | None:
    """The warning when an accepted answer moves B vertically while a map's ground lies far from where its
    recorded heights above take-off put it (run.json "height_above_takeoff", `map.recorded_height`): a focal
    length off scales that map's heights, and the vertical move carries the error (nu42: B moved 102.6 m by a
    map 100 m low, within two height datums' difference, so `_height_datum_warning` was silent). None otherwise."""
    from ...database.session_io import read_map_record
    from ..map.recorded_height import ground_off_beyond

    pairs = np.asarray(ans.associations, np.int64).reshape(-1, 2)
    if not len(pairs) or ans.transform is None:
        return None
    off = []
    for path in (a, b):
        try:
            record = read_map_record(path) if Path(path).is_dir() else None
        except InputError:
            record = None
        if (ground := ground_off_beyond((record or {}).get("height_above_takeoff"))) is not None:
            off.append(f"{path}'s ground lies {abs(ground):.0f} m {'above' if ground > 0 else 'below'}")
    if not off:
        return None
    pb = np.asarray(points_b, np.float64)[pairs[:, 1]]
    dz = float(np.median(ans.transform.apply(pb)[:, 2] - pb[:, 2]))
    return (f"the answer moves B {dz:+.1f} m vertically, and {' and '.join(off)} where its recorded heights above "
            "take-off put it (its map's warning: ground that far from the take-off point's, or a focal length off): if "
            "the focal length, the vertical part of this answer, and heights compared across these maps, inherit that "
            "error")
