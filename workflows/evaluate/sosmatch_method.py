"""SOS-Match's row of the evaluation: the match's answer on the two maps (searched in-process, or read from a
match.json), its hypotheses and verified answer turned into keyframe-pair claims, and their errors against the
ground truth."""

from __future__ import annotations

import dataclasses
import logging
import math
import statistics
from pathlib import Path
from typing import Any

import numpy as np

from ...database.evaluation_io import read_match_hypotheses
from ...database.map_loading import read_map_noise, session_map_noise, session_sfm_poses
from ...database.match_io import check_match_maps, read_match_json
from ...plugin.association.hypotheses import MIN_LANDMARKS_TO_ALIGN
from ...plugin.errors import InputError
from ...plugin.evaluation.claims import Hypothesis, claim_scores, observer_geometry
from ...plugin.multisession import Sim3
from ...plugin.params import Params, params_to_dict
from ...plugin.verification import hypothesis_agrees
from .checks import _check_sweep_floor
from .ground_truth import GroundTruthSession, _map_arrays, _map_frame_centers, _observers, world_from_map

log = logging.getLogger(__name__)


def _run_sosmatch(params: Params, gt_a: GroundTruthSession, gt_b: GroundTruthSession, map_a: Path, map_b: Path,
                  match_dir: Path | None, sweep_floor: int | None, repeats: int, max_observers: int | None,
                  separation: float | None = None, transform_chosen: bool = False) -> dict:
    from ...plugin.association.windowed_search import search
    from ..match.transform_choice import answer_plan, plan_search

    pa, ha, bytes_a, lmap_a = _map_arrays(map_a)
    pb, hb, bytes_b, lmap_b = _map_arrays(map_b)
    # each map's frame against the ground truth's: the true a_from_b, and the keyframes in each map's frame
    world_a, world_b = (world_from_map(gt.path, m, lm.epsg if lm is not None else 0)
                        for gt, m, lm in ((gt_a, map_a, lmap_a), (gt_b, map_b, lmap_b)))
    truth = world_a.inverse().compose(world_b)
    centers_a, centers_b = _map_frame_centers(gt_a, map_a, world_a), _map_frame_centers(gt_b, map_b, world_b)
    obs_a, _ = _observers(gt_a, map_a, max_observers, centers_a)
    obs_b, _ = _observers(gt_b, map_b, max_observers, centers_b)
    if obs_a.shape[0] != len(pa) or obs_b.shape[0] != len(pb):
        raise InputError("landmarks.csv and landmarks.sosmap disagree on the number of landmarks", map_a)
    noise = [read_map_noise(m) if lm is None else session_map_noise(m, lm)
             for m, lm in ((map_a, lmap_a), (map_b, lmap_b))]
    # the searches `sosmatch match` runs: the transform the maps' pose sources choose unless the user chose it
    # (rev51 D3: evaluate searched SfM maps rigidly where match fits a similarity); a match file is scored as it is
    plan = plan_search(params, transform_chosen or match_dir is not None,
                       *(session_sfm_poses(m, lm) for m, lm in ((map_a, lmap_a), (map_b, lmap_b))), *noise,
                       pa, ha, pb, hb)
    derivation = plan.first.derivation
    assoc_params = derivation.params
    out: dict[str, Any] = {"map_bytes": [bytes_a, bytes_b], "landmarks": [len(pa), len(pb)],
                           "association": params_to_dict(assoc_params), "derived": derivation.record,
                           "map_noise": [None if n is None else n.to_dict() for n in noise]}
    best = None
    if match_dir is not None:
        hyps = read_match_hypotheses(match_dir, assoc_params.max_gravity_angle_deg)
        match_json = match_dir / "match.json" if match_dir.is_dir() else match_dir
        if lmap_a is None or lmap_b is None:
            raise InputError("scoring a match file needs both maps' landmarks.sosmap (to check that the match is "
                             "about them)", map_a if lmap_a is None else map_b)
        check_match_maps(hyps.match, lmap_a, lmap_b, match_json, names=(str(map_a), str(map_b)))
        hypotheses = [Hypothesis(a, float(s), bool(ok), None if h.transform is None else h.transform.rotation)
                      for a, s, ok, h in zip(hyps.associations, hyps.sizes, hyps.gravity_ok, hyps.match.hypotheses)]
        out["search_seconds"] = hyps.seconds
        out["search_seconds_runs"] = [hyps.seconds]
        out["kernel_compile_seconds"] = _kernel_compile_seconds(read_match_json(match_json), match_json)
        out["curve_floor_theta_S"] = hyps.min_associations
        if hyps.match.accepted:  # the match's answer (verified unless it ran without verification)
            best = {"associations": hyps.match.associations.tolist(),
                    "transform": hyps.match.transform.matrix().tolist(), "answer": hyps.match.source}
        accepted = np.flatnonzero(hyps.accepted)
        theta_s = hyps.min_associations if hyps.min_associations is not None else assoc_params.min_associations
        out["accepted"] = [(hyps.associations[k], hyps.match.hypotheses[k].transform) for k in accepted]
        ver_doc = read_match_json(match_json).get("verification")
        verified_by_match = None if ver_doc is None else (
            hyps.match.transform, hyps.match.associations, hyps.match.runner_up_support or 0,
            _clear_in_file(ver_doc, len(hyps.match.associations), hyps.match.runner_up_support or 0, params), None)
    elif min(len(pa), len(pb)) < MIN_LANDMARKS_TO_ALIGN:
        # Too few landmarks for any transform: the method claims nothing (an honest zero, not an error; a
        # --sweep-floor was refused before, `check_sweep_floor_maps`).
        log.warning("maps have %d and %d landmarks: SOS-Match can claim nothing", len(pa), len(pb))
        hypotheses = []
        theta_s = assoc_params.min_associations
        out["accepted"] = []
        verified_by_match = None
        out.update(search_seconds=0.0, search_seconds_runs=[0.0], curve_floor_theta_S=None, accepted_hypotheses=0,
                   window_pairs=0, note=f"maps have {len(pa)} and {len(pb)} landmarks")
    else:
        # the time of the match's answer as `sosmatch match` records it: the search and its verification, without
        # compiling or loading numba kernels (`MatchAnswer.timings`)
        times = []
        answer = None
        compile_s = 0.0
        common = bool(lmap_a is not None and lmap_b is not None and lmap_a.epsg == lmap_b.epsg != 0)
        for _ in range(max(1, repeats)):
            planned = answer_plan(plan, pa, ha, pb, hb, common_frame=common)
            answer = planned.answer
            # the search the answer was made with (the rigid one after a similarity's scale no dome makes)
            derivation = planned.search.derivation
            assoc_params = derivation.params
            times.append(answer.timings["total_s"])
            compile_s += answer.timings["kernel_compile_s"]
            _check_sweep_floor(sweep_floor, (answer.searched or assoc_params).min_associations)
        result = answer.search
        out.update(association=params_to_dict(assoc_params), derived=derivation.record)
        if planned.note is not None:  # as match.json's search_mode
            out["transform_from_poses"] = planned.note
        # the parameters of the search whose hypotheses these are: the first of two searches keeps the configured
        # windows and theta_S (`first_search_params`), so its operating point is the configured theta_S
        searched = answer.searched or assoc_params
        out["search_seconds"] = statistics.median(times)
        out["search_seconds_runs"] = times
        out["kernel_compile_seconds"] = compile_s
        out["verify_seconds"] = answer.timings["verify_s"]
        if sweep_floor is None or sweep_floor >= searched.min_associations:
            floor, sweep = searched.min_associations, result  # the curve starts at the operating point
        else:  # a lower floor keeps hypotheses with small |S| (costly: the solver runs on far more window pairs)
            floor = sweep_floor
            sweep = search(pa, ha, pb, hb, dataclasses.replace(searched, min_associations=floor))
        out["curve_floor_theta_S"] = floor
        hypotheses = [
            Hypothesis(h.associations, float(h.size),
                       h.transform is not None and bool(h.tilt_deg <= assoc_params.max_gravity_angle_deg),
                       None if h.transform is None else h.transform.rotation)
            for h in sweep.hypotheses
        ]
        if answer.accepted:
            best = {"associations": answer.associations.tolist(), "transform": answer.transform.to_matrix().tolist(),
                    "answer": answer.source}
        theta_s = searched.min_associations
        out["accepted"] = [] if result is None else [(result.hypotheses[k].associations, result.hypotheses[k].transform)
                                                     for k in result.accepted]
        out["accepted_hypotheses"] = 0 if result is None else len(result.accepted)
        out["window_pairs"] = 0 if result is None else result.num_window_pairs
        v = answer.verification
        verified_by_match = None if v is None else (
            None if v.best is None else v.best.transform,
            np.zeros((0, 2), np.int64) if v.best is None else v.best.associations, v.runner_up_support,
            v.clear and not v.beyond_prior, answer.timings["verify_s"])
    verification, verified, winner = _verified_claim(verified_by_match, pb, theta_s, truth)
    out["verification"] = verification
    out["num_hypotheses"] = len(hypotheses)
    out["operating_theta_S"] = int(theta_s)
    out["accepted_truth"] = [{"size": int(len(assoc)), **error_to_identity(t, pb[assoc[:, 1]], truth, pb)}
                             for assoc, t in out["accepted"]]
    geometry = None
    if separation is not None:
        geometry = (observer_geometry(obs_a, pa, centers_a), observer_geometry(obs_b, pb, centers_b), separation)
    out["geometry"] = geometry
    out["scores_windows"] = claim_scores(hypotheses, obs_a, obs_b, geometry)
    if verification is None:  # no verification ran (`--no-verify`): the matcher answers with its windows
        out["scores"] = out["scores_windows"]
    elif verified is None:
        # the verification refused: `sosmatch match` answers "no match", so the matcher claims nothing (its
        # window hypotheses are chance-level |S| 7 as often as true ones across seasons: world 97's crossing
        # flight had 8 "accepted" at 2-21 m; they stay in the windows-only row, the paper's protocol)
        out["scores"] = np.full_like(out["scores_windows"], np.nan)
    else:  # the matcher's answer: the verified alignment and the window hypotheses that agree with it
        tol = 2.0 * assoc_params.distance_tolerance_m
        agreeing = [h for h in hypotheses if hypothesis_agrees(h.associations, winner, pa, pb, tol)]
        for entry, (assoc, _) in zip(out["accepted_truth"], out["accepted"]):
            entry["agrees_with_verified"] = hypothesis_agrees(assoc, winner, pa, pb, tol)
        out["scores"] = claim_scores(agreeing + [verified], obs_a, obs_b, geometry)
        verification["window_hypotheses_agreeing"] = len(agreeing)
        verification["window_hypotheses_dropped"] = int(sum(h.valid for h in hypotheses)) - len(agreeing)
    out["best"] = best
    out["positions"] = (world_a.apply(pa), world_b.apply(pb))  # the ground truth's frame (landmark truth, overlay)
    out["sizes"] = (ha, hb)
    out["observers"] = (obs_a, obs_b)
    return out


