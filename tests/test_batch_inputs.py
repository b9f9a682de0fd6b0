"""What batch is given and how it reads it (rev48): a flight given as the flights folder, the cause of a stale
merged model after --no-merge, the record of a pair's comparison, --nearest on sessions without a shared frame."""

from pathlib import Path

import pytest

from sosmatch.workflows import batch


def _flight(folder, pose_file=True):
    (folder / "images").mkdir(parents=True)
    (folder / "images" / "frame_00000.jpg").write_bytes(b"")
    if pose_file:
        (folder / "poses.csv").write_text("name,x,y,z\n")
    return folder


@pytest.mark.parametrize("kind", ["poses", "synth", "mapped", "images"])
def test_a_flight_given_as_the_flights_folder_is_refused(tmp_path, cli_error, kind):
    """rev48 D2: `batch flights/a` mapped a's images/ and labels/ as two flights of photos by structure from
    motion, beside the poses a held."""
    flight = _flight(tmp_path / "a", pose_file=kind != "images")
    (flight / "labels").mkdir()
    (flight / "labels" / "frame_00000.png").write_bytes(b"")
    if kind == "synth":
        (flight / "session.json").write_text("{}")
    if kind == "mapped":
        (flight / "sparse").mkdir()
        for name in ("landmarks.sosmap", "landmarks.csv"):
            (flight / name).write_text("")
    err = cli_error("batch", flight, "--out", tmp_path / "out")
    assert f" {flight}: is itself a flight (" in err, err
    assert "give the folder that holds the flights" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("inside", ["out", "f1/out"])
def test_an_output_inside_the_flights_folder_is_refused(tmp_path, cli_error, inside):
    """nu59 D6: `batch F --out F/out` was taken (the README: an output is never inside an input directory), left
    out of its own discovery and skipped, with a warning, by every other batch of F."""
    root = tmp_path / "flights"
    _flight(root / "f1")
    err = cli_error("batch", root, "--out", root / inside)
    assert f"output is inside the input {root}" in err, err
    assert not (root / inside).exists()



def test_a_batch_output_an_earlier_version_took_inside_the_flights_is_told_to_move(tmp_path, cli_error):
    """rev59 D3: a batch output inside FLIGHTS, taken before that was refused, was refused on its re-run with no word
    that moving it keeps its results (its state's paths are relative to it)."""
    from sosmatch.database.outputs import open_output_dir

    root = tmp_path / "flights"
    _flight(root / "f1")
    with open_output_dir(root / "out", "batch", "identity") as out:
        out.finish()
    before = sorted(p.name for p in (root / "out").iterdir())
    err = cli_error("batch", root, "--out", root / "out")
    assert f"output is inside the input {root}" in err and "move the folder out" in err, err
    assert sorted(p.name for p in (root / "out").iterdir()) == before

def test_a_stray_photo_beside_the_flight_folders_does_not_make_the_flights_folder_a_flight(tmp_path):
    root = tmp_path / "flights"
    _flight(root / "f1")
    (root / "overview.jpg").write_bytes(b"")
    assert [(f.name, f.kind) for f in batch.discover_flights(root)] == [("f1", "poses")]


def _toy_flights(root, boxes):
    from sosmatch.tools.toy_sessions import lawnmower, make_world, write_toy_session, yaw_transform

    world = make_world(260, extent_m=400, seed=3)
    for k, (name, box) in enumerate(boxes.items()):
        write_toy_session(root / name, world, lawnmower(*box, 60, 40, 12), yaw_transform(20 * k, (3 * k, 0, 0)),
                          seed=k)
    return root


@pytest.fixture(scope="module")
def toy_batch(tmp_path_factory):
    """Two overlapping toy flights batched (oracle matcher, changes on) from the folder above them, with the
    flights folder and OUT given as relative paths; (that folder, the report)."""
    from sosmatch.tools.toy_sessions import oracle_pair_task
    from sosmatch.workflows.executors import LocalExecutor

    root = tmp_path_factory.mktemp("toy_batch")
    _toy_flights(root / "flights", {"A": (20, 140, 20, 140), "B": (60, 180, 40, 160)})
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        report = batch.run("flights", "out", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                           options=batch.BatchOptions(progress=False))
    assert [g["status"] for g in report.groups] == ["done"] and (root / "out" / "merged" / "A").is_dir()
    return root, report


