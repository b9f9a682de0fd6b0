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


def settings_from_args(args: argparse.Namespace, preset: bool = True) -> set[str]:
    """The dotted names of the settings `--preset` (unless not `preset`), `--config` and `--set` chose
    (`config_io.chosen_settings`)."""
    from ...database.config_io import chosen_settings, parse_override

    overrides = dict(parse_override(text) for text in args.overrides)
    return chosen_settings(args.config, overrides, getattr(args, "preset", None) if preset else None)


def add_min_confidence_argument(parser: argparse.ArgumentParser) -> None:
    """`--min-confidence` of change detection (`changes.min_confidence`), for `changes` and `batch` alike."""
    parser.add_argument("--min-confidence", type=float, default=None,
                        help="report gone / new only when the claim's confidence reaches this (0-1; below: unseen). "
                             "The confidence is a score, not the chance that a claim is right: the probability that "
                             "the object is absent from the other session at prior odds 1, from that session's "
                             "segments and images, calibrated on the pair's own kept landmarks (README: the "
                             "precision measured at each value). Default: changes.min_confidence (0.8)")


def with_min_confidence(params: Params, args: argparse.Namespace) -> Params:
    """`params` with `--min-confidence` as changes.min_confidence when it was given; InputError outside 0-1."""
    from ...plugin.errors import InputError
    from ...plugin.params import with_overrides

    if args.min_confidence is None:
        return params
    if not 0.0 <= args.min_confidence <= 1.0:
        raise InputError(f"--min-confidence must be between 0 and 1, got {args.min_confidence}")
    return with_overrides(params, {"changes.min_confidence": float(args.min_confidence)})
