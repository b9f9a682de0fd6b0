"""The evaluation's computation: ground truth of both sessions, the match (our verified answer and the raw
window hypotheses: sosmatch_method), the baselines (baselines), the PR curves and the outputs; what it refuses
before any work is in checks (the package docstring says what and why)."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ...database.atomic import write_text_atomic
from ...database.json_text import json_default
from ...database.output_markers import VersionedIdentity, content_fingerprint, versioned_identity
from ...database.outputs import OutputDir, open_output_dir
from ...database.session_images import check_map_of_images
from ...plugin.errors import InputError
from ...plugin.evaluation.claims import separation_ratio
from ...plugin.evaluation.iou import iou_matrix
from ...plugin.evaluation.metrics import FP_IOU, TP_IOU, PRCurve, operating_point, pr_curve
from ...plugin.params import Params
from .baselines import _load_images, _run_baseline
from .checks import METHODS, _map_dirs, check_options, check_sweep_floor_maps, check_two_sessions
from .ground_truth import check_positive_pairs, check_same_ground_truth_frame, load_ground_truth
from .report import format_table, plot_overlay, plot_pr, row_of
from .sosmatch_method import _run_sosmatch
from .sosmatch_method import error_to_identity as error_to_identity  # re-exported: its home before the split
from .truth import has_object_truth, landmark_truth

log = logging.getLogger(__name__)
# below the table of evaluation.md: what SOS-Match's search time holds (and what not)
SEARCH_TIME_NOTE = ("SOS-Match's search time: its search and the verification on the full maps (wall), without the "
                    "one-off compile or load of the numba kernels (minutes on the first match of an install; "
                    "evaluation.json `kernel_compile_seconds`).")
# keyframes tilted further than this from nadir (an oblique survey: `synth --camera-tilt`): the footprint-IoU
# truth is named as the paper's nadir protocol (at 20 deg the oracle recall fell from 0.97 to 0.77, at 35 deg to 0.28)
OBLIQUE_NOTE_DEG = 15.0
# timing repeats of evaluate's own search when none are given (`run(repeats=None)`, `evaluate` without --repeats)
DEFAULT_REPEATS = 3
# the files an evaluation writes, its record last: a user's file at one of their names is refused when the folder
# is taken, before the evaluation
EVALUATION_FILES = ("pr.png", "overlay.png", "evaluation.md", "evaluation.json")


def _jsonable(res: dict) -> dict:
    c: PRCurve = res["curve"]
    keep = {k: v for k, v in res.items() if k not in ("scores", "scores_windows", "curve", "positions", "sizes",
                                                      "observers", "accepted", "geometry")}
    keep["summary"] = c.summary
    keep["curve"] = {"thresholds": c.thresholds.tolist(), "precision": c.precision.tolist(),
                     "recall": c.recall.tolist(), "tp": c.tp.tolist(), "fp": c.fp.tolist()}
    keep["claimed_pairs"] = int(np.isfinite(res["scores"]).sum())
    return keep


def run(params: Params, session_a: str | Path, session_b: str | Path, out_dir: str | Path,
        map_a: str | Path | None = None, map_b: str | Path | None = None, match_dir: str | Path | None = None,
        methods: Sequence[str] = METHODS, case: str | None = None, dem: str | Path | None = None,
        ground_height: float = 0.0, sweep_floor: int | None = None, repeats: int | None = None,
        max_observers: int | None = None,
        overlap_test: bool = True, baseline_threads: int = 0, overwrite: bool = False,
        transform_chosen: bool = False) -> dict:
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
        transform_chosen: the user chose `association.transform` (--set, --config, --preset); else the search of
            maps whose poses came from structure from motion fits a similarity, as `sosmatch match` does
            (`workflows.match.transform_choice`).
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
            "max_observers": max_observers, "overlap_test": overlap_test,
            # only when chosen: evaluations without the choice keep their identity
            **({"transform_chosen": True} if transform_chosen else {})})

    # the inputs by what they hold, so that a project moved or copied whole is the same evaluation (nu37 D1);
    # until then by their real paths: such an output (not moved) is this one too
    identity = identity_of([None if p is None else content_fingerprint(p) for p in inputs]).accepting(
        identity_of([None if p is None else str(Path(p).resolve()) for p in inputs]))
    with open_output_dir(out_dir, "evaluate", identity, inputs=inputs, overwrite=overwrite,
                         legacy_record="evaluation.json", files=EVALUATION_FILES) as taken:
        try:
            evaluation, write = _evaluate(params, session_a, session_b, out_dir, map_a, map_b, match_dir, methods,
                                          case, dem, ground_height, sweep_floor, repeats, max_observers,
                                          baseline_threads, overlap_test, transform_chosen)
        except InputError:
            # refused before anything is written (a --sweep-floor above the theta_S known only after the search,
            # a match file of other maps): an evaluation this one was to --overwrite stands, complete, as it was
            taken.restore_previous()
            raise
        write(taken)
        taken.finish()
    return evaluation


def _evaluate(params: Params, session_a: Path, session_b: Path, out_dir: Path, map_a: str | Path | None,
              map_b: str | Path | None, match_dir: str | Path | None, methods: Sequence[str], case: str,
              dem: str | Path | None, ground_height: float, sweep_floor: int | None, repeats: int,
              max_observers: int | None, baseline_threads: int,
              overlap_test: bool = True, transform_chosen: bool = False) -> tuple[dict, Callable[[OutputDir], None]]:
    """`run` inside its taken output directory: the evaluation, and what writes it (evaluation.json / .md, pr.png,
    overlay.png). Nothing is written before the call: a refusal (InputError) leaves the directory untouched."""
    from ...tools.baselines.base import BaselineConfig

    t0 = time.perf_counter()
    check_same_ground_truth_frame(session_a, session_b)
    if "sosmatch" in methods:  # an incomplete synth session refused now, not after the search
        for session in (session_a, session_b):
            has_object_truth(session)
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
                                            sweep_floor, repeats, max_observers, separation, transform_chosen)
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

    def write(out: OutputDir) -> None:
        plot_pr({m: r["curve"] for m, r in results.items()}, out.staged("pr.png"), case)
        plot_overlay(gt_a, gt_b, results.get("sosmatch"), out.staged("overlay.png"), case)
        write_text_atomic(out.staged("evaluation.md"), md)
        write_text_atomic(out.staged("evaluation.json"),
                          json.dumps(evaluation, indent=1, default=json_default) + "\n")
        out.publish(EVALUATION_FILES[:-1], last=EVALUATION_FILES[-1])  # the record last: its presence = done

    return evaluation, write



def demo_step(session_a: str | Path, session_b: str | Path, map_a: str | Path, map_b: str | Path,
              out_dir: str | Path, case: str = "demo: summer vs winter", overwrite: bool = False) -> dict:
    """The demo's last step: evaluate its two sessions with both baselines and print the table."""
    evaluation = run(Params(), session_a, session_b, out_dir, map_a=map_a, map_b=map_b, case=case, repeats=1,
                     overwrite=overwrite)
    out_dir = Path(out_dir)
    print((out_dir / "evaluation.md").read_text(encoding="utf-8"), end="")
    print(f"precision-recall plot: {out_dir / 'pr.png'}\nmap overlay: {out_dir / 'overlay.png'}")
    return evaluation
