"""A flight is merged once (rev33): two maps of one flight made with different settings (other landmarks, the
same photos) are refused by merge and left out, said, by batch; two flights whose photos share only their file
names are two flights."""

import hashlib
import json
import logging
import shutil
from pathlib import Path

import pytest

from sosmatch.database.colmap_model import load_reconstruction
from sosmatch.database.landmark_map import landmark_map_fingerprint
from sosmatch.database.output_markers import MARKER
from sosmatch.database.session_io import read_session
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.multisession import Sim3
from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import lawnmower, make_world, oracle_pair_task, toy_match_json, write_toy_session
from sosmatch.workflows import batch, merge, merge_pairs
from sosmatch.workflows.batch.discovery import one_session_per_flight
from sosmatch.workflows.executors import LocalExecutor


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def record_images(session, photos: dict[str, str], folder: str) -> None:
    """run.json as `sosmatch map` records a flight's images: the folder's digest (`fingerprints.images`) and each
    keyframe's contents (`keyframe_images`); `photos`: name -> what the photo shows (its bytes' stand-in)."""
    run = {"format": "sosmatch-map-run", "version": 1, "fingerprints": {"images": _digest(folder)},
           "keyframe_images": {name: _digest(content) for name, content in photos.items()}}
    (session.path / "run.json").write_text(json.dumps(run) + "\n")


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """F1 and F1_again: one flight mapped twice (other landmark noise: other maps; the same photos). F2: another
    flight over the same ground whose photos have the same names (DJI_0001.JPG ...) and other contents. F1_half:
    half of F1's photos in a folder of their own (another folder digest, the same photos)."""
    root = tmp_path_factory.mktemp("flights")
    world = make_world(260, seed=11)
    path = lawnmower(20, 140, 20, 140, 60, 40, 10)
    made = {name: write_toy_session(root / name, world, path, Sim3.identity(), seed=seed)
            for name, seed in (("F1", 1), ("F1_again", 3), ("F2", 5), ("F1_half", 7))}
    names = [f"DJI_{k:04d}.JPG" for k in range(1, 21)]
    record_images(made["F1"], {n: f"flight 1 {n}" for n in names}, "folder of flight 1")
    record_images(made["F1_again"], {n: f"flight 1 {n}" for n in names[::2]}, "folder of flight 1")
    record_images(made["F2"], {n: f"flight 2 {n}" for n in names}, "folder of flight 2")
    record_images(made["F1_half"], {n: f"flight 1 {n}" for n in names[10:]}, "half of flight 1")
    return root, made


