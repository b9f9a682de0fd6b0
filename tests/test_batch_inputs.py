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
