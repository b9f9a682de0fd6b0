"""`sosmatch evaluate A B --out DIR`: the paper's table and PR figure for one session pair, baselines beside."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_params_arguments, params_from_args, settings_from_args

NAME = "evaluate"
HELP = "score SOS-Match and the ORB/SIFT+RANSAC baselines against footprint-IoU ground truth (table + PR plot)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session_a", type=Path, help="session directory with poses.csv (ground truth), cameras.txt, "
                        "images/ and optionally terrain.npz")
    parser.add_argument("session_b", type=Path, help="the other session directory")
    parser.add_argument("--out", type=Path, required=True, help="output directory (evaluation.md/.json, pr.png, "
                        "overlay.png)")
    parser.add_argument("--map-a", type=Path, help="mapped session of A (default: SESSION_A if it holds landmarks)")
    parser.add_argument("--map-b", type=Path, help="mapped session of B (default: SESSION_B if it holds landmarks)")
    parser.add_argument("--match", type=Path, help="score this `sosmatch match` output instead of searching here")
    parser.add_argument("--methods", default="sosmatch,orb_ransac,sift_ransac",
                        help="comma-separated subset of sosmatch,orb_ransac,sift_ransac")
    parser.add_argument("--case", help="case name for the table")
    parser.add_argument("--dem", type=Path, help="elevation raster for the footprints (default: terrain.npz or "
                        "flat ground)")
    parser.add_argument("--ground-height", type=float, default=0.0, help="height of the flat ground (m, default 0) "
                        "for sessions without terrain.npz when no --dem is given (unused otherwise)")
    parser.add_argument("--sweep-floor", type=int, help="theta_S floor of the precision-recall sweep (default: the "
                        "search's theta_S; lower extends the curve at a much higher cost; above it, with --match, "
                        "without the sosmatch method or on a map of fewer than 3 landmarks: refused)")
    # no default here (None: `workflows.evaluate.workflow.DEFAULT_REPEATS`, not imported: it loads the kernels):
    # a --repeats given where no search of evaluate's own runs is refused, the default is not
    parser.add_argument("--repeats", type=int, help="timing repeats of the search (median; default 3; with --match "
                        "or without the sosmatch method: refused)")
    parser.add_argument("--max-observers", type=int, help="claims use only the N observers nearest each landmark")
    parser.add_argument("--no-overlap-test", action="store_true",
                        help="an association claims every pair of its observers, also pairs it places too far apart "
                             "to overlap (the earlier rule)")
    parser.add_argument("--baseline-threads", type=int, default=0,
                        help="worker threads of the baselines (0: one per core)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a complete `sosmatch evaluate` output of other inputs or settings in --out")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...workflows.evaluate import run as evaluate

    params = params_from_args(args)
    result = evaluate(
        params, args.session_a, args.session_b, args.out, map_a=args.map_a, map_b=args.map_b, match_dir=args.match,
        methods=[m.strip() for m in args.methods.split(",") if m.strip()], case=args.case, dem=args.dem,
        ground_height=args.ground_height, sweep_floor=args.sweep_floor, repeats=args.repeats,
        max_observers=args.max_observers, baseline_threads=args.baseline_threads,
        overwrite=args.overwrite, overlap_test=not args.no_overlap_test,
        # a transform the user chose is searched as it is; else the maps' pose sources choose it, as in `match`
        transform_chosen="association.transform" in settings_from_args(args),
    )
    print((Path(args.out) / "evaluation.md").read_text(encoding="utf-8"), end="")
    return 0 if result["rows"] is not None else 1
