"""`sosmatch config dump|check`: show or validate the parameters."""

from __future__ import annotations

import argparse
import sys

from ._common import add_params_arguments, params_from_args

NAME = "config"
HELP = "print the effective parameters as TOML (dump) or validate a config file (check)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=["dump", "check"], help="dump: print TOML; check: validate only")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...database.config_io import dump_params

    params = params_from_args(args)
    if args.action == "dump":
        sys.stdout.write(dump_params(params))
    else:
        print(f"{_what(args)}: ok")
    return 0


def _what(args: argparse.Namespace) -> str:
    """What was checked, in the order it applies: the preset, the config file, each --set."""
    parts = ([f"preset {args.preset}"] if getattr(args, "preset", None) else []) + \
        ([str(args.config)] if args.config else []) + [f"--set {s}" for s in (getattr(args, "overrides", None) or [])]
    return " + ".join(parts) or "defaults"