def _verified_claim(verified: tuple | None, pb: np.ndarray, theta_s: int,
                    truth: Sim3 | None = None) -> tuple[dict | None, Hypothesis | None, Any]:
    """The match's verified answer as a claim (the verification `plugin.match_answer.match_maps` ran, in this
    process or as match.json records it; one verification for `sosmatch match`, batch and this evaluation).
    `verified`: (transform, associations, runner-up support, clear, seconds), None when it did not run; `clear`:
    the verification's own decision apart from theta_S (its winner beats every rival by min_ratio and chance by
    the false-alarm rate: `plugin.verification.Verification.clear`, match.json `verification.clear`).
    Returns its record and, when it is clear, the claiming hypothesis of its associations scored by their number
    (its support), so that the theta_S sweep accepts it exactly when support > theta_S, and its transform (None
    without a clear winner)."""
    if verified is None:
        return None, None, None
    transform, assoc, runner_up, clear, seconds = verified
    assoc = np.asarray(assoc, dtype=np.int64).reshape(-1, 2)
    if transform is None or not len(assoc):
        return {"support": 0, "accepted": False, "seconds": seconds}, None, None
    clear = bool(clear)
    record = {"support": int(len(assoc)), "runner_up_support": int(runner_up), "transform": transform.to_dict(),
              "clear_winner": clear, "accepted": bool(clear and len(assoc) > theta_s), "seconds": seconds,
              **error_to_identity(transform, pb[assoc[:, 1]], truth, pb), "associations": assoc.tolist()}
    if not clear:
        return record, None, None
    return record, Hypothesis(assoc, float(len(assoc)), True, transform.rotation), transform


