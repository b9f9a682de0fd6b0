"""The evaluation's computation: ground truth of both sessions, the match (our verified answer and the raw
window hypotheses), the baselines, the PR curves and the outputs (the package docstring says what and why)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...database.atomic import write_text_atomic
from ...database.evaluation_io import read_match_hypotheses
from ...database.json_text import json_default
from ...database.landmark_map import check_two_maps, read_landmark_map
from ...database.map_loading import read_map_noise, session_map_noise
from ...database.match_io import check_match_maps, read_match_json
from ...database.output_markers import VersionedIdentity, check_finished, content_fingerprint, versioned_identity
from ...database.outputs import open_output_dir
from ...database.session_images import check_map_of_images
from ...database.session_io import check_session_usable
from ...plugin.association.hypotheses import MIN_LANDMARKS_TO_ALIGN
from ...plugin.errors import InputError
from ...plugin.evaluation.claims import (
    Hypothesis,
    claim_scores,
    observer_geometry,
    separation_ratio,
)
from ...plugin.evaluation.iou import iou_matrix
from ...plugin.evaluation.metrics import FP_IOU, TP_IOU, PRCurve, operating_point, pr_curve
from ...plugin.map_noise import derived_search_params
from ...plugin.multisession import Sim3
from ...plugin.params import Params, params_to_dict
from ...plugin.verification import hypothesis_agrees
from .ground_truth import (
    GroundTruthSession,
    _map_arrays,
    _map_frame_centers,
    _observers,
    check_positive_pairs,
    check_same_ground_truth_frame,
    load_ground_truth,
    world_from_map,
)
from .report import format_table, plot_overlay, plot_pr, row_of
from .truth import landmark_truth

log = logging.getLogger(__name__)
# below the table of evaluation.md: what SOS-Match's search time holds (and what not)
SEARCH_TIME_NOTE = ("SOS-Match's search time: its search and the verification on the full maps (wall), without the "
                    "one-off compile or load of the numba kernels (minutes on the first match of an install; "
                    "evaluation.json `kernel_compile_seconds`).")
# keyframes tilted further than this from nadir (an oblique survey: `synth --camera-tilt`): the footprint-IoU
# truth is named as the paper's nadir protocol (at 20 deg the oracle recall fell from 0.97 to 0.77, at 35 deg to 0.28)
OBLIQUE_NOTE_DEG = 15.0

METHODS = ("sosmatch", "orb_ransac", "sift_ransac")
# timing repeats of evaluate's own search when none are given (`run(repeats=None)`, `evaluate` without --repeats)
DEFAULT_REPEATS = 3


def _run_sosmatch(params: Params, gt_a: GroundTruthSession, gt_b: GroundTruthSession, map_a: Path, map_b: Path,
                  match_dir: Path | None, sweep_floor: int | None, repeats: int, max_observers: int | None,
                  separation: float | None = None) -> dict:
    from ...plugin.association.windowed_search import search
    from ...plugin.match_answer import match_maps

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
    derivation = derived_search_params(params.association, *noise, pa, ha, pb, hb)  # as `sosmatch match` does
    assoc_params = derivation.params
    first_try = derivation.first_try
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
        for _ in range(max(1, repeats)):
            common = bool(lmap_a is not None and lmap_b is not None and lmap_a.epsg == lmap_b.epsg != 0)
            answer = match_maps(pa, ha, pb, hb, dataclasses.replace(params, association=assoc_params),
                                common_frame=common, first_try=first_try, wider_try=derivation.wider_try,
                                near_try=derivation.near_try)
            times.append(answer.timings["total_s"])
            compile_s += answer.timings["kernel_compile_s"]
            _check_sweep_floor(sweep_floor, (answer.searched or assoc_params).min_associations)
        result = answer.search
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


def _load_images(gt: GroundTruthSession, image_dir: Path) -> list[np.ndarray]:
    from ...database.flight_levels import flight_white_level
    from ...database.images import read_gray

    paths = [image_dir / name for name in gt.names]
    white = flight_white_level(paths)
    return [read_gray(path, white) for path in paths]


def _run_baseline(name: str, gt_a: GroundTruthSession, gt_b: GroundTruthSession, images_a: list[np.ndarray],
                  images_b: list[np.ndarray], config: Any) -> dict:
    from ...tools.baselines import get_backend

    backend = get_backend(name)
    fa, fb = backend.extract(images_a, config), backend.extract(images_b, config)
    counts, seconds = backend.match_all(fa, fb, config)
    scores = counts.astype(np.float64)
    scores[counts <= 0] = np.nan  # no (or too few) matches: no claim at any threshold
    return {"search_seconds": seconds, "search_seconds_runs": [seconds], "extract_seconds": fa.seconds + fb.seconds,
            "map_bytes": [fa.nbytes, fb.nbytes], "scores": scores}


def _jsonable(res: dict) -> dict:
    c: PRCurve = res["curve"]
    keep = {k: v for k, v in res.items() if k not in ("scores", "scores_windows", "curve", "positions", "sizes",
                                                      "observers", "accepted", "geometry")}
    keep["summary"] = c.summary
    keep["curve"] = {"thresholds": c.thresholds.tolist(), "precision": c.precision.tolist(),
                     "recall": c.recall.tolist(), "tp": c.tp.tolist(), "fp": c.fp.tolist()}
    keep["claimed_pairs"] = int(np.isfinite(res["scores"]).sum())
    return keep


def _check_sweep_floor(sweep_floor: int | None, theta_s: int) -> None:
    """A floor above the search's theta_S (derived per pair, so known only once the search has run) would change
    nothing: the curve already starts at theta_S (nu45: `--sweep-floor 100` was ignored silently)."""
    if sweep_floor is not None and sweep_floor > theta_s:
        raise InputError(f"--sweep-floor {sweep_floor} is above this pair's theta_S ({theta_s}, where the curve "
                         "already starts): a floor only extends the curve below theta_S; give a smaller one or "
                         "leave it out")


def check_options(ground_height: float, sweep_floor: int | None, repeats: int | None, max_observers: int | None,
                  baseline_threads: int, methods: Sequence[str] = METHODS, match_dir: str | Path | None = None) -> None:
    """Refuse (one-line InputError naming the option) values that make no evaluation. Before: --max-observers 0
    left every landmark without an observer and scored F1 0.000 'limited by front end' with exit 0, a negative
    one sliced observers off the wrong end, a NaN ground height gave NaN footprints, and --repeats / --sweep-floor
    / --baseline-threads below their meaning were taken silently; --sweep-floor and a given --repeats (`repeats`
    not None; None: `DEFAULT_REPEATS`) are refused where no search of evaluate's own runs (they were ignored)."""
    if not math.isfinite(ground_height) or abs(ground_height) > 1e5:
        raise InputError(f"--ground-height must be a finite height in metres (within 100 km), got {ground_height!r}")
    if max_observers is not None and max_observers < 1:
        raise InputError(f"--max-observers must be at least 1 (or left out: every observer), got {max_observers}")
    if sweep_floor is not None and sweep_floor < 2:
        raise InputError(f"--sweep-floor must be at least 2 (the smallest theta_S), got {sweep_floor}")
    if sweep_floor is not None and ("sosmatch" not in methods or match_dir is not None):
        raise InputError("--sweep-floor sets the floor of evaluate's own sosmatch search: " + (
            "a --match file is scored with the hypotheses its search kept" if match_dir is not None else
            "give --methods sosmatch (or leave --sweep-floor out)"))
    if repeats is not None and repeats < 1:
        raise InputError(f"--repeats must be at least 1, got {repeats}")
    if repeats is not None and ("sosmatch" not in methods or match_dir is not None):
        raise InputError("--repeats times evaluate's own sosmatch search: " + (
            "a --match file is scored with the search time it records" if match_dir is not None else
            "give --methods sosmatch (or leave --repeats out)"))
    if baseline_threads < 0:
        raise InputError(f"--baseline-threads must be 0 (one per core) or more, got {baseline_threads}")


