"""`sosmatch match A B --out DIR`: associate two landmark maps (windowed CLIPPER search, then verification)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_params_arguments, params_from_args, settings_from_args

NAME = "match"
HELP = "associate two landmark maps (sessions, .sosmap files or COLMAP models): match.json, associations.csv, PNG"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("a", type=Path, help="map A: session directory, .sosmap file or COLMAP model directory")
    parser.add_argument("b", type=Path, help="map B, matched into A's frame")
    parser.add_argument("--out", type=Path, required=True, help="output directory (match.json, associations.csv, "
                                                                "match.png)")
    parser.add_argument("--workers", type=int, default=None,
                        help="(kept for scripts; unused: the compiled search runs in one process)")
    parser.add_argument("--exhaustive", action="store_true",
                        help="straightforward reference search of every window pair (slow; same result)")
    parser.add_argument("--no-verify", action="store_true",
                        help="answer with the window consensus as it is, without verifying the hypotheses on the "
                             "full maps (verification.enabled)")
    parser.add_argument("--no-plot", action="store_true", help="skip match.png")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a complete `sosmatch match` output of other maps or settings in --out")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...plugin.errors import InputError
    from ...workflows.match import run as run_match

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    params = params_from_args(args)
    # a transform the user chose is used as it is; otherwise the maps' pose sources choose it (README "Matching")
    chosen = settings_from_args(args)
    result = run_match(params, args.a, args.b, args.out, workers=args.workers, exhaustive=args.exhaustive,
                       plot=not args.no_plot, overwrite=args.overwrite, verify=False if args.no_verify else None,
                       transform_chosen="association.transform" in chosen,
                       # a preset's tolerances are the starting point the derivation refines (README), not a choice
                       chosen=settings_from_args(args, preset=False))
    print(f"match: {result.summary()}")
    return 0
