"""The synthetic truth of an evaluated map pair (ours): which object every landmark is, the common landmarks,
which eligible objects the segmenter found in both maps, the size agreement and the oracle recall
(`plugin.evaluation.landmark_truth`); the label images, objects and maps are read here."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ...database.session_io import map_keyframe_names, map_min_observations
from ...plugin.errors import InputError
from ...plugin.params import Params

OBJECT_TRUTH_FILES = ("objects.csv", "frames.json", "labels")


def has_object_truth(session: Path) -> bool:
    """Whether SESSION holds object truth (objects.csv, frames.json, labels/): an orthophoto session or a real
    flight may lack it (their objects are then not scored); a session rendered by `sosmatch synth` always has it,
    so one missing there is an incomplete session, refused (InputError naming the file) rather than scored
    without its object columns."""
    from ...database.synth_session import rendered_by_synth

    missing = [f for f in OBJECT_TRUTH_FILES if not (session / f).exists()]
    if missing and rendered_by_synth(session):
        raise InputError("file not found: a session rendered by `sosmatch synth` has it (an incomplete copy? "
                         "render it again)", session / missing[0])
    return not missing


def keyframes_for_a_landmark(params: Params, map_dir: Path) -> int:
    """The fewest keyframes in which the map at MAP_DIR could make a landmark of an object: one more than the theta_n
    it was made with (run.json, lowered by its flight's views where `params.for_flight` did), else than the
    configured one (maps without the record)."""
    return (map_min_observations(map_dir) or params.triangulation.min_observations) + 1


def landmark_truth(params: Params, session_a: Path, session_b: Path, map_a: Path, map_b: Path, sos: dict,
                   iou: np.ndarray) -> dict | None:
    """Common landmarks of the two maps against the synthetic ground-truth objects, the size agreement of the
    common pairs and the oracle recall (`plugin.evaluation.landmark_truth`); None without object truth."""
    from ...database.evaluation_io import landmark_observed_objects, segment_objects
    from ...database.synth_session import load_synth_session
    from ...plugin.evaluation.landmark_truth import (
        common_landmarks,
        count_by,
        eligible_objects,
        majority_objects,
        oracle_recall,
        segmented_objects,
    )

    if not (has_object_truth(session_a) and has_object_truth(session_b)):
        return None
    t0 = time.perf_counter()
    synth = [load_synth_session(s) for s in (session_a, session_b)]
    seen, segmented = [], []
    # an object is eligible when each map's keyframes saw it often enough to make a landmark there
    min_keyframes = [keyframes_for_a_landmark(params, m) for m in (map_a, map_b)]
    for s, m, least in zip(synth, (map_a, map_b), min_keyframes):
        names = map_keyframe_names(m)
        keyframes = None if names is None else set(names)
        counts: dict[int, int] = {}
        for frame in s.frames:
            if keyframes is None or frame["name"] in keyframes:
                for oid in frame["visible_object_ids"]:
                    counts[int(oid)] = counts.get(int(oid), 0) + 1
        seen.append(counts)
        # which objects the segmenter found often enough (every mask, from the map's database), where it exists
        has_db = names is not None and (m / "database.db").is_file()
        size = (s.camera.width, s.camera.height)
        segmented.append(segmented_objects(segment_objects(m, s.path / "labels", names, size), least)
                         if has_db else None)
    present = [s.present_objects()["id"] for s in synth]
    eligible = eligible_objects(present[0], present[1], seen[0], seen[1], *min_keyframes)
    kind_of = {int(o["id"]): str(o["kind"]) for s in synth for o in s.objects}
    objs = [majority_objects(landmark_observed_objects(m, s.path / "labels")) for s, m in zip(synth, (map_a, map_b))]
    (pa, pb), (ha, hb) = sos["positions"], sos["sizes"]
    common = common_landmarks(objs[0], objs[1], pa, pb, ha, hb, eligible, kind_of)
    theta_r = sos["association"]["max_size_difference"]  # the gate the search used (possibly derived)
    out = common.summary(theta_r)
    from ...plugin.association.gates import size_ratio

    gated = common.pairs[size_ratio(common.sizes[:, 0], common.sizes[:, 1]) <= theta_r] if len(common.pairs) else \
        common.pairs
    out["oracle"] = oracle_recall(common.pairs, sos["observers"][0], sos["observers"][1], iou, sos.get("geometry"))
    out["oracle_size_gated"] = oracle_recall(gated, sos["observers"][0], sos["observers"][1], iou, sos.get("geometry"))
    out["eligible_by_kind"] = count_by([kind_of[int(o)] for o in eligible])
    out["mapped_a_by_kind"] = count_by([kind_of[int(o)] for o in common.mapped_a])
    out["mapped_b_by_kind"] = count_by([kind_of[int(o)] for o in common.mapped_b])
    out["landmarks_on_objects"] = [int(np.count_nonzero(o.object_ids > 0)) for o in objs]
    if segmented[0] is not None and segmented[1] is not None:
        # eligible objects segmented in > theta_n keyframes of both maps, and those of them not common: the front
        # end's losses split into the segmenter's (not segmented) and tracking + triangulation's (segmented, lost)
        both = np.intersect1d(np.intersect1d(eligible, segmented[0]), segmented[1])
        lost = np.setdiff1d(both, common.objects)
        out["segmented_both_by_kind"] = count_by([kind_of[int(o)] for o in both])
        out["segmented_not_common_by_kind"] = count_by([kind_of[int(o)] for o in lost])
        radius = {int(o["id"]): float(o["radius"]) for s in synth for o in s.objects}
        unseg = np.setdiff1d(eligible, both)
        out["unsegmented_radius_m"] = [radius[int(o)] for o in unseg]
        out["unsegmented_kinds"] = [kind_of[int(o)] for o in unseg]
    # associations of accepted hypotheses that join two landmarks of one object (the truth the search should find)
    ids_a, ids_b = objs[0].object_ids, objs[1].object_ids
    out["accepted_same_object"] = [int(np.count_nonzero((ids_a[a[:, 0]] == ids_b[a[:, 1]]) & (ids_a[a[:, 0]] > 0)))
                                   for a, _ in sos["accepted"]]
    out["common_pairs"] = [[int(o), int(i), int(j), float(x), float(y)] for o, (i, j), (x, y)
                           in zip(common.objects, common.pairs, common.sizes)]
    out["seconds"] = time.perf_counter() - t0
    return out
