"""Batch: discovery, map/match/merge stages over several flights, failures reported per flight, resume,
the session graph (groups, spanning-tree transforms) and identical results on a Dask LocalCluster."""

import csv
import io
import json
import logging
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from sosmatch.plugin.errors import InputError
from sosmatch.plugin.multisession import Edge, Sim3, connected_groups, nearest_pairs, spanning_transforms
from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import lawnmower, make_world, oracle_pair_task, write_toy_session, yaw_transform
from sosmatch.workflows import batch
from sosmatch.workflows.batch.pairs import CHOSEN_BY_TIME, pairs_chosen_by
from sosmatch.workflows.executors import DaskExecutor, LocalExecutor

# A, B and C overlap in a chain (A-B, B-C; A-C too little to accept): C reaches A's frame only through B.
# D is far away. Groups: {A, B, C} and {D}.
FLIGHTS = {
    "A": ((20, 120, 20, 120), yaw_transform(0, (0, 0, 0))),
    "B": ((80, 180, 40, 140), yaw_transform(35, (12, -4, 1))),
    "C": ((150, 250, 60, 160), yaw_transform(-60, (-30, 25, -2))),
    "D": ((600, 700, 600, 700), yaw_transform(90, (5, 5, 0))),
}


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("flights")
    world = make_world(700, extent_m=720, seed=5)
    truth = {}
    for k, (name, (box, tf)) in enumerate(FLIGHTS.items()):
        s = write_toy_session(root / name, world, lawnmower(*box, 60, 35, 10), tf, seed=10 + k)
        truth[name] = s.session_from_world
    broken = root / "E_broken"
    (broken / "images").mkdir(parents=True)
    (broken / "images" / "frame_00000.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    (broken / "poses.csv").write_text("name,x,y,z\nframe_00000.jpg,1,2\n")
    (root / "notes").mkdir()  # not a flight: ignored
    return root, truth


def choose_pairs(names, sessions, nearest, times=None):
    """(the pairs batch matches, those of them added for their capture times), from `pairs_chosen_by`."""
    reasons = pairs_chosen_by(names, sessions, nearest, times)
    return list(reasons), [p for p, why in reasons.items() if why == CHOSEN_BY_TIME]


def _normalised(report_path, out_dir, made_in=None):
    """report.json without what legitimately differs between runs: timings, executor, out dir, resumed flags
    (`made_in`: the folder a copied OUT was made in, which the records it holds name, as changes.json its match)."""
    text = report_path.read_text().replace(str(out_dir), "OUT")
    if made_in is not None:
        text = text.replace(str(made_in), "OUT")
    data = json.loads(text)
    data.pop("executor"), data.pop("seconds")
    for item in data["sessions"] + data["pairs"] + data["groups"]:
        item.pop("seconds", None), item.pop("resumed", None)
    return data


def _run(flights_root, out, executor):
    return batch.run(flights_root, out, executor=executor, options=batch.BatchOptions(progress=False),
                     pair_fn=oracle_pair_task)


@pytest.fixture(scope="module")
def local_run(flights, tmp_path_factory):
    root, truth = flights
    out = tmp_path_factory.mktemp("out_local")
    with LocalExecutor(2) as ex:
        report = _run(root, out, ex)
    return out, report


def test_discovery(flights, tmp_path, caplog):
    root, _ = flights
    found = batch.discover_flights(root)
    assert [(f.name, f.kind) for f in found] == [("A", "mapped"), ("B", "mapped"), ("C", "mapped"),
                                                 ("D", "mapped"), ("E_broken", "poses")]
    with pytest.raises(InputError, match="no flights"):
        batch.discover_flights(tmp_path)
    assert main(["batch", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    # a folder of photos gets its poses by structure from motion, an ODM project from its reconstruction
    for name in ("photos", "odm"):
        (tmp_path / "kinds" / name / "images").mkdir(parents=True)
        (tmp_path / "kinds" / name / "images" / "a.jpg").write_bytes(b"")
    (tmp_path / "kinds" / "odm" / "opensfm").mkdir()
    (tmp_path / "kinds" / "odm" / "opensfm" / "reconstruction.json").write_text("[]")
    (tmp_path / "kinds" / "moved").symlink_to(tmp_path / "gone")  # a flight unmounted or moved: said, skipped
    with caplog.at_level("WARNING"):
        kinds = [(f.name, f.kind) for f in batch.discover_flights(tmp_path / "kinds")]
    assert kinds == [("odm", "opensfm"), ("photos", "images")]
    assert "moved: a link to" in caplog.text and "does not exist" in caplog.text


def test_discovery_skips_what_is_not_a_flight_and_says_so(flights, local_run, tmp_path, caplog):
    """The seventh new-user sweep: two links to one flight were mapped (and merged) twice; a flight folder whose
    images were not copied was dropped at INFO as having "no images, pose file or mapped session"; an earlier
    batch output kept in the flights folder was taken for a flight."""
    root, _ = flights
    kinds = tmp_path / "kinds"
    kinds.mkdir()
    (kinds / "A").symlink_to(root / "A")
    (kinds / "A_again").symlink_to(root / "A")
    (kinds / "no_images").mkdir()
    (kinds / "no_images" / "poses.csv").write_text("name,x,y,z\n")
    shutil.copytree(local_run[0], kinds / "last_run", symlinks=True)
    with caplog.at_level("WARNING"):
        found = [(f.name, f.kind) for f in batch.discover_flights(kinds)]
    assert found == [("A", "mapped")]
    assert "A_again: the same folder as flight A" in caplog.text
    assert "no_images: a pose file but no images" in caplog.text
    assert "last_run: an output of `sosmatch batch`, not a flight" in caplog.text


def test_batch_stages_failures_and_groups(flights, local_run):
    root, truth = flights
    out, report = local_run
    status = {s["name"]: s["status"] for s in report.sessions}
    assert status == {"A": "done", "B": "done", "C": "done", "D": "done", "E_broken": "failed"}
    assert not report.ok and len(report.failures) == 1 and "E_broken" in report.failures[0]
    assert (out / "logs" / "map-E_broken.log").exists()
    done = {p["pair"]: p for p in report.pairs if p["status"] == "done"}
    assert sorted(done) == ["A__B", "A__C", "A__D", "B__C", "B__D", "C__D"]
    assert sum(p["status"] == "skipped" for p in report.pairs) == 4  # every pair with the failed flight
    assert {k for k, p in done.items() if p["accepted"]} == {"A__B", "B__C"}
    # a refused pair holds no associations; what its best candidate had is its own column
    assert all((p["num_associations"] > 0) == p["accepted"] and (p["refused_support"] is None) == p["accepted"]
               for p in done.values())
    assert {k for k, p in done.items() if p.get("in_graph")} == {"A__B", "B__C"}
    groups = {g["reference"]: g for g in report.groups}
    big = next(g for g in report.groups if len(g["members"]) == 3)
    assert sorted(big["members"]) == ["A", "B", "C"] and big["status"] == "done"
    assert groups["D"]["status"] == "single"
    # Every member lands where the truth puts it in the reference frame.
    ref = truth[big["reference"]]
    for name, t in big["reference_from_session"].items():
        est = Sim3(t["rotation"], t["translation"], t["scale"])
        want = ref.compose(truth[name].inverse())
        assert np.allclose(est.apply(np.array([[100.0, 100.0, 5.0]])), want.apply(np.array([[100.0, 100.0, 5.0]])),
                           atol=0.2)
    rec = pycolmap.Reconstruction(str(out / "merged" / big["reference"] / "sparse"))
    n_images = sum(pycolmap.Reconstruction(str(root / n / "sparse")).num_images() for n in "ABC")
    assert rec.num_images() == big["images"] == n_images and big["fused"] > 20
    # change detection of every pair in the graph: the toy world did not change, so nothing is gone or new
    # nu60 D2: pairs.csv's `kept` counted A's landmarks where `unseen` added A's and B's; now every count of
    # `sosmatch changes` (changes.json `counts`), each of one map, named as there
    rows = {r["pair"]: r for r in csv.DictReader((out / "pairs.csv").open())}
    assert "kept" not in rows["A__B"] and "unseen" not in rows["A__B"]
    for key in ("A__B", "B__C"):
        assert (out / "pairs" / key / "changes" / "changes.csv").is_file()
        counts = json.loads((out / "pairs" / key / "changes" / "changes.json").read_text())["counts"]
        assert counts["kept_a"] > 0 and counts["kept_b"] > 0 and counts["gone"] == counts["new"] == 0
        assert {k: done[key][k] for k in counts} == counts
        columns = ("gone", "new", "kept_a", "kept_b", "unseen_a", "unseen_b", "gone_unmapped", "new_unmapped")
        assert {k: int(rows[key][k]) for k in columns} == {k: counts[k] for k in columns}
    assert not (out / "pairs" / "A__D" / "changes").exists()
    # what change detection warned of (the toy sessions record no images) is the pair's and the report's
    for key in ("A__B", "B__C"):
        assert any("no surface evidence" in w for w in done[key]["changes_warnings"])
        assert f"pair {key} changes: {done[key]['changes_warnings'][0]}" in report.warnings
    assert json.loads((out / "report.json").read_text())["warnings"] == report.warnings
    assert "pair A__B changes: " in (out / "report.md").read_text()
    for name in ("report.md", "report.json", "sessions.csv", "pairs.csv", "session_graph.png"):
        assert (out / name).stat().st_size > 0
    # a pair's row counts its warnings beside its status (its texts: the Warnings list)
    assert f"| A__B | done | {len(batch.pair_warnings(done['A__B']))} | True |" in (out / "report.md").read_text()
    # a pair without an accepted answer says why in its `refused` column (the oracle's matches are not verified),
    # and is no warning: most pairs of a folder of flights do not overlap
    assert done["A__D"]["refused"] == "no match, not verified (its best candidate holds 0 associations)"
    assert done["A__D"]["refused_by"] == "match" and not any("A__D" in w for w in report.warnings)
    row = next(line for line in (out / "report.md").read_text().splitlines() if line.startswith("| A__D |"))
    assert "| no match, not verified (its best candidate holds 0 associations) |" in row


def test_resume_skips_finished_tasks(flights, local_run, tmp_path):
    root, _ = flights
    out, first = local_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)  # a moved OUT resumes: state files hold paths relative to OUT
    states = list((copy / "state").rglob("*.json"))
    assert states and not any(str(out) in f.read_text() for f in states)
    (copy / "state" / "match" / "A__B.json").unlink()  # as if the run had been killed before this pair finished
    again = _run(root, copy, LocalExecutor(0))
    resumed = {p["pair"]: p.get("resumed", False) for p in again.pairs if p["status"] == "done"}
    assert resumed.pop("A__B") is False and all(resumed.values())
    assert all(s.get("resumed") for s in again.sessions if s["status"] == "done")
    assert all(g.get("resumed") for g in again.groups if g.get("status") == "done")
    assert all(p.get("changes") for p in again.pairs if p.get("in_graph"))
    # a finished comparison read by a resumed batch says its warnings again
    assert all(p.get("changes_warnings") for p in again.pairs if p.get("in_graph"))
    assert [w for w in again.warnings if "changes: " in w] == [w for w in first.warnings if "changes: " in w]
    assert _normalised(copy / "report.json", copy, out) == _normalised(out / "report.json", out)


def test_dask_local_cluster_gives_identical_results(flights, local_run, tmp_path):
    pytest.importorskip("dask.distributed")
    root, _ = flights
    out, _ = local_run
    with DaskExecutor(workers=2) as ex:
        report = _run(root, tmp_path / "out", ex)
    assert report.executor == "dask (LocalCluster)"
    assert _normalised(tmp_path / "out" / "report.json", tmp_path / "out") == _normalised(out / "report.json", out)
    big = next(g for g in report.groups if len(g["members"]) == 3)["reference"]
    r1 = pycolmap.Reconstruction(str(out / "merged" / big / "sparse"))
    r2 = pycolmap.Reconstruction(str(tmp_path / "out" / "merged" / big / "sparse"))
    xyz1 = np.array([r1.points3D[i].xyz for i in sorted(r1.points3D)])
    xyz2 = np.array([r2.points3D[i].xyz for i in sorted(r2.points3D)])
    assert np.array_equal(xyz1, xyz2)
    assert (tmp_path / "out" / "merged" / big / "landmarks.sosmap").read_bytes() == \
        (out / "merged" / big / "landmarks.sosmap").read_bytes()


def test_merged_group_passes_colmap_38(local_run):
    colmap = shutil.which("colmap")
    if colmap is None:
        pytest.skip("COLMAP command line not installed")
    out, report = local_run
    big = next(g for g in report.groups if len(g["members"]) == 3)
    res = subprocess.run([colmap, "model_analyzer", "--path", str(out / "merged" / big["reference"] / "sparse")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and f"Points: {big['points3D']}" in res.stdout


def test_graph_helpers():
    t = yaw_transform(90, (1, 0, 0))
    edges = [Edge(0, 1, t, 10), Edge(1, 2, t, 3), Edge(0, 2, t.compose(t), 1), Edge(3, 4, t, 5)]
    assert connected_groups(6, edges) == [[0, 1, 2], [3, 4], [5]]
    ref, ref_from, tree = spanning_transforms([0, 1, 2], edges)
    assert ref == 1 and len(tree) == 2 and Edge(0, 2, t.compose(t), 1) not in tree  # heaviest edges kept
    x = np.array([[3.0, -2.0, 1.0]])
    assert np.allclose(ref_from[1].apply(x), x)
    assert np.allclose(ref_from[0].apply(x), t.inverse().apply(x))  # 1_from_0 = (0_from_1)^-1
    assert np.allclose(ref_from[2].apply(x), t.apply(x))  # 1_from_2
    centres = np.array([[0, 0, 0], [1, 0, 0], [10, 0, 0], [11, 0, 0]], float)
    assert nearest_pairs(centres, 1) == [(0, 1), (2, 3)]
    assert len(nearest_pairs(centres, 3)) == 6


def test_cli_batch_with_the_real_association_search(tmp_path):
    """`sosmatch batch` end to end on three toy flights with the real matcher; exit code 0, then resumed."""
    world = make_world(260, seed=11)
    boxes = {"F1": (20, 140, 20, 140), "F2": (90, 220, 90, 220), "F3": (20, 140, 20, 140)}
    frames = {"F1": yaw_transform(0, (0, 0, 0)), "F2": yaw_transform(40, (15, -8, 3)),
              "F3": yaw_transform(-25, (-5, 9, 0))}
    truth = {}
    for k, name in enumerate(boxes):
        truth[name] = write_toy_session(tmp_path / "flights" / name, world, lawnmower(*boxes[name], 60, 40, 10),
                                        frames[name], seed=k).session_from_world
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "flights"), "--out", str(out), "--workers", "0", "--no-progress",
            "--set", "association.window_stride=25"]  # fewer window pairs: a quicker test, same code
    assert main(args) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["ok"] and [p["accepted"] for p in report["pairs"]] == [True, True, True]
    assert [p["chosen_by"] for p in report["pairs"]] == ["every pair"] * 3
    for p in report["pairs"]:  # verified on the full maps by `match`: more support than the window consensus
        doc = json.loads((out / "pairs" / p["pair"] / "match.json").read_text())
        ver = doc["verification"]
        assert doc["answer"] == "verified" == p["answer"]
        assert ver["accepted"] and ver["support"] == p["num_associations"] >= p["match_associations"]
        assert len(ver["associations"]) == ver["support"] and p["match_accepted"]
        t = p["transform"]
        est = Sim3(t["rotation"], t["translation"], t["scale"])
        want = truth[p["a"]].compose(truth[p["b"]].inverse())
        probe = np.array([[80.0, 80.0, 3.0], [150.0, 120.0, 0.0]])
        assert np.abs(est.apply(probe) - want.apply(probe)).max() < 0.5
    (group,) = report["groups"]
    assert sorted(group["members"]) == ["F1", "F2", "F3"] and group["status"] == "done"
    assert main(args) == 0  # resumed: nothing left to do
    again = json.loads((out / "report.json").read_text())
    assert all(p.get("resumed") for p in again["pairs"]) and again["groups"][0].get("resumed")


def test_nearest_pairs_need_one_frame():
    sessions = {n: {"center": [x, 0.0, 50.0], "epsg": 0} for n, x in zip("ABCD", (0.0, 10.0, 100.0, 110.0))}
    assert choose_pairs(list("ABCD"), sessions, None)[0] == [tuple(p) for p in
                                                             ("AB", "AC", "AD", "BC", "BD", "CD")]
    assert choose_pairs(list("ABCD"), sessions, 1)[0] == [("A", "B"), ("C", "D")]
    # report.json's chosen_by names why each pair is matched, not only the pairs added for their capture times
    assert set(pairs_chosen_by(list("ABCD"), sessions, None).values()) == {"every pair"}
    assert pairs_chosen_by(list("ABCD"), sessions, 1) == {
        ("A", "B"): "nearest by camera position (--nearest 1)", ("C", "D"): "nearest by camera position (--nearest 1)"}
    sessions["D"]["epsg"] = 32617  # not one frame: positions say nothing, so every pair is matched
    assert len(choose_pairs(list("ABCD"), sessions, 1)[0]) == 6
    assert all(why.startswith("every pair (--nearest needs") for why in
               pairs_chosen_by(list("ABCD"), sessions, 1).values())


def test_contradicting_pairs_are_left_out_of_the_graph():
    from sosmatch.plugin.multisession import consistent_edges

    frames = [yaw_transform(30 * i, (10 * i, -5 * i, 0)) for i in range(4)]  # session_from_world

    def edge(a, b, w, wrong=False):
        t = frames[a].compose(frames[b].inverse())
        if wrong:  # a wrong accepted pair: B placed 40 m off and turned
            t = yaw_transform(60, (40, 0, 0)).compose(t)
        return Edge(a, b, t, w)

    probes = [np.array([[50.0, 50.0, 0.0], [150.0, 80.0, 0.0]])] * 4
    good = [edge(0, 1, 100), edge(2, 3, 80), edge(0, 2, 6), edge(1, 3, 5)]
    wrong = edge(0, 3, 9, wrong=True)
    kept, dropped, alone = consistent_edges(4, good + [wrong], probes, 5.0)
    assert dropped == [wrong] and len(kept) == 4 and not alone
    ref, ref_from, _ = spanning_transforms([0, 1, 2, 3], kept)
    for i in range(4):  # every session lands where the truth puts it
        want = frames[ref].compose(frames[i].inverse())
        assert np.allclose(ref_from[i].apply(probes[0]), want.apply(probes[0]), atol=1e-6)
    # Only contradicting links between two groups: the groups stay apart.
    kept, dropped, _ = consistent_edges(4, good[:2] + [edge(0, 2, 6, wrong=True), edge(1, 3, 5)], probes, 5.0)
    assert len(dropped) == 2 and connected_groups(4, kept) == [[0, 1], [2, 3]]
    # A single edge between two groups has nothing to contradict it.
    kept, dropped, alone = consistent_edges(3, [edge(0, 1, 10), edge(1, 2, 3)], probes, 5.0)
    assert not dropped and not alone and len(kept) == 2


def test_a_lone_imprecise_edge_joins_nothing_unless_corroborated():
    """nu44: an imprecise answer (its own predicted error beyond its gate: two disjoint tiles of one map, B up to
    58 m off) is no evidence enough to join two groups alone; another agreeing edge, direct or through a path of
    precise ones, corroborates it; a precise lone edge joins as before."""
    from dataclasses import replace

    from sosmatch.plugin.multisession import consistent_edges

    frames = [yaw_transform(30 * i, (10 * i, -5 * i, 0)) for i in range(3)]  # session_from_world

    def edge(a, b, w, imprecise=False):
        return Edge(a, b, frames[a].compose(frames[b].inverse()), w, imprecise)

    probes = [np.array([[50.0, 50.0, 0.0], [150.0, 80.0, 0.0]])] * 3
    lone = edge(0, 1, 9, imprecise=True)
    kept, dropped, alone = consistent_edges(2, [lone], probes, 5.0)
    assert alone == [lone] and not kept and not dropped
    assert connected_groups(2, kept) == [[0], [1]]
    # the same edge precise: joined, as every lone edge before
    kept, dropped, alone = consistent_edges(2, [replace(lone, imprecise=False)], probes, 5.0)
    assert len(kept) == 1 and not dropped and not alone
    # corroborated by a second agreeing edge between the same sessions (a stand-in for another session's path:
    # batch matches each pair once)
    twin = edge(0, 1, 4, imprecise=True)
    kept, dropped, alone = consistent_edges(2, [lone, twin], probes, 5.0)
    assert len(kept) == 2 and not dropped and not alone
    # corroborated through precise edges 0-2 and 2-1, though it is the heaviest edge of all
    kept, dropped, alone = consistent_edges(3, [lone, edge(0, 2, 6), edge(2, 1, 5)], probes, 5.0)
    assert len(kept) == 3 and not dropped and not alone and connected_groups(3, kept) == [[0, 1, 2]]
    # wrong and alone (its pair's other sessions matched nothing): kept apart, not merged 40 m off
    off = replace(lone, a_from_b=yaw_transform(60, (40, 0, 0)).compose(lone.a_from_b))
    kept, dropped, alone = consistent_edges(3, [off, edge(0, 2, 6)], probes, 5.0)
    assert alone == [off] and len(kept) == 1 and connected_groups(3, kept) == [[0, 2], [1]]
    # wrong and contradicted by a precise path: the precise edge decides, the imprecise one is rejected and
    # blocks nothing (rev27: both had been left out, and the sessions kept apart)
    kept, dropped, alone = consistent_edges(3, [off, edge(0, 2, 6), edge(2, 1, 5)], probes, 5.0)
    assert dropped == [off] and not alone and connected_groups(3, kept) == [[0, 1, 2]]
    # set aside while alone, judged again when another edge connects its groups: imprecise 0-1 (heaviest) is
    # alone first; two agreeing imprecise edges then join {1, 2}; imprecise 0-2 meets the set-aside 0-1, they agree
    chain = [lone, edge(1, 2, 8, imprecise=True), edge(1, 2, 3, imprecise=True), edge(0, 2, 1, imprecise=True)]
    kept, dropped, alone = consistent_edges(3, chain, probes, 5.0)
    assert not alone and not dropped and len(kept) == 4 and connected_groups(3, kept) == [[0, 1, 2]]


def test_cli_batch_exit_code_says_a_flight_failed(tmp_path):
    world = make_world(200, seed=3)
    for k, name in enumerate(("F1", "F2")):
        write_toy_session(tmp_path / "flights" / name, world, lawnmower(20, 140, 20, 140, 60, 40, 12),
                          yaw_transform(20 * k, (3 * k, 0, 0)), seed=k)
    bad = tmp_path / "flights" / "F3"
    (bad / "images").mkdir(parents=True)
    (bad / "images" / "a.jpg").write_bytes(b"not an image")
    (bad / "poses.csv").write_text("nonsense\n")
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "flights"), "--out", str(out), "--workers", "0", "--no-progress",
            "--set", "association.window_stride=25"]
    assert main(args) == 1
    report = json.loads((out / "report.json").read_text())
    assert not report["ok"] and report["failures"][0].startswith("session F3")
    assert [(p["pair"], p["status"]) for p in report["pairs"]] == [("F1__F2", "done"), ("F1__F3", "skipped"),
                                                                   ("F2__F3", "skipped")]
    assert report["groups"][0]["status"] == "done"  # the flights that worked were still merged


