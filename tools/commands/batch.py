"""`sosmatch batch FLIGHTS_DIR --out OUT`: map every flight, match pairs, merge connected groups, report."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (
    add_min_confidence_argument,
    add_params_arguments,
    params_from_args,
    settings_from_args,
    with_min_confidence,
)

NAME = "batch"
HELP = "map a folder of flights, match session pairs, merge each connected group into one model (resumable)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("flights_dir", type=Path, help="one sub-folder per flight (images + poses.csv, geotagged "
                        "images, a synth session or an already mapped session)")
    parser.add_argument("--out", type=Path, required=True,
                        help="output directory (re-run the same command to resume): sessions/ (one map each), "
                        "pairs/ (matches, changes), merged/ (one model per group), report.md/.json, sessions.csv, "
                        "pairs.csv, session_graph.png, state/")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes (0: run in this process)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the tasks on this Dask cluster")
    where.add_argument("--dask-local", action="store_true", help="start a Dask LocalCluster of --workers processes")
    parser.add_argument("--nearest", type=int, metavar="K",
                        help="match only pairs among the K nearest sessions (by camera positions in a common frame)")
    parser.add_argument("--ekf", action="store_true", help="synth flights: map with poses_ekf.csv (noisy poses)")
    parser.add_argument("--no-verify", action="store_true",
                        help="take each pair's match consensus as is instead of verifying every window hypothesis "
                             "on the full maps (the default; see README)")
    parser.add_argument("--refine", action="store_true",
                        help="with --no-verify: refine each accepted consensus on the full maps as `merge "
                             "--refine` does (verification already refines its winner)")
    parser.add_argument("--no-merge", action="store_true", help="stop after the session graph")
    parser.add_argument("--no-changes", action="store_true",
                        help="skip change detection of the accepted pairs (pairs/A__B/changes/)")
    add_min_confidence_argument(parser)  # the pairs' change detection, as `sosmatch changes`
    parser.add_argument("--epsg", type=int,
                        help="the projected CRS (EPSG code) of the flights of photos' poses (default: each flight's "
                             "UTM zone of its median GPS fix); flights of one site on either side of a UTM zone edge "
                             "are mapped in one")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace outputs in --out made with other parameters (without it such a re-run is "
                             "refused; a flight whose files changed is mapped again either way, and its pairs, merges "
                             "and comparisons made again); also map again the sessions another sosmatch version made "
                             "(without it they are kept, with a warning)")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...plugin.errors import InputError
    from ...workflows import batch
    from ...workflows.executors import make_executor

    if args.workers < 0:
        raise InputError(f"--workers must be >= 0, got {args.workers}")
    if args.nearest is not None and args.nearest < 1:
        raise InputError(f"--nearest must be >= 1, got {args.nearest}")
    params = with_min_confidence(params_from_args(args), args)
    if args.refine and not args.no_verify:
        raise InputError("--refine only applies with --no-verify (verification already refines its winner)")
    options = batch.BatchOptions(nearest=args.nearest, ekf=args.ekf, merge=not args.no_merge, refine=args.refine,
                                 verify=not args.no_verify, changes=not args.no_changes, epsg=args.epsg,
                                 progress=not (args.no_progress or args.quiet), overwrite=args.overwrite,
                                 transform_chosen="association.transform" in settings_from_args(args))
    with make_executor(args.workers, args.scheduler, args.dask_local) as executor:
        report = batch.run(args.flights_dir, args.out, params, executor, options)
    done = sum(s["status"] == "done" for s in report.sessions)
    accepted = sum(p["status"] == "done" and bool(p.get("accepted")) for p in report.pairs)
    print(f"{args.out}: {done}/{len(report.sessions)} sessions mapped, {len(report.pairs)} pairs "
          f"({accepted} accepted; {report.changes_line()}), {len(report.groups)} groups; report "
          f"{args.out / 'report.md'}")
    for line in report.warnings:
        print(f"WARNING {line}")
    for line in report.failures:
        print(f"FAILED {line}")
    return 0 if report.ok else 1
