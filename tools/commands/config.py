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
        print(f"{args.config or 'defaults'}: ok")
    return 0