def test_refine_needs_no_verify(tmp_path, capsys):
    (tmp_path / "flights").mkdir()
    assert main(["batch", str(tmp_path / "flights"), "--out", str(tmp_path / "o"), "--refine"]) == 2
    assert "--refine only applies with --no-verify" in capsys.readouterr().err


def test_a_changed_flight_is_redone_and_a_relative_flights_dir_resumes(flights, tmp_path, monkeypatch):
    """New-user sweep: a mapped flight replaced by another map kept every pair's old match (the state's
    fingerprint named the flight's path, not its contents), and an adopted flight given by a relative path was
    stored relative to the cwd and looked up relative to OUT, so it never resumed."""
    root, _ = flights
    monkeypatch.chdir(tmp_path)
    shutil.copytree(root / "A", tmp_path / "fl" / "A")
    shutil.copytree(root / "B", tmp_path / "fl" / "B")
    first = _run("fl", "out", LocalExecutor(0))
    again = _run("fl", "out", LocalExecutor(0))
    assert all(s.get("resumed") for s in again.sessions) and all(p.get("resumed") for p in again.pairs)
    world = make_world(700, extent_m=720, seed=5)
    shutil.rmtree(tmp_path / "fl" / "B")  # B mapped again, from another flight over the same ground
    write_toy_session(tmp_path / "fl" / "B", world, lawnmower(70, 170, 30, 130, 60, 35, 10),
                      yaw_transform(35, (12, -4, 1)), seed=99)
    third = _run("fl", "out", LocalExecutor(0))
    assert [s.get("resumed", False) for s in third.sessions] == [True, False]
    assert not third.pairs[0].get("resumed", False)
    # the tenth sweep: the group's merged model and the pair's changes, the batch's own products of what changed,
    # are remade (they were refused, "use --overwrite", exit 1)
    assert not third.failures and all(g["status"] != "failed" for g in third.groups)
    from sosmatch.database.landmark_map import landmark_map_fingerprint, read_landmark_map

    match = json.loads((tmp_path / "out" / "pairs" / "A__B" / "match.json").read_text())
    assert match["map_b"]["fingerprint"] == landmark_map_fingerprint(read_landmark_map("fl/B/landmarks.sosmap"))
    assert third.pairs[0]["num_associations"] != first.pairs[0]["num_associations"]


