"""`batch --no-verify --refine`: one refined transform per pair, the one `sosmatch merge --refine` makes
(`merge.refined_answer`), shared by the graph, the merge, the changes and the report (rev33: the merge used a
refit on the consensus' associations, the changes and the report the consensus itself, 0.5 m apart)."""

import json
from pathlib import Path

import numpy as np

from sosmatch.database.match_io import read_match
from sosmatch.database.session_io import read_session
from sosmatch.plugin.multisession import Sim3, transform_error
from sosmatch.plugin.params import Params
from sosmatch.tools.toy_sessions import lawnmower, load_toy_session, make_world, toy_match_json, write_toy_session
from sosmatch.tools.toy_sessions import yaw_transform as turned
from sosmatch.workflows import batch, merge
from sosmatch.workflows.executors import LocalExecutor


def off_consensus_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """A matcher whose unverified answer (the window consensus) is 0.8 deg and ~0.6 m off the truth."""
    a, b = load_toy_session(session_a), load_toy_session(session_b)
    truth = a.session_from_world.compose(b.session_from_world.inverse())
    centre = read_session(a.path).landmarks.positions.mean(0)
    off = Sim3(np.eye(3), centre).compose(turned(0.8, (0.4, -0.4, 0.2))).compose(Sim3(np.eye(3), -centre))
    return batch.summarise_match(toy_match_json(a, b, Path(pair_dir) / "match.json", transform=off.compose(truth)))


def window_consensus_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`off_consensus_task` whose answer pairs only 12 of the landmarks the maps share, as a window consensus does."""
    off_consensus_task(session_a, session_b, pair_dir)
    path = Path(pair_dir) / "match.json"
    doc = json.loads(path.read_text())
    doc["hypotheses"][0]["associations"] = doc["hypotheses"][0]["associations"][:12]
    path.write_text(json.dumps(doc) + "\n")
    return batch.summarise_match(path)


def toy_flights(tmp_path: Path) -> dict[str, Sim3]:
    """Two toy flights B, C in tmp_path/fl; each session's session_from_world."""
    world = make_world(400, extent_m=300, seed=5)
    boxes = {"B": ((20, 140, 20, 140), Sim3.identity()), "C": ((80, 200, 60, 180), turned(-60, (-30, 25, -2)))}
    truth = {}
    for k, (name, (box, tf)) in enumerate(boxes.items()):
        truth[name] = write_toy_session(tmp_path / "fl" / name, world, lawnmower(*box, 60, 35, 10), tf,
                                        seed=10 + k).session_from_world
    return truth


def refined_batch(tmp_path: Path, pair_fn=off_consensus_task, flights: bool = True
                  ) -> tuple[batch.BatchReport, dict[str, Sim3]]:
    """The toy flights (`toy_flights`, unless `flights` is off: already there) batched with `--no-verify --refine`
    by `pair_fn` into tmp_path/out; the report and each session's session_from_world."""
    truth = toy_flights(tmp_path) if flights else {}
    report = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), pair_fn=pair_fn,
                       options=batch.BatchOptions(progress=False, verify=False, refine=True))
    return report, truth


def test_a_refined_pair_has_one_transform_in_graph_merge_changes_and_report(tmp_path):
    report, truth = refined_batch(tmp_path)
    out = tmp_path / "out"
    rec = {p["pair"]: p for p in report.pairs}["B__C"]
    assert rec["accepted"] and rec["in_graph"] and rec["refine"]["associations_used"] > 20
    pair = Sim3.from_dict(rec["transform"])
    # the one refinement of merge --refine
    match = read_match(rec["match"])
    one = merge.refined_answer(read_session(tmp_path / "fl" / "B").landmarks,
                               read_session(tmp_path / "fl" / "C").landmarks, match, Params())
    assert np.allclose(pair.matrix(), one.transform.matrix())
    pts = read_session(tmp_path / "fl" / "C").landmarks.positions
    assert transform_error(pair, truth["B"].compose(truth["C"].inverse()), pts)[0] < 0.15
    # ... which the merge and the changes used
    group = report.groups[0]
    ref_from = {n: Sim3.from_dict(t) for n, t in group["reference_from_session"].items()}
    assert np.allclose(ref_from["B"].inverse().compose(ref_from["C"]).matrix(), pair.matrix(), atol=1e-9)
    merged = json.loads((out / "merged" / group["reference"] / "merge.json").read_text())
    assert merged["reference_from_session"] == [ref_from[n].to_dict() for n in group["members"]]
    changes = json.loads(Path(rec["changes"]).read_text())
    assert np.allclose(Sim3.from_dict(changes["a_from_b"]).matrix(), pair.matrix())


def test_a_refined_group_fuses_what_merge_refine_fuses(tmp_path):
    """rev46 D2: batch's merge of a refined pair fused the match's own associations under the refined transform
    (9 where `merge --refine` of the same maps and match fused 18): it fuses the refined transform's pairs, and
    merge.json records the refinement, as merge's does."""
    report, _ = refined_batch(tmp_path, window_consensus_task)
    rec = {p["pair"]: p for p in report.pairs}["B__C"]
    group = report.groups[0]
    alone = merge.run(tmp_path / "fl" / "B", tmp_path / "fl" / "C", rec["match"], tmp_path / "alone", refine=True)
    assert alone.num_fused > 20
    assert (group["fused"], group["rejected_associations"]) == (alone.num_fused, alone.num_rejected)
    merged = json.loads((tmp_path / "out" / "merged" / group["reference"] / "merge.json").read_text())
    refine = json.loads((tmp_path / "alone" / "merge.json").read_text())["refine"]
    assert merged["refine"] == [{"pair": ["B", "C"], **rec["refine"]}]
    assert {k: refine[k] for k in ("associations_used", "dof")} == {k: rec["refine"][k] for k in
                                                                    ("associations_used", "dof")}


def test_a_group_an_earlier_sosmatch_merged_from_the_consensus_pairs_is_merged_again(tmp_path, monkeypatch):
    """A batch --refine of an earlier sosmatch fused a refined pair's consensus associations (rev46 D2): the same
    batch run again merges its group again, with the refined pairs, instead of resuming the old model."""
    from sosmatch.workflows.batch import graph

    refine = graph._refine_pair
    # the earlier sosmatch: the pair refined alike, its refinement's pairs not handed to the merge
    monkeypatch.setattr(graph, "_refine_pair", lambda *args: refine(*args) and None)
    before, _ = refined_batch(tmp_path, window_consensus_task)
    assert before.groups[0]["fused"] == 12
    monkeypatch.undo()
    report, _ = refined_batch(tmp_path, window_consensus_task, flights=False)
    group = report.groups[0]
    assert not group.get("resumed") and group["fused"] > 20
    assert "refine" in json.loads((tmp_path / "out" / "merged" / group["reference"] / "merge.json").read_text())
    again, _ = refined_batch(tmp_path, window_consensus_task, flights=False)  # ... once: then it resumes
    assert again.groups[0].get("resumed") and again.groups[0]["fused"] == group["fused"]
