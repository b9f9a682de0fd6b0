"""Merge mapped sessions into one COLMAP model in one frame (`sosmatch merge`, and the merge stage of batch).

`run(session_a, session_b, match_json, out_dir)` brings session B into A's frame with the accepted transform of
match.json (rigid or similarity, applied with `pycolmap.Reconstruction.transform(pycolmap.Sim3d)`), optionally
refines an unverified answer's transform on the full maps and fuses the pairs it supports (`merge_refine`), and
writes one model. `merge_sessions(...)` is the general case used
by batch: N sessions, each with its reference_from_session transform, and fusion groups of landmarks.

How models are combined: every session's cameras, images and 3D points are copied into a new
`pycolmap.Reconstruction` with fresh, dense ids (cameras, then images, in session order, each in id order),
image names are prefixed with the session label (`LABEL/frame_00000.jpg`) so they stay unique, and each group
of associated landmarks becomes ONE 3D point whose track holds every session's observations
(`Reconstruction.merge_points3D`: the position is the track-length-weighted mean). Associations whose landmarks
no longer pass their match's own test after alignment (`FusePair`: the gate and height weight match.json records
for its answer, measured in the frame of the pair's first session, whose metres it is in; else
`max_fuse_distance_m` in 3D) are not fused (an outlier association would otherwise drag two distinct objects into
one point); of the rest, each pair fuses a one-to-one set (nearest first: an unverified match may pair one
landmark with several), and a group never takes two landmarks of one session. Every association not fused is
counted in merge.json.

Output directory (a "merged session", readable by match/merge again):
    sparse/            COLMAP binary model (opens in pycolmap 4.x and COLMAP 3.8)
    landmarks.sosmap   merged landmark map: the reference session's landmarks in order (fused ones at the
                       reference's index), then each other session's unfused landmarks in order
    landmarks.csv      index,point3d_id,x,y,z,size_m,num_observations,image_names_json (a JSON list)
    merge.json         sessions, transforms, counts (written last: its presence means the merge finished)
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import write_text_atomic
from ..database.colmap_model import TEXT_MODEL, colmap_text_name_problem, load_reconstruction
from ..database.landmark_map import (
    POSE_SOURCE_GIVEN,
    POSE_SOURCE_SFM,
    LandmarkMap,
    crs_disagreement,
    write_landmark_map,
)
from ..database.map_loading import (
    merged_size_definition,
    session_map_noise,
    session_sfm_poses,
    session_size_definition,
    size_definitions_differ,
)
from ..database.match_io import MatchSummary, answer_gate, check_match_maps, match_content, read_match
from ..database.match_notes import check_georeferences, imprecise_note, precision_note, unverified_note
from ..database.output_checks import check_output_dir
from ..database.output_markers import fingerprint, resolved_path
from ..database.outputs import OutputDir, open_output_dir
from ..database.session_io import (
    MERGE_RECORD,
    SessionFiles,
    read_session,
    write_landmarks_csv,
)
from ..plugin.errors import InputError
from ..plugin.map_noise import MapNoise
from ..plugin.multisession import Sim3, associations_not_fused, fusion_groups
from ..plugin.params import Params
from .changes import check_alignment
from .merge_pairs import (
    FusePair,
    distinct_flights,
    filter_associations,
    maps_of,
    session_fingerprint,
)
from .merge_refine import Refinement, fused_pair, refined_answer

# importable from here as before the split (`merge_refine`, `match_notes`): batch, tests and benchmarks use them
__all__ = ["MERGE_FORMAT", "MergeResult", "Refinement", "label_problem", "merge_sessions", "precision_note",
           "ignored_settings", "refined_answer", "run"]

log = logging.getLogger(__name__)

MERGE_FORMAT = "sosmatch merge v1"
# the files a merge writes beside sparse/, its record last: checked when it takes the folder (a user's file there is
# refused before the merge, not after it)
MERGE_FILES = ("landmarks.sosmap", "landmarks.csv", MERGE_RECORD)


@dataclass
class MergeResult:
    """What a merge produced (also written to merge.json)."""

    out_dir: Path
    sessions: list[str]
    labels: list[str]
    transforms: list[Sim3]  # reference_from_session, per session
    num_cameras: int = 0
    num_images: int = 0
    num_points3d: int = 0
    num_landmarks: int = 0
    num_fused: int = 0  # fusion groups that became one 3D point
    # associations not fused: too far apart after alignment, without a 3D point, not one-to-one (a landmark
    # paired with several), or joining two landmarks of one session
    num_rejected: int = 0
    refined: bool = False
    # where its poses came from (`landmark_map.POSE_SOURCE_*`, as run.json's `pose_source`): structure from motion
    # when any session's did (its landmarks carry that block's dome), so that `match` fits a scale to it too
    pose_source: str = POSE_SOURCE_GIVEN
    # wall time of the merge, for the caller; not in merge.json, which same inputs write byte for byte (rev45 D6)
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """merge.json's fields of the result (`_write_merge_record` adds the versions and the caller's record)."""
        return {
            "format": MERGE_FORMAT,
            "sessions": self.sessions,
            "labels": self.labels,
            "reference": self.sessions[0] if self.sessions else None,
            "reference_from_session": [t.to_dict() for t in self.transforms],
            "counts": {
                "cameras": self.num_cameras,
                "images": self.num_images,
                "points3D": self.num_points3d,
                "landmarks": self.num_landmarks,
                "fused": self.num_fused,
                "rejected_associations": self.num_rejected,
            },
            "refined": self.refined,
            "pose_source": self.pose_source,
            **self.extra,
        }


def label_problem(label: str) -> str | None:
    """Why `label` cannot prefix a merged model's image names (`LABEL/name`), or None: white space, which COLMAP's
    text model cannot hold (`colmap_model.colmap_text_name_problem`, as `map --text` refuses such image names: rev45
    D2, a session folder `sum mer` converted to TXT read back as 40 images all named `sum`), or a '/', which would
    make the label ambiguous in the names (`merge_pairs.older_merged_flights` parts them at the first '/')."""
    if (problem := colmap_text_name_problem([f"{label}/"], TEXT_MODEL)) is not None:
        return f"session label {label!r} holds white space, which {problem[1].partition(', which ')[2]}"
    if "/" in label:
        return f"session label {label!r} holds '/', which would part it from the image names wrongly"
    return None


def _labels(sessions: list[SessionFiles], labels: list[str] | None) -> list[str]:
    """Each session's label, the prefix of its images' names in the merged model (`LABEL/frame_00000.jpg`): its
    folder's name (`SessionFiles.name`), or its position (`s0`, `s1`, ...) when two folders share a name.
    InputError for a label the names cannot carry (`label_problem`), naming the session: before any work."""
    derived = labels is None
    if labels is None:
        labels = [s.name for s in sessions]
        if len(set(labels)) != len(labels):  # two sessions with the same folder name: fall back to positions
            labels = [f"s{i}" for i in range(len(sessions))]
    if len(labels) != len(sessions) or len(set(labels)) != len(labels) or any(not lb for lb in labels):
        raise InputError(f"session labels must be unique and non-empty, got {labels}")
    for session, label in zip(sessions, labels):
        if (problem := label_problem(label)) is not None:
            raise InputError(f"{problem}: the merged model names its images LABEL/name; "
                             f"{'rename the session folder' if derived else 'give another label'}", session.path)
    return list(labels)


def _merged_noise(sessions: Sequence[SessionFiles], transforms: Sequence[Sim3]) -> MapNoise | None:
    """The merged map's noise figures (`MapNoise.of_merged`), each session's metres in the reference frame's
    (a similarity transform's scale), so that matching the merged map derives its tolerances as for its parts."""
    parts = []
    for s, t in zip(sessions, transforms):
        n = session_map_noise(s.path, s.landmarks, s.record)
        parts.append(None if n is None else dataclasses.replace(
            n, ground_resolution_m=n.ground_resolution_m * t.scale, residual_m=n.residual_m * t.scale))
    return MapNoise.of_merged(parts)


def merge_sessions(
    sessions: list[SessionFiles],
    transforms: list[Sim3],
    pairs: Sequence[FusePair | tuple[int, int, np.ndarray]],
    out_dir: str | Path,
    labels: list[str] | None = None,
    max_fuse_distance_m: float = 2.0,
    record: dict[str, Any] | None = None,
    overwrite: bool = False,
    inputs: Sequence[str | Path] = (),
    earlier_records: Sequence[dict[str, Any]] = (),
    warnings: Sequence[str] = (),
    identity_record: dict[str, Any] | None = None,
    say: Sequence[str] = (),
) -> MergeResult:
    """Combine sessions into one COLMAP model in the frame of `transforms` (reference_from_session each).

    `pairs`: `FusePair`s (session index a, session index b, (K,2) landmark index pairs, the match's gate) whose
    landmarks are fused (a plain (a, b, pairs) tuple is judged by `max_fuse_distance_m` in 3D). Writes
    out_dir/{sparse/, landmarks.sosmap, landmarks.csv, merge.json} (built in out_dir/.partial, published
    together, merge.json last, `record` added to it); returns the counts. `out_dir` is taken through
    `sosmatch.database.outputs` (`overwrite`: replace a complete merge of other inputs; `inputs`: further input
    paths besides the sessions, e.g. the match file). `earlier_records`: the records an earlier sosmatch wrote
    for the same merge (`outputs.open_output_dir`'s `earlier`). `warnings`: what was said of its inputs (merge.json
    `warnings`, e.g. that two maps' georeferences disagree), recorded beside the merge, not part of its identity.
    `identity_record`: the record as the identity holds it (default `record`), e.g. its inputs by their content.
    `say`: warnings logged once the output directory is taken (after every refusal, so that a refusal is one line).
    """
    t0 = time.perf_counter()
    if len(sessions) != len(transforms) or not sessions:
        raise ValueError("need one transform per session and at least one session")
    labels = _labels(sessions, labels)
    fused = [FusePair(*q).identity() for q in pairs]
    prints = [session_fingerprint(s) for s in sessions]

    def identity_of(rec: dict[str, Any] | None) -> str:
        return fingerprint({"sessions": prints, "labels": labels, "transforms": [t.to_dict() for t in transforms],
                            "eps": max_fuse_distance_m, "record": rec, "pairs": fused})

    identity = identity_of(record if identity_record is None else identity_record)
    # an older merge.json's flights known by their names only: said (once the output is taken), never refused on
    # names
    flights, notes = distinct_flights(sessions)
    # the merged map's size definition, from its flights' (read back by `session_size_definition`): fused landmarks
    # average their members' sizes, so maps of two definitions make one of mixed sizes; said (rev54 D2: silent)
    defs = [session_size_definition(s.path, s.record) for s in sessions]
    if (differ := size_definitions_differ(defs, [str(s.path) for s in sessions])) is not None:
        notes = [*notes, f"the sessions define landmark sizes differently ({differ}): the merged map's sizes mix "
                 "the definitions (fused landmarks average them), which the size gate of `match` and `changes` "
                 "compares as one; map the sessions with the same setting to merge sizes of one definition"]
    warnings = [*warnings, *notes]
    with open_output_dir(out_dir, "merge", identity, inputs=[*(s.path for s in sessions), *inputs],
                         overwrite=overwrite, legacy_record=MERGE_RECORD,
                         earlier=[identity_of(r) for r in earlier_records], files=MERGE_FILES) as out:
        for text in [*say, *notes]:
            log.warning("%s", text)
        # the flights it holds (their maps and images: `merge_pairs.session_flights`; `flight_maps` for an older
        # sosmatch) and the warnings go into merge.json (not into the identity: earlier merges keep theirs)
        said = {"warnings": list(warnings)} if warnings else {}
        result = _merge_into(out, sessions, transforms, pairs, labels, max_fuse_distance_m,
                             {**(record or {}), "flight_maps": maps_of(flights), "flights": flights,
                              "size_definition": merged_size_definition(defs), **said}, t0)
        out.finish()
    return result


def _merge_into(out: OutputDir, sessions: list[SessionFiles], transforms: list[Sim3],
                pairs: Sequence[FusePair | tuple[int, int, np.ndarray]], labels: list[str], max_fuse_distance_m: float,
                record: dict[str, Any], t0: float) -> MergeResult:
    """`merge_sessions` inside its taken output directory: build in the staging area, then publish."""
    import pycolmap

    out_dir = out.path
    pairs, rejected = filter_associations(sessions, transforms, pairs, max_fuse_distance_m)
    groups = fusion_groups(pairs)
    # associations the groups could not hold (one would join two landmarks of one session): not fused either
    rejected += associations_not_fused(pairs, groups)

    merged = pycolmap.Reconstruction()
    point_map: list[dict[int, int]] = []  # per session: old point3D id -> new id
    own_error: dict[int, float] = {}  # new point3D id -> the error its session recorded
    image_names: dict[int, str] = {}
    next_camera, next_image = 1, 1
    for session, transform, label in zip(sessions, transforms, labels):
        rec = load_reconstruction(session.sparse_dir)
        if not np.allclose(transform.matrix(), Sim3.identity().matrix()):
            rec.transform(pycolmap.Sim3d(transform.matrix()))
        camera_map: dict[int, int] = {}
        for cid in sorted(rec.cameras):
            cam = rec.cameras[cid]
            merged.add_camera_with_trivial_rig(
                pycolmap.Camera(
                    model=cam.model, width=cam.width, height=cam.height, params=cam.params, camera_id=next_camera
                )
            )
            camera_map[cid] = next_camera
            next_camera += 1
        image_map: dict[int, int] = {}
        skipped = 0
        for iid in sorted(rec.images):
            img = rec.images[iid]
            if not img.has_pose:
                skipped += 1  # an unregistered image carries no observation worth keeping in a merged model
                continue
            keypoints = np.array([p.xy for p in img.points2D], dtype=np.float64).reshape(-1, 2)
            name = f"{label}/{img.name}"
            new = pycolmap.Image(
                name=name, keypoints=keypoints, camera_id=camera_map[img.camera_id], image_id=next_image
            )
            merged.add_image_with_trivial_frame(new, img.cam_from_world())
            image_map[iid] = next_image
            image_names[next_image] = name
            next_image += 1
        if skipped:
            log.info("%s: %d unregistered images left out", session.name, skipped)
        pmap: dict[int, int] = {}
        for pid in sorted(rec.points3D):
            pt = rec.points3D[pid]
            track = pycolmap.Track()
            for el in pt.track.elements:
                if el.image_id in image_map:
                    track.add_element(image_map[el.image_id], el.point2D_idx)
            if track.length() == 0:
                continue
            pmap[pid] = merged.add_point3D(pt.xyz, track, pt.color)
            own_error[pmap[pid]] = float(pt.error)
        point_map.append(pmap)

    # Fuse: each group of associated landmarks becomes one point; remember where every member landed.
    fused_pid: dict[tuple[int, int], int] = {}
    members_of: dict[int, list[tuple[int, int]]] = {}
    num_fused = 0
    for group in groups:
        pids = []
        for s, lm in group:
            pid = point_map[s].get(int(sessions[s].point3d_ids[lm]))
            if pid is not None:
                pids.append(pid)
        if len(pids) < 2:
            continue
        current = pids[0]
        for other in pids[1:]:
            current = merged.merge_points3D(current, other)
        for member in group:
            fused_pid[member] = current
        members_of[current] = list(group)
        num_fused += 1
    merged.update_point_3d_errors()
    # a landmark not fused keeps the error its session recorded: for one located from the views that see its mask
    # whole that is the error over those views (`triangulation.located_from_whole_masks`), which recomputing over
    # all its views (cut ones included, off by design) would undo; a fused point's error is over all its members'
    for pid, error in own_error.items():
        if pid not in members_of and pid in merged.points3D:
            merged.points3D[pid].error = error

    # Merged landmark map: session order, fused landmarks once (at their first member's place).
    positions, sizes, pids_out, nobs, names = [], [], [], [], []
    emitted: set[int] = set()
    for s, session in enumerate(sessions):
        lm_pos = transforms[s].apply(session.landmarks.positions)
        lm_size = session.landmarks.sizes.astype(np.float64) * transforms[s].scale
        for i in range(len(session.landmarks)):
            pid = fused_pid.get((s, i))
            if pid is None:
                old = int(session.point3d_ids[i])
                pid = point_map[s].get(old, -1) if old >= 0 else -1
                pos, size = lm_pos[i], lm_size[i]
            else:
                if pid in emitted:
                    continue
                members = members_of[pid]
                pos = np.asarray(merged.points3D[pid].xyz)
                msizes = [sessions[m].landmarks.sizes[mi] * transforms[m].scale for m, mi in members]
                size = float(np.nanmean(msizes)) if np.any(np.isfinite(msizes)) else np.nan
            if pid >= 0:
                emitted.add(pid)
                els = merged.points3D[pid].track.elements
                nobs.append(len(els))
                names.append(sorted({image_names[e.image_id] for e in els}))
            else:
                nobs.append(0)
                names.append([])
            positions.append(pos)
            sizes.append(size)
            pids_out.append(pid)
    ref = sessions[0].landmarks
    # a merged map of any SfM-posed session is SfM-posed: its landmarks keep that block's dome (rev51 D2: without
    # the flag the merged map was matched rigidly again, "imprecise")
    sfm = any(session_sfm_poses(s.path, s.landmarks, s.record) for s in sessions)
    lmap = LandmarkMap(np.asarray(positions).reshape(-1, 3), np.asarray(sizes), ref.origin, ref.epsg,
                       _merged_noise(sessions, transforms), sfm_poses=sfm)

    sparse = out.staged("sparse")
    sparse.mkdir()
    merged.write_binary(str(sparse))
    write_landmark_map(out.staged("landmarks.sosmap"), lmap)
    write_landmarks_csv(out.staged("landmarks.csv"), lmap, np.asarray(pids_out), np.asarray(nobs), names)
    result = MergeResult(
        out_dir=out_dir,
        # resolved, as the match is recorded (rev45 D6: typed relative paths meant little read from elsewhere)
        sessions=[str(resolved_path(s.path)) for s in sessions],
        labels=labels,
        transforms=list(transforms),
        num_cameras=merged.num_cameras(),
        num_images=merged.num_images(),
        num_points3d=merged.num_points3D(),
        num_landmarks=len(lmap),
        num_fused=num_fused,
        num_rejected=rejected,
        pose_source=POSE_SOURCE_SFM if sfm else POSE_SOURCE_GIVEN,
    )
    record = dict(record)
    result.refined = bool(record.pop("refined", False))
    result.seconds = time.perf_counter() - t0
    _write_merge_record(out.staged(MERGE_RECORD), result, record)
    out.publish(["sparse", *MERGE_FILES[:-1]], last=MERGE_RECORD)
    return result


def _write_merge_record(path: Path, result: MergeResult, extra: dict[str, Any]) -> None:
    """merge.json (published last, so that its presence means the whole merge finished)."""
    import pycolmap

    from ..plugin import __version__

    data = result.to_dict()
    data["versions"] = {"sosmatch": __version__, "pycolmap": pycolmap.__version__, "numpy": np.__version__}
    data.update(extra)
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")


def _precision_of(match: MatchSummary, refinement: Refinement | None, a: LandmarkMap, b: LandmarkMap,
                  gate: float) -> str | None:
    """Why the transform the merge uses may place B's landmarks beyond `gate` (None: it is precise): the match's
    answer's imprecision (`imprecise_note`), or, when --refine replaced the answer (`Refinement.fuse`), the refined
    fit's own (`answer_uncertainty` on the pairs it fitted, as `match` measures its answer). rev54 D1: a refined
    transform 2.4 m at most from the truth inside a 3.2 m gate was said and recorded to "inherit" the unrefined
    answer's 4.9 m."""
    if refinement is None or refinement.fuse is None:
        return imprecise_note(match)
    from ..plugin.answer_uncertainty import answer_uncertainty

    unc = answer_uncertainty(a.positions, b.positions, refinement.transform, refinement.fuse.associations,
                             gate)
    if match.imprecise and unc is not None:
        log.info("the match's answer was imprecise; the refined transform (%d pairs) may place B's landmarks up to "
                 "%.1f m from where they belong (95 %%), its gate %g m", refinement.used, unc.predicted_max_m, gate)
    if unc is None or not unc.imprecise:
        return None
    return (f"the refined transform ({refinement.used} pairs) is imprecise: "
            f"{unc.warning().removeprefix('imprecise answer: ')}")


def ignored_settings(chosen: Collection[str], match: MatchSummary, refine: bool) -> str:
    """The chosen settings (dotted names) a merge of `match` does not use, as one text ("" when none): it uses the
    changes section (its alignment control, `changes.check_alignment`), association.distance_tolerance_m only for
    a match.json that records no gate (`answer_gate`), and, with --refine of an unverified answer, the verification
    settings match.json does not record (`refined_answer`). rev54 D3: `--set association.distance_tolerance_m=0.1`
    and `--preset paper` wrote the same bytes as without them, without a word."""
    refining = refine and match.source != "verified"
    used = {name for name in chosen if name.startswith("changes.")
            or (name == "association.distance_tolerance_m" and match.gate_m is None)
            or (refining and name.startswith("verification.") and name.partition(".")[2] not in match.refinement)}
    ignored = sorted(set(chosen) - used)
    return ", ".join(ignored[:6]) + (f" and {len(ignored) - 6} more" if len(ignored) > 6 else "")


def run(
    session_a: str | Path,
    session_b: str | Path,
    match_json: str | Path,
    out_dir: str | Path,
    params: Params | None = None,
    refine: bool = False,
    labels: tuple[str, str] | None = None,
    overwrite: bool = False,
    trust_images: bool = False,
    chosen: Collection[str] = (),
) -> MergeResult:
    """Merge session B into session A's frame using match.json's accepted hypothesis; see the module docstring.

    With `refine`, an unverified answer's transform is refined on the full maps as the match's verification
    refines an alignment (`refined_answer`); a verified answer is that refinement already and is kept (said). A
    refined transform fuses the pairs it supports (`Refinement.fuse`), not the answer's associations.
    Raises InputError when match.json was computed for other maps (`match_io.check_match_maps`) or has no
    accepted hypothesis, or when its transform (refined or not) does not bring the maps together
    (`changes.check_alignment`), or when the images agree but the two maps' georeferences do not
    (`match_notes.georeference_note`: one of them is wrong, and the merged model would place B's landmarks by A's)
    unless `trust_images` (then said, and recorded in merge.json). `overwrite`: replace a complete merge of other
    inputs in `out_dir`. `chosen`: the settings the user chose (`config_io.chosen_settings`): those the merge does
    not use are said (`ignored_settings`).
    """
    params = params or Params()
    # a bad --out (a user's folder, an input, a file) is refused before any work and any warning (rev45 D4: after
    # the analysis, below its warnings), as `changes` does; `open_output_dir` still decides the rest
    check_output_dir(out_dir, "merge", inputs=[session_a, session_b, match_json], legacy_record=MERGE_RECORD)
    a, b = read_session(session_a), read_session(session_b)
    names = _labels([a, b], list(labels) if labels else None)  # refused before any work (`label_problem`)
    match = read_match(match_json)
    check_match_maps(match, a.landmarks, b.landmarks, match_json, names=(str(session_a), str(session_b)))
    if not match.accepted or match.transform is None:
        raise InputError("match has no accepted hypothesis: the sessions cannot be merged", match_json)
    said = [] if (crs := crs_disagreement(a.landmarks, b.landmarks)) is None else [crs]
    if b.landmarks.epsg and not a.landmarks.epsg:  # the model is in A's frame: B's georeference is not carried
        said.append(f"{session_b} is georeferenced (EPSG:{b.landmarks.epsg}) and {session_a} is not: the merged model "
                    f"is in {session_a}'s local frame; match and merge with the georeferenced session first to keep "
                    "its georeference")
    if (note := precision_note(a, b, str(session_a), str(session_b))) is not None:
        said.append(note)
    imprecise_at = len(said)  # the answer's precision is said once the transform used is known (`_precision_of`)
    # a probably wrong result is no success: the user decides which georeference stands
    if (note := check_georeferences(match, a.landmarks, b.landmarks, match_json, trust_images, "merged",
                                    "merges it")) is not None:
        said.append(f"{session_b}: {note}; merged all the same (--trust-images): the model keeps {session_a}'s "
                    "georeference")
    if (note := unverified_note(match)) is not None:
        how = "refining its window consensus on the full maps (--refine)" if refine else \
            "merging its window consensus as it is"
        said.append(f"{match_json}: {note}: {how}; `sosmatch match` again verifies it")
    transform = match.transform
    # the answer's own gate (recorded in match.json: the tolerance the match derived from the maps), for the
    # refinement, the control and the fusion alike; a match.json without it: the configured one
    gate = answer_gate(match, params.association.distance_tolerance_m)
    refinement = refined_answer(a.landmarks, b.landmarks, match, params) if refine else None
    used, dof = 0, 0
    if refinement is not None:
        transform, used, dof = refinement.transform, refinement.used, refinement.dof
    if (note := _precision_of(match, refinement, a.landmarks, b.landmarks, gate)) is not None:
        said.insert(imprecise_at, f"{match_json}: {note}: the merged model inherits that error")
    # the control of `changes` (a merge never fuses what it refuses as chance), at the answer's own gate: maps of
    # 20 m objects (NAIP, theta_eps 8 m) have no counterparts at the configured 2 m even at the true alignment;
    # said before any warning, so that a refusal is one line
    check_alignment(a, b, transform, params, match.source == "verified", gate, match_json, "nothing merged")
    # the warnings are said once the output directory is taken (`merge_sessions`' `say`), so that a refusal of it
    # is one line too; --refine asked for and nothing refined: a warning, as match says of an option it ignores (at
    # INFO, `-q` hid it and the output line alone did not tell it)
    say = [*said, *([f"{match_json}: {refinement.note}"] if refinement is not None and refinement.note else [])]
    if (ignored := ignored_settings(chosen, match, refine)):
        say.append(f"{ignored}: not used by merge, ignored (it fuses at the match's own gate, {gate:g} m, refines by "
                   "the settings match.json records, and takes only changes.* for its alignment control; mapping "
                   "and search settings act in `map` and `match`)")
    if not labels and names != [a.name, b.name]:  # the folder names fell back to places (`_labels`): said (rev45 D7)
        say.append(f"{session_a} and {session_b} share the folder name {a.name!r}: their images are named "
                   f"{names[0]}/... and {names[1]}/... in the merged model (merge.json `labels`)")
    # the match file by its real path: another spelling of it is the same input (and the same merge)
    # merge.json records the match file by its real path; the identity names the match by its content (what it
    # says, `match_content`), so that a project moved or copied whole is the same merge (nu37 D1)
    kept = refinement is not None and refinement.note is not None
    record = {"refined": bool(refine and used), "match": str(resolved_path(match_json)),
              "match_transform": match.transform.to_dict(),
              "refine": {"requested": refine, "associations_used": used, "dof": dof,
                         **({"kept": refinement.note} if kept else {})}}
    # a --refine that refined nothing (`refinement.note`) writes what the merge without it writes: the same output
    # (rev45 D5: refused over a merge byte for byte the same); merge.json still says it was asked for
    same = {**record, "refine": {"requested": False, "associations_used": 0, "dof": 0}} if kept else record
    result = merge_sessions(
        [a, b],
        [Sim3.identity(), transform],
        [fused_pair(0, 1, match, refinement)],
        out_dir,
        labels=names,
        max_fuse_distance_m=gate,
        record=record,
        overwrite=overwrite,
        inputs=[match_json],
        identity_record={**same, "match": match_content(match)},
        # merges until nu37 named the match by its real path, before 2026-12-05 as it was spelt: the same merge
        # when it lies there again; a --refine that refined nothing until rev45 D5 had an identity of its own
        earlier_records=[same, {**same, "match": str(match_json)},
                         *([{**record, "match": match_content(match)}, record] if kept else [])],
        warnings=said,
        say=say,
    )
    log.info(
        "merged %s + %s: %d images, %d points, %d fused landmarks",
        a.name, b.name, result.num_images, result.num_points3d, result.num_fused,
    )
    return result