def test_the_most_precise_georeference_anchors_a_group(flights, tmp_path):
    """nu34 D3: a batch of a 1.4 m GPS session (named first) and an RTK one (0.049 m) merged in the GPS one's frame,
    the RTK landmarks 0.56 m off instead of 0.26, nothing said. The measured noise of each georeference (the
    session's poses/poses.json) ranks them; comparable ones (within a factor 2), and all when none is known, are
    ranked by their edges as before."""
    from types import SimpleNamespace

    from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
    from sosmatch.workflows.batch.tasks import _session_summary
    from sosmatch.workflows.merge import precision_note

    t = yaw_transform(10, (1, 0, 0))
    edges = [Edge(0, 1, t, 10), Edge(1, 2, t, 8)]
    assert spanning_transforms([0, 1, 2], edges, {0, 1, 2})[0] == 1  # the strongest
    assert spanning_transforms([0, 1, 2], edges, {0, 1, 2}, {1: 1.4, 2: 0.049})[0] == 2
    assert spanning_transforms([0, 1, 2], edges, {0, 1, 2}, {1: 1.4, 2: 0.9})[0] == 1  # comparable
    assert spanning_transforms([0, 1, 2], edges, {0, 1, 2}, {2: 0.049})[0] == 2  # 1's noise not known
    assert spanning_transforms([0, 1, 2], edges, {0, 1}, {1: 1.4, 2: 0.049})[0] == 1  # 2 not georeferenced
    root, _ = flights
    sessions = {}
    for name, sigma in (("A", 1.4), ("B", 0.049)):
        shutil.copytree(root / name, tmp_path / name)
        lm = read_landmark_map(tmp_path / name / "landmarks.sosmap")
        write_landmark_map(tmp_path / name / "landmarks.sosmap", LandmarkMap(lm.positions, lm.sizes, lm.origin, 32632))
        (tmp_path / name / "poses").mkdir()
        (tmp_path / name / "poses" / "poses.json").write_text(
            json.dumps({"georegistration": {"gps_horizontal_sigma_m": sigma}}))
        assert _session_summary(name, "mapped", tmp_path / name)["georeference_sigma_m"] == sigma
        sessions[name] = SimpleNamespace(path=tmp_path / name, landmarks=SimpleNamespace(epsg=32632))
    note = precision_note(sessions["A"], sessions["B"], "A", "B")
    assert note is not None and "B's georeference is more precise (GPS noise 0.05 m measured) than A's" in note
    assert "keeps A's" in note and precision_note(sessions["B"], sessions["A"], "B", "A") is None
    assert _session_summary("C", "mapped", root / "C")["georeference_sigma_m"] is None