def test_a_batch_pair_s_comparison_records_its_match_and_absolute_paths(toy_batch):
    """rev48 D4: a batch pair's changes.json said `"match": ""` and held the paths relative to the directory the
    batch was started from; it names the pair's match.json, as `sosmatch changes --match` does, all absolute."""
    import json

    root, report = toy_batch
    pair = next(p for p in report.pairs if p["pair"] == "A__B")
    assert pair["changes_status"] == "done"
    record = json.loads((root / "out" / "pairs" / "A__B" / "changes" / "changes.json").read_text())
    assert record["match"] == str((root / "out" / "pairs" / "A__B" / "match.json").resolve())
    # (toy flights are mapped sessions, used where they lie)
    assert record["session_a"] == str((root / "flights" / "A").resolve())
    assert record["session_b"] == str((root / "flights" / "B").resolve())
    assert all(record[k] == "" or Path(record[k]).is_absolute() for k in ("images_a", "images_b"))


def test_after_no_merge_an_earlier_merged_model_is_named_for_what_it_is(toy_batch, tmp_path, caplog):
    """rev48 D3: after --no-merge the earlier run's merged/A was "made by an earlier run, whose reference A was;
    its group is merged as A now": nothing is merged now."""
    import shutil

    from sosmatch.tools.toy_sessions import oracle_pair_task
    from sosmatch.workflows.executors import LocalExecutor

    root, _ = toy_batch
    shutil.copytree(root / "out", tmp_path / "out")
    with caplog.at_level("WARNING"):
        again = batch.run(root / "flights", tmp_path / "out", executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                          options=batch.BatchOptions(progress=False, merge=False, overwrite=True))
    assert again.stale_outputs == ["merged/A"] and [g["status"] for g in again.groups] == ["not merged"]
    assert "merged/A (made by an earlier run; --no-merge: this run merges no group)" in caplog.text
    assert "merged as" not in caplog.text


def test_nearest_matches_a_session_in_a_local_frame_of_its_own_with_every_other(tmp_path, caplog):
    """rev48 D5: every EPSG-0 session was taken to share one frame, so a flight of photos without GPS (structure
    from motion: its own frame, origin under the flight) was "nearest" to whichever session lay near that origin."""
    from sosmatch.workflows.batch.pairs import CHOSEN_OWN_FRAME, pairs_chosen_by

    sessions = {n: {"kind": "synth", "center": [x, 0.0, 50.0], "epsg": 0, "session": str(tmp_path / n)}
                for n, x in zip("ABCD", (0.0, 10.0, 100.0, 110.0))}
    sessions["S"] = {"kind": "images", "center": [1.0, 0.0, 50.0], "epsg": 0, "session": str(tmp_path / "S")}
    (tmp_path / "M" / "poses").mkdir(parents=True)  # an adopted map of such a flight: its poses' record in it
    (tmp_path / "M" / "poses" / "poses.json").write_text("{}")
    sessions["M"] = {"kind": "mapped", "center": [99.0, 0.0, 50.0], "epsg": 0, "session": str(tmp_path / "M")}
    names = ["A", "B", "C", "D", "M", "S"]
    with caplog.at_level("WARNING"):
        chosen = pairs_chosen_by(names, sessions, 1)
    nearest = "nearest by camera position (--nearest 1)"
    assert {p: why for p, why in chosen.items() if why == nearest} == {("A", "B"): nearest, ("C", "D"): nearest}
    assert [p for p, why in chosen.items() if why == CHOSEN_OWN_FRAME] == [
        ("A", "M"), ("A", "S"), ("B", "M"), ("B", "S"), ("C", "M"), ("C", "S"), ("D", "M"), ("D", "S"), ("M", "S")]
    assert "--nearest: M, S are each in a local frame of its own" in caplog.text
    sessions["S"]["epsg"] = sessions["M"]["epsg"] = 32617  # with GPS: georeferenced, placed (another frame: all)
    assert set(pairs_chosen_by(names, sessions, 1).values()) == {
        "every pair (--nearest needs every session's position in one frame)"}
