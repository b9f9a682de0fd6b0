"""Reading the association result (match.json, written by `sosmatch match`) for merge and batch.

Only `read_match` knows the file's layout, so a schema change is one edit here. What merge and batch need is
the accepted hypothesis: its landmark associations (index in A, index in B) and its transform a_from_b
(x_A = s R x_B + t).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..plugin.errors import InputError
from ..plugin.multisession import Sim3
from .text_input import read_user_text


@dataclass
class MatchSummary:
    """The hypothesis of a match.json that merging uses, and whether it was accepted."""

    accepted: bool
    transform: Sim3 | None  # a_from_b; None when no hypothesis exists
    associations: np.ndarray  # (K,2) int64 landmark index pairs (A, B) of the chosen hypothesis
    transform_kind: str = "rigid"
    num_hypotheses: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


def _sim3(data: Any, path: Path) -> Sim3:
    try:
        rot = np.asarray(data["rotation"], dtype=np.float64)
        if rot.shape == (4,):  # quaternion (w, x, y, z)
            from ..plugin.geometry import quat_to_rotmat

            rot = quat_to_rotmat(rot)
        t = np.asarray(data["translation"], dtype=np.float64).reshape(3)
        scale = float(data.get("scale", 1.0))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"transform needs rotation (3x3), translation (3) and scale: {exc}", path) from None
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) or not np.all(np.isfinite(t)) or not scale > 0:
        raise InputError("transform is not a finite 3x3 rotation, 3-vector translation and positive scale", path)
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
        raise InputError("transform rotation is not a rotation matrix", path)
    return Sim3(rot, t, scale)


def _associations(data: Any, path: Path) -> np.ndarray:
    try:
        arr = np.asarray(data if data is not None else [], dtype=np.int64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise InputError("associations must be a list of [index_a, index_b] integer pairs", path) from None
    if np.any(arr < 0):
        raise InputError("associations hold negative landmark indices", path)
    return arr


def read_match_json(path: str | Path) -> dict[str, Any]:
    """The parsed match.json (a directory means its match.json); InputError if unreadable or not an object."""
    path = Path(path)
    if path.is_dir():
        path = path / "match.json"
    text = read_user_text(path, "match file")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"cannot read match file: {exc}", path) from None
    if not isinstance(data, dict):
        raise InputError("match file must hold a JSON object", path)
    return data


def read_match(path: str | Path) -> MatchSummary:
    """Read match.json and return the hypothesis to merge with.

    That is the consensus (the transform refitted on the associations of every accepted window pair that
    agrees with the best one; written only when a hypothesis was accepted), else the best accepted hypothesis,
    else the largest one (then `accepted` is False).
    """
    path = Path(path)
    data = read_match_json(path)
    hyps = data.get("hypotheses") or []
    if not isinstance(hyps, list) or not all(isinstance(h, dict) for h in hyps):
        raise InputError("'hypotheses' must be a list of objects", path)
    kind = str(data.get("transform_kind", "rigid"))
    consensus = data.get("consensus")
    if isinstance(consensus, dict) and consensus.get("transform") is not None:
        return MatchSummary(True, _sim3(consensus["transform"], path),
                            _associations(consensus.get("associations"), path), kind, len(hyps))
    best = data.get("best")
    chosen: dict | None = None
    if isinstance(best, int) and not isinstance(best, bool) and 0 <= best < len(hyps):
        chosen = hyps[best]
    if chosen is None or not chosen.get("accepted", False):
        accepted = [h for h in hyps if h.get("accepted")]
        pool = accepted or hyps
        if pool:
            chosen = max(pool, key=lambda h: len(h.get("associations") or []))
    if chosen is None:
        return MatchSummary(False, None, np.zeros((0, 2), np.int64), kind, len(hyps))
    transform = _sim3(chosen["transform"], path) if chosen.get("transform") is not None else None
    return MatchSummary(
        accepted=bool(chosen.get("accepted", False)) and transform is not None,
        transform=transform,
        associations=_associations(chosen.get("associations"), path),
        transform_kind=kind,
        num_hypotheses=len(hyps),
    )