def test_a_group_with_a_georeferenced_session_is_merged_in_its_frame(flights, tmp_path):
    """The reference of a merged group is its best-connected session among the georeferenced ones: with the
    best-connected one (B, local), a group holding a georeferenced flight (C, here EPSG:32632) was merged into a
    local frame and the model lost its georeference (world 131: a DJI-tagged flight and five local ones)."""
    from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
    from sosmatch.workflows.export import run as export

    root, truth = flights
    for name in ("A", "B", "C"):
        shutil.copytree(root / name, tmp_path / "fl" / name)
    c = read_landmark_map(tmp_path / "fl" / "C" / "landmarks.sosmap")
    write_landmark_map(tmp_path / "fl" / "C" / "landmarks.sosmap", LandmarkMap(c.positions, c.sizes, c.origin, 32632))
    with LocalExecutor(1) as ex:
        report = _run(tmp_path / "fl", tmp_path / "out", ex)
    (group,) = report.groups
    assert group["reference"] == "C" and sorted(group["members"]) == ["A", "B", "C"]
    merged = read_landmark_map(tmp_path / "out" / "merged" / "C" / "landmarks.sosmap")
    assert merged.epsg == 32632
    # C's cameras stay where its georeference put them; A's land there through B
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "merged" / "C" / "sparse"))
    c_rec = pycolmap.Reconstruction(str(tmp_path / "fl" / "C" / "sparse"))
    for img in c_rec.images.values():
        assert np.allclose(rec.find_image_with_name(f"C/{img.name}").projection_center(), img.projection_center(),
                           atol=1e-6)
    a_rec = pycolmap.Reconstruction(str(tmp_path / "fl" / "A" / "sparse"))
    c_from_a = truth["C"].compose(truth["A"].inverse())
    img = next(iter(a_rec.images.values()))
    assert np.allclose(rec.find_image_with_name(f"A/{img.name}").projection_center(),
                       c_from_a.apply(img.projection_center()), atol=0.5)
    # the toy's coordinates (a few hundred metres) are no UTM 32N position: lon/lat exports refuse them (nu6), the
    # PLY carries the CRS without converting
    assert export(tmp_path / "out" / "merged" / "C", ply=tmp_path / "m.ply")["epsg"] == 32632


def test_the_report_says_how_far_each_pair_s_transform_moves_b_s_landmarks(flights, local_run):
    """pairs.csv: the median and max of |T(p) - p| over B's landmarks, against the truth; the translation of
    a_from_b is the move of the origin, which B's 35 deg turn about a point ~100 m from the data makes another
    figure entirely."""
    import csv

    from sosmatch.database.landmark_map import read_landmark_map

    root, truth = flights
    out, _ = local_run
    rows = {r["pair"]: r for r in csv.DictReader((out / "pairs.csv").open())}
    assert "shift_m" not in rows["A__B"]
    for key in ("A__B", "B__C"):
        a, b = key.split("__")
        a_from_b = truth[a].compose(truth[b].inverse())
        moved = a_from_b.displacement(read_landmark_map(root / b / "landmarks.sosmap").positions)
        got = float(rows[key]["moved_median_m"]), float(rows[key]["moved_max_m"])
        print(key, got, "median, max m; |t| of a_from_b", np.linalg.norm(a_from_b.translation))
        assert abs(got[0] - np.median(moved)) < 0.3 and abs(got[1] - moved.max()) < 0.5
        assert abs(np.linalg.norm(a_from_b.translation) - got[0]) > 5.0  # the origin's move is not the landmarks'
    assert rows["A__D"]["moved_median_m"] == ""  # no accepted transform: nothing moves


def test_displacement_is_how_far_the_points_move_not_the_origin():
    """A 2.7 deg roll about a point 300 m from the origin (the nu5 sweep's tilted one-line map) translates the
    origin 14 m; the landmarks within 30 m of that point move at most 30 m x 2 sin(1.35 deg) = 1.4 m."""
    angle = np.radians(2.7)
    roll = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    centre = np.array([0.0, 300.0, 0.0])
    t = Sim3(roll, centre - roll @ centre)
    rng = np.random.default_rng(3)
    points = centre + rng.uniform(-20.0, 20.0, (50, 3))
    moved = t.displacement(points)
    assert moved.shape == (50,) and moved.max() <= 2 * 30.0 * np.sin(angle / 2)
    assert np.allclose(moved, np.linalg.norm(t.apply(points) - points, axis=1))
    assert np.linalg.norm(t.translation) > 10.0 * np.median(moved)
    assert np.allclose(Sim3(np.eye(3), [3.0, 4.0, 0.0]).displacement(points), 5.0)


def test_a_setting_of_later_stages_or_a_moved_flights_folder_maps_nothing_again(flights, tmp_path, monkeypatch):
    """Tenth sweep: any `--set` (even `changes.min_confidence`) mapped every flight again (the map stage's
    fingerprint held the whole parameter tree), and so did moving the flights folder (it held the folder's
    path); a verification setting, on the contrary, kept every pair's old match (the pair's fingerprint lacked
    it). A flight's map now depends on its contents and the mapping parameters, a pair on what `match` reads."""
    from sosmatch.plugin.params import Params, with_overrides

    root, _ = flights
    monkeypatch.chdir(tmp_path)
    for name in "AB":
        shutil.copytree(root / name, tmp_path / "fl" / name)

    def run(flights_dir, params, overwrite=True):
        return batch.run(flights_dir, "out", params, executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                         options=batch.BatchOptions(progress=False, overwrite=overwrite))

    first = run("fl", Params(), overwrite=False)
    assert not any(s.get("resumed") for s in first.sessions)
    looser = with_overrides(Params(), {"changes.min_confidence": 0.5})
    again = run("fl", looser)
    assert all(s.get("resumed") for s in again.sessions) and all(p.get("resumed") for p in again.pairs)
    stricter = with_overrides(looser, {"verification.false_alarm": 0.001})
    third = run("fl", stricter)
    assert all(s.get("resumed") for s in third.sessions) and not any(p.get("resumed") for p in third.pairs)
    shutil.move(tmp_path / "fl", tmp_path / "moved")
    # these flights are adopted maps, used where they lie: moved, they are other sessions (a copy left behind could
    # change without the batch noticing), read again there and matched again; a mapped flight resumes its map
    fourth = run("moved", stricter, overwrite=False)
    assert [Path(s["session"]).resolve() for s in fourth.sessions] == [(tmp_path / "moved" / n).resolve()
                                                                        for n in "AB"]
    assert not any(p.get("resumed") for p in fourth.pairs)
    coarser = with_overrides(stricter, {"keyframes.interval_m": 4.0})
    fifth = run("moved", coarser)
    assert not any(s.get("resumed") for s in fifth.sessions)


def test_a_batch_state_of_the_earlier_map_fingerprint_resumes(flights, tmp_path):
    """Outputs made before the map stage's fingerprint changed (it held the folder's path and every parameter)
    resume their maps instead of mapping every flight again."""
    from sosmatch.plugin.params import Params, params_to_dict
    from sosmatch.workflows.batch.discovery import flight_signature
    from sosmatch.workflows.batch.state import STATE_VERSION, fingerprint

    root, _ = flights
    shutil.copytree(root / "A", tmp_path / "fl" / "A")
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False, merge=False, changes=False)
    batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    state = out / "state" / "map" / "A.json"
    data = json.loads(state.read_text())
    path = tmp_path / "fl" / "A"
    data["fingerprint"] = fingerprint({"flight": str(path.resolve()), "kind": "mapped", "ekf": False,
                                       "contents": flight_signature(path), "params": params_to_dict(Params())})
    assert data["version"] == STATE_VERSION
    state.write_text(json.dumps(data))
    again = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    assert again.sessions[0].get("resumed")
    assert json.loads(state.read_text())["fingerprint"] != data["fingerprint"]  # re-saved under today's


def test_outputs_of_a_removed_flight_are_named_and_skipped_changes_are_not_zero(flights, tmp_path, capsys):
    """Tenth sweep: a flight removed since an earlier run left its pairs in OUT without a word, and a run
    without change detection said "0 landmarks gone, 0 new" (as if nothing changed)."""
    root, _ = flights
    for name in "ABC":
        shutil.copytree(root / name, tmp_path / "fl" / name)
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False)
    first = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    assert first.stale_outputs == [] and first.changes_line().startswith("changes summed over 2 pair(s): ")
    assert {p["changes_status"] for p in first.pairs if p.get("in_graph")} == {"done"}
    shutil.rmtree(tmp_path / "fl" / "C")
    again = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    # C's pairs, and the merged model of the old group if its reference changed (the chain's middle, B, was)
    current = {f"merged/{g['reference']}" for g in again.groups}
    assert {"pairs/A__C", "pairs/B__C"} <= set(again.stale_outputs)
    assert all(s.startswith("pairs/") or (s.startswith("merged/") and s not in current) for s in again.stale_outputs)
    assert (out / "pairs" / "B__C" / "match.json").is_file()  # left in place: named, not deleted
    assert json.loads((out / "report.json").read_text())["stale_outputs"] == again.stale_outputs
    assert "pairs/B__C" in (out / "report.md").read_text()
    off = batch.run(tmp_path / "fl", tmp_path / "off", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                    options=batch.BatchOptions(progress=False, changes=False))
    assert off.changes_line().startswith("no changes detected") and "gone" not in off.changes_line()


