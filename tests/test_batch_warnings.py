"""What batch's report says of its sessions' maps and its pairs' matches (nu42 D4: a session whose images and EXIF
contradict each other on the focal length, and a pair whose answer is imprecise, were "ok" in report.json: their
warnings were only in the session's run.json and the pair's match.json)."""

import csv
import json
import shutil
from pathlib import Path

import pytest

from sosmatch.plugin.errors import InputError
from sosmatch.tools.toy_sessions import lawnmower, make_world, oracle_pair_task, write_toy_session, yaw_transform
from sosmatch.workflows import batch
from sosmatch.workflows.executors import LocalExecutor
from sosmatch.workflows.map.quality import recorded_verdict_warnings

FOCAL = "poses: camera 1: the images and EXIF contradict each other on the focal length by 9.8 sigmas"
REPEATED = "1 image(s) repeat another's exposure: frame_3-Edit.jpg (= frame_3.jpg)"
IMPRECISE = "imprecise answer: B's 101 landmarks may lie up to 1.2 m from where it puts them"


def imprecise_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`oracle_pair_task` whose match.json also records a warning of `match` (as its worker writes it)."""
    oracle_pair_task(session_a, session_b, pair_dir, params)
    path = Path(pair_dir) / "match.json"
    doc = json.loads(path.read_text())
    doc["warnings"] = [f"{session_b}: {IMPRECISE}"]
    path.write_text(json.dumps(doc))
    return batch.summarise_match(path)


@pytest.fixture()
def flights(tmp_path):
    """Two overlapping toy flights (mapped sessions); A's run.json records a warning of `sosmatch map`."""
    world = make_world(300, extent_m=300, seed=5)
    for k, (name, box, tf) in enumerate((("A", (20, 120, 20, 120), yaw_transform(0, (0, 0, 0))),
                                         ("B", (60, 160, 40, 140), yaw_transform(35, (12, -4, 1))))):
        write_toy_session(tmp_path / "fl" / name, world, lawnmower(*box, 60, 35, 10), tf, seed=10 + k)
    verdict = {"status": "ok", "refusals": [], "warnings": [FOCAL]}
    (tmp_path / "fl" / "A" / "run.json").write_text(json.dumps({"verdict": verdict}))
    # its poses' record (structure from motion in the session): the verdict repeats the focal length's warning
    (tmp_path / "fl" / "A" / "poses").mkdir()
    (tmp_path / "fl" / "A" / "poses" / "poses.json").write_text(json.dumps(
        {"format": "sosmatch-poses", "warnings": [FOCAL.removeprefix("poses: "), REPEATED]}))
    return tmp_path / "fl"


def _run(flights: Path, out: Path) -> batch.BatchReport:
    return batch.run(flights, out, executor=LocalExecutor(0), pair_fn=imprecise_pair_task,
                     options=batch.BatchOptions(progress=False, changes=False))


def test_the_report_says_every_warning_of_a_session_s_map_and_a_pair_s_match(flights, tmp_path):
    out = tmp_path / "out"
    report = _run(flights, out)
    said = [f"session A: {FOCAL}", f"session A: poses: {REPEATED}", f"pair A__B match: {flights / 'B'}: {IMPRECISE}"]
    assert report.warnings == said and report.ok and report.status == "3 warning(s)"
    data = json.loads((out / "report.json").read_text())
    assert data["warnings"] == said and data["status"] == "3 warning(s)"
    sessions = {s["name"]: s for s in data["sessions"]}
    assert sessions["A"]["warnings"] == [FOCAL, f"poses: {REPEATED}"] and "warnings" not in sessions["B"]
    assert data["pairs"][0]["match_warnings"] == [f"{flights / 'B'}: {IMPRECISE}"]
    md = (out / "report.md").read_text()
    assert "3 warning(s)" in md and "; ok;" not in md and all(f"- {w}" in md for w in said)
    rows = {r["name"]: r["warnings"] for r in csv.DictReader((out / "sessions.csv").open())}
    assert rows == {"A": "2", "B": "0"}
    assert [r["warnings"] for r in csv.DictReader((out / "pairs.csv").open())] == ["1"]

    # a resumed batch (every stage finished, also one whose state an earlier sosmatch wrote without them) says
    # them again, read from the records, nothing redone
    for state in (out / "state").rglob("*.json"):
        doc = json.loads(state.read_text())
        if isinstance(doc.get("result"), dict):
            doc["result"].pop("warnings", None), doc["result"].pop("match_warnings", None)
            state.write_text(json.dumps(doc))
    again = _run(flights, out)
    assert all(s.get("resumed") for s in again.sessions) and all(p.get("resumed") for p in again.pairs)
    assert again.warnings == said


