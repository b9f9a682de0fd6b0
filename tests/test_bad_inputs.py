"""Bad inputs found by the issue-14 audit: each is the project's one-line error naming the file (exit 2), and
readers refuse exactly what their writers refuse (one validation per format)."""

from __future__ import annotations

import json
import os
import struct
import zlib

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, encode_landmark_map, read_landmark_map, write_landmark_map
from sosmatch.database.match_io import read_match
from sosmatch.database.poses import format_poses_csv, read_poses_csv, write_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Poses
from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import toy_match_json


@pytest.fixture
def toy(toy_sessions):
    return toy_sessions.root, toy_sessions.a, toy_sessions.b, toy_sessions.c


# --- defect 3: a match.json of other sessions ------------------------------------------------------------------


def test_merge_refuses_a_match_of_other_sessions(toy, tmp_path, cli_error):
    root, a, b, c = toy
    ab = toy_match_json(a, b, tmp_path / "ab.json")
    err = cli_error("merge", a.path, c.path, "--match", ab, "--out", tmp_path / "M")
    assert "computed for other maps" in err
    # nu59 D5: it said "map <C> differs", not which side nor what the match had there
    assert f"map B given ({c.path}) is not the match's map B (" in err and str(b.path.name) in err
    same = cli_error("merge", a.path, a.path, "--match", ab, "--out", tmp_path / "M")
    assert f"map B given ({a.path}) is not the match's map B (" in same and "map A given" not in same
    assert "other order" in cli_error("merge", b.path, a.path, "--match", ab, "--out", tmp_path / "M")
    legacy = json.loads(ab.read_text())
    del legacy["map_a"], legacy["map_b"]
    (tmp_path / "old.json").write_text(json.dumps(legacy))
    assert "does not identify its maps" in cli_error("merge", a.path, b.path, "--match",
                                                           tmp_path / "old.json", "--out", tmp_path / "M")
    assert not (tmp_path / "M").exists()


# --- defect 5: match.json that used to crash the readers ----------------------------------------------------------


@pytest.mark.parametrize("edit, fragment", [
    (lambda d: d["hypotheses"][0].update(associations=[[10**40, 1]]), "must be within"),
    (lambda d: d["hypotheses"][0].update(associations=[[1.7, 1]]), "must be an integer, got 1.7"),
    (lambda d: d["hypotheses"][0]["transform"].update(scale=float("inf")), "scale must be a finite number"),
    (lambda d: d["hypotheses"][0].update(accepted="yes"), "accepted must be true or false"),
    (lambda d: d.update(hypotheses={"0": 1}), "hypotheses must be a list"),
    (lambda d: d["hypotheses"][0]["transform"].update(rotation=[[1, 0], [0, 1]]), "rotation must be a 3x3"),
    (lambda d: d.update(best=7), "best must be within"),
    (lambda d: d.update(format="sosmatch match v0"), "this sosmatch reads 'sosmatch match v1'"),
])
def test_damaged_match_json_is_one_line(toy, tmp_path, cli_error, edit, fragment):
    _, a, b, _ = toy
    path = toy_match_json(a, b, tmp_path / "m.json")
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    assert fragment in cli_error("merge", a.path, b.path, "--match", path, "--out", tmp_path / "M")
    assert not (tmp_path / "M").exists()  # an infinite scale no longer leaves half a model


def test_deeply_nested_and_huge_number_json_are_one_line(tmp_path):
    for text in ("[" * 200_000, '{"hypotheses": [' + "9" * 5000 + "]}"):
        (tmp_path / "m.json").write_text(text)
        with pytest.raises(InputError, match="cannot read match file"):
            read_match(tmp_path / "m.json")


# --- defects 5 and 6: pose CSVs --------------------------------------------------------------------------------


POSES = Poses(["a.jpg", "b.jpg"], np.tile(np.eye(3), (2, 1, 1)), np.array([[0.0, 0, 10], [5.0, 0, 10]]))


