"""Which sosmatch made an output: the package version and a digest of the package's source files.

An output's identity keys its inputs and settings, not the code (an output of an earlier version with the same
settings is the same output, and resumes: `database.output_markers.VersionedIdentity`). The package version alone
does not tell two builds apart (it changes with releases, the code with every commit), so a run's record also
holds `source_digest`: sha256 of the package's Python sources (path and contents; the tests and the benchmark
scripts left out, as they make no output), read once per process (~230 files, ~10 ms of CPU). Deterministic: the
same files give the same digest in any checkout or installation; a git commit would not see uncommitted changes
and is missing from an installed package.

`map` records both in run.json (`versions.sosmatch`, `versions.sosmatch_source`); `batch` warns once per session
it keeps that another version made (`other_version`), and `--overwrite` maps it again.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parents[1]
# sources that make no output: a change to them is no other version of the outputs
LEFT_OUT = ("tests", "tools/benchmarks")


@lru_cache(maxsize=1)
def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """The first 16 hex digits of the sha256 of the package's Python sources (each file's path inside the package
    and the sha256 of its contents, in path order; hidden folders, caches and `LEFT_OUT` left out)."""
    h = hashlib.sha256()
    for path in sorted(package_dir.rglob("*.py")):
        rel = path.relative_to(package_dir).as_posix()
        parts = rel.split("/")
        if any(p.startswith(".") or p == "__pycache__" for p in parts) or any(
                rel == d or rel.startswith(d + "/") for d in LEFT_OUT):
            continue
        h.update(rel.encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()[:16]


def code_versions() -> dict[str, str]:
    """This sosmatch, as a run's record holds it: {"sosmatch": package version, "sosmatch_source": digest}."""
    from ..plugin import __version__

    return {"sosmatch": __version__, "sosmatch_source": source_digest()}


def describe(versions: dict[str, Any]) -> str:
    """"sosmatch 0.1.0 (source 9d2e43e721bc03ed)"; a record made before the digest was recorded says so."""
    source = versions.get("sosmatch_source")
    if not versions.get("sosmatch"):
        return "an earlier sosmatch (its version was not recorded)"
    return (f"sosmatch {versions.get('sosmatch', '?')} "
            f"({f'source {source}' if source else 'an earlier sosmatch: its source was not recorded'})")


def other_version(record: dict[str, Any] | None) -> str | None:
    """`describe` of the sosmatch that made an output (`record`: its run.json) when that is not this one (another
    package version or source digest, or none recorded), else None. None too for a record that is not a dict."""
    if not isinstance(record, dict):
        return None
    made = record.get("versions")
    made = made if isinstance(made, dict) else {}
    today = code_versions()
    if all(made.get(k) == v for k, v in today.items()):
        return None
    return describe(made)


def kept_message(where: object, made_by: str, redo: str) -> str:
    """The warning of an output kept as another sosmatch made it (`made_by`, `other_version`'s), once per output:
    "WHERE: kept as made by ..., with the same inputs and settings; this is ...: --overwrite REDO with this one"."""
    return (f"{where}: kept as made by {made_by}, with the same inputs and settings; this is "
            f"{describe(code_versions())} (another version may make it otherwise): --overwrite {redo} with this one")
