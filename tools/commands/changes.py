"""`sosmatch changes A B --match AB/match.json --out DIR`: which objects were kept, gone, new or unseen."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_min_confidence_argument, add_params_arguments, params_from_args, with_min_confidence

NAME = "changes"
HELP = ("object-level change detection between two aligned mapped sessions: changes.csv, changes.geojson, "
        "changes.png, changes.json")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command's arguments: the two sessions, their match, the output and the options of change detection."""
    parser.add_argument("session_a", type=Path, help="mapped session directory (the reference frame)")
    parser.add_argument("session_b", type=Path, help="mapped session directory, compared in A's frame")
    parser.add_argument("--match", type=Path, required=True,
                        help="match.json of `sosmatch match A B` (or of a batch pair) with an accepted transform")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    add_min_confidence_argument(parser)
    parser.add_argument("--images-a", type=Path, default=None,
                        help="A's keyframe images (default: the directory A's run.json records, if it exists); "
                             "with B's, the images are evidence of what changed")
    parser.add_argument("--images-b", type=Path, default=None, help="B's keyframe images (as --images-a)")
    parser.add_argument("--no-plot", action="store_true", help="skip changes.png")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a complete `sosmatch changes` output in --out made from other inputs")
    parser.add_argument("--trust-images", action="store_true",
                        help="compare even when the match's images agree but the two maps' georeferences disagree "
                             "beyond association.georeference_prior_m (one of them is wrong; changes.geojson keeps "
                             "A's); refused without it")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Compare the two sessions, write the outputs and print the summary line; 0 on success (errors: InputError)."""
    from ...workflows.changes import run as run_changes

    params = with_min_confidence(params_from_args(args), args)
    result = run_changes(args.session_a, args.session_b, args.match, args.out, params, plot=not args.no_plot,
                         overwrite=args.overwrite, images_a=args.images_a, images_b=args.images_b,
                         trust_images=args.trust_images)
    print(f"changes: {result.summary()} -> {args.out / 'changes.csv'}")
    return 0
