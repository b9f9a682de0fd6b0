"""Batch resume: the state store (OUT/state/STAGE/KEY.json) and the stage runner that skips finished tasks."""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from ...database.atomic import write_text_atomic
from ..executors import Executor, TaskResult

log = logging.getLogger(__name__)

STATE_VERSION = 2  # 2: paths relative to OUT


def fingerprint(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


PATH_KEYS = ("session", "match", "merged", "changes")  # result fields that hold paths
MADE_FROM = "made_from"  # a state's digest of the inputs its task was made from (`run_stage`)


class StateStore:
    """OUT/state/STAGE/KEY.json: the fingerprint and result of every finished task, written atomically.

    Paths inside OUT are stored relative to OUT (`base`), so a moved or copied OUT directory still resumes;
    paths outside it (an already mapped flight adopted as it is) are stored absolute.
    """

    def __init__(self, root: Path, base: Path | None = None) -> None:
        self.root = root
        self.base = base if base is not None else root.parent

    def _relative(self, result: dict[str, Any]) -> dict[str, Any]:
        out = dict(result)
        base = self.base.resolve()
        for key in PATH_KEYS:
            if isinstance(out.get(key), str):
                resolved = Path(out[key]).resolve()
                try:
                    out[key] = resolved.relative_to(base).as_posix()
                except ValueError:  # outside OUT (an adopted mapped flight): absolute, not relative to the cwd
                    out[key] = str(resolved)
        return out

    def _absolute(self, result: dict[str, Any]) -> dict[str, Any]:
        out = dict(result)
        for key in PATH_KEYS:
            if isinstance(out.get(key), str) and not Path(out[key]).is_absolute():
                out[key] = str(self.base / out[key])
        return out

    def _path(self, stage: str, key: str) -> Path:
        return self.root / stage / f"{key}.json"

    def get(self, stage: str, key: str, fingerprint: str) -> dict[str, Any] | None:
        path = self._path(stage, key)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return None
        if data.get("version") != STATE_VERSION or data.get("fingerprint") != fingerprint:
            return None
        result = data.get("result")
        return self._absolute(result) if isinstance(result, dict) else None

    def names_its_inputs(self, stage: str, key: str, fingerprint: str) -> bool:
        """Whether the finished task's state records what it was made from (`run_stage`'s `made_from`); a task
        without a state counts as one that does (it was not made by an earlier sosmatch)."""
        done = self.get(stage, key, fingerprint)
        return done is None or MADE_FROM in done

    def put(self, stage: str, key: str, fingerprint: str, result: dict[str, Any]) -> None:
        data = {"version": STATE_VERSION, "fingerprint": fingerprint, "result": self._relative(result)}
        write_text_atomic(self._path(stage, key), json.dumps(data, indent=1, sort_keys=True) + "\n")


def record_result(result: TaskResult, log_dir: Path, stage: str, key: str) -> dict[str, Any]:
    if result.ok:
        return {"status": "done", "seconds": round(result.seconds, 3), **result.value}
    write_text_atomic(log_dir / f"{stage}-{key}.log", result.traceback or result.error)
    log.warning("%s %s failed: %s", stage, key, result.error)
    return {"status": "failed", "error": result.error.splitlines()[0] if result.error else "failed",
            "seconds": round(result.seconds, 3)}


def run_stage(
    executor: Executor, fn: Any, tasks: dict[str, tuple], fingerprints: dict[str, list[str | None]],
    state: StateStore, stage: str, out_dir: Path, desc: str, progress: bool, still_valid: Any = None,
    earlier: dict[str, list[str]] | None = None, redo: Collection[str] = (),
    made_from: dict[str, str] | None = None, unrecorded: Callable[[str, dict[str, Any]], bool] | None = None,
    on_done: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Skip tasks whose state matches, run the rest, save the state of each that succeeds as its result arrives
    (then `on_done(key)`): Ctrl-C, or a worker killed under another task, loses only the tasks still running, and
    the re-run resumes the others (rev48 D1: a stage's states were saved once all its tasks had returned, so an
    interrupted stage was done again from its start). The tasks `redo` run whatever their state (made from a
    session mapped again by this version: `batch.workflow._kept_session`).

    `fingerprints`: each task's fingerprint per version of sosmatch (`plugin.params.build_versions`: today's
    first, then earlier versions', None where a version cannot have made it); `earlier`: further fingerprints an
    earlier version of the batch gave the same task. A state saved under an earlier one is taken as this one's and
    re-saved under today's, so an output made before a fingerprint changed resumes.

    `made_from`: a digest of the inputs each task reads now (the maps of a pair, the match of a control); the
    fingerprints key the settings and the flights, not what an earlier stage made of them, which a run killed
    between two stages (`--overwrite` re-mapping a session) leaves changed under an unchanged fingerprint. Saved
    in the task's state; a state of other inputs is run again. A state without one (an earlier sosmatch's) is
    kept when `unrecorded(key, state)` says it is still about these inputs (no `unrecorded`: kept)."""
    records: dict[str, dict[str, Any]] = {}
    todo = {}
    today = {key: fingerprints[key][0] for key in tasks}
    for key, args in tasks.items():
        if key in redo:
            todo[key] = args
            continue
        done = state.get(stage, key, today[key])
        migrated = False
        for old in [*fingerprints[key][1:], *(earlier or {}).get(key, [])]:
            if done is not None:
                break
            if old is not None and old != today[key]:
                done, migrated = state.get(stage, key, old), True
        if done is not None and made_from is not None and key in made_from:
            if MADE_FROM in done:
                done = done if done[MADE_FROM] == made_from[key] else None
            elif unrecorded is not None and not unrecorded(key, done):
                done = None
        if done is not None and (still_valid is None or still_valid(done)):
            if migrated:  # re-saved under today's fingerprint (one without `made_from` stays without: unknown)
                state.put(stage, key, today[key], done)
            records[key] = {**{k: v for k, v in done.items() if k != MADE_FROM}, "status": "done", "resumed": True}
        else:
            todo[key] = args

    def arrived(res: TaskResult) -> None:
        key = str(res.key)
        rec = record_result(res, out_dir / "logs", stage, key)
        if res.ok:
            inputs = {MADE_FROM: made_from[key]} if made_from is not None and key in made_from else {}
            state.put(stage, key, today[key], {**{k: v for k, v in rec.items() if k != "status"}, **inputs})
            if on_done is not None:
                on_done(key)
        records[key] = rec

    if todo:
        executor.run(fn, todo, desc=desc, progress=progress, on_result=arrived)
    return {key: records[key] for key in tasks}