def test_comparisons_after_the_flights_folder_moved_read_the_images_where_they_are(tmp_path):
    """The session's review: a moved flights folder resumes its maps, whose run.json records the images' old
    place; a comparison run afterwards (a changed changes setting) found none there and went without the surface
    evidence. The batch passes each flight's images as they are now."""
    from sosmatch.plugin.params import Params, with_overrides

    for k in (1, 2):
        assert main(["synth", "-q", "--world-seed", "7", "--session-seed", str(k), "--frames", "30", "--width", "320",
                     "--height", "240", "--out", str(tmp_path / "fl" / f"F{k}")]) == 0
    first = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0),
                      options=batch.BatchOptions(progress=False))
    assert first.pairs[0].get("changes_status") == "done"
    shutil.move(tmp_path / "fl", tmp_path / "moved")
    again = batch.run(tmp_path / "moved", tmp_path / "out", with_overrides(Params(), {"changes.min_confidence": 0.9}),
                      executor=LocalExecutor(0), options=batch.BatchOptions(progress=False, overwrite=True))
    assert all(s.get("resumed") for s in again.sessions) and again.pairs[0].get("resumed")
    changes = json.loads((tmp_path / "out" / "pairs" / "F1__F2" / "changes" / "changes.json").read_text())
    assert [changes["images_a"], changes["images_b"]] == [str(tmp_path / "moved" / f / "images") for f in ("F1", "F2")]


def _georeferenced_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`oracle_pair_task` for maps in one EPSG: match.json records, as `match` does, how far the answer moves B
    from its georeference (`chance.median_horizontal_move` over B's paired landmarks) and the 50 m radius."""
    from sosmatch.database.landmark_map import read_landmark_map
    from sosmatch.database.match_io import read_match
    from sosmatch.plugin.chance import median_horizontal_move
    from sosmatch.workflows.batch import summarise_match

    oracle_pair_task(session_a, session_b, pair_dir, params)
    path = Path(pair_dir) / "match.json"
    m, data = read_match(path), json.loads(path.read_text())
    if m.accepted:
        paired = read_landmark_map(Path(session_b) / "landmarks.sosmap").positions[m.associations[:, 1]]
        data["search_mode"] = {"position_prior": "georeference 50 m: refused there",
                               "georeference_off_m": round(median_horizontal_move(m.transform, paired), 2)}
    data["params"] = {"association": {"georeference_prior_m": 50.0}}
    path.write_text(json.dumps(data))
    return summarise_match(path)


def test_batch_keeps_apart_flights_whose_images_agree_and_georeferences_do_not(flights, tmp_path, monkeypatch,
                                                                               capsys):
    """The twenty-first sweep: two flights of one EPSG whose georeferences are 428 m apart: `match` warned (in its
    worker), batch merged them and said nothing; the twenty-fifth: a flight tagged in Switzerland and its copy
    tagged in Fiji (two EPSG codes, 16,684 km) were merged into one group, the Swiss landmarks placed in Fiji. The
    pair (`match_notes.georeference_note`) is now said in report.json / .md and the output, and left out of the
    session graph: the two flights stay in separate groups, nothing merged. A match.json that records no offset
    (older, or across two codes before) is measured from the sessions' maps."""
    import functools

    from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map

    root, _ = flights
    for name, epsg, fl in (("A", 32632, "fl"), ("B", 32632, "fl"), ("A", 32632, "fl2"), ("B", 32732, "fl2")):
        shutil.copytree(root / name, tmp_path / fl / name)
        lm = read_landmark_map(tmp_path / fl / name / "landmarks.sosmap")
        write_landmark_map(tmp_path / fl / name / "landmarks.sosmap", LandmarkMap(lm.positions, lm.sizes, lm.origin,
                                                                                  epsg))
    runs = (("fl", _georeferenced_pair_task, r"(\d+) m"), ("fl2", oracle_pair_task, r"\d{1,2},\d{3} km"))
    run = batch.run
    for fl, task, distance in runs:
        monkeypatch.setattr(batch, "run", functools.partial(run, pair_fn=task))
        out = tmp_path / f"out_{fl}"
        assert main(["batch", str(tmp_path / fl), "--out", str(out), "--workers", "0", "--no-changes",
                     "--no-progress"]) == 0
        said = re.compile(rf"pair A__B: B: images agree, georeferences disagree by {distance}: one georeference is "
                          "wrong .*left out of the session graph")
        stdout = capsys.readouterr().out
        assert said.search(stdout), stdout
        report = json.loads((out / "report.json").read_text())
        assert len(report["warnings"]) == 1 and said.search(report["warnings"][0]) and report["ok"]
        assert said.search((out / "report.md").read_text())
        (pair,) = report["pairs"]
        assert pair["accepted"] and pair["in_graph"] is False
        assert sorted(g["members"] for g in report["groups"]) == [["A"], ["B"]]
        assert all(g["status"] == "single" for g in report["groups"]) and not (out / "merged").exists()


def turned_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """`oracle_pair_task` whose answer for A__B is an unverified consensus turned 72 degrees about A's landmarks
    (far off, as `match --no-verify`'s consensus of A503 and B10, 680 m off); the other pairs' true."""
    from sosmatch.database.session_io import read_session
    from sosmatch.tools.toy_sessions import load_toy_session, toy_match_json

    a, b = load_toy_session(session_a), load_toy_session(session_b)
    if (Path(session_a).name, Path(session_b).name) != ("A", "B"):
        return oracle_pair_task(session_a, session_b, pair_dir, params)
    truth = a.session_from_world.compose(b.session_from_world.inverse())
    centre = read_session(a.path).landmarks.positions.mean(0)
    turned = Sim3(np.eye(3), centre).compose(yaw_transform(-72, (0, 0, 0))).compose(Sim3(np.eye(3), -centre))
    path = toy_match_json(a, b, Path(pair_dir) / "match.json", transform=turned.compose(truth))
    return batch.summarise_match(path)


def test_a_pair_merge_would_refuse_joins_no_group(flights, tmp_path):
    """merge refuses a transform that does not bring the maps together (`changes.check_alignment`), but batch
    merged through `merge_sessions` directly: with --no-verify a consensus far off was fused into a group. Every
    accepted pair now passes the same control before the session graph; a refused one is reported as refused,
    with the reason, and joins no group; the true pair B__C is merged as before."""
    root, _ = flights
    for name in ("A", "B", "C"):
        shutil.copytree(root / name, tmp_path / "fl" / name)
    report = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), pair_fn=turned_pair_task,
                       options=batch.BatchOptions(progress=False))
    pairs = {p["pair"]: p for p in report.pairs}
    ab = pairs["A__B"]
    assert ab["status"] == "done" and not ab["accepted"] and not ab.get("in_graph") and ab["refused_support"] > 6
    assert "does not bring the maps together" in ab["refused"] and "left out of the session graph" in ab["refused"]
    assert pairs["B__C"]["accepted"] and pairs["B__C"]["in_graph"] and "refused" not in pairs["B__C"]
    groups = {tuple(sorted(g["members"])): g for g in report.groups}
    assert set(groups) == {("A",), ("B", "C")} and groups[("B", "C")]["status"] == "done"
    assert any("A__B refused" in w for w in report.warnings)
    assert "does not bring the maps together" in (tmp_path / "out" / "report.md").read_text()
    assert not (tmp_path / "out" / "pairs" / "A__B" / "changes").exists()


def test_each_pair_s_match_is_read_once_after_the_match_stage(flights, tmp_path, monkeypatch):
    """The stages after matching (the georeference warning, the alignment control, the merge) share one parsed
    match.json per accepted pair (`workflow._read_matches`): each read it again before (3 reads, plus the match
    stage's own summary)."""
    from collections import Counter

    from sosmatch.database import match_io

    root, _ = flights
    for name in ("A", "B", "C"):
        shutil.copytree(root / name, tmp_path / "fl" / name)
    reads, read = Counter(), match_io.read_match

    def counting(path):
        reads[Path(path).parent.name] += 1
        return read(path)

    monkeypatch.setattr(match_io, "read_match", counting)
    report = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                       options=batch.BatchOptions(progress=False))
    accepted = sorted(p["pair"] for p in report.pairs if p["accepted"])
    assert accepted == ["A__B", "B__C"] and report.groups[0]["status"] == "done"
    # one read by the match stage's summary (`summarise_match`), one for every later stage
    assert {key: reads[key] for key in accepted} == {"A__B": 2, "B__C": 2}


def test_batch_maps_flights_of_photos_in_the_crs_it_is_given(tmp_path, monkeypatch):
    """`batch --epsg` (the advice of `match` for one site across a UTM zone edge): a flight of photos is mapped
    with its structure-from-motion poses in that CRS (`PosesFromImages.epsg`); without it, as before."""
    import sosmatch.workflows.map as map_workflow
    from sosmatch.plugin.params import Params
    from sosmatch.workflows.batch.tasks import map_task

    (tmp_path / "F" / "images").mkdir(parents=True)
    seen = []

    def stop(params, inputs, out, **kwargs):
        seen.append(inputs.epsg)
        raise InputError("stop here")

    monkeypatch.setattr(map_workflow, "run", stop)
    for epsg in (32760, None):
        with pytest.raises(InputError, match="stop here"):
            map_task("F", "images", str(tmp_path / "F"), str(tmp_path / "s"), Params(), False, False, epsg)
    assert seen == [32760, None]


