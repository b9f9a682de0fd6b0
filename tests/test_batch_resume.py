"""rev48 D1: a batch stage saves each task's state as its result arrives, so a Ctrl-C or a worker killed (out of
memory) loses only the tasks it took down, and the re-run resumes the others. Real worker processes, no mocks."""

import json
import os
from pathlib import Path

import pytest

from sosmatch.tools.toy_sessions import lawnmower, make_world, oracle_pair_task, write_toy_session, yaw_transform
from sosmatch.workflows import batch
from sosmatch.workflows.batch.state import StateStore, run_stage
from sosmatch.workflows.executors import WORKER_DIED, LocalExecutor

TRIGGER = "SOSMATCH_TEST_BREAK"  # "exit:KEY" or "interrupt:KEY": what the task of KEY does (env of the workers)


def _break_if_asked(key: str) -> None:
    how, _, which = os.environ.get(TRIGGER, "").partition(":")
    if which == key and how == "exit":
        os._exit(9)  # as the OOM killer: the worker process is gone, no result, no exception
    if which == key and how == "interrupt":
        raise KeyboardInterrupt


def counting_task(key: str, log_dir: str) -> dict:
    """Appends its key to a file of its own (how often it ran), then breaks where the environment says."""
    with open(Path(log_dir) / f"{key}.runs", "a") as f:
        f.write("x")
    _break_if_asked(key)
    return {"value": key.upper()}


def _stage(tmp_path: Path, executor, keys=("t1", "t2", "t3")) -> dict:
    tasks = {k: (k, str(tmp_path)) for k in keys}
    return run_stage(executor, counting_task, tasks, {k: [f"fp-{k}"] for k in keys},
                     StateStore(tmp_path / "state", tmp_path), "demo", tmp_path, "demo", False)


def _runs(tmp_path: Path, key: str) -> int:
    path = tmp_path / f"{key}.runs"
    return len(path.read_text()) if path.exists() else 0


def test_a_worker_killed_under_a_task_fails_that_task_only_and_the_rerun_resumes_the_rest(tmp_path, monkeypatch):
    monkeypatch.setenv(TRIGGER, "exit:t2")
    with LocalExecutor(1) as ex:  # one worker: t1 has finished when t2 kills it; t3 runs on a new pool
        first = _stage(tmp_path, ex)
    assert first["t1"]["status"] == first["t3"]["status"] == "done"
    assert first["t2"] == {"status": "failed", "error": WORKER_DIED, "seconds": 0.0}
    assert "BrokenProcessPool" in (tmp_path / "logs" / "demo-t2.log").read_text()
    monkeypatch.delenv(TRIGGER)
    with LocalExecutor(1) as ex:
        again = _stage(tmp_path, ex)
    assert again["t1"].get("resumed") and again["t3"].get("resumed") and not again["t2"].get("resumed")
    assert again["t2"]["status"] == "done" and again["t2"]["value"] == "T2"
    assert [_runs(tmp_path, k) for k in ("t1", "t2", "t3")] == [1, 2, 1]


@pytest.mark.parametrize("workers", [0, 1])
def test_an_interrupted_stage_keeps_the_tasks_that_finished(tmp_path, monkeypatch, workers):
    monkeypatch.setenv(TRIGGER, "interrupt:t2")  # Ctrl-C while t2 runs (in this process, or in its worker)
    with LocalExecutor(workers) as ex, pytest.raises(KeyboardInterrupt):
        _stage(tmp_path, ex)
    assert (tmp_path / "state" / "demo" / "t1.json").is_file()
    assert not (tmp_path / "state" / "demo" / "t2.json").exists()
    monkeypatch.delenv(TRIGGER)
    with LocalExecutor(workers) as ex:
        again = _stage(tmp_path, ex)
    assert again["t1"].get("resumed") and not again["t2"].get("resumed")
    assert _runs(tmp_path, "t1") == 1 and _runs(tmp_path, "t2") == 2


