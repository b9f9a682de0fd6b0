"""The `sosmatch` command line: parse, call a documented Python function, print. Nothing else lives here.

Subcommands are the modules of `sosmatch.tools.commands`, discovered at start-up. Each module defines
`NAME`, `HELP`, `add_arguments(parser)` and `run(args) -> int`, and imports heavy libraries only inside `run`
so that `sosmatch --help` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

from .interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED, Terminated, interruption, stop_as_interrupt

# sosmatch's own modules (numpy, every command) are imported inside `main`'s handler of Ctrl-C: a Ctrl-C in the
# first seconds of a run (start-up takes seconds on a loaded machine) is then the one line, not a traceback

EXIT_USER_ERROR = 2
log = logging.getLogger("sosmatch")


def _command_modules() -> list:
    from . import commands

    modules = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        modules.append(importlib.import_module(f"{commands.__name__}.{info.name}"))
    return modules


class _Parser(argparse.ArgumentParser):
    """A usage error is one line like every other user error (argparse prints the whole usage first): what is
    wrong and where the help is; exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    from ..plugin import __version__
    from .commands._common import user_path

    parser = _Parser(
        prog="sosmatch",
        description="Open-set segment landmark maps and cross-session correspondence search (SOS-Match).",
    )
    parser.add_argument("--version", action="version", version=f"sosmatch {__version__}")
    verbosity = _Parser(add_help=False)
    verbosity.add_argument("-v", "--verbose", action="count", default=0, help="more logging (twice: debug)")
    verbosity.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    parser.commands = {}  # name -> the command's parser, whose error() names its own --help
    for module in _command_modules():
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP, parents=[verbosity])
        parser.commands[module.NAME] = cmd
        module.add_arguments(cmd)
        for action in cmd._actions:  # every path argument of every command: an empty one is refused
            if action.type is Path:
                action.type = user_path
        cmd.set_defaults(_run=module.run)
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    logging.getLogger("sosmatch").setLevel(level)
    # COLMAP's C++ log (glog): silent unless asked for debug output, and on stderr like ours instead of a file per
    # run in /tmp. Commands import pycolmap inside `run`, after this, so glog must be told through its environment
    # (read when pycolmap loads); a user's own GLOG_* settings win.
    os.environ.setdefault("GLOG_logtostderr", "1")
    os.environ.setdefault("GLOG_minloglevel", "0" if verbose > 1 else "2")
    if "pycolmap" in sys.modules:  # already loaded (the CLI called from Python): set the flags themselves
        colmap_log = sys.modules["pycolmap"].logging
        colmap_log.logtostderr = os.environ["GLOG_logtostderr"] not in ("0", "false")
        colmap_log.minloglevel = int(os.environ["GLOG_minloglevel"])


# A value that starts with a minus: argparse takes a token for a value only when it looks like "-1" or "-1.5" (its
# own pattern), so `--takeoff-altitude -1e3`, `--x -.5`, `--x -inf` and a comma list whose first number is negative
# (`--geo-origin -33.45,-70.66`, the southern or western hemisphere; `--shift -20,10`) failed with "expected one
# argument". argparse documents `--opt=VALUE` for such values; this pre-pass writes them so.
def _is_negative_number(token: str) -> bool:
    """A token starting with a minus that Python reads as a number, or as a comma list of numbers (no option's name
    does)."""
    if not token.startswith("-") or token.startswith("--"):
        return False
    try:
        for part in token.split(","):
            float(part)
    except ValueError:
        return False
    return True


def value_options(parser: argparse.ArgumentParser) -> set[str]:
    """The option strings of `parser` that take a value (not the flags such as -q, --csv, --ekf)."""
    return {name for action in parser._actions if action.nargs != 0 for name in action.option_strings}