def test_two_maps_of_one_flight_are_refused_by_merge_naming_both(flights, tmp_path, capsys):
    """rev33: maps/main/summer and maps/border/summer (one flight, two settings): match accepted 234
    associations, merge wrote 200 images (every photo twice), exit 0: the flight was known by its landmark map."""
    _, made = flights
    f1 = made["F1"]
    for other, why in (("F1_again", "the same images"), ("F1_half", "10 of its images, by content")):
        match = toy_match_json(f1, made[other], tmp_path / other / "match.json")
        with pytest.raises(InputError, match=rf"holds a flight that .*F1 holds already \({why}\)"):
            merge.run(f1.path, made[other].path, match, tmp_path / f"M_{other}")
        assert not (tmp_path / f"M_{other}").exists()
    match = tmp_path / "F1_again" / "match.json"
    code = main(["merge", str(f1.path), str(made["F1_again"].path), "--match", str(match), "--out",
                 str(tmp_path / "M_cli")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "F1_again" in err[0] and "/F1 holds already" in err[0]


def test_flights_whose_photos_share_only_their_names_merge_and_merge_json_records_the_images(flights, tmp_path):
    _, made = flights
    res = merge.run(made["F1"].path, made["F2"].path, toy_match_json(made["F1"], made["F2"], tmp_path / "m.json"),
                    tmp_path / "M")
    assert res.num_fused > 20
    merged = read_session(tmp_path / "M")
    recorded = merge_pairs.session_flights(merged)
    assert [f["images"] for f in recorded] == [_digest("folder of flight 1"), _digest("folder of flight 2")]
    # a merged session holding F1 refuses F1 mapped again, by its images (not its landmark map, which differs)
    with pytest.raises(InputError, match=r"holds a flight that .*M holds already \(the same images\)"):
        merge_pairs.distinct_flights([merged, read_session(made["F1_again"].path)])


def test_batch_leaves_a_second_map_of_a_flight_out_and_says_so(flights, tmp_path):
    """rev33: a batch over a folder holding two maps of one flight merged them (every photo twice) and said "ok".
    It keeps the first by name, leaves the other out of matching and merging, and warns."""
    root, made = flights
    folder = tmp_path / "flights"
    folder.mkdir()
    for name in ("F1", "F1_again"):
        (folder / name).symlink_to(made[name].path)
    with LocalExecutor(1) as ex:
        report = batch.run(folder, tmp_path / "out", executor=ex,
                           options=batch.BatchOptions(progress=False, changes=False), pair_fn=oracle_pair_task)
    assert report.pairs == []
    again = next(s for s in report.sessions if s["name"] == "F1_again")
    assert again["same_flight_as"] == "F1"
    assert any("F1_again: the same flight as F1 (the same images)" in w for w in report.warnings)
    assert report.status != "ok"
    assert all(len(g["members"]) == 1 for g in report.groups)


def test_merge_and_batch_take_their_answers_from_one_walk_of_the_flights(flights):
    """Which session repeats a flight of an earlier one, and why, is one walk (`merge_pairs.walk_flights`): merge
    refuses the first repeat, batch leaves each out and goes on; a repeat's flights are not held."""
    _, made = flights
    order = ["F1", "F2", "F1_again", "F1_half"]
    checks = list(merge_pairs.walk_flights((n, merge_pairs.session_flights(read_session(made[n].path)))
                                           for n in order))
    assert [(c.holder, c.repeat, c.notes) for c in checks] == [
        ("F1", None, []), ("F2", None, []), ("F1_again", ("F1", "the same images"), []),
        ("F1_half", ("F1", "10 of its images, by content"), [])]
    sessions = {n: {"session": str(made[n].path)} for n in order}
    assert one_session_per_flight(order, sessions) == ["F1", "F2"]
    assert [sessions[n].get("same_flight_as") for n in order] == [None, None, "F1", "F1"]
    for name, check in zip(order[2:], checks[2:]):
        assert f"the same flight as F1 ({check.repeat[1]})" in sessions[name]["warnings"][0]
        with pytest.raises(InputError, match=rf"holds a flight that .*F1 holds already \({check.repeat[1]}\)"):
            merge_pairs.distinct_flights([read_session(made[n].path) for n in ("F1", "F2", name)])


def _as_mapped(made, tmp_path, name: str, flight: str, folder: str):
    """A copy of the toy session `name` whose run.json records the photos of its model's images (by their names
    there) as `flight`'s and its image folder as `folder`."""
    copy = tmp_path / name
    shutil.copytree(made[name].path, copy)
    names = [img.name for img in load_reconstruction(copy / "sparse").images.values()]
    record_images(read_session(copy), {n: f"{flight} {n}" for n in names}, folder)
    return read_session(copy)


def _older_merge(made, tmp_path):
    """M: F1 and F2 (as mapped: `_as_mapped`) merged, its merge.json as an older sosmatch wrote it (no `flights`),
    and F1_again as mapped (F1's photos, another landmark map); returns (M, F1_again)."""
    f1 = _as_mapped(made, tmp_path, "F1", "flight 1", "folder of flight 1")
    f2 = _as_mapped(made, tmp_path, "F2", "flight 2", "folder of flight 2")
    again = _as_mapped(made, tmp_path, "F1_again", "flight 1", "folder of flight 1")
    merge.run(f1.path, f2.path, toy_match_json(made["F1"], made["F2"], tmp_path / "m.json"), tmp_path / "M")
    record = json.loads((tmp_path / "M" / "merge.json").read_text())
    del record["flights"]  # as an older sosmatch wrote it
    (tmp_path / "M" / "merge.json").write_text(json.dumps(record))
    return read_session(tmp_path / "M"), again


def test_an_older_merged_session_is_known_by_its_sessions_records_and_else_warned_of_by_image_names(flights,
                                                                                                      tmp_path):
    """rev34: a merge.json of an older sosmatch records the flights' maps only (`flight_maps`, no `flights`):
    F1 mapped again (other landmarks, the same photos) was merged into it with every photo twice, exit 0. Its
    input sessions, found where it names them and still holding the maps merged, say which images it holds; once
    F1 is gone, the names in its model are all that is left: they warn, and never refuse (F2's photos have F1's
    names)."""
    _, made = flights
    merged, again = _older_merge(made, tmp_path)
    with pytest.raises(InputError, match=r"holds a flight that .*M holds already \(the same images\)"):
        merge_pairs.distinct_flights([merged, again])

    (tmp_path / "F1").rename(tmp_path / "F1_moved")
    names = len(load_reconstruction(again.path / "sparse").images)
    other = _as_mapped(made, tmp_path, "F1_half", "flight 3", "folder of flight 3")  # F1's names, other photos
    for session in (again, other):
        held, notes = merge_pairs.distinct_flights([merged, session])
        assert len(held) == 3 and len(notes) == 1
        assert f"hold flights with {names} image names in common" in notes[0] and "records no images" in notes[0]
    # F2, still where M names it, is known by its photos; F1 by its map and its images' names in M's model
    assert [(f["images"], len(f["names"])) for f in held[:2]] == [(_digest("folder of flight 2"), names),
                                                                  (None, names)]


def _no_answer(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """A matcher (`batch.pair_task`'s signature) that finds no answer: match.json of the two maps, refused."""
    refs = {}
    for key, path in (("map_a", session_a), ("map_b", session_b)):
        lmap = read_session(path).landmarks
        refs[key] = {"path": path, "landmarks": len(lmap), "fingerprint": landmark_map_fingerprint(lmap)}
    doc = {"format": "sosmatch match v1", **refs, "transform_kind": "rigid", "best": 0,
           "hypotheses": [{"associations": [], "transform": Sim3.identity().to_dict(), "accepted": False}]}
    (Path(pair_dir) / "match.json").parent.mkdir(parents=True, exist_ok=True)
    (Path(pair_dir) / "match.json").write_text(json.dumps(doc) + "\n")
    return batch.summarise_match(Path(pair_dir) / "match.json")


def test_batch_says_what_merge_says_of_flights_known_by_their_image_names_only(flights, tmp_path, caplog):
    """Two flights sharing image names, one of them known by its names only (an older merged session whose input
    is gone), may be one flight mapped twice: merge says so and merges; batch said nothing (fix91's closing
    note). It keeps both and says the same, in its log and its report, of the later one."""
    _, made = flights
    merged, again = _older_merge(made, tmp_path)
    (tmp_path / "F1").rename(tmp_path / "F1_moved")
    (merged.path / MARKER).unlink()  # an older sosmatch's merge, taken by batch for a mapped session
    folder = tmp_path / "flights"
    folder.mkdir()
    (folder / "M").symlink_to(merged.path)
    (folder / "X").symlink_to(again.path)
    held, said = merge_pairs.distinct_flights([read_session(folder / "M"), read_session(folder / "X")])
    assert len(held) == 3 and len(said) == 1
    with caplog.at_level(logging.WARNING, logger="sosmatch"), LocalExecutor(1) as ex:
        report = batch.run(folder, tmp_path / "out", executor=ex, pair_fn=_no_answer,
                           options=batch.BatchOptions(progress=False, changes=False))
    x = next(s for s in report.sessions if s["name"] == "X")
    assert "same_flight_as" not in x and x["warnings"] == [said[0].replace(str(folder / "X"), "X")
                                                           .replace(str(folder / "M"), "M")]
    assert [p["pair"] for p in report.pairs] == ["M__X"]
    assert f"session X: {x['warnings'][0]}" in report.warnings and report.status != "ok"
    assert any(r.levelno == logging.WARNING and x["warnings"][0] in r.getMessage() for r in caplog.records)