def run(params: Params, session_a: str | Path, session_b: str | Path, out_dir: str | Path,
        map_a: str | Path | None = None, map_b: str | Path | None = None, match_dir: str | Path | None = None,
        methods: Sequence[str] = METHODS, case: str | None = None, dem: str | Path | None = None,
        ground_height: float = 0.0, sweep_floor: int | None = None, repeats: int | None = None,
        max_observers: int | None = None,
        overlap_test: bool = True, baseline_threads: int = 0, overwrite: bool = False) -> dict:
    """Evaluate SOS-Match and the baselines on one session pair; returns the evaluation dict (also written).

    Args:
        params: method parameters (keyframe interval, association parameters, seed).
        session_a, session_b: session directories with ground truth: poses.csv (ground-truth poses),
            cameras.txt, images/ (for the baselines) and optionally terrain.npz.
        out_dir: receives evaluation.json, evaluation.md, pr.png, overlay.png.
        map_a, map_b: mapped session directories (landmarks.sosmap, landmarks.csv); default: the session
            directory itself when it holds landmarks.csv. Needed for "sosmatch".
        match_dir: a `sosmatch match` output (match.json) to score instead of searching in-process.
        methods: any of "sosmatch", "orb_ransac", "sift_ransac".
        case: the case name for the table (default "A vs B" from the directory names).
        dem: an elevation raster for the footprints (instead of terrain.npz / flat ground at `ground_height`).
        sweep_floor: theta_S used to collect hypotheses for the curve (None: the configured theta_S, i.e. the
            timed search's own hypotheses; lower values extend the curve but can cost many times the search);
            repeats: timing repeats of our search (None: `DEFAULT_REPEATS`; a number is refused with `match_dir`
            or without "sosmatch", where no search of evaluate's own runs).
        max_observers: per landmark, keep only this many observers (nearest) when forming claims.
        overlap_test: an association claims only the observer pairs it places close enough to overlap
            (`plugin.evaluation.claims`, ObserverGeometry); False: every observer pair (the earlier rule).
        baseline_threads: worker threads of the baselines over keyframe pairs (0: one per core).
        overwrite: replace a complete evaluation of other inputs or settings in `out_dir` (taken through
            `sosmatch.database.outputs`).
    """
    session_a, session_b, out_dir = Path(session_a), Path(session_b), Path(out_dir)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    if not methods:  # `--methods ''` wrote an evaluation without a row, exit 0
        raise InputError(f"no method to evaluate: give one or more of {', '.join(METHODS)}")
    check_options(ground_height, sweep_floor, repeats, max_observers, baseline_threads, methods, match_dir)
    repeats = DEFAULT_REPEATS if repeats is None else repeats  # (in the identity as before: 3 when not given)
    check_two_sessions(session_a, session_b, map_a, map_b, "sosmatch" in methods)
    check_sweep_floor_maps(sweep_floor, _map_dirs(session_a, session_b, map_a, map_b))
    case = case or f"{session_a.name} vs {session_b.name}"
    inputs = [session_a, session_b, map_a, map_b, match_dir, dem]

    def identity_of(named: list[str | None]) -> VersionedIdentity:
        return versioned_identity(lambda as_dict: {
            "inputs": named, "params": as_dict(params), "methods": list(methods), "case": case,
            "ground_height": ground_height, "sweep_floor": sweep_floor, "repeats": repeats,
            "max_observers": max_observers, "overlap_test": overlap_test})

    # the inputs by what they hold, so that a project moved or copied whole is the same evaluation (nu37 D1);
    # until then by their real paths: such an output (not moved) is this one too
    identity = identity_of([None if p is None else content_fingerprint(p) for p in inputs]).accepting(
        identity_of([None if p is None else str(Path(p).resolve()) for p in inputs]))
    with open_output_dir(out_dir, "evaluate", identity, inputs=inputs, overwrite=overwrite,
                         legacy_record="evaluation.json") as taken:
        try:
            evaluation, write = _evaluate(params, session_a, session_b, out_dir, map_a, map_b, match_dir, methods,
                                          case, dem, ground_height, sweep_floor, repeats, max_observers,
                                          baseline_threads, overlap_test)
        except InputError:
            # refused before anything is written (a --sweep-floor above the theta_S known only after the search,
            # a match file of other maps): an evaluation this one was to --overwrite stands, complete, as it was
            taken.restore_previous()
            raise
        write()
        taken.finish()
    return evaluation