def test_a_batch_without_warnings_is_plainly_ok(flights, tmp_path):
    (flights / "A" / "run.json").unlink()
    shutil.rmtree(flights / "A" / "poses")
    report = batch.run(flights, tmp_path / "out", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                       options=batch.BatchOptions(progress=False, changes=False))
    assert report.warnings == [] and report.status == "ok"
    assert "; ok;" in (tmp_path / "out" / "report.md").read_text()


def test_a_map_accepted_despite_refusals_is_a_warning_and_a_bad_verdict_is_named(tmp_path):
    record = tmp_path / "run.json"
    record.write_text(json.dumps({"verdict": {"status": "accepted_despite_refusals", "refusals": ["too few landmarks"],
                                              "warnings": ["w"]}}))
    assert recorded_verdict_warnings(tmp_path) == ["w", "accepted although too few landmarks (quality.refuse is off)"]
    record.write_text(json.dumps({"verdict": {"status": "ok", "warnings": "not a list"}}))
    with pytest.raises(InputError, match="verdict"):
        recorded_verdict_warnings(tmp_path)
    record.write_text(json.dumps({"format": "older, no verdict"}))
    assert recorded_verdict_warnings(tmp_path) == []
    shutil.rmtree(tmp_path)
    assert recorded_verdict_warnings(tmp_path) == []


def test_a_verdict_that_repeats_every_poses_warning_is_said_once(flights, tmp_path):
    """rev26: the map's verdict now holds all its poses.json's warnings (`poses.result.map_warnings`); batch, which
    also reads poses.json, says each once."""
    verdict = {"status": "ok", "refusals": [], "warnings": [FOCAL, f"poses: {REPEATED}"]}
    (flights / "A" / "run.json").write_text(json.dumps({"verdict": verdict}))
    report = _run(flights, tmp_path / "out")
    assert report.warnings == [f"session A: {FOCAL}", f"session A: poses: {REPEATED}",
                               f"pair A__B match: {flights / 'B'}: {IMPRECISE}"]


def uncertain_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`oracle_pair_task` whose answer records itself imprecise (its predicted error beyond its gate), as match
    writes it."""
    oracle_pair_task(session_a, session_b, pair_dir, params)
    path = Path(pair_dir) / "match.json"
    doc = json.loads(path.read_text())
    doc["answer_uncertainty"] = {"predicted_max_m": 58.1, "gate_m": 2.81, "imprecise": True}
    path.write_text(json.dumps(doc))
    return batch.summarise_match(path)


def test_a_lone_imprecise_pair_joins_no_group_and_the_report_says_why(flights, tmp_path):
    """nu44 D2: two disjoint tiles of one map were verified (p 0.001) with an answer whose own uncertainty put B up
    to 58 m off, and batch merged them on that one edge. Uncorroborated, it is kept apart and said; the same pair
    precise is merged as before."""
    report = batch.run(flights, tmp_path / "out", executor=LocalExecutor(0), pair_fn=uncertain_pair_task,
                       options=batch.BatchOptions(progress=False, changes=False))
    (pair,) = report.pairs
    assert pair["accepted"] and pair["in_graph"] is False and "uncorroborated: kept apart" in pair["left_out"]
    assert f"pair A__B: {pair['left_out']}" in report.warnings and "sosmatch merge" in pair["left_out"]
    assert sorted(g["members"] for g in report.groups) == [["A"], ["B"]]
    assert not (tmp_path / "out" / "merged").exists() or not any((tmp_path / "out" / "merged").iterdir())
    precise = batch.run(flights, tmp_path / "out2", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                        options=batch.BatchOptions(progress=False, changes=False))
    assert precise.pairs[0]["in_graph"] and "left_out" not in precise.pairs[0] and len(precise.groups) == 1
