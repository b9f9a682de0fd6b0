"""What batch is given and how it reads it (rev48): a flight given as the flights folder, the cause of a stale
merged model after --no-merge, the record of a pair's comparison, --nearest on sessions without a shared frame."""

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


def test_after_no_merge_an_earlier_merged_model_is_named_for_what_it_is(tmp_path, caplog):
    """rev48 D3: after --no-merge the earlier run's merged/A was "made by an earlier run, whose reference A was;
    its group is merged as A now": nothing is merged now."""
    from sosmatch.tools.toy_sessions import oracle_pair_task
    from sosmatch.workflows.executors import LocalExecutor

    flights = _toy_flights(tmp_path / "flights", {"A": (20, 140, 20, 140), "B": (60, 180, 40, 160)})
    out = tmp_path / "out"
    first = batch.run(flights, out, executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                      options=batch.BatchOptions(progress=False, changes=False))
    assert [g["status"] for g in first.groups] == ["done"] and (out / "merged" / "A").is_dir()
    with caplog.at_level("WARNING"):
        again = batch.run(flights, out, executor=LocalExecutor(0), pair_fn=oracle_pair_task,
                          options=batch.BatchOptions(progress=False, changes=False, merge=False, overwrite=True))
    assert again.stale_outputs == ["merged/A"] and [g["status"] for g in again.groups] == ["not merged"]
    assert "merged/A (made by an earlier run; --no-merge: this run merges no group)" in caplog.text
    assert "merged as" not in caplog.text
