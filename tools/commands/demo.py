"""`sosmatch demo`: synthesise two seasons over the same path and run the pipeline on them."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "demo"
HELP = "run the end-to-end demo (summer and winter sessions, contact sheet, then the later stages)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("demo_out"), help="output directory (default demo_out)")
    parser.add_argument("--frames", type=int, default=80, help="frames per synthetic session (default 80; at least "
                        "theta_n + 1, 6 at the defaults, so that map finds landmarks)")
    parser.add_argument("--overwrite", action="store_true",
                        help="re-run steps whose outputs already exist, replacing them (also needed to redo a demo "
                             "made with another --frames)")
    # the flag's name before it was --overwrite, as every other command's (nu54): kept for scripts, not listed
    parser.add_argument("--force", dest="overwrite", action="store_true", help=argparse.SUPPRESS)


def run(args: argparse.Namespace) -> int:
    from ...workflows.demo import run_demo

    for name, status, seconds in run_demo(args.out, frames=args.frames, overwrite=args.overwrite):
        print(f"{name:20s} {status:8s} {seconds:6.1f} s")
    return 0
