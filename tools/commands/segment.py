"""`sosmatch segment IMAGE_OR_DIR... --out DIR [--backend NAME]`: masks, overlays and a per-image summary."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._common import add_params_arguments, params_from_args

NAME = "segment"
HELP = "segment images with a backend, describe the masks, write overlay PNGs and per-image summaries"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", type=Path, metavar="IMAGE_OR_DIR", help="image files or folders")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created)")
    parser.add_argument("--backend", help="segmentation backend (default: segmentation.backend, 'classical')")
    parser.add_argument("--no-overlays", action="store_true", help="write only the JSON summaries")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a complete `sosmatch segment` output of other images or settings in --out")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...plugin.errors import InputError
    from ...plugin.params.checks import valid_values
    from ...plugin.params.mapping import SegmentationParams
    from ...workflows import segment

    params = params_from_args(args)
    valid = valid_values(SegmentationParams, "backend")
    if args.backend is not None and valid is not None and not valid.accepts(args.backend):
        # the option's name, not the params class's (`--set segmentation.backend=` names its key likewise)
        raise InputError(f"--backend must be {valid.describe()}, got {args.backend!r}")
    report = segment.run(args.inputs, args.out, params, backend=args.backend, write_overlays=not args.no_overlays,
                         overwrite=args.overwrite)
    ok = [r for r in report.images if r.error is None]
    masks = sum(r.num_masks for r in ok)
    print(f"{len(ok)} image(s) segmented, {masks} masks; overlays and summary.csv in {args.out}")
    for r in report.failed:  # one line per bad image
        print(f"sosmatch segment: error: {r.error}", file=sys.stderr)
    if len(report.failed) > 1:
        print(f"sosmatch segment: {len(report.failed)} images failed", file=sys.stderr)
    return 2 if report.failed else 0