@pytest.mark.parametrize("edit, fragment", [
    (lambda t: t.replace("a.jpg", '"' + "x" * 140_000 + '"'), "field larger than field limit"),
    (lambda t: t.replace("a.jpg", ""), "empty image name"),
    (lambda t: t.replace("5.0,", "1e300,"), r"beyond 1e\+08 m"),
    (lambda t: t.replace("crs: local", "crs: EPSG:4294967295"), "not an EPSG code"),
    (lambda t: t.replace("crs: local", "crs: EPSG:4326"), "not a projected CRS"),
    (lambda t: "\n".join(t.splitlines()[:4]) + "\n", "holds no poses"),
])
def test_bad_pose_csv_is_refused_naming_it(tmp_path, edit, fragment):
    path = tmp_path / "poses.csv"
    path.write_text(edit(format_poses_csv(POSES)))
    with pytest.raises(InputError, match=fragment) as exc:
        read_poses_csv(path)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)


def test_pose_writer_refuses_what_the_reader_refuses():
    for names, centres in ((["", "b.jpg"], POSES.centers), (POSES.names, POSES.centers * 1e300)):
        with pytest.raises(ValueError):
            format_poses_csv(Poses(names, POSES.rotations, centres))
    with pytest.raises(ValueError, match="projected"):
        format_poses_csv(POSES, 4326)
    odd = Poses(["with, comma.jpg", "b.jpg"], POSES.rotations, POSES.centers)  # quoted by the writer
    assert read_poses_csv_text(format_poses_csv(odd)).names == odd.names


def read_poses_csv_text(text: str) -> Poses:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "p.csv").write_text(text)
        return read_poses_csv(Path(d) / "p.csv")[0]


def test_header_only_pose_csv_blames_the_pose_file(toy, tmp_path, cli_error):
    path = tmp_path / "poses.csv"
    path.write_text("# sosmatch poses v1\nname,x,y,z,qw,qx,qy,qz\n")
    images = tmp_path / "images"
    images.mkdir()
    err = cli_error("map", "--images", images, "--poses", path, "--camera", toy[0] / "none.txt",
                          "--out", tmp_path / "o")
    assert f"{path}: pose file holds no poses" in err


# --- defect 6: .sosmap fields the writer refuses ------------------------------------------------------------------


def _sosmap_with(origin=(0.0, 0.0, 0.0), epsg=0, offset=0.0, size=1.0) -> bytes:
    header = struct.pack("<8sHHI3dII", b"SOSMAP\0\0", 1, 1, 1, *origin, epsg, 0)
    rec = np.array([(offset, 0.0, 0.0, size)], dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("s", "<f2")])
    body = header + rec.tobytes()
    return body + struct.pack("<I", zlib.crc32(body))  # checksum-valid


@pytest.mark.parametrize("fields, fragment", [
    ({"origin": (1.7e308, 0.0, 0.0)}, "origin is beyond"),
    ({"offset": 2.0e6}, r"more than 1e\+06 m from its origin"),
    ({"epsg": 4294967295}, "not an EPSG code"),
    ({"size": 0.0}, "not positive metres"),
])
def test_sosmap_reader_refuses_what_the_writer_refuses(tmp_path, cli_error, fields, fragment):
    path = tmp_path / "m.sosmap"
    path.write_bytes(_sosmap_with(**fields))
    with pytest.raises(InputError, match=fragment):
        read_landmark_map(path)
    lmap = LandmarkMap(np.array([[fields.get("offset", 0.0), 0, 0]]) + np.array(fields.get("origin", (0, 0, 0))),
                       [fields.get("size", 1.0)], fields.get("origin", (0, 0, 0)), fields.get("epsg", 0))
    with pytest.raises(ValueError):
        encode_landmark_map(lmap)
    assert fragment.replace("\\", "") in cli_error("match", path, path, "--out", tmp_path / "o")


# --- defect 9: messages that name the file ---------------------------------------------------------------------


