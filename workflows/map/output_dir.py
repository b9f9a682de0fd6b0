"""The map's output directory: refusal rules, SESSION_DIR/.partial, and publishing finished outputs."""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from ...database.atomic import write_text_atomic
from ...database.colmap_db import (
    check_database_writable,
)
from ...plugin.errors import InputError

log = logging.getLogger(__name__)

PARTIAL = ".partial"
OUTPUTS = ("database.db", "sparse", "landmarks.sosmap", "landmarks.ply", "landmarks.csv")


def prepare_output_dir(out_dir: Path, fingerprint: str, overwrite: bool) -> Path:
    """Check that `out_dir` may receive this run; create SESSION_DIR/.partial and return it.

    Refuses (InputError) a directory that cannot be written, a session made from other inputs, a non-empty
    directory that is not a sosmatch session (unless `overwrite`), and a database locked by another process.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("output path exists and is not a directory", out_dir)
    run_json = out_dir / "run.json"
    if out_dir.is_dir() and not overwrite:
        if run_json.is_file():
            try:
                previous = json.loads(run_json.read_text(encoding="utf-8"))["fingerprints"]["inputs"]
            except (OSError, ValueError, KeyError, TypeError):
                previous = None
            if previous != fingerprint:
                raise InputError("output directory holds a session made from other inputs (use --overwrite to "
                                 "replace it)", out_dir)
        else:
            others = [p.name for p in out_dir.iterdir() if p.name != PARTIAL]
            try:  # an interrupted run (possibly killed while moving its outputs into place) left its inputs here
                started = json.loads((out_dir / PARTIAL / "inputs.json").read_text(encoding="utf-8"))["inputs"]
            except (OSError, ValueError, KeyError, TypeError):
                started = None
            if started is not None and started != fingerprint:
                raise InputError("output directory holds an interrupted run from other inputs (use --overwrite to "
                                 "replace it)", out_dir)
            if others and started is None:
                raise InputError(f"output directory is not empty and is not a sosmatch session ({others[0]}, ...);"
                                 " use --overwrite to write into it anyway", out_dir)
    check_database_writable(out_dir / "database.db")
    partial = out_dir / PARTIAL
    try:
        partial.mkdir(parents=True, exist_ok=True)
        write_text_atomic(partial / "inputs.json", json.dumps({"inputs": fingerprint}) + "\n")
    except OSError as exc:
        raise InputError(f"cannot write output directory: {exc.strerror or exc}", out_dir) from None
    return partial


def publish(partial: Path, out_dir: Path, names: Sequence[str]) -> None:
    """Move finished outputs from .partial into out_dir; run.json goes last so its presence means complete."""
    (out_dir / "run.json").unlink(missing_ok=True)
    for name in names:
        src, dst = partial / name, out_dir / name
        if dst.is_dir() and not dst.is_symlink():
            old = partial / (name + ".old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(dst, old)
            os.replace(src, dst)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(src, dst)
    os.replace(partial / "run.json", out_dir / "run.json")
