"""What a merge fuses and from which flights (`workflows.merge`, and batch's merge stage): the landmark pairs of
each session pair and the test they must pass after alignment (`FusePair`, `filter_associations`), a transform
refitted on the pairs it already explains (`refine_transform`), and the flights a session holds, so that no flight
is merged twice (`flight_maps`, `distinct_flights`), with the fingerprint a merge of a session depends on
(`session_fingerprint`)."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..database.landmark_map import landmark_map_fingerprint
from ..database.output_markers import fingerprint, sha256_file
from ..database.session_io import MERGE_RECORD, SessionFiles
from ..database.text_input import read_user_json
from ..plugin.errors import InputError
from ..plugin.multisession import Sim3, one_to_one, umeyama
from ..plugin.refinement import pairing_distance


class FusePair(NamedTuple):
    """Landmark associations of sessions a and b to fuse, and the test they passed against their alignment: the
    match's own gate (`MatchSummary.gate_m`, `gate_z_weight`; `pairing_distance`). A verified match pairs
    landmarks within the theta_eps derived from the maps (2.7 m on 100 m flights) with heights at half weight;
    re-judging them at the configured 2 m in 3D left 16 of 35 verified summer-winter associations unfused.
    gate_m None: `max_fuse_distance_m` of the merge, in 3D."""

    a: int
    b: int
    associations: np.ndarray
    gate_m: float | None = None
    z_weight: float = 1.0


def match_fuse_pair(a: int, b: int, match: Any) -> FusePair:
    """The FusePair of a match's answer (a `database.match_io.MatchSummary`) between sessions a and b."""
    return FusePair(a, b, match.associations, match.gate_m, match.gate_z_weight)


def filter_associations(
    sessions: list[SessionFiles], transforms: list[Sim3], pairs: Sequence[FusePair | tuple[int, int, np.ndarray]],
    max_dist: float
) -> tuple[list[tuple[int, int, np.ndarray]], int]:
    """Keep, of each pair's associations, a one-to-one set (`one_to_one`, nearest first, in that order) whose two
    landmarks pass their pair's gate (`FusePair`; plain (a, b, associations): within max_dist in 3D) and have 3D
    points; returns (kept pairs, number of associations left out).

    The distance is measured in the frame of the pair's session a, whose metres the gate is in (the match paired
    them there); in the reference frame a similarity transform's scale multiplied it (rev33: 138 / 52 / 21 of 138
    fused at reference scale 1 / 2 / 3). One-to-one: an unverified match (a window consensus) may pair one
    landmark with several, and grouping them all chained landmarks no association links (rev33: 5.7 m apart under
    a 2.95 m gate)."""
    kept, rejected = [], 0
    for pair in pairs:
        a, b, assoc, gate, z_weight = FusePair(*pair)
        gate = max_dist if gate is None else gate
        assoc = np.asarray(assoc, dtype=np.int64).reshape(-1, 2)
        na, nb = len(sessions[a].landmarks), len(sessions[b].landmarks)
        valid = (assoc[:, 0] < na) & (assoc[:, 1] < nb)
        if not np.all(valid):
            raise InputError(
                f"associations refer to landmarks beyond the maps ({na} in {sessions[a].name}, "
                f"{nb} in {sessions[b].name}); was match.json computed on these sessions?"
            )
        a_from_b = transforms[a].inverse().compose(transforms[b])
        pa = sessions[a].landmarks.positions[assoc[:, 0]]
        pb = a_from_b.apply(sessions[b].landmarks.positions[assoc[:, 1]])
        dist = pairing_distance(pa, pb, z_weight)
        ok = dist <= gate
        ok &= (sessions[a].point3d_ids[assoc[:, 0]] >= 0) & (sessions[b].point3d_ids[assoc[:, 1]] >= 0)
        taken = one_to_one(assoc, dist, ok)
        rejected += len(assoc) - len(taken)
        kept.append((a, b, assoc[taken]))
    return kept, rejected


def flight_maps(session: SessionFiles) -> list[str]:
    """The landmark maps (content fingerprints) of the flights a session holds: a merged session's as its
    merge.json records them (`flight_maps`), a flight's its own (and a merged session's of an older sosmatch, whose
    record has none). InputError naming merge.json when it is unreadable: a merged session taken for one flight
    would let a flight it holds be merged into it again."""
    record = session.path / MERGE_RECORD
    recorded = read_user_json(record, "merge record", redo="re-run `sosmatch merge`").get("flight_maps") \
        if record.is_file() else None
    if isinstance(recorded, list) and recorded and all(isinstance(f, str) for f in recorded):
        return sorted(set(recorded))
    return [landmark_map_fingerprint(session.landmarks)]


def distinct_flights(sessions: Sequence[SessionFiles]) -> list[str]:
    """The flights' maps of all `sessions` (`flight_maps`); InputError when one flight is in two of them (the
    eleventh sweep: a flight merged into a season map that already held it, its images twice in the model)."""
    seen: dict[str, Path] = {}
    for s in sessions:
        for f in flight_maps(s):
            if f in seen:
                raise InputError(f"holds a flight that {seen[f]} holds already (the same landmark map): merging "
                                 "it again would put its images into the model twice", s.path)
            seen[f] = s.path
    return sorted(seen)


def session_fingerprint(session: SessionFiles) -> str:
    """What a merge of `session` depends on: its landmarks (content fingerprint), landmark table and model."""
    files = sorted(p for p in session.sparse_dir.iterdir() if p.is_file())
    return fingerprint({"landmarks": landmark_map_fingerprint(session.landmarks),
                        "point3d_ids": hashlib.sha256(np.ascontiguousarray(session.point3d_ids, "<i8")).hexdigest(),
                        "sparse": {p.name: sha256_file(p) for p in files}})


def refine_transform(
    a: SessionFiles, b: SessionFiles, associations: np.ndarray, initial: Sim3, with_scale: bool, gate_m: float
) -> tuple[Sim3, int]:
    """Re-estimate a_from_b by least squares on every association that `initial` already explains within gate_m.

    Returns (transform, number of associations used); keeps `initial` when fewer than 3 survive the gate.
    """
    assoc = np.asarray(associations, dtype=np.int64).reshape(-1, 2)
    pa = a.landmarks.positions[assoc[:, 0]]
    pb = b.landmarks.positions[assoc[:, 1]]
    inliers = np.linalg.norm(initial.apply(pb) - pa, axis=1) <= gate_m
    if np.count_nonzero(inliers) < 3:
        return initial, 0
    try:
        return umeyama(pb[inliers], pa[inliers], with_scale=with_scale), int(np.count_nonzero(inliers))
    except ValueError:  # collinear inliers: the initial transform is all we have
        return initial, 0
