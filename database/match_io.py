"""match.json (written by `sosmatch match`): its one validation, its one reader, and the one check that a match
belongs to the maps a consumer holds.

`parse_match` validates a parsed document: every field merge, batch, evaluate (and the later stages) read has
its type and range checked, so a damaged or hand-edited file is a one-line InputError, never a traceback or a
silently wrong value (a float index is not truncated, an infinite scale is refused). The writer
(`workflows.match`) runs the same validation on what it is about to write, so the reader accepts exactly what
the writer writes. `read_match` reads and validates a file. `check_match_maps` is how every consumer makes sure
the match was computed for its maps: match.json names each map by a content fingerprint
(`landmark_map.landmark_map_fingerprint`), compared here, with a clear message for maps given in swapped order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..plugin.errors import InputError
from ..plugin.multisession import Sim3
from ..plugin.params.matching import MAX_ASSOCIATIONS
from .landmark_map import LandmarkMap, landmark_map_fingerprint
from .output_markers import check_finished
from .text_input import read_user_json

MATCH_FORMAT = "sosmatch match v1"
MAX_INDEX = 2**31 - 1  # landmark indices are int32-sized (a map of 2^31 landmarks would be 30 GB)


@dataclass
class MatchHypothesis:
    """One solved window pair of match.json."""

    associations: np.ndarray  # (K,2) int64 landmark index pairs (A, B)
    transform: Sim3 | None  # a_from_b; None when the window pair gave none
    accepted: bool | None  # None: not recorded
    tilt_deg: float | None  # the transform's roll/pitch angle to gravity, when recorded


@dataclass
class MapRef:
    """How match.json names one of its maps."""

    path: str | None
    fingerprint: str | None  # content fingerprint (None: written by an older sosmatch)
    landmarks: int | None


@dataclass
class MatchSummary:
    """A validated match.json: the hypothesis merging uses, and everything else consumers read."""

    accepted: bool
    transform: Sim3 | None  # a_from_b; None when no hypothesis exists
    associations: np.ndarray  # (K,2) int64 landmark index pairs (A, B) of the chosen hypothesis
    transform_kind: str = "rigid"
    num_hypotheses: int = 0
    extra: dict[str, Any] = field(default_factory=dict)
    hypotheses: list[MatchHypothesis] = field(default_factory=list)
    map_a: MapRef = field(default_factory=lambda: MapRef(None, None, None))
    map_b: MapRef = field(default_factory=lambda: MapRef(None, None, None))
    seconds: float | None = None  # the answer's time (search + verification)
    min_associations: int | None = None  # theta_S of the search
    # where the answer comes from: "verified" (the verification on the full maps; `accepted` is its decision),
    # "consensus" (the window consensus, not verified), "hypothesis" (no consensus: the best or largest one)
    source: str = "hypothesis"
    consensus_accepted: bool = False  # the window search's own answer, whatever the verification decided
    consensus_transform: Sim3 | None = None
    consensus_associations: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    runner_up_support: int | None = None  # the verification's best rival (None: not verified)
    search_mode: dict[str, Any] = field(default_factory=dict)  # which search ran (match.json "search_mode")
    # the test the answer's associations passed against its transform: distance (`plugin.refinement.
    # pairing_distance` with gate_z_weight) within gate_m; the verification pairs within the search's theta_eps with
    # heights weighted by verification.z_weight, the window consensus within theta_eps in 3D (None: not recorded)
    gate_m: float | None = None
    gate_z_weight: float = 1.0
    # match.json "answer_uncertainty" (`plugin.answer_uncertainty`): the accepted answer's predicted placement
    # error at B's landmarks exceeds its gate (False: within it, or not recorded by an older sosmatch)
    imprecise: bool = False
    predicted_max_m: float | None = None  # that error's largest 95 % radius over the common area (None: not recorded)
    imprecise_reason: str = ""  # answer_uncertainty.reason: why (a scale disagreement, flipped heights; "": not said)
    # maps in one EPSG with an accepted answer: how far it moves B from its georeference (search_mode.
    # georeference_off_m), the radius the georeference is trusted to (params.association.georeference_prior_m) and
    # how the search used it (search_mode.position_prior); None: not recorded (`georeference_note`)
    georeference_off_m: float | None = None
    georeference_radius_m: float | None = None
    position_prior: str | None = None
    warnings: list[str] = field(default_factory=list)  # what `match` warned of (match.json "warnings", since fix15)
    # how the match refines an alignment on the full maps: its recorded verification section's dof, final_dof,
    # tilt_prior_deg, z_weight, max_size_difference and coarse_factor (params.verification; those missing: not
    # recorded); `merge --refine` and batch refine an unverified answer with them (`merge_refine.refined_answer`)
    refinement: dict[str, float] = field(default_factory=dict)


# --- field validation (each raises InputError naming the file and the field) -----------------------------------


def _where(field_name: str) -> str:
    return f"match file field {field_name}"


def _int(value: Any, name: str, path: Path, lo: int = 0, hi: int = MAX_INDEX) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{_where(name)} must be an integer, got {_short(value)}", path)
    if not lo <= value <= hi:
        raise InputError(f"{_where(name)} must be within [{lo}, {hi}], got {_short(value)}", path)
    return value


def _float(value: Any, name: str, path: Path, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{_where(name)} must be a finite number, got {_short(value)}", path)
    return float(value)


def _positive(value: Any, name: str, path: Path) -> float | None:
    """An optional positive finite number (None when absent)."""
    value = _float(value, name, path, allow_none=True)
    if value is not None and value <= 0:
        raise InputError(f"{_where(name)} must be positive, got {_short(value)}", path)
    return value


def _bool(value: Any, name: str, path: Path) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{_where(name)} must be true or false, got {_short(value)}", path)
    return value


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _sim3(data: Any, name: str, path: Path) -> Sim3:
    if not isinstance(data, dict):
        raise InputError(f"{_where(name)} must be an object with rotation, translation and scale", path)
    rot = data.get("rotation")
    if isinstance(rot, list) and len(rot) == 4:  # quaternion (w, x, y, z)
        from ..plugin.geometry import quat_to_rotmat

        q = np.array([_float(v, f"{name}.rotation", path) for v in rot])
        if abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise InputError(f"{_where(name)}.rotation quaternion is not unit length", path)
        r = quat_to_rotmat(q)
    elif isinstance(rot, list) and len(rot) == 3 and all(isinstance(row, list) and len(row) == 3 for row in rot):
        r = np.array([[_float(v, f"{name}.rotation", path) for v in row] for row in rot])
    else:
        raise InputError(f"{_where(name)}.rotation must be a 3x3 matrix (rows) or a quaternion [w, x, y, z]", path)
    t = data.get("translation")
    if not (isinstance(t, list) and len(t) == 3):
        raise InputError(f"{_where(name)}.translation must be [x, y, z]", path)
    t = np.array([_float(v, f"{name}.translation", path) for v in t])
    scale = _float(data.get("scale", 1.0), f"{name}.scale", path)
    if not 1e-6 <= scale <= 1e6:
        raise InputError(f"{_where(name)}.scale must be within [1e-6, 1e6], got {scale!r}", path)
    if np.abs(t).max() > 1e9:
        raise InputError(f"{_where(name)}.translation is beyond 1e9 m", path)
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0:
        raise InputError(f"{_where(name)}.rotation is not a rotation matrix", path)
    return Sim3(r, t, scale)


def parse_associations(data: Any, name: str, path: Path) -> np.ndarray:
    """A validated (K,2) int64 array of [index_a, index_b] pairs (JSON integers only: 1.7 is refused, not 1)."""
    if data is None:
        return np.zeros((0, 2), np.int64)
    if not isinstance(data, list):
        raise InputError(f"{_where(name)} must be a list of [index_a, index_b] integer pairs", path)
    out = np.empty((len(data), 2), np.int64)
    for k, pair in enumerate(data):
        if not (isinstance(pair, list) and len(pair) == 2):
            raise InputError(f"{_where(name)} must be a list of [index_a, index_b] integer pairs", path)
        out[k, 0] = _int(pair[0], name, path)
        out[k, 1] = _int(pair[1], name, path)
    return out


def _map_ref(data: Any, name: str, path: Path) -> MapRef:
    if data is None:
        return MapRef(None, None, None)
    if not isinstance(data, dict):
        raise InputError(f"{_where(name)} must be an object", path)
    fp = data.get("fingerprint")
    if fp is not None and not (isinstance(fp, str) and 0 < len(fp) <= 128):
        raise InputError(f"{_where(name)}.fingerprint must be a string", path)
    count = data.get("landmarks")
    p = data.get("path")
    return MapRef(p if isinstance(p, str) else None, fp,
                  None if count is None else _int(count, f"{name}.landmarks", path))


def parse_match(data: Any, path: str | Path = "<match>") -> MatchSummary:
    """Validate a parsed match.json document and return what consumers read (see `read_match`)."""
    path = Path(path)
    if not isinstance(data, dict):
        raise InputError("match file must hold a JSON object", path)
    fmt = data.get("format", MATCH_FORMAT)
    if not isinstance(fmt, str) or not fmt.startswith("sosmatch match"):
        raise InputError(f"not a sosmatch match file (format {_short(fmt)})", path)
    if fmt != MATCH_FORMAT:  # another version's fields may mean something else: never guess
        raise InputError(f"match file of format {_short(fmt)}; this sosmatch reads {MATCH_FORMAT!r}: re-run "
                         "`sosmatch match`", path)
    raw_hyps = data.get("hypotheses")
    if raw_hyps is None:
        raise InputError("match file needs a 'hypotheses' list", path)
    if not isinstance(raw_hyps, list) or not all(isinstance(h, dict) for h in raw_hyps):
        raise InputError("match file field hypotheses must be a list of objects", path)
    hyps = []
    for k, h in enumerate(raw_hyps):
        name = f"hypotheses[{k}]"
        transform = None if h.get("transform") is None else _sim3(h["transform"], f"{name}.transform", path)
        tilt = _float(h.get("tilt_deg"), f"{name}.tilt_deg", path, allow_none=True)
        if tilt is None and h.get("roll_deg") is not None and h.get("pitch_deg") is not None:
            tilt = max(abs(_float(h["roll_deg"], f"{name}.roll_deg", path)),
                       abs(_float(h["pitch_deg"], f"{name}.pitch_deg", path)))
        accepted = None if h.get("accepted") is None else _bool(h["accepted"], f"{name}.accepted", path)
        assoc = parse_associations(h.get("associations"), f"{name}.associations", path)
        hyps.append(MatchHypothesis(assoc, transform, accepted, tilt))
    kind = data.get("transform_kind", "rigid")
    if kind not in ("rigid", "similarity"):
        raise InputError(f"match file field transform_kind must be 'rigid' or 'similarity', got {_short(kind)}", path)
    best = data.get("best")
    if best is not None:
        best = _int(best, "best", path, 0, max(len(hyps) - 1, 0))
        if not hyps:
            raise InputError("match file field best refers to a hypothesis but there are none", path)
    consensus = data.get("consensus")
    if consensus is not None and not isinstance(consensus, dict):
        raise InputError("match file field consensus must be an object", path)
    timings = data.get("timings")
    seconds = data.get("search_seconds", timings.get("total_s") if isinstance(timings, dict) else None)
    seconds = _float(seconds, "search_seconds", path, allow_none=True)
    params = data.get("params")
    theta = None
    gate, z_weight, summary_radius, refinement = None, None, None, {}
    if isinstance(params, dict):
        assoc = params.get("association")
        theta = assoc.get("min_associations") if isinstance(assoc, dict) else params.get("min_associations")
        theta = None if theta is None else _int(theta, "params.association.min_associations", path, 0,
                                                MAX_ASSOCIATIONS)
        gate = _positive(assoc.get("distance_tolerance_m") if isinstance(assoc, dict) else None,
                         "params.association.distance_tolerance_m", path)
        radius = assoc.get("georeference_prior_m") if isinstance(assoc, dict) else None
        summary_radius = _float(radius, "params.association.georeference_prior_m", path, allow_none=True)
        ver_params = params.get("verification")
        z_weight = _positive(ver_params.get("z_weight") if isinstance(ver_params, dict) else None,
                             "params.verification.z_weight", path)
        refinement = _refinement(ver_params if isinstance(ver_params, dict) else {}, path)
    summary = MatchSummary(False, None, np.zeros((0, 2), np.int64), kind, len(hyps), hypotheses=hyps,
                           map_a=_map_ref(data.get("map_a"), "map_a", path),
                           map_b=_map_ref(data.get("map_b"), "map_b", path), seconds=seconds, min_associations=theta)
    mode = data.get("search_mode")
    summary.search_mode = mode if isinstance(mode, dict) else {}
    summary.refinement = refinement
    summary.georeference_radius_m = summary_radius
    off = _float(summary.search_mode.get("georeference_off_m"), "search_mode.georeference_off_m", path,
                 allow_none=True)
    if off is not None and off < 0:
        raise InputError(f"{_where('search_mode.georeference_off_m')} must be >= 0, got {_short(off)}", path)
    summary.georeference_off_m = off
    prior = summary.search_mode.get("position_prior")
    summary.position_prior = prior if isinstance(prior, str) else None
    said = data.get("warnings", [])
    if not isinstance(said, list) or not all(isinstance(w, str) for w in said):
        raise InputError(f"{_where('warnings')} must be a list of texts, got {_short(said)}", path)
    summary.warnings = list(said)
    searched = summary.search_mode.get("searched")
    if isinstance(searched, dict) and searched.get("min_associations") is not None:
        # theta_S of the search whose hypotheses these are (the first of two searches keeps the configured one)
        summary.min_associations = _int(searched["min_associations"], "search_mode.searched.min_associations",
                                        path, 0, MAX_ASSOCIATIONS)
    # The window search's own answer: the consensus (the transform refitted on the associations of every accepted
    # window pair that agrees with the best one; written only when one was accepted), else the best accepted
    # hypothesis, else the largest one (then not accepted).
    if consensus is not None and consensus.get("transform") is not None:
        summary.source = "consensus"
        # a consensus that holds no more than theta_S associations is no answer (written since 2026-12-04)
        summary.consensus_accepted = _bool(consensus.get("accepted", True), "consensus.accepted", path)
        summary.consensus_transform = _sim3(consensus["transform"], "consensus.transform", path)
        summary.consensus_associations = parse_associations(consensus.get("associations"), "consensus.associations",
                                                            path)
    else:
        chosen = hyps[best] if best is not None else None
        if chosen is None or not chosen.accepted:
            pool = [h for h in hyps if h.accepted] or hyps
            if pool:
                chosen = max(pool, key=lambda h: len(h.associations))
        if chosen is not None:
            summary.consensus_accepted = bool(chosen.accepted) and chosen.transform is not None
            summary.consensus_transform = chosen.transform
            summary.consensus_associations = chosen.associations
    summary.accepted = summary.consensus_accepted
    summary.transform = summary.consensus_transform
    summary.associations = summary.consensus_associations
    # The answer every consumer uses: the verification's when it ran (match.json "verification", the default)
    ver = data.get("verification")
    if ver is not None:
        if not isinstance(ver, dict):
            raise InputError("match file field verification must be an object or null", path)
        summary.source = "verified"
        summary.accepted = _bool(ver.get("accepted"), "verification.accepted", path)
        summary.transform = (None if ver.get("transform") is None
                             else _sim3(ver["transform"], "verification.transform", path))
        summary.associations = parse_associations(ver.get("associations"), "verification.associations", path)
        summary.runner_up_support = _int(ver.get("runner_up_support", 0), "verification.runner_up_support", path)
        _check_verified_associations(summary.associations, ver.get("support"), path)
        if summary.accepted and summary.transform is None:
            raise InputError("match file field verification is accepted without a transform", path)
    if summary.source == "verified" and isinstance(ver.get("method"), dict) and ver["method"].get("gate_m") is not None:
        gate = _positive(ver["method"]["gate_m"], "verification.method.gate_m", path)  # the gate its pairs passed
    summary.gate_m = gate
    if summary.source == "verified" and z_weight is not None:
        summary.gate_z_weight = z_weight
    unc = data.get("answer_uncertainty")
    if unc is not None:
        if not isinstance(unc, dict):
            raise InputError("match file field answer_uncertainty must be an object or null", path)
        summary.imprecise = _bool(unc.get("imprecise", False), "answer_uncertainty.imprecise", path)
        summary.predicted_max_m = _float(unc.get("predicted_max_m"), "answer_uncertainty.predicted_max_m", path,
                                         allow_none=True)
        reason = unc.get("reason", "")
        if not isinstance(reason, str):
            raise InputError("match file field answer_uncertainty.reason must be a string", path)
        summary.imprecise_reason = reason
        if summary.imprecise and summary.predicted_max_m is None:  # the consumers' warning says how far off
            raise InputError("match file field answer_uncertainty.predicted_max_m is missing: an imprecise answer "
                             "records its predicted error", path)
    if kind == "rigid":  # a scale in a rigid match is an edit: merge and changes would apply it
        for what, t in (("the answer's", summary.transform), ("the consensus'", summary.consensus_transform)):
            if t is not None and abs(t.scale - 1.0) > 1e-9:
                raise InputError(f"{what} transform has scale {t.scale:g} in a match of transform_kind 'rigid'", path)
    return summary


# the recorded verification settings a refinement of the answer uses (`MatchSummary.refinement`), valid as
# `VerificationParams` declares them (one check: a value `match` itself can write is never refused here)
REFINEMENT_FIELDS = ("dof", "final_dof", "tilt_prior_deg", "z_weight", "max_size_difference", "coarse_factor")
_INTEGER_FIELDS = ("dof", "final_dof")


def _refinement(section: dict[str, Any], path: Path) -> dict[str, float]:
    """The verification settings a match.json records for refining an alignment (`REFINEMENT_FIELDS`), each
    checked against `VerificationParams`' own declaration (InputError naming the field); those it does not record
    are left out."""
    from ..plugin.params.checks import valid_values
    from ..plugin.params.matching import VerificationParams

    out: dict[str, float] = {}
    for name in REFINEMENT_FIELDS:
        if section.get(name) is None:
            continue
        value: float = _float(section[name], f"params.verification.{name}", path)  # type: ignore[assignment]
        if name in _INTEGER_FIELDS and value == int(value):
            value = int(value)
        valid = valid_values(VerificationParams, name)
        if valid is not None and not valid.accepts(value):
            raise InputError(f"{_where('params.verification.' + name)} must be {valid.describe()}, got "
                             f"{_short(section[name])}", path)
        out[name] = value
    return out


def answer_gate(match: MatchSummary | None, configured_m: float) -> float:
    """The association tolerance (theta_eps) of the match that produced a transform: what its answer's pairs
    passed (`MatchSummary.gate_m`: the tolerance match derived from the maps, or the verification's gate), at which
    every consumer judges the transform (the alignment control of changes, merge and batch; merge's refinement and
    fusion). `configured_m`, the configured theta_eps, only when there is no match or it records none: maps of
    20 m objects (NAIP, theta_eps 8.2 m) have 1 counterpart in 142 at 2 m at their true alignment."""
    return match.gate_m if match is not None and match.gate_m is not None else configured_m


def _check_verified_associations(assoc: np.ndarray, support: Any, path: Path) -> None:
    """The verification's associations are mutual nearest neighbours (each landmark at most once) and its support
    is their number: an edited list (a landmark paired twice, pairs removed) was merged and compared without a
    word (37 associations cut to none: merge 'succeeded' fusing 0)."""
    name = "verification.associations"
    for side, label in ((0, "A"), (1, "B")):
        values, counts = np.unique(assoc[:, side], return_counts=True)
        if np.any(counts > 1):
            raise InputError(f"{_where(name)} pairs landmark {int(values[counts > 1][0])} of map {label} more than "
                             "once (the verification pairs each landmark at most once)", path)
    if support is not None and _int(support, "verification.support", path) != len(assoc):
        raise InputError(f"{_where(name)} holds {len(assoc)} pairs but verification.support is {support}", path)


def read_match_json(path: str | Path) -> dict[str, Any]:
    """The parsed (not yet validated) match.json (a directory means its match.json); InputError if unreadable."""
    path = Path(path)
    if path.is_dir():
        if not (path / "match.json").exists():
            raise InputError("folder holds no match.json (give the match.json of `sosmatch match`, or its folder)",
                             path)
        path = path / "match.json"
    check_finished(path.parent, path)  # a killed `match --overwrite` leaves the old match.json beside new files
    return read_user_json(path, "match file", redo="re-run `sosmatch match`")


def match_content(match: MatchSummary) -> str:
    """What a match says, not where its file lies: its maps (content fingerprints), its answer (transform,
    associations, gate, source). An output made from a match names it by this in its identity, so that the same
    project moved or copied elsewhere is the same output (nu37 D1), and a match.json written again by a re-run of
    `match` (other timings) too."""
    import hashlib

    from .output_markers import fingerprint

    assoc = hashlib.sha256(np.ascontiguousarray(match.associations, dtype="<i8").tobytes()).hexdigest()
    return fingerprint({"map_a": match.map_a.fingerprint, "map_b": match.map_b.fingerprint,
                        "accepted": match.accepted, "source": match.source, "kind": match.transform_kind,
                        "transform": None if match.transform is None else match.transform.to_dict(),
                        "associations": assoc, "gate_m": match.gate_m, "gate_z_weight": match.gate_z_weight})


def read_match(path: str | Path) -> MatchSummary:
    """Read and validate match.json (or a directory holding it): the hypothesis to merge with, every hypothesis,
    the maps it was computed for. Use `check_match_maps` before trusting its indices for your maps."""
    path = Path(path)
    doc = read_match_json(path)
    return parse_match(doc, path / "match.json" if path.is_dir() else path)


def check_match_maps(match: MatchSummary, map_a: LandmarkMap, map_b: LandmarkMap, path: str | Path,
                     names: tuple[str, str] = ("A", "B")) -> None:
    """Refuse (InputError naming `path`) a match that was not computed for exactly these two maps, in this order.

    Every consumer of a match.json (merge, evaluate, batch, changes) calls this before using its indices."""
    path = Path(path)
    fa, fb = landmark_map_fingerprint(map_a), landmark_map_fingerprint(map_b)
    ref_a, ref_b = match.map_a.fingerprint, match.map_b.fingerprint
    if ref_a is None or ref_b is None:
        raise InputError("match file does not identify its maps (no map fingerprints: written by an older sosmatch "
                         "or by hand); re-run `sosmatch match`", path)
    if (ref_a, ref_b) == (fa, fb):
        for ref, lmap, name in ((match.map_a, map_a, names[0]), (match.map_b, map_b, names[1])):
            if ref.landmarks is not None and ref.landmarks != len(lmap):  # a fingerprint collision or a hand edit
                raise InputError(f"match file says map {name} has {ref.landmarks} landmarks, it has {len(lmap)}", path)
        too_far = [h for h in [match.associations, *(h.associations for h in match.hypotheses)] if len(h) and (
            h[:, 0].max() >= len(map_a) or h[:, 1].max() >= len(map_b))]
        if too_far:
            raise InputError("match file holds landmark indices beyond its maps", path)
        _check_answer_brings_its_pairs_together(match, map_a, map_b, path)
        return
    if (ref_a, ref_b) == (fb, fa):
        raise InputError(f"match file was computed for these maps in the other order (its map A is {names[1]}); "
                         "give them as the match had them", path)
    # which side differs, by its letter, the map given and the match's own (nu59 D5: "map M1 differs" for
    # `merge M1 M1` left the reader to guess whether the given M1 or the match's M1 was meant)
    which = [f"map {side} given ({given}) is not the match's map {side} ({ref.path or 'a map without a path'})"
             for side, given, ref, fp in (("A", names[0], match.map_a, fa), ("B", names[1], match.map_b, fb))
             if ref.fingerprint != fp]
    raise InputError(f"match file was computed for other maps: {'; '.join(which)}; re-run `sosmatch match` on "
                     "these", path)


def _check_answer_brings_its_pairs_together(match: MatchSummary, map_a: LandmarkMap, map_b: LandmarkMap,
                                            path: Path) -> None:
    """Refuse a verified answer whose transform does not put its own associations within the gate they were
    paired in (the median distance; every verified pair passed it under that transform): a transform edited by
    hand (the nineteenth sweep: moved 50 m, `merge` fused none of 99 associations and said so only in its summary;
    moved 3 m, `changes` reported 8 gone / 21 new instead of 4 / 10, exit 0). An unverified consensus is not
    tested: its pairs passed the gate under each window's own transform, not under the one refitted on all of
    them. Files that do not record their gate pass."""
    from ..plugin.refinement import pairing_distance

    assoc = match.associations
    if match.source != "verified" or match.transform is None or not len(assoc) or match.gate_m is None:
        return
    d = pairing_distance(map_a.positions[assoc[:, 0]], match.transform.apply(map_b.positions[assoc[:, 1]]),
                         match.gate_z_weight)
    median = float(np.median(d))
    if not median <= match.gate_m:
        raise InputError(f"its transform puts its own {len(assoc)} associations {median:.2f} m apart (median) where "
                         f"they were paired within {match.gate_m:.2f} m: the transform or the associations were "
                         "edited; re-run `sosmatch match`", path)