def _clear_in_file(ver_doc: dict, support: int, runner_up: int, params: Params) -> bool:
    """match.json's `verification.clear` (and not `beyond_prior`: a winner beyond the position prior is no answer
    of its chance test, and the match refused it); files written before the chance model had only the ratio test."""
    if "clear" in ver_doc:
        return bool(ver_doc["clear"]) and not bool(ver_doc.get("beyond_prior", False))
    min_ratio = float((ver_doc.get("method") or {}).get("min_ratio", params.verification.min_ratio))
    return bool(support >= min_ratio * runner_up)


def error_to_identity(transform: Any, points_b: np.ndarray, truth: Sim3 | None = None,
                      map_b: np.ndarray | None = None) -> dict:
    """How far a hypothesis is from the truth, at the centroid of its own associated B landmarks: `error_m` (3D),
    `horizontal_m`, `yaw_deg`, and `max_m` (the largest displacement of any of them). The evaluation's sessions
    share one world frame (their footprints are compared in it), so the true transform is the identity, up to
    each map's own pose drift (1-2 m on the synthetic EKF poses); `truth`: the true a_from_b when a map is in
    another frame than the world (`world_from_map`: a georeferenced map), else the identity.

    `map_b` (all of B's landmarks): also `map_median_m` and `map_max_m`, the horizontal displacement over every
    landmark of B, where a merge or a change comparison uses the transform. The centroid of the pairs is where a
    fit is best: a yaw 0.68 deg off read 1.9 m there and moved B's landmarks a median 8.8 m, at most 23 m (NAIP)."""
    from ...plugin.association.rigid import roll_pitch_yaw_deg

    nan = float("nan")
    over_map = {} if map_b is None else {"map_median_m": nan, "map_max_m": nan}
    if transform is None or len(points_b) == 0:
        return {"error_m": nan, "horizontal_m": nan, "yaw_deg": nan, "max_m": nan, **over_map}
    truth = truth or Sim3.identity()
    centre = points_b.mean(axis=0)
    d = transform.apply(centre[None])[0] - truth.apply(centre[None])[0]
    if map_b is not None and len(map_b):
        moved = np.linalg.norm((transform.apply(map_b) - truth.apply(map_b))[:, :2], axis=1)
        over_map = {"map_median_m": float(np.median(moved)), "map_max_m": float(moved.max())}
    return {"error_m": float(np.linalg.norm(d)), "horizontal_m": float(np.hypot(d[0], d[1])),
            "yaw_deg": abs(roll_pitch_yaw_deg(transform.rotation @ truth.rotation.T)[2]),
            "max_m": float(np.linalg.norm(transform.apply(points_b) - truth.apply(points_b), axis=1).max()),
            **over_map}


def _kernel_compile_seconds(match_doc: dict, path: Path) -> float | None:
    """The time a match file's run spent compiling or loading numba kernels, kept out of its `search_seconds`
    (match.json `timings.kernel_compile_s`); None, with a warning, for a file of an older sosmatch, whose search
    time holds that compile when its run was the first of an install (151 s for a search of 0.9 s, nu54)."""
    timings = match_doc.get("timings")
    value = timings.get("kernel_compile_s") if isinstance(timings, dict) else None
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
        return float(value)
    log.warning("%s records no kernel compile time (written by an older sosmatch): its search time includes the "
                "numba kernel compile if that run compiled them (the first match of an install); re-run sosmatch "
                "match to time the search alone", path)
    return None