def test_geojson_of_a_map_stamped_with_a_geographic_crs(tmp_path, cli_error):
    path = tmp_path / "m.sosmap"
    write_landmark_map(path, LandmarkMap(np.array([[10.0, 20.0, 1.0]]), [1.0], epsg=4326))
    err = cli_error("export", "--geojson", path, "--out", tmp_path / "l.geojson")
    assert f"{path}: EPSG:4326" in err and "not a projected CRS" in err
    write_landmark_map(path, LandmarkMap(np.array([[10.0, 20.0, 1.0]]), [1.0], epsg=32767))
    assert f"{path}: unknown EPSG code 32767" in cli_error("export", "--geojson", path, "--out",
                                                                 tmp_path / "l.geojson")
    assert not (tmp_path / "l.geojson").exists()
    write_landmark_map(path, LandmarkMap(np.array([[10.0, 20.0, 1.0]]), [1.0], epsg=0))  # a local frame
    assert f"{path}: the landmark map has no geographic reference" in cli_error("export", "--geojson", path,
                                                                                "--out", tmp_path / "l.geojson")
    assert not (tmp_path / "l.geojson").exists()


def test_segment_reports_a_bad_image_once(tmp_path, capsys):
    import cv2

    src = tmp_path / "in"
    src.mkdir()
    cv2.imwrite(str(src / "a.png"), np.full((60, 80, 3), 120, np.uint8))
    (src / "bad.jpg").write_bytes(b"\xff\xd8 broken")
    assert main(["segment", str(src), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("bad.jpg") == 1 and len(err.strip().splitlines()) == 1, err


# --- defect 5: batch inputs -------------------------------------------------------------------------------------


def test_batch_refuses_a_flight_folder_name_that_is_not_utf8(toy, tmp_path, cli_error):
    flights = tmp_path / "flights"
    flights.mkdir()
    os.mkdir(os.fsencode(str(flights)) + b"/\xff\xfe")
    err = cli_error("batch", flights, "--out", tmp_path / "out")
    assert "not valid UTF-8" in err and not (tmp_path / "out").exists()


def test_unreachable_scheduler_is_one_line(tmp_path, cli_error):
    pytest.importorskip("dask.distributed")
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        err = cli_error("batch", tmp_path, "--out", tmp_path / "out", "--scheduler",
                              "tcp://127.0.0.1:9")
    assert "cannot reach the Dask scheduler tcp://127.0.0.1:9" in err


# --- a database.db that is not COLMAP's: refused by name, and never written (pycolmap adds its schema to any file)


@pytest.mark.parametrize("content", [b"", b"\x9f" * 5000, "other sqlite"])
def test_a_database_that_is_not_colmaps_is_refused_and_left_alone(toy, tmp_path, cli_error, content):
    import shutil
    import sqlite3

    _, a, b, _ = toy
    ab = toy_match_json(a, b, tmp_path / "ab.json")
    b2 = tmp_path / "B"
    shutil.copytree(b.path, b2)
    db = b2 / "database.db"
    if content == "other sqlite":
        with sqlite3.connect(db) as con:
            con.execute("CREATE TABLE notes (text)")
    else:
        db.write_bytes(content)
    before = db.read_bytes()
    err = cli_error("changes", a.path, b2, "--match", ab, "--out", tmp_path / "C")
    assert str(db) in err and "not a COLMAP database" in err
    assert db.read_bytes() == before and not (tmp_path / "C").exists()


# --- synth: a NaN or infinite setting passed every range check and failed in the renderer (a traceback) -----------


@pytest.mark.parametrize("flags", [["--gps-sigma", "nan", "--geotags", "exif"], ["--ekf-drift", "inf"],
                                   ["--rotate", "nan"], ["--shift", "nan,0"], ["--yaw-tag-sigma", "inf"]])
def test_synth_refuses_settings_that_are_not_finite(tmp_path, cli_error, flags):
    err = cli_error("synth", "--out", tmp_path / "S", "--frames", "2", *flags)
    assert "must be a finite number" in err
    assert not (tmp_path / "S").exists()


# --- the sixth new-user sweep (nu6) -------------------------------------------------------------------------------


def _disc_flight(root, frames=6):
    from sosmatch.plugin.geometry import Camera
    from sosmatch.tools.toy_sessions import render_disc_flight

    render_disc_flight(root, Camera(160, 120, 120.0, 120.0, 80.0, 60.0), frames=frames)
    return root


def test_a_flight_that_never_moves_a_keyframe_apart_is_one_line_before_any_work(tmp_path, cli_error):
    """Every camera centre within keyframes.interval_m of the first (a hover, one position copied to every row):
    one keyframe. Before: the segmentation ran, then pycolmap's assertion 'Need at least two images for
    triangulation' came out as a traceback (exit 1)."""
    root = _disc_flight(tmp_path / "f")
    poses = read_poses_csv(root / "poses.csv")[0]
    hover = Poses(poses.names, poses.rotations, poses.centers[:1] + 0.1 * np.arange(len(poses.names))[:, None])
    write_poses_csv(root / "hover.csv", hover)
    err = cli_error("map", "--images", root / "images", "--poses", root / "hover.csv", "--camera",
                    root / "cameras.txt", "--out", tmp_path / "M")
    assert f"{root / 'hover.csv'}: the 6 camera centres lie within 0.87 m of the first" in err
    assert not (tmp_path / "M").exists()
    # a keyframe interval longer than the flight is the same: named with its parameter
    err = cli_error("map", "--images", root / "images", "--poses", root / "poses.csv", "--camera",
                    root / "cameras.txt", "--out", tmp_path / "M", "--set", "keyframes.interval_m=50")
    assert "keyframes.interval_m" in err and not (tmp_path / "M").exists()


def test_a_byte_order_mark_is_not_part_of_a_text_input(toy, tmp_path, cli_error):
    """Excel's "CSV UTF-8" and Windows editors start a file with a UTF-8 byte order mark. Before: a valid pose
    table was refused with 'header must be name,x,y,z,... got \\ufeff# sosmatch poses v1', a config TOML with
    'invalid TOML: Invalid statement', a match.json as 'not valid JSON'. Each reads as it does without it."""
    from sosmatch.database.cameras import read_cameras_txt, write_cameras_txt
    from sosmatch.database.config_io import load_params
    from sosmatch.plugin.geometry import Camera

    def with_bom(path):
        bom = path.with_name("bom_" + path.name)
        bom.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
        return bom

    poses = Poses(["a.jpg", "b.jpg"], np.repeat(np.eye(3)[None], 2, 0), np.array([[0.0, 0, 50], [5.0, 0, 50]]))
    (tmp_path / "p.csv").write_text(format_poses_csv(poses))
    back = read_poses_csv(with_bom(tmp_path / "p.csv"))[0]
    assert back.names == poses.names and np.allclose(back.centers, poses.centers)
    write_cameras_txt(tmp_path / "cameras.txt", {1: Camera(160, 120, 100.0, 100.0, 80.0, 60.0)})
    assert read_cameras_txt(with_bom(tmp_path / "cameras.txt")) == read_cameras_txt(tmp_path / "cameras.txt")
    (tmp_path / "c.toml").write_text("[tracking]\nepipolar_margin_px = 8.0\n")
    assert load_params(with_bom(tmp_path / "c.toml")).tracking.epipolar_margin_px == 8.0
    _, a, b, _ = toy
    ab = toy_match_json(a, b, tmp_path / "ab.json")
    assert read_match(with_bom(ab)).associations.tolist() == read_match(ab).associations.tolist()
    # a byte order mark in the middle of a file is still refused like any stray character
    (tmp_path / "mid.csv").write_text(format_poses_csv(poses).replace("a.jpg,", "a.jpg,\ufeff"))
    with pytest.raises(InputError):
        read_poses_csv(tmp_path / "mid.csv")


@pytest.mark.parametrize("edit, fragment", [
    (lambda v: v["associations"].append([v["associations"][0][0], 10**6]), "pairs landmark"),  # A's twice
    (lambda v: v["associations"].append([10**6, v["associations"][0][1]]), "of map B more than once"),
    (lambda v: v.update(associations=[]), "holds 0 pairs but verification.support is"),
])
def test_an_edited_verified_answer_is_refused(toy, tmp_path, cli_error, edit, fragment):
    """match.json's verified associations edited by hand: a landmark paired twice, or the list cut while the
    support stays. Before: merge fused what was left and reported success (0 fused for an emptied list)."""
    _, a, b, _ = toy
    path = toy_match_json(a, b, tmp_path / "m.json")
    doc = json.loads(path.read_text())
    hyp = doc["hypotheses"][0]  # a verified answer as `sosmatch match` writes it
    doc["verification"] = {"accepted": True, "transform": hyp["transform"], "associations": hyp["associations"],
                           "support": len(hyp["associations"]), "runner_up_support": 0}
    path.write_text(json.dumps(doc))
    assert read_match(path).accepted
    edit(doc["verification"])
    path.write_text(json.dumps(doc))
    err = cli_error("merge", a.path, b.path, "--match", path, "--out", tmp_path / "M")
    assert fragment in err and str(path) in err and not (tmp_path / "M").exists()


@pytest.mark.parametrize("workers", ["0", "-3"])
def test_map_refuses_a_worker_count_below_one(tmp_path, cli_error, workers):
    """Before: map took 0 or -3 workers as 1 without a word (match refuses them)."""
    root = _disc_flight(tmp_path / "f", frames=3)
    err = cli_error("map", "--poses", root / "poses.csv", "--images", root / "images", "--out", tmp_path / "M",
                    "--workers", workers)
    assert f"--workers must be >= 1, got {workers}" in err and not (tmp_path / "M").exists()


@pytest.mark.parametrize("flags, fragment", [
    (["--epsg", "4326"], "--epsg: EPSG:4326 (WGS 84) is not a projected CRS"),  # was: ValueError traceback
    (["--epsg", "99999"], "--epsg: EPSG code 99999 is not an EPSG code"),  # was: pyproj CRSError traceback
    (["--mount", "bogus"], "unknown camera mount 'bogus'"),  # was: taken when the images had gimbal tags
    (["--sensor-width-mm", "nan"], "sensor width must be a positive number"),
    (["--position-sigma", "-1"], "position sigma must be a positive number"),
    (["--attitude-sigma", "inf"], "attitude sigma must be a positive number"),
    (["--nominal-height", "nan"], "nominal height must be a positive number"),  # `poses`: scales a block without GPS
])
def test_poses_from_exif_options_are_checked_before_the_images_are_read(tmp_path, cli_error, flags, fragment):
    import cv2

    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "a.jpg"), np.zeros((8, 8, 3), np.uint8))  # no EXIF at all
    if flags[0] == "--nominal-height":
        err = cli_error("poses", tmp_path / "imgs", "--out", tmp_path / "p", *flags)
        assert fragment in err and not (tmp_path / "p").exists()
        return
    err = cli_error("poses-from-exif", tmp_path / "imgs", "--out", tmp_path / "p" / "poses.csv", *flags)
    assert fragment in err and not (tmp_path / "p" / "poses.csv").exists()