def test_a_control_that_breaks_fails_its_pair_and_the_batch_and_a_rerun_redoes_it(tmp_path, monkeypatch, capsys):
    """nu26: the code changed under a running batch, and 14 of 21 pairs were recorded as "refused: its alignment
    control failed: ImportError: cannot import name 'read_user_json'", nothing merged, "ok", exit 0. An exception
    that is no InputError says nothing of the pair: it fails (as a failed match), the batch exits 1, and the
    re-run controls it again (its match resumed). The trigger is that ImportError, in-process: the readers the
    control calls turn every corrupt file tried (truncated or garbage COLMAP binaries, landmark map and table,
    a session without sparse/) into an InputError, so no input reaches it. A far flight's pairs, refused by
    `match`'s verification, say why in report.md in match's words."""
    from sosmatch.workflows import changes

    world = make_world(260, extent_m=600, seed=11)
    boxes = {"F1": (20, 140, 20, 140), "F2": (60, 180, 40, 160), "F3": (440, 560, 440, 560)}
    for k, (name, box) in enumerate(boxes.items()):
        write_toy_session(tmp_path / "flights" / name, world, lawnmower(*box, 60, 40, 12),
                          yaw_transform(20 * k, (3 * k, 0, 0)), seed=k)
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "flights"), "--out", str(out), "--workers", "0", "--no-progress",
            "--set", "association.window_stride=25"]
    monkeypatch.delattr(changes, "check_alignment")  # `from ..changes import check_alignment`: ImportError
    assert main(args) == 1
    stdout = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    pair = {p["pair"]: p for p in report["pairs"]}["F1__F2"]
    assert pair["status"] == "failed" and not pair["accepted"] and "refused" not in pair
    assert pair["error"].startswith("its alignment control failed: ImportError: cannot import name 'check_alignment'")
    assert not report["ok"] and report["failures"] == [f"pair F1__F2: {pair['error']}"]
    assert "FAILED pair F1__F2: its alignment control failed: ImportError" in stdout
    assert not any("F1__F2 refused" in w for w in report["warnings"])  # (what its match warned of is said)
    assert "ImportError" in (out / "logs" / "control-F1__F2.log").read_text()
    md = (out / "report.md").read_text()
    assert "1 failure(s)" in md.splitlines()[2] and re.search(r"\| F1__F2 \| failed \| \d+ \| False \|", md)
    assert all(g["status"] == "single" for g in report["groups"])  # nothing merged on a pair nobody controlled
    for key in ("F1__F3", "F2__F3"):
        refused = {p["pair"]: p for p in report["pairs"]}[key]
        assert refused["status"] == "done" and not refused["accepted"]
        assert refused["refused"].startswith("verification: no match") and refused["refused_by"] == "match"
        assert re.search(rf"\| {key} \| done \| \d+ \| False \|", md) and f"| {refused['refused']} |" in md

    monkeypatch.undo()  # the code is whole again: the re-run redoes the control, not the match
    assert main(args) == 0
    again = {p["pair"]: p for p in json.loads((out / "report.json").read_text())["pairs"]}
    assert again["F1__F2"]["status"] == "done" and again["F1__F2"]["accepted"] and again["F1__F2"]["in_graph"]
    assert all(p.get("resumed") for p in again.values())  # every match kept
    groups = json.loads((out / "report.json").read_text())["groups"]
    assert any(sorted(g["members"]) == ["F1", "F2"] and g["status"] == "done" for g in groups)


def test_the_alignment_control_refuses_a_pair_whose_match_file_is_corrupt(flights, tmp_path):
    """`alignment_task` reading the match itself (no parsed one given): a corrupt match.json is an InputError of
    the pair's inputs, a refusal with its reason (it escaped the task before, and batch now reports any
    exception that escapes as a failed pair)."""
    from sosmatch.plugin.params import Params
    from sosmatch.workflows.batch.tasks import alignment_task

    root, _ = flights
    bad = tmp_path / "match.json"
    bad.write_text('{"format": "sosmatch match v1", "hypotheses": [')
    res = alignment_task(str(root / "A"), str(root / "B"), str(bad), Sim3.identity().to_dict(), Params())
    assert str(bad) in res["refused"]


def test_a_batch_of_a_version_before_the_jpeg_settings_resumes(flights, tmp_path):
    """The batch marker's identity is the batch's own 16-digit fingerprint (state.fingerprint): an earlier version's
    identity (here: before quality/changes.min_jpeg_quality existed, every other setting recorded) must be rebuilt
    with that digest too, else the whole batch is refused after an upgrade (a2d633f). At that version's behaviour:
    tracking.truncation_aware, registered later, was off (on by default since fix76, it changes the maps: at
    today's defaults such a batch is refused, naming the --set that resumes it)."""
    import dataclasses

    from sosmatch.database.output_markers import MARKER
    from sosmatch.plugin.params import ADDED, Params, with_overrides
    from sosmatch.workflows.batch.state import fingerprint

    root, _ = flights
    for name in ("A", "B"):
        shutil.copytree(root / name, tmp_path / "fl" / name)
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False, merge=False, changes=False)
    then = with_overrides(Params(), {"tracking.truncation_aware": False})
    batch.run(tmp_path / "fl", out, then, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    params = dataclasses.asdict(then)
    names = [a.name for a in ADDED]
    for dotted in names[names.index("quality.min_jpeg_quality"):]:  # that version had none of the later ones either
        section, key = dotted.split(".")
        del params[section][key]
    earlier = fingerprint({"params": params, "matcher": oracle_pair_task.__qualname__,
                           **{k: v for k, v in dataclasses.asdict(options).items()
                              if k not in ("progress", "overwrite", "epsg", "transform_chosen")}})
    marker = json.loads((out / MARKER).read_text())
    today = marker["identity"]
    assert earlier != today
    (out / MARKER).write_text(json.dumps({**marker, "identity": earlier}))
    with pytest.raises(InputError, match="--set tracking.truncation_aware=false would accept it"):
        batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    again = batch.run(tmp_path / "fl", out, then, executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                      options=options)
    assert all(s.get("resumed") for s in again.sessions) and again.pairs and all(p.get("resumed") for p in again.pairs)
    assert json.loads((out / MARKER).read_text())["identity"] == today  # re-marked under today's identity


def test_flights_touched_but_unchanged_are_not_mapped_again(flights, tmp_path, caplog):
    """nu37 D3: tar, zip or FAT copies keep mtimes to whole seconds (2 s), `cp` without -p not at all, and every
    flight was mapped again (hours on real flights). A listing that differs only in mtimes is checked by content
    (sha256 recorded when the flight was mapped): the same bytes resume the map and the stages after it; other
    bytes of the same size still map it again."""
    root, _ = flights
    for name in "AB":
        shutil.copytree(root / name, tmp_path / "fl" / name)
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False, merge=False, changes=False)

    def run():
        return batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)

    def touch(offset_s):
        for path in (tmp_path / "fl").rglob("*"):
            if path.is_file():
                t = int(path.stat().st_mtime) + offset_s
                os.utime(path, (t, t))

    run()
    touch(-100)  # whole seconds, as tar or zip restore them
    with caplog.at_level(logging.INFO, logger="sosmatch"):
        again = run()
    assert all(s.get("resumed") for s in again.sessions)
    assert all(p.get("resumed") for p in again.pairs if p["status"] == "done")
    assert "same contents" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="sosmatch"):
        third = run()  # the touched listing is known to hold the same bytes now: not read again
    assert all(s.get("resumed") for s in third.sessions) and "same contents" not in caplog.text
    changed = tmp_path / "fl" / "A" / "poses.csv"
    data = bytearray(changed.read_bytes())
    data[-2] = ord("7") if data[-2] != ord("7") else ord("8")  # another digit: same size, other bytes
    changed.write_bytes(bytes(data))
    touch(-200)
    fourth = run()
    assert {s["name"]: bool(s.get("resumed")) for s in fourth.sessions} == {"A": False, "B": True}


def test_a_flight_whose_images_changed_is_mapped_again_not_failed(tmp_path):
    """nu37 D6: after one image of a flight the batch had mapped was re-exported, the re-run failed that flight
    ("holds a complete `sosmatch map` output made from other inputs ...; use --overwrite") and dropped its pairs,
    against the README's "redoes only what changed". The session folder is the batch's own product (a changed
    setting is refused before any work by the batch's own identity), so it is made again, as merges and
    comparisons are."""
    from PIL import Image

    for k in (1, 2):
        assert main(["synth", "-q", "--world-seed", "7", "--session-seed", str(k), "--frames", "24", "--width", "320",
                     "--height", "240", "--out", str(tmp_path / "fl" / f"F{k}")]) == 0
    # rev58 D1: F2's photos lie elsewhere, its images/ a link to them (the listing did not enter it: F2 resumed)
    (tmp_path / "fl" / "F2" / "images").rename(tmp_path / "photos")
    (tmp_path / "fl" / "F2" / "images").symlink_to(tmp_path / "photos", target_is_directory=True)
    options = batch.BatchOptions(progress=False, merge=False, changes=False)
    first = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), options=options)
    assert not first.failures and all(s["status"] == "done" for s in first.sessions)
    image = sorted((tmp_path / "fl" / "F2" / "images").glob("*.jpg"))[5]
    Image.open(image).point(lambda v: min(255, v + 20)).save(image, quality=90)
    again = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), options=options)
    assert not again.failures, again.failures
    status = {s["name"]: (s["status"], bool(s.get("resumed"))) for s in again.sessions}
    assert status == {"F1": ("done", True), "F2": ("done", False)}
    assert again.pairs and all(p["status"] == "done" and not p.get("resumed") for p in again.pairs)


