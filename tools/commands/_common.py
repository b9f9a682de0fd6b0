"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...plugin.params import Params


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """`--config FILE` and repeatable `--set section.key=value` for commands that use method parameters."""
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
    return load_params(args.config, overrides)
