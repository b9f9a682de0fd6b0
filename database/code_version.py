"""Which sosmatch made an output: the package version and a digest of the package's source files.

An output's identity keys its inputs and settings, not the code (an output of an earlier version with the same
settings is the same output, and resumes: `database.output_markers.VersionedIdentity`). The package version alone
does not tell two builds apart (it changes with releases, the code with every commit), so a run's record also
holds `source_digest`: sha256 of the package's Python sources (path and contents of the .py files in its own
folders, `PACKAGE_FOLDERS`, as setup.py installs them; the benchmark scripts left out, as they make no output),
read once per process (~230 files, ~10 ms of CPU). Deterministic: the same sources give the same digest in a
checkout, an editable or a regular installation, whatever lies beside the folders (setup.py, tests, build/, a
venv) and with CRLF or LF line endings; a git commit would not see uncommitted changes and is missing from an
installed package.

`map` records both in run.json (`versions.sosmatch`, `versions.sosmatch_source`); `batch` warns once per session
it keeps that another version made (`other_version`), and `--overwrite` maps it again.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parents[1]
# The package's own folders, as setup.py's TOP_LEVEL installs them: in a checkout PACKAGE_DIR is the repository
# root, which also holds setup.py, tests, perhaps build/ or a venv, none of them installed, so the same code would
# get another digest installed than checked out. Top-level modules of the package (none today) would be hashed too.
PACKAGE_FOLDERS = ("plugin", "database", "workflows", "tools")
TOP_LEVEL_MODULES = ("__init__.py", "__main__.py")
# sources inside those folders that make no output: a change to them is no other version of the outputs
LEFT_OUT = ("tools/benchmarks",)


def _package_sources(package_dir: Path) -> list[tuple[str, Path]]:
    """(path inside the package, file) of each source `source_digest` hashes, in path order."""
    found = [(name, package_dir / name) for name in TOP_LEVEL_MODULES if (package_dir / name).is_file()]
    for folder in PACKAGE_FOLDERS:
        for path in (package_dir / folder).rglob("*.py"):
            rel = path.relative_to(package_dir).as_posix()
            if any(p.startswith(".") or p == "__pycache__" for p in rel.split("/")) or any(
                    rel == d or rel.startswith(d + "/") for d in LEFT_OUT):
                continue
            found.append((rel, path))
    return sorted(found)


@lru_cache(maxsize=1)
def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """The first 16 hex digits of the sha256 of the package's Python sources (each file's path inside the package
    and the sha256 of its contents with CRLF / CR line endings read as LF, in path order; only the package's own
    folders, `PACKAGE_FOLDERS`, without hidden folders, caches and `LEFT_OUT`)."""
    h = hashlib.sha256()
    for rel, path in _package_sources(package_dir):
        text = path.read_bytes().replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        h.update(rel.encode() + b"\0" + hashlib.sha256(text).digest())
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
    return (f"sosmatch {versions['sosmatch']} "
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