def check_two_sessions(session_a: Path, session_b: Path, map_a: str | Path | None, map_b: str | Path | None,
                       with_maps: bool) -> None:
    """InputError before any work when the pair is one session (by path), or (`with_maps`) when a map is one that
    `sosmatch map` refused or has not finished, or the two maps are one map or copies (`check_two_maps`): a
    session scored against itself came out as a perfect F1 1.000, a refused map as F1 0 "limited by the front
    end"; `match` refuses both."""
    if session_a.resolve() == session_b.resolve():
        raise InputError("A and B are the same session: nothing to evaluate (give the sessions of two flights)",
                         session_b)
    if not with_maps:
        return
    maps = _map_dirs(session_a, session_b, map_a, map_b)
    for m in maps:
        check_finished(m)  # a killed map leaves only its staging: say so, not "no landmarks.csv"
        if (m / "landmarks.sosmap").is_file():
            check_session_usable(m)
    if all((m / "landmarks.sosmap").is_file() for m in maps):
        check_two_maps(maps[0], maps[1], *(read_landmark_map(m / "landmarks.sosmap") for m in maps), "evaluate")


def _map_dirs(session_a: Path, session_b: Path, map_a: str | Path | None,
              map_b: str | Path | None) -> tuple[Path, Path]:
    """The mapped sessions the sosmatch method scores: `map_a` / `map_b`, else the session directories."""
    return (Path(map_a) if map_a is not None else session_a, Path(map_b) if map_b is not None else session_b)


