"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...plugin.params import Params


def user_path(text: str) -> Path:
    """A path argument (every `type=Path` argument of every command is made this one, `tools.cli`). An empty one
    (`--out "$OUT"` with OUT unset) became Path('.'): match wrote its outputs into the current folder and map read
    it as the image folder ('.: only 0 image(s) have a pose')."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty path (an unset shell variable?)")
    return Path(text)


def output_file(text: str) -> Path:
    """A path argument that names a file to write (`user_path`), refused as a usage error when it ends in a path
    separator (`--out exports/`, a folder meant; the Path made of it drops the slash, and the export was written
    as a file named `exports`)."""
    if text.endswith(("/", "\\")):
        raise argparse.ArgumentTypeError(f"{text!r} ends in a separator, a folder: give a file name")
    return user_path(text)


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """`--preset NAME`, `--config FILE` and repeatable `--set section.key=value` for commands that use method
    parameters (applied in that order)."""
    from ...plugin.params import PRESETS

    parser.add_argument("--preset", choices=sorted(PRESETS), default=None,
                        help="named parameter preset: paper (the method as published; the defaults are ours), "
                             "survey (photogrammetric flights, frames 30-40 m apart) or aerial (association of "
                             "km-scale maps from coarse imagery); see README")
    parser.add_argument("--config", type=Path, help="TOML file of parameters (see `sosmatch config dump`)")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one parameter, e.g. --set tracking.epipolar_margin_px=8 (repeatable)",
    )


def params_from_args(args: argparse.Namespace) -> Params:
    from ...database.config_io import load_params, parse_override

    overrides = dict(parse_override(text) for text in args.overrides)
    return load_params(args.config, overrides, getattr(args, "preset", None))