def join_negative_numbers(argv: Sequence[str], takes_value: Callable[[str], bool] | None = None) -> list[str]:
    """`--opt -1e3` -> `--opt=-1e3`, `--opt -1.5,2` -> `--opt=-1.5,2`: an option that takes a value followed by a
    number (or a comma list of numbers) starting with a minus, in any form Python's float() reads, gets it as its
    value (what the user meant); its own check then judges the value. A flag taking no value (`takes_value` says
    which: by default any option) leaves the token alone, as a positional (a folder named -1 after --csv). Tokens
    after `--` are left alone."""
    out: list[str] = []
    past_separator = False  # one flag, not a scan of `out` per token: argv may hold tens of thousands of paths
    for token in argv:
        prev = out[-1] if out else ""
        if not past_separator and prev.startswith("-") and "=" not in prev and not _is_negative_number(prev) \
                and _is_negative_number(token) and (takes_value is None or takes_value(prev)):
            out[-1] = f"{prev}={token}"
        else:
            out.append(token)
            past_separator = past_separator or token == "--"
    return out


def _command_takes_value(parser: argparse.ArgumentParser, argv: Sequence[str]) -> Callable[[str], bool]:
    """Which option strings of the command named in `argv` take a value; an abbreviation (argparse takes unique
    prefixes) counts when every option it may stand for takes one."""
    command = next((t for t in argv if not t.startswith("-")), None)
    sub = parser.commands.get(command) if command is not None else None
    if sub is None:
        return lambda option: False
    valued = value_options(sub)
    every = {name for action in sub._actions for name in action.option_strings}

    def takes_value(option: str) -> bool:
        if option in every:
            return option in valued
        candidates = [name for name in every if option.startswith("--") and name.startswith(option)]
        return bool(candidates) and all(name in valued for name in candidates)
    return takes_value


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `sosmatch` console script. Returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    run = {"command": next((t for t in argv if not t.startswith("-")), None)}  # named before it is parsed
    try:
        with stop_as_interrupt():
            return _main(argv, run)
    except BaseException as exc:  # noqa: BLE001 - only an interruption is handled here, the rest re-raised
        stop = interruption(exc)
        if stop is None:
            raise
        what = "terminated" if isinstance(stop, Terminated) else "interrupted"
        name = f"sosmatch {run['command']}" if run["command"] else "sosmatch"
        print(f"{name}: {what} (re-run the same command to resume)", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(stop, Terminated) else EXIT_INTERRUPTED


def _main(argv: list[str], run: dict[str, str | None]) -> int:
    from ..database.full_disk import FULL_DISK_ERRNOS
    from ..plugin.errors import InputError

    parser = build_parser()
    args, unknown = parser.parse_known_args(join_negative_numbers(argv, _command_takes_value(parser, argv)))
    run["command"] = args.command
    if unknown:  # argparse leaves a command's unknown flags to the top-level parser, whose help lists no flags
        # -q / -v are every command's own options: given before the command they reach no parser that knows them
        early = [t for t in unknown if t in ("-q", "--quiet", "--verbose") or re.fullmatch(r"-v+", t)]
        where = f" ({' '.join(early)} goes after the command: sosmatch {args.command} {' '.join(early)} ...)" \
            if early else ""
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}{where}")
    _setup_logging(args.verbose, args.quiet)
    try:
        code = args._run(args)
    except InputError as exc:
        if args.verbose:
            log.exception("user error")
        print(f"sosmatch {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:
        if exc.errno not in FULL_DISK_ERRNOS or interruption(exc) is not None:
            raise
        # a full disk or quota mid-run is the user's to fix, like a bad input: one line, and the run resumes (every
        # output is written atomically; the temporaries of this one are removed by the next run)
        if args.verbose:
            log.exception("disk full")
        where = exc.filename or getattr(args, "out", None)
        where = f"{where}: " if where is not None else ""
        print(f"sosmatch {args.command}: error: {where}{os.strerror(exc.errno)}: free some space, then re-run the "
              "same command to resume", file=sys.stderr)
        return EXIT_USER_ERROR
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
