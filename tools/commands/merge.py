"""`sosmatch merge A B --match MATCH_JSON --out MERGED`: one COLMAP model from two mapped sessions."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_params_arguments, params_from_args, settings_from_args

NAME = "merge"
HELP = "merge session B into session A's frame with the accepted transform of a match (one COLMAP model)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session_a", type=Path, help="mapped session directory (the reference frame)")
    parser.add_argument("session_b", type=Path, help="mapped session directory brought into A's frame")
    parser.add_argument("--match", type=Path, required=True, help="match.json of `sosmatch match A B`")
    parser.add_argument("--out", type=Path, required=True, help="output directory (sparse/, landmarks, merge.json)")
    parser.add_argument("--refine", action="store_true",
                        help="refine an unverified answer (match --no-verify) on the full maps as the "
                        "match's verification refines its winner, and fuse the pairs the refined transform supports "
                        "(a verified answer is kept: it is that already)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a complete `sosmatch merge` output of other inputs in --out")
    parser.add_argument("--trust-images", action="store_true",
                        help="merge even when the match's images agree but the two maps' georeferences disagree "
                             "beyond association.georeference_prior_m (one of them is wrong; the merged model keeps "
                             "A's); refused without it")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...workflows import merge

    res = merge.run(args.session_a, args.session_b, args.match, args.out, params_from_args(args), refine=args.refine,
                    overwrite=args.overwrite, trust_images=args.trust_images,
                    chosen=settings_from_args(args))
    print(
        f"{args.out}: {res.num_images} images, {res.num_points3d} points, {res.num_landmarks} landmarks "
        f"({res.num_fused} fused, {res.num_rejected} {'association' if res.num_rejected == 1 else 'associations'} "
        f"not fused){' [refined]' if res.refined else ''}"
    )
    return 0
