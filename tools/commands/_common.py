"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...plugin.params import Params


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """`--preset NAME`, `--config FILE` and repeatable `--set section.key=value` for commands that use method
    parameters (applied in that order)."""
    from ...plugin.params import PRESETS

    parser.add_argument("--preset", choices=sorted(PRESETS), default=None,
                        help="named parameter preset: paper (the defaults), survey (photogrammetric flights, "
                             "frames 30-40 m apart) or aerial (association of km-scale maps from coarse imagery); "
                             "see README")
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