def test_a_flights_listing_follows_links_and_stops_at_a_loop(tmp_path, caplog):
    """rev58 D1: `flight_signature` did not enter a linked images/ folder, so replacing photos there left the
    listing (and the map's fingerprint) as it was and the batch resumed the old map. A linked file counts with its
    target; a link to a folder it lies in is a loop, left out with a warning, not listed without end."""
    from sosmatch.workflows.batch.discovery import flight_signature

    photos, flight = tmp_path / "photos", tmp_path / "F"
    photos.mkdir()
    flight.mkdir()
    (photos / "a.jpg").write_bytes(b"1" * 10)
    (tmp_path / "poses.csv").write_text("name,x\n")
    (flight / "images").symlink_to(photos, target_is_directory=True)
    (flight / "poses.csv").symlink_to(tmp_path / "poses.csv")
    (flight / "gone.txt").symlink_to(tmp_path / "nothing")  # dangling: not listed, as before
    before = flight_signature(flight)
    assert [e[:2] for e in before] == [("images/a.jpg", 10), ("poses.csv", 7)]
    (photos / "a.jpg").write_bytes(b"2" * 11)  # a photo replaced behind the link
    assert flight_signature(flight) != before
    st = (tmp_path / "poses.csv").stat()
    (tmp_path / "poses.csv").write_text("name,y\n")  # a linked file's content changed
    os.utime(tmp_path / "poses.csv", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert flight_signature(flight)[1][2] == st.st_mtime_ns + 10**9
    (photos / "up").symlink_to(flight, target_is_directory=True)  # F/images/up -> F: a loop
    with caplog.at_level(logging.WARNING):
        looped = flight_signature(flight)
    assert [e[0] for e in looped] == ["images/a.jpg", "poses.csv"]
    assert "a loop" in caplog.text and "images/up" in caplog.text


def test_a_group_keeps_its_reference_as_flights_are_added(flights, tmp_path, caplog):
    """nu40: a sixth flight added to a finished batch of five moved the merged model's reference from f1 to f5 (the
    best-connected session changes with every flight), left merged/f1 behind and guessed at flights removed. The
    reference of the previous run stays while it is in the group; when it cannot, the log says the actual cause."""
    root, _ = flights
    for name in "AB":
        shutil.copytree(root / name, tmp_path / "fl" / name)
    out = tmp_path / "out"
    options = batch.BatchOptions(progress=False, changes=False)
    first = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    assert [g["reference"] for g in first.groups] == ["A"]
    shutil.copytree(root / "C", tmp_path / "fl" / "C")  # C links to B only: B is now the best connected
    again = batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), pair_fn=oracle_pair_task, options=options)
    (group,) = again.groups
    assert group["reference"] == "A" and sorted(group["members"]) == ["A", "B", "C"] and group["status"] == "done"
    assert again.stale_outputs == [] and "reference_note" not in group
    fresh = batch.run(tmp_path / "fl", tmp_path / "fresh", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                      options=options)
    assert [g["reference"] for g in fresh.groups] == ["B"]  # a first run: the best-connected session
    shutil.rmtree(tmp_path / "fl" / "B")  # A and C are no longer linked: merged/B has a cause, said
    caplog.clear()
    with caplog.at_level("WARNING"):
        gone = batch.run(tmp_path / "fl", tmp_path / "fresh", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                         options=options)
    assert "merged/B" in gone.stale_outputs
    assert "merged/B (flight B is no longer in the flights folder)" in caplog.text
    assert "--nearest no longer chooses?" not in caplog.text


def test_spanning_transforms_keeps_an_earlier_reference_while_it_is_eligible():
    from sosmatch.plugin.multisession import Edge, Sim3, spanning_transforms

    one = Sim3.identity()
    edges = [Edge(0, 1, one, 50.0), Edge(1, 2, one, 50.0)]
    assert spanning_transforms([0, 1, 2], edges)[0] == 1  # the strongest
    assert spanning_transforms([0, 1, 2], edges, keep={0})[0] == 0
    assert spanning_transforms([0, 1, 2], edges, keep={0, 2}, preferred={2})[0] == 2  # a georeference first
    assert spanning_transforms([0, 1, 2], edges, keep={0, 2})[0] == 0  # two groups joined: ties by index


def test_nearest_also_matches_each_flight_with_its_neighbours_in_time(monkeypatch):
    """nu40: 6 flights of one site, --nearest 2 chose by camera position only and dropped 2-3, 3-4, 4-5 and 5-6,
    the consecutive surveys. With capture times, each flight's previous and next overlapping flight is matched."""
    from sosmatch.workflows.batch import pairs as pairs_mod

    centres = {"f1": (294.0, 295.2), "f2": (302.3, 290.0), "f3": (288.0, 301.0), "f4": (298.6, 299.7),
               "f5": (288.9, 290.3), "f6": (297.3, 297.7)}  # the sessions' mean camera positions in nu40
    names = list(centres)
    sessions = {n: {"center": [x, y, 100.0], "epsg": 0, "session": n} for n, (x, y) in centres.items()}
    boxes = {n: (0.0, 0.0, 600.0, 600.0) for n in names} | {"far": (2000.0, 0.0, 2600.0, 600.0)}
    monkeypatch.setattr(pairs_mod, "_footprint", boxes.get)
    by_position = choose_pairs(names, sessions, 2)[0]
    assert ("f2", "f3") not in by_position and ("f5", "f6") not in by_position
    times = {n: 86400.0 * k for k, n in enumerate(names)}
    chosen, added = choose_pairs(names, sessions, 2, times)
    assert added == [("f2", "f3"), ("f3", "f4"), ("f4", "f5"), ("f5", "f6")]
    assert sorted(chosen) == sorted(set(by_position) | set(added))
    # a flight of another site flown in between is no one's neighbour, and does not hide f3 from f4
    sessions["far"] = {"center": [2300.0, 300.0, 100.0], "epsg": 0, "session": "far"}
    times["far"] = 2.5 * 86400.0
    assert pairs_mod.time_neighbour_pairs(names + ["far"], times, boxes) == [
        ("f1", "f2"), ("f2", "f3"), ("f3", "f4"), ("f4", "f5"), ("f5", "f6")]
    reasons = pairs_mod.pairs_chosen_by(names, sessions, 2, times)
    assert [p for p, why in reasons.items() if why == "consecutive flights by capture time"] == added
    assert all(reasons[p] == "nearest by camera position (--nearest 2)" for p in by_position)
    assert choose_pairs(names, sessions, 2, {})[1] == []  # no capture times: by position only
    assert choose_pairs(names, sessions, None, times)[1] == []  # every pair anyway


def test_a_flight_s_time_is_its_images_exif_capture_time(tmp_path):
    from PIL import Image

    from sosmatch.database.exif import ImageMetadata
    from sosmatch.database.exif_write import embed_metadata
    from sosmatch.workflows.batch.pairs import read_flight_time

    (tmp_path / "images").mkdir()
    for k, stamp in enumerate(("2026:05:01 10:00:00", "2026:05:01 10:05:00", "2026:05:01 10:10:00")):
        buf = io.BytesIO()
        Image.new("RGB", (8, 8)).save(buf, format="JPEG")
        jpeg = embed_metadata(buf.getvalue(), ImageMetadata("x.jpg", 8, 8, datetime_original=stamp))
        (tmp_path / "images" / f"img_{k}.jpg").write_bytes(jpeg)
    assert read_flight_time(tmp_path / "images").seconds == pytest.approx(1777629900.0)  # 10:05 UTC, the median
    assert read_flight_time(None).seconds is None


def _timed_flight(folder, stamps, offset=None, gps=None):
    """A folder of 8x8 JPEGs written by PIL with these EXIF DateTimeOriginal values (None: no tag), an
    OffsetTimeOriginal and GPS date/time ("YYYY:MM:DD", (h, m, s)) on every image when given."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    folder.mkdir(parents=True)
    for k, stamp in enumerate(stamps):
        exif = Image.Exif()
        sub = exif.get_ifd(0x8769)
        if stamp is not None:
            sub[0x9003] = stamp
        if offset is not None:
            sub[0x9011] = offset
        if gps is not None:
            exif.get_ifd(0x8825).update({0x1D: gps[0], 0x07: tuple(IFDRational(v, 1) for v in gps[1])})
        Image.new("RGB", (8, 8)).save(folder / f"img_{k:02d}.jpg", format="JPEG", exif=exif)
    return folder


def test_a_flight_s_time_is_utc_where_its_images_say_their_zone(tmp_path):
    """nu41: OffsetTimeOriginal was ignored, so a flight of a camera in +09:00 flown at 11:00 UTC was put at 20:00
    and the flights were paired out of order (truth 1-2-3-4; chosen 1-3, 2-4, 3-4). GPS date and time are UTC and
    come first; a camera clock whole hours from them is the camera's zone."""
    from sosmatch.workflows.batch.pairs import read_flight_time

    day = 1777593600.0  # 2026-05-01 00:00 UTC
    plus9 = read_flight_time(_timed_flight(tmp_path / "a", ["2026:05:01 20:00:00"] * 3, offset="+09:00"))
    assert plus9.seconds == pytest.approx(day + 11 * 3600) and plus9.utc
    minus = read_flight_time(_timed_flight(tmp_path / "b", ["2026:05:01 07:30:00"] * 3, offset="-04:30"))
    assert minus.seconds == pytest.approx(day + 12 * 3600)
    gps = read_flight_time(_timed_flight(tmp_path / "c", ["2026:05:01 22:00:00"] * 3, gps=("2026:05:01", (13, 0, 0))))
    assert gps.seconds == pytest.approx(day + 13 * 3600) and gps.utc  # the GPS time, not the camera's clock
    clock = read_flight_time(_timed_flight(tmp_path / "d", ["2026:05:01 10:00:00"] * 3))
    assert clock.seconds == pytest.approx(day + 10 * 3600) and not clock.utc  # no zone said: the camera clock