def check_sweep_floor_maps(sweep_floor: int | None, maps: Sequence[Path]) -> None:
    """InputError naming the map, before any work, when a --sweep-floor is given and a map has fewer landmarks than
    a transform needs: no search runs (the method claims nothing, an honest zero), so there is no curve for a floor
    to extend (it was ignored silently, exit 0). The other refusals of the floor: `check_options` (with --match or
    without the sosmatch method, which `run` checks first) and `_check_sweep_floor` (above theta_S)."""
    if sweep_floor is None:
        return
    for m in maps:
        if not (m / "landmarks.csv").exists():
            continue  # not a mapped session: `_evaluate` says so
        n = len(_map_arrays(m)[0])
        if n < MIN_LANDMARKS_TO_ALIGN:
            raise InputError(f"--sweep-floor {sweep_floor}: this map has {n} landmark(s), fewer than the "
                             f"{MIN_LANDMARKS_TO_ALIGN} a transform needs, so no search runs and there is no curve "
                             "for a floor to extend; leave --sweep-floor out", m)


def _evaluate(params: Params, session_a: Path, session_b: Path, out_dir: Path, map_a: str | Path | None,
              map_b: str | Path | None, match_dir: str | Path | None, methods: Sequence[str], case: str,
              dem: str | Path | None, ground_height: float, sweep_floor: int | None, repeats: int,
              max_observers: int | None, baseline_threads: int,
              overlap_test: bool = True) -> tuple[dict, Callable[[], None]]:
    """`run` inside its taken output directory: the evaluation, and what writes it (evaluation.json / .md, pr.png,
    overlay.png). Nothing is written before the call: a refusal (InputError) leaves the directory untouched."""
    from ...tools.baselines.base import BaselineConfig

    t0 = time.perf_counter()
    check_same_ground_truth_frame(session_a, session_b)
    gt_a = load_ground_truth(params, session_a, dem, ground_height)
    gt_b = load_ground_truth(params, session_b, dem, ground_height)
    iou = iou_matrix(gt_a.footprints, gt_b.footprints)
    log.info("%s: %d x %d keyframes, %d positive pairs (IoU > %.3f), ground truth in %.1f s", case, len(gt_a.names),
             len(gt_b.names), int((iou > TP_IOU).sum()), TP_IOU, time.perf_counter() - t0)
    check_positive_pairs(gt_a, gt_b, iou, session_b)
    for gt in (gt_a, gt_b):
        if gt.off_nadir_deg > OBLIQUE_NOTE_DEG:
            log.warning("%s: its keyframes look %.0f deg off nadir: the footprint-IoU truth counts the far part of "
                        "oblique footprints, where few landmarks lie, as overlap, so the per-keyframe recall "
                        "understates the match (BENCHMARKS.md, Oblique surveys)", gt.path, gt.off_nadir_deg)
    results: dict[str, dict] = {}
    if "sosmatch" in methods:
        ma, mb = _map_dirs(session_a, session_b, map_a, map_b)
        for m, session in ((ma, session_a), (mb, session_b)):
            if not (m / "landmarks.csv").exists():
                raise InputError("not a mapped session (no landmarks.csv); run `sosmatch map` first", m)
            check_map_of_images(m, session / "images")
        cam = gt_a.camera
        separation = separation_ratio(cam.width, cam.height, float(np.sqrt(cam.fx * cam.fy))) if overlap_test else None
        results["sosmatch"] = _run_sosmatch(params, gt_a, gt_b, ma, mb, Path(match_dir) if match_dir else None,
                                            sweep_floor, repeats, max_observers, separation)
    baselines = [m for m in methods if m != "sosmatch"]
    if baselines:
        images_a, images_b = _load_images(gt_a, session_a / "images"), _load_images(gt_b, session_b / "images")
        config = BaselineConfig(seed=params.seed, threads=baseline_threads)
        for m in baselines:
            log.info("%s: %s on %d x %d keyframe pairs", case, m, len(images_a), len(images_b))
            results[m] = _run_baseline(m, gt_a, gt_b, images_a, images_b, config)
    for res in results.values():
        res["curve"] = pr_curve(res["scores"], iou)
    if "sosmatch" in results:
        sos = results["sosmatch"]
        sos["landmark_truth"] = landmark_truth(params, session_a, session_b, ma, mb, sos, iou)
        # the same search scored without the full-map verification: the window hypotheses alone (as the paper)
        windows = {k: v for k, v in sos.items() if k not in ("scores", "curve", "verification")}
        windows["scores"] = sos["scores_windows"]
        windows["curve"] = pr_curve(windows["scores"], iou)
        results["sosmatch_windows"] = windows
        for res in (sos, windows):
            res["operating_point"] = operating_point(res["curve"], res["operating_theta_S"] + 0.5)
    order = ["sosmatch", "sosmatch_windows"] + [m for m in results if not m.startswith("sosmatch")]
    results = {m: results[m] for m in order if m in results}  # the windows-only row beside ours
    rows = [row_of(case, m, res) for m, res in results.items()]
    evaluation = {
        "case": case,
        "sessions": [str(session_a), str(session_b)],
        "out_dir": str(out_dir),
        "keyframes": [len(gt_a.names), len(gt_b.names)],
        "protocol": {"tp_iou": TP_IOU, "fp_iou": FP_IOU, "keyframe_interval_m": params.keyframes.interval_m,
                     "positive_pairs": int((iou > TP_IOU).sum()), "negative_pairs": int((iou < FP_IOU).sum())},
        "rows": rows,
        "methods": {m: _jsonable(res) for m, res in results.items()},
    }
    md = f"# Evaluation: {case}\n\n" + format_table(rows) + (
        f"\n{SEARCH_TIME_NOTE}\n" if "sosmatch" in results else "") + (
        f"\nKeyframes {len(gt_a.names)} x {len(gt_b.names)}; {evaluation['protocol']['positive_pairs']} pairs with "
        f"IoU > {TP_IOU}, {evaluation['protocol']['negative_pairs']} with IoU < {FP_IOU}.\n\n"
        "![precision-recall](pr.png)\n\n![map overlay](overlay.png)\n")

    def write() -> None:
        plot_pr({m: r["curve"] for m, r in results.items()}, out_dir / "pr.png", case)
        plot_overlay(gt_a, gt_b, results.get("sosmatch"), out_dir / "overlay.png", case)
        write_text_atomic(out_dir / "evaluation.md", md)
        write_text_atomic(out_dir / "evaluation.json", json.dumps(evaluation, indent=1, default=json_default) + "\n")

    return evaluation, write



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


def demo_step(session_a: str | Path, session_b: str | Path, map_a: str | Path, map_b: str | Path,
              out_dir: str | Path, case: str = "demo: summer vs winter", overwrite: bool = False) -> dict:
    """The demo's last step: evaluate its two sessions with both baselines and print the table."""
    evaluation = run(Params(), session_a, session_b, out_dir, map_a=map_a, map_b=map_b, case=case, repeats=1,
                     overwrite=overwrite)
    out_dir = Path(out_dir)
    print((out_dir / "evaluation.md").read_text(encoding="utf-8"), end="")
    print(f"precision-recall plot: {out_dir / 'pr.png'}\nmap overlay: {out_dir / 'overlay.png'}")
    return evaluation