def test_a_truncated_colmap_text_model_is_refused_not_read_in_part(toy, tmp_path, cli_error):
    """pycolmap reads a points3D.txt cut inside a line as far as it goes. Before: a text model truncated at 700
    bytes matched as 4 of its 42 landmarks ('no match', exit 0). Now the file must end with a line end and hold
    the records its `# Number of ...` header counts."""
    import pycolmap

    from sosmatch.database.colmap_model import load_reconstruction

    _, a, b, _ = toy
    model = tmp_path / "model"
    model.mkdir()
    pycolmap.Reconstruction(str(a.path / "sparse")).write_text(str(model))
    assert len(load_reconstruction(model).points3D) > 10
    text = (model / "points3D.txt").read_text()
    lines = text.splitlines(keepends=True)
    for cut, fragment in ((text[:len(text) // 2].rstrip("\n")[:-3], "ends inside a line"),
                          ("".join(lines[:len(lines) // 2]), "says it holds")):
        (model / "points3D.txt").write_text(cut)
        err = cli_error("match", model, b.path, "--out", tmp_path / "m")
        assert f"{model / 'points3D.txt'}: file {fragment}" in err and not (tmp_path / "m").exists()
    (model / "points3D.txt").write_text(text)
    images = (model / "images.txt").read_text().splitlines(keepends=True)
    (model / "images.txt").write_text("".join(images[:-2]))  # one image (pose and POINTS2D lines) less
    assert "images.txt: file says it holds" in cli_error("match", model, b.path, "--out", tmp_path / "m")


@pytest.mark.parametrize("argv", [["match", "A", "B", "--out", ""], ["match", "", "B", "--out", "M"],
                                  ["map", "--images", "", "--poses", "p.csv", "--out", "M"],
                                  ["export", "A", "--csv", "--out="], ["config", "check", "--config", " "]])
def test_an_empty_path_argument_is_refused(tmp_path, monkeypatch, capsys, argv):
    """`--out "$OUT"` with OUT unset: before, the empty path was the current folder (match wrote match.json,
    associations.csv and match.png into it; map read it as the image folder). Every command's path arguments; a
    usage error, so argparse's one line and exit 2."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert "empty path (an unset shell variable?)" in err and list(tmp_path.iterdir()) == []


def test_quiet_before_the_command_says_where_it_goes(capsys):
    """nu45: `sosmatch -q config check` said "config: unrecognized arguments: -q", though config has -q: every
    command's -q / -v follow the command's name."""
    with pytest.raises(SystemExit) as stop:
        main(["-q", "config", "check"])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1
    assert "-q goes after the command: sosmatch config -q" in err


@pytest.mark.parametrize("argv", [
    ["export", "{src}", "--csv", "--out", "{tmp}/newdir/"],
    ["check-poses", "--poses", "{src}", "--out", "{tmp}/figures/"],
    ["poses-from-exif", "{src}", "--out", "{tmp}/poses/"],
])
def test_a_file_output_given_as_a_folder_is_refused(tmp_path, capsys, argv):
    """`export --csv --out newdir/` wrote a CSV file named `newdir` (the path's trailing slash was dropped). A
    usage error: argparse's one line and exit 2."""
    with pytest.raises(SystemExit) as stop:
        main([a.format(src=tmp_path / "none", tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert "ends in a separator, a folder: give a file name" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_circles_without_geojson_is_refused(toy, tmp_path, cli_error):
    """nu45: `export --ply --circles` exported points and exit 0: the option was ignored (and recorded, so a
    later `export --ply` of the same map to that file needed --overwrite)."""
    _, a, _, _ = toy
    for fmt in ("--ply", "--csv"):
        err = cli_error("export", a.path, fmt, "--circles", "--out", tmp_path / "x.out")
        assert "--circles draws GeoJSON polygons" in err
    assert list(tmp_path.iterdir()) == []


def test_a_session_whose_run_has_not_finished_is_not_used(toy, tmp_path, cli_error):
    """The eighth new-user sweep killed `map --overwrite` (after editing the camera): the directory kept the old
    complete map beside the unfinished run, and match, changes and export used it as the new one."""
    import json
    import shutil

    root, a, b, _ = toy
    killed = tmp_path / "A"
    shutil.copytree(a.path, killed)
    (killed / ".sosmatch-output.json").write_text(json.dumps(
        {"format": "sosmatch output v1", "command": "map", "identity": "x", "complete": False}))
    for argv in (["export", killed, "--csv", "--out", tmp_path / "a.csv"],
                 ["match", killed, b.path, "--out", tmp_path / "M"]):
        err = cli_error(*argv)
        assert "a `sosmatch map` run into this directory has not finished" in err and str(killed) in err
    assert not (tmp_path / "a.csv").exists() and not (tmp_path / "M").exists()


def test_outputs_of_unfinished_runs_are_refused_wherever_they_are_read(toy, tmp_path, cli_error):
    """The twelfth new-user sweep killed `match --overwrite` (its new associations.csv beside the old match.json,
    which merge and changes then used), killed `merge --overwrite` (its map file, given by name, was matched and
    exported), and a `synth` (map said "pose file is a folder"). Every reader of such an output refuses it in one
    line naming the unfinished command, and nothing is written."""
    import shutil

    root, a, b, _ = toy

    def unfinished(folder, command):
        (folder / ".sosmatch-output.json").write_text(json.dumps(
            {"format": "sosmatch output v1", "command": command, "identity": "x", "complete": False}))

    m = tmp_path / "M"
    m.mkdir()
    ab = toy_match_json(a, b, m / "match.json")
    unfinished(m, "match")
    for argv in (["merge", a.path, b.path, "--match", ab, "--out", tmp_path / "G"],
                 ["changes", a.path, b.path, "--match", m, "--out", tmp_path / "C"]):
        err = cli_error(*argv)
        assert "a `sosmatch match` run into its directory" in err and "has not finished" in err and str(ab) in err
    g = tmp_path / "merged"
    shutil.copytree(a.path, g)
    (g / "run.json").unlink(missing_ok=True)  # a merged model's folder: its map file is read as a bare .sosmap
    unfinished(g, "merge")
    for argv in (["match", g / "landmarks.sosmap", b.path, "--out", tmp_path / "M2"],
                 ["export", g / "landmarks.sosmap", "--csv", "--out", tmp_path / "g.csv"]):
        err = cli_error(*argv)
        assert "a `sosmatch merge` run into its directory" in err and str(g / "landmarks.sosmap") in err
    s = tmp_path / "S"
    (s / ".partial").mkdir(parents=True)
    unfinished(s, "synth")
    err = cli_error("map", "--poses", s, "--out", tmp_path / "mapped")
    assert "a `sosmatch synth` run into this directory has not finished" in err
    assert not any((tmp_path / n).exists() for n in ("G", "C", "M2", "g.csv", "mapped"))
    # a finished session kept in a folder of the user's that holds an unfinished run is its own output: used
    u = tmp_path / "U"
    shutil.copytree(a.path, u / "A")
    (u / "A" / ".sosmatch-output.json").write_text(json.dumps(
        {"format": "sosmatch output v1", "command": "map", "identity": "x", "complete": True}))
    unfinished(u, "batch")
    assert main(["export", str(u / "A" / "landmarks.sosmap"), "--csv", "--out", str(tmp_path / "u.csv"), "-q"]) == 0
    assert main(["export", str(u / "A"), "--csv", "--out", str(tmp_path / "u2.csv"), "-q"]) == 0


def test_map_inputs_name_their_session_and_their_one_camera(tmp_path, cli_error):
    """The eighth new-user sweep: `map --poses S --out S/mapout` wrote into the synth session it read; run.json
    named the pose file as the camera of a synth session; a cameras.txt of two cameras beside the pose file was
    answered with "no camera intrinsics: give --camera"."""
    from sosmatch.workflows.map import load_inputs

    s = tmp_path / "S"
    assert main(["synth", "--out", str(s), "--frames", "4", "--width", "160", "--height", "120", "-q"]) == 0
    err = cli_error("map", "--poses", s, "--out", s / "mapout")
    assert "inside" in err and not (s / "mapout").exists()
    assert load_inputs(None, s).sources["camera"] == str(s / "cameras.txt")
    root = _disc_flight(tmp_path / "f", frames=3)
    line = (root / "cameras.txt").read_text().strip().splitlines()[-1]
    # a second camera of another size (an identical copy is the same camera: test_shared_cameras)
    other = line.split()
    other[0], other[2] = "2", str(int(other[2]) * 2)
    (root / "cameras.txt").write_text(f"{line}\n{' '.join(other)}\n")
    err = cli_error("map", "--images", root / "images", "--poses", root / "poses.csv", "--out", tmp_path / "M")
    assert f"{root / 'cameras.txt'}: holds 2 different cameras" in err and not (tmp_path / "M").exists()


def test_poses_refuses_a_truncated_image_as_map_does(tmp_path, cli_error):
    """The eighth new-user sweep: `sosmatch poses` registered a JPEG cut short (COLMAP's reader decodes what is
    there), and `map` then refused that image; now both say so, before any feature is extracted."""
    import cv2

    rng = np.random.default_rng(0)
    (tmp_path / "imgs").mkdir()
    for k in range(4):
        cv2.imwrite(str(tmp_path / "imgs" / f"f{k}.jpg"), rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    cut = tmp_path / "imgs" / "f2.jpg"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    err = cli_error("poses", tmp_path / "imgs", "--out", tmp_path / "P")
    assert f"{cut}: corrupt or truncated image" in err


def test_two_images_or_poses_of_one_file_name_are_refused_naming_both(tmp_path, cli_error):
    """Two flights' frames in sub-folders (`flight1/f000.jpg`, `flight2/f000.jpg`), with poses from a model or a CSV:
    the map stores each image under its file name, and after the whole segmentation died with `RuntimeError: SQLite
    error: constraint failed` (a traceback, a partial run). The same poses with one flat folder paired both poses
    with one file. Both are refused before any work, naming the two."""
    import shutil

    root = _disc_flight(tmp_path / "f", frames=4)
    poses = read_poses_csv(root / "poses.csv")[0]
    half = [f"flight{1 + k // 2}/{n}" for k, n in enumerate(poses.names[:2] * 2)]  # frame 0, 1 in each flight
    write_poses_csv(root / "two.csv", Poses(half, poses.rotations, poses.centers))
    nested = tmp_path / "nested"
    for k, name in enumerate(half):
        (nested / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(root / "images" / poses.names[k], nested / name)
    args = ("--poses", root / "two.csv", "--camera", root / "cameras.txt", "--out", tmp_path / "M")
    err = cli_error("map", "--images", nested, *args)
    first, second = nested / "flight1" / poses.names[0], nested / "flight2" / poses.names[0]
    assert f"{nested}: images {first} and {second} share the file name {poses.names[0]!r}" in err
    assert not (tmp_path / "M").exists()
    err = cli_error("map", "--images", root / "images", *args)  # flat: both flights' poses pair with one file
    assert (f"{root / 'two.csv'}: poses 'flight1/{poses.names[0]}' and 'flight2/{poses.names[0]}' both pair with "
            f"the image {root / 'images' / poses.names[0]}") in err
    assert not (tmp_path / "M").exists()


@pytest.mark.parametrize("value", ["-1e9", "-1E+9", "-1_000_000.", "-inf"])
def test_a_negative_number_in_any_float_form_reaches_the_options_own_check(tmp_path, cli_error, value):
    """nu45: `--takeoff-altitude -1e3` was "expected one argument": argparse takes a token starting with a minus
    for a value only in its "-1" / "-1.5" forms. Every such value now reaches the option, whose own check judges
    it (here: beyond 100 km, or not finite)."""
    import cv2

    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "a.jpg"), np.zeros((8, 8, 3), np.uint8))
    err = cli_error("poses", tmp_path / "imgs", "--out", tmp_path / "p", "--takeoff-altitude", value)
    assert "take-off altitude must be a finite number of metres" in err and not (tmp_path / "p").exists()


def test_every_numeric_option_takes_a_negative_value_in_any_float_form(capsys):
    """Each float / int option of every command given a negative value in scientific, leading-dot and trailing-dot
    form: the value reaches the option (its type parses it, or says it is not an int), never "expected one
    argument"."""
    from sosmatch.tools.cli import build_parser, join_negative_numbers

    parser = build_parser()
    checked = 0
    for name, command in parser.commands.items():
        for action in command._actions:
            if action.type not in (float, int) or not action.option_strings or action.nargs is not None:
                continue
            values = ("-1e3", "-.5", "-2.", "-3") if action.type is float else ("-3",)
            for value in ("-1e0",) if action.choices else values:  # --pitch-sign / --roll-sign: -1 or 1
                argv = [name, action.option_strings[-1], value]
                try:
                    args, _ = parser.parse_known_args(join_negative_numbers(argv))
                except SystemExit:  # a required positional is missing: the option itself was read
                    err = capsys.readouterr().err
                    assert "expected one argument" not in err and action.option_strings[-1] not in err, (argv, err)
                else:
                    assert getattr(args, action.dest) == action.type(value), argv
                checked += 1
    assert checked > 50
    assert join_negative_numbers(["--a", "-1e3", "--", "-x", "-5"]) == ["--a=-1e3", "--", "-x", "-5"]


def test_a_flag_taking_no_value_leaves_a_negative_looking_positional_alone():
    """`export --csv -1 --out y.csv` (a map folder named -1): --csv takes no value, so -1 stays the positional
    (joined as --csv=-1, argparse refused it: 'ignored explicit argument'); a valued option, also abbreviated, still
    takes its negative number."""
    from sosmatch.tools.cli import _command_takes_value, build_parser, join_negative_numbers

    parser = build_parser()
    for argv, source in ((["export", "--csv", "-1", "--out", "y.csv"], "-1"),
                         (["export", "--csv", "-q", "-1", "--out", "y.csv"], "-1")):
        args = parser.parse_args(join_negative_numbers(argv, _command_takes_value(parser, argv)))
        assert str(args.source) == source and args.out.name == "y.csv", argv
    argv = ["export", "map", "--csv", "--out", "y.csv", "--eps", "-5"]
    args, _ = parser.parse_known_args(join_negative_numbers(argv, _command_takes_value(parser, argv)))
    assert args.epsg == -5