def breaking_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`oracle_pair_task`, whose worker dies (or is interrupted) on the pair the environment names."""
    _break_if_asked(Path(pair_dir).name)
    return oracle_pair_task(session_a, session_b, pair_dir, params)


def test_a_batch_whose_worker_dies_reports_the_pair_failed_and_resumes_the_others(tmp_path, monkeypatch):
    """The batch goes on after a worker died under a pair (the reviewer's run: a BrokenProcessPool traceback, no
    report.json, and the re-run mapped every flight again); the re-run matches that pair alone."""
    world = make_world(260, extent_m=400, seed=3)
    for k, (name, box) in enumerate({"A": (20, 140, 20, 140), "B": (60, 180, 40, 160),
                                     "C": (100, 220, 60, 180)}.items()):
        write_toy_session(tmp_path / "flights" / name, world, lawnmower(*box, 60, 40, 12),
                          yaw_transform(20 * k, (3 * k, 0, 0)), seed=k)
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False, changes=False, merge=False)
    monkeypatch.setenv(TRIGGER, "exit:A__C")
    with LocalExecutor(1) as ex:
        report = batch.run(tmp_path / "flights", out, executor=ex, options=options, pair_fn=breaking_pair_task)
    pairs = {p["pair"]: p for p in report.pairs}
    assert pairs["A__C"]["status"] == "failed" and pairs["A__C"]["error"] == WORKER_DIED
    assert pairs["A__B"]["status"] == pairs["B__C"]["status"] == "done" and not report.ok
    assert report.failures == [f"pair A__C: {WORKER_DIED}"]
    assert json.loads((out / "report.json").read_text())["failures"] == report.failures
    monkeypatch.delenv(TRIGGER)
    with LocalExecutor(1) as ex:
        again = batch.run(tmp_path / "flights", out, executor=ex, options=options, pair_fn=breaking_pair_task)
    resumed = {p["pair"]: bool(p.get("resumed")) for p in again.pairs}
    assert resumed == {"A__B": True, "A__C": False, "B__C": True} and again.ok
    assert all(s.get("resumed") for s in again.sessions)


def test_a_pairs_counts_are_read_from_its_changes_record_and_an_earlier_ones_are_not_summed(tmp_path):
    """nu60 D1/D2: a pair's counts come from its changes.json (`workflow._changes_record`), also of a comparison
    a resumed batch finds finished whose state an earlier version wrote (then `gone` summed landmarks and objects
    never mapped); a record without every count is said and left out of the sums, not read as zeros."""
    from sosmatch.database.changes_io import CHANGES_FORMAT
    from sosmatch.plugin.changes import COUNT_KEYS
    from sosmatch.workflows.batch.report import BatchReport
    from sosmatch.workflows.batch.workflow import _changes_record

    counts = {k: i + 1 for i, k in enumerate(COUNT_KEYS)}
    pairs = []
    for key, held in (("A__B", counts), ("A__C", {k: v for k, v in counts.items() if k != "flat_a"})):
        path = tmp_path / key / "changes.json"
        path.parent.mkdir()
        path.write_text(json.dumps({"format": CHANGES_FORMAT, "counts": held, "warnings": []}))
        # the state of an earlier version: `gone` of landmarks and objects never mapped, `kept` of A alone
        rec = {"pair": key, "changes_status": "done", "changes": str(path), "gone": 99, "kept": 99}
        _changes_record(key, rec)
        pairs.append(rec)
    assert {k: pairs[0][k] for k in COUNT_KEYS} == counts and not pairs[0].get("changes_warnings")
    assert "gone" not in pairs[1] and "holds no counts of" in pairs[1]["changes_warnings"][0]
    line = BatchReport(tmp_path, pairs=pairs).changes_line()
    assert line.startswith(f"changes summed over 1 pair(s): {counts['gone']} gone,")
    assert line.endswith("; 1 pair(s) without counts")
