"""A batch's pairs, controls, merges and comparisons are kept only while the maps (and matches) they were made from
are the ones there now (`state.run_stage`'s `made_from`): a `batch --overwrite` killed after re-mapping a session and
before its pairs left the old pairs, controls, merges and changes in place, and no later run (nor another
--overwrite) made them again (rev39, finding 2)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from sosmatch.database.landmark_map import read_landmark_map, write_landmark_map
from sosmatch.database.match_io import match_content, read_match
from sosmatch.tools.toy_sessions import lawnmower, make_world, oracle_pair_task, write_toy_session, yaw_transform
from sosmatch.workflows import batch
from sosmatch.workflows.batch.discovery import flight_signature
from sosmatch.workflows.executors import LocalExecutor


def _remapped(session: Path, scale: float) -> None:
    """The session's landmarks' sizes scaled by `scale` (their positions stay those of its 3D points, which the
    control compares), as a re-map by other code changes a map, with the file's size and mtime kept: what the map
    stage knows of it (`flight_signature`) stays the same, as after an interrupted --overwrite, whose map stage
    finished (its state is today's) and whose later stages did not run."""
    path = session / "landmarks.sosmap"
    before, st = flight_signature(session), path.stat()
    lmap = read_landmark_map(path)
    write_landmark_map(path, dataclasses.replace(lmap, sizes=lmap.sizes * scale))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert flight_signature(session) == before


def _state(out: Path, stage: str, key: str) -> dict:
    return json.loads((out / "state" / stage / f"{key}.json").read_text())["result"]


def _states(out: Path) -> dict[str, float]:
    return {p.relative_to(out).as_posix(): p.stat().st_mtime_ns for p in sorted((out / "state").rglob("*.json"))}


def test_stages_made_from_an_earlier_map_are_made_again(tmp_path):
    world = make_world(700, extent_m=720, seed=5)
    for k, (name, box, tf) in enumerate((("A", (20, 120, 20, 120), yaw_transform(0, (0, 0, 0))),
                                         ("B", (80, 180, 40, 140), yaw_transform(35, (12, -4, 1))))):
        write_toy_session(tmp_path / "fl" / name, world, lawnmower(*box, 60, 35, 10), tf, seed=10 + k)
    out = tmp_path / "out"

    def run() -> batch.BatchReport:
        report = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                           options=batch.BatchOptions(progress=False))
        assert not report.failures, report.failures
        return report

    def made_from_the_match_there() -> None:  # the control, the changes and the merge name today's match
        content = match_content(read_match(out / "pairs" / "A__B" / "match.json"))
        assert _state(out, "control", "A__B")["made_from"] == content
        assert _state(out, "changes", "A__B")["made_from"] == content
        assert _state(out, "merge", "A")["made_from"]

    first = run()
    assert first.pairs[0]["accepted"] and first.pairs[0]["changes_status"] == "done"
    assert [g["members"] for g in first.groups] == [["A", "B"]] and (out / "merged" / "A").is_dir()
    made_from_the_match_there()
    old_control, old_changes = (out / "state" / "control" / "A__B.json").read_text(), (
        out / "state" / "changes" / "A__B.json").read_text()

    # B mapped again (an interrupted --overwrite): its pair, control, merge and changes are made again
    _remapped(tmp_path / "fl" / "B", 1.1)
    second = run()
    assert second.sessions[1].get("resumed") and not second.pairs[0].get("resumed")
    assert not second.groups[0].get("resumed")
    made_from_the_match_there()
    assert _state(out, "control", "A__B")["made_from"] != json.loads(old_control)["result"]["made_from"]

    # killed after the pair was matched again, before its control and changes: those are made again alone
    (out / "state" / "control" / "A__B.json").write_text(old_control)
    (out / "state" / "changes" / "A__B.json").write_text(old_changes)
    third = run()
    assert third.pairs[0].get("resumed") and third.groups[0].get("resumed")
    made_from_the_match_there()
    saved = _states(out)
    assert run().pairs[0].get("resumed") and _states(out) == saved  # and then kept

    # a batch of an earlier sosmatch (states without `made_from`) resumes everything while its maps are unchanged
    for path in (out / "state").glob("*/*.json"):
        if path.parent.name == "contents":  # not a stage's
            continue
        data = json.loads(path.read_text())
        data["result"].pop("made_from", None)
        path.write_text(json.dumps(data))
    saved = _states(out)
    earlier = run()
    assert all(s.get("resumed") for s in earlier.sessions) and all(p.get("resumed") for p in earlier.pairs)
    assert all(g.get("resumed") for g in earlier.groups)
    assert _states(out) == saved  # nothing made again, nothing re-saved
    # ... and makes its pair again for another map, and after it what was made of the pair
    _remapped(tmp_path / "fl" / "B", 1.1)
    again = run()
    assert not again.pairs[0].get("resumed") and not again.groups[0].get("resumed")
    made_from_the_match_there()