def test_a_flight_s_time_ignores_reset_clocks_and_a_minority_of_wrong_ones(tmp_path):
    """nu41: a clock reset to 2000-01-01 after the first image dated the flight 2000 (its pair with the flight
    before dropped silently); one image without a time and one at 2000 averaged to a 2013 flight time."""
    from sosmatch.workflows.batch.pairs import read_flight_time

    day2 = 1777680000.0  # 2026-05-02 00:00 UTC
    reset = ["2026:05:02 10:00:00"] + [f"2000:01:01 00:0{k}:00" for k in range(4)]
    assert read_flight_time(_timed_flight(tmp_path / "a", reset)).seconds == pytest.approx(day2 + 10 * 3600)
    mixed = [None, "2026:05:02 10:00:00", "2000:01:01 00:00:05", "2026:05:02 10:01:00", "2026:05:02 10:02:00"]
    assert read_flight_time(_timed_flight(tmp_path / "b", mixed)).seconds == pytest.approx(day2 + 10 * 3600 + 60)
    # a wrong clock far from the flight's own majority is an outlier (median of the rest), not data
    odd = ["2026:05:02 10:00:00"] * 4 + ["2019:07:14 15:00:00"] * 2 + ["2026:05:02 10:04:00"] * 3
    assert read_flight_time(_timed_flight(tmp_path / "c", odd)).seconds == pytest.approx(day2 + 10 * 3600)
    # the dates software writes with dashes (or a "T") are dates too
    dashed = read_flight_time(_timed_flight(tmp_path / "d", ["2026-05-02 10:00:00", "2026-05-02T10:00:00"]))
    assert dashed.seconds == pytest.approx(day2 + 10 * 3600)
    # without a majority, or with only reset clocks, the flight has no time, and says why
    split = read_flight_time(_timed_flight(tmp_path / "e", ["2026:05:02 10:00:00", "2025:01:01 10:00:00"]))
    assert split.seconds is None and "disagree" in split.why
    only_reset = read_flight_time(_timed_flight(tmp_path / "f", ["2000:01:01 00:00:00"] * 3))
    assert only_reset.seconds is None and "2000-01-01" in only_reset.why


def test_a_flight_s_time_reads_up_to_9_images_spread_over_it(tmp_path, monkeypatch):
    from sosmatch.database import exif
    from sosmatch.workflows.batch.pairs import read_flight_time

    read = []
    monkeypatch.setattr(exif, "read_capture_time", lambda p, f=exif.read_capture_time: read.append(p.name) or f(p))
    stamps = ["2000:01:01 00:00:00"] * 20 + ["2026:05:02 10:00:00"] * 21  # the first half's clock was reset
    assert read_flight_time(_timed_flight(tmp_path / "a", stamps)).seconds == pytest.approx(1777716000.0)
    assert read == [f"img_{k:02d}.jpg" for k in (0, 5, 10, 15, 20, 25, 30, 35, 40)]


def test_flights_without_a_usable_time_are_said_in_one_warning(tmp_path, caplog):
    from sosmatch.workflows.batch.pairs import flight_times

    good = _timed_flight(tmp_path / "a", ["2026:05:01 10:00:00"] * 2, offset="+00:00")
    none = _timed_flight(tmp_path / "b", [None, None])
    reset = _timed_flight(tmp_path / "c", ["2000:01:01 00:00:00"] * 2)
    clock = _timed_flight(tmp_path / "d", ["2026:05:03 10:00:00"] * 2)
    with caplog.at_level("WARNING"):
        times = flight_times({"a": good, "b": none, "c": reset, "m": None, "d": clock})
    assert times["a"] is not None and times["b"] is None and times["c"] is None and times["m"] is None
    lines = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(lines) == 2
    assert "b (no image carries a capture time" in lines[0] and "c (its images' clocks were reset" in lines[0]
    assert "m (a mapped session" in lines[0]
    assert "d carry their cameras' clock times without a zone" in lines[1]
    said = []
    flight_times({"a": good, "b": none, "c": reset, "m": None, "d": clock}, said)
    assert said == lines  # for report.json's warnings


def test_flights_without_a_capture_time_are_a_warning_of_the_report(flights, tmp_path):
    """nu54 M2: `batch --nearest` logged "no usable capture time" and report.json said `"warnings": []`, status
    "ok"; README: status is "ok" only without failures and warnings."""
    root, _ = flights
    for name in "AB":
        shutil.copytree(root / name, tmp_path / "fl" / name)
    options = batch.BatchOptions(progress=False, changes=False, nearest=1)
    report = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                       options=options)
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert any(w.startswith("--nearest: no usable capture time for A (") for w in data["warnings"])
    assert data["status"] != "ok" and data["status"] == report.status and "warning(s)" in report.status
    assert "no usable capture time" in (tmp_path / "out" / "report.md").read_text()


def test_a_flight_s_camera_zone_comes_from_its_gps_times(tmp_path):
    """Images with both GPS and camera times whole hours apart give the camera's zone to its images that carry the
    camera time only; a camera clock reset to 2000-01-01 (whole hours from the GPS time too) is no zone."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    from sosmatch.workflows.batch.pairs import read_flight_time

    def flight(folder, stamps):
        folder.mkdir()
        for k, (local, gps) in enumerate(stamps):
            exif = Image.Exif()
            exif.get_ifd(0x8769)[0x9003] = local
            if gps is not None:
                exif.get_ifd(0x8825).update({0x1D: "2026:05:02", 0x07: tuple(IFDRational(v, 1) for v in gps)})
            Image.new("RGB", (8, 8)).save(folder / f"img_{k}.jpg", format="JPEG", exif=exif)
        return folder

    # camera at +02:00 (and 30 s fast); two of three images lost the GPS time: all three UTC, 10:00-10:02
    zoned = flight(tmp_path / "a", [("2026:05:02 12:00:30", (10, 0, 0)), ("2026:05:02 12:01:30", None),
                                    ("2026:05:02 12:02:30", None)])
    ft = read_flight_time(zoned)
    assert ft.utc and ft.seconds == pytest.approx(1777716000.0 + 90.0)
    reset = flight(tmp_path / "b", [("2000:01:01 00:00:00", (10, 0, 0)), ("2026:05:02 12:01:00", None),
                                    ("2026:05:02 12:02:00", None)])
    ft = read_flight_time(reset)  # no zone: the GPS time alone (UTC), the clock-only images left aside
    assert ft.utc and ft.seconds == pytest.approx(1777716000.0)


def test_a_batch_folder_moved_mid_run_stops_it_in_one_line_and_nothing_comes_back(flights, tmp_path):
    """`mv OUT NEW` while the batch runs: one line naming OUT and the new place (exit 2 from the CLI), no folder
    re-created at OUT by a later stage (the pairs, the state), and the same batch on NEW resumes its maps."""
    root, _ = flights
    shutil.copytree(root / "A", tmp_path / "fl" / "A")
    shutil.copytree(root / "B", tmp_path / "fl" / "B")
    out, moved = tmp_path / "out", tmp_path / "moved"

    def move_then_match(*args):
        if out.exists():
            out.rename(moved)
        return oracle_pair_task(*args)

    with pytest.raises(InputError, match=f"^{out}: was moved or deleted while sosmatch batch was writing it "
                                         rf"\(now {moved}\)"):
        batch.run(tmp_path / "fl", out, executor=LocalExecutor(0), options=batch.BatchOptions(progress=False),
                  pair_fn=move_then_match)
    assert not out.exists() and not (moved / ".sosmatch-output.lock").exists()
    again = _run(tmp_path / "fl", moved, LocalExecutor(0))
    assert all(s.get("resumed") for s in again.sessions) and not again.failures


def test_a_reset_clock_is_judged_before_its_zone_moves_it(tmp_path):
    """rev25: the reset test ran on the time shifted to UTC, so 2000-01-01 00:12 at +09:00 (1999-12-31 in UTC)
    was taken for a real time and dated the flight."""
    from sosmatch.workflows.batch.pairs import read_flight_time

    day2 = 1777680000.0  # 2026-05-02 00:00 UTC
    stamps = ["2026:05:02 19:00:00"] + ["2000:01:01 00:12:00"] * 4  # +09:00: 10:00 UTC, then the reset clock
    ft = read_flight_time(_timed_flight(tmp_path / "a", stamps, offset="+09:00"))
    assert ft.seconds == pytest.approx(day2 + 10 * 3600) and ft.utc


def test_an_epsg_that_is_no_projected_crs_is_refused_whatever_the_flights(tmp_path, cli_error):
    """nu45: `batch --epsg 99999` (or 4326) on flights with their own poses ran to the end, exit 0, with only a
    warning that no flight of photos used it; `map --epsg` and `poses --epsg` refuse the same codes."""
    (tmp_path / "F").mkdir()
    for code in ("99999", "4326"):
        err = cli_error("batch", tmp_path / "F", "--out", tmp_path / "O", "--epsg", code)
        assert "--epsg: EPSG" in err
    assert not (tmp_path / "O").exists()


def test_batch_takes_min_confidence_as_changes_does(tmp_path, cli_error, monkeypatch):
    """rev44 D7: batch's warnings advise `--min-confidence`, which batch lacked (only `--set
    changes.min_confidence=`). It has the option now, with the meaning, the check and the parameter of `changes`."""
    from types import SimpleNamespace

    from sosmatch.workflows import batch as batch_workflow

    (tmp_path / "F").mkdir()
    assert "--min-confidence must be between 0 and 1" in cli_error(
        "batch", tmp_path / "F", "--out", tmp_path / "O", "--min-confidence", "2")
    assert not (tmp_path / "O").exists()
    given = {}

    def record(flights_dir, out, params, executor, options):  # what the command hands the workflow
        given["params"] = params
        return SimpleNamespace(sessions=[], pairs=[], groups=[], warnings=[], failures=[], ok=True,
                               changes_line=lambda: "")

    monkeypatch.setattr(batch_workflow, "run", record)
    assert main(["batch", str(tmp_path / "F"), "--out", str(tmp_path / "O"), "--workers", "0",
                 "--min-confidence", "0.3"]) == 0
    assert given["params"].changes.min_confidence == 0.3
