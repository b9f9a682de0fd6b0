"""`sosmatch changes` end to end on toy mapped sessions (B with objects removed and added), its outputs, and bad
input: one-line errors and nothing written."""

import json
import shutil

import numpy as np
import pycolmap
import pytest

from sosmatch.database.changes_io import CHANGE_COLUMNS, read_changes_csv
from sosmatch.database.landmark_map import read_landmark_map, write_landmark_map
from sosmatch.database.outputs import open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.multisession import Sim3
from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import (
    lawnmower,
    load_toy_session,
    make_spaced_world,
    make_world,
    toy_match_json,
    write_toy_session,
    yaw_transform,
)


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    root = tmp_path_factory.mktemp("changes")
    world = make_spaced_world(320, seed=4)
    rng = np.random.default_rng(9)
    present_a = rng.random(320) > 0.08
    present_b = rng.random(320) > 0.08
    path = lawnmower(20, 200, 20, 200, 60, 40, 8)
    a = write_toy_session(root / "A", world, path, Sim3.identity(), seed=1, present=present_a)
    b = write_toy_session(root / "B", world, path + [25.0, 15.0, 0.0], yaw_transform(30, (10, -5, 1)), seed=2,
                          present=present_b)
    other = write_toy_session(root / "C", make_world(320, seed=99), path, Sim3.identity(), seed=3)
    toy_match_json(a, b, root / "AB" / "match.json")
    toy_match_json(a, other, root / "AC" / "match.json")
    return root, world, a, b, present_a, present_b


def run(args, capsys):
    code = main(["changes", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out.strip(), out.err.strip()


def test_changes_end_to_end(toy, tmp_path, capsys):
    root, world, a, b, present_a, present_b = toy
    out = tmp_path / "C"
    # the toy sessions have no images: the segments' probability is the confidence (test_claims_untested_...)
    untested = ["--set", "changes.untested_object_rate=1"]
    code, line, _ = run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out, *untested],
                        capsys)
    assert code == 0 and line.startswith("changes: ") and "\n" not in line and "gone" in line
    rows = read_changes_csv(out / "changes.csv")
    assert (out / "changes.csv").read_text().splitlines()[0] == ",".join(CHANGE_COLUMNS)
    assert np.sum(rows["source"] == "landmark") == len(a.object_ids) + len(b.object_ids)
    assert np.array_equal(rows["index"][(rows["session"] == "A") & (rows["source"] == "landmark")],
                          np.arange(len(a.object_ids)))
    doc = json.loads((out / "changes.json").read_text())
    landmark = rows["source"] == "landmark"
    assert doc["format"] == "sosmatch changes v1"
    assert doc["counts"]["gone"] == int(np.sum(rows["class"][landmark] == "gone"))
    assert doc["counts"]["gone_unmapped"] == int(np.sum(rows["class"][~landmark] == "gone"))
    assert (out / "changes.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / "changes.geojson").exists()  # a local frame
    # truth: every A landmark of a removed object that B's flight covered is gone, present ones are kept
    a_rows = rows[(rows["session"] == "A") & (rows["source"] == "landmark")]
    removed = ~present_b[a.object_ids]
    compared = a_rows["class"] != "unseen"
    assert np.all(a_rows["class"][compared & removed] == "gone") and np.sum(compared & removed) >= 3
    assert np.mean(a_rows["class"][compared & ~removed] == "kept") > 0.95
    b_rows = rows[(rows["session"] == "B") & (rows["source"] == "landmark")]
    added = ~present_a[b.object_ids]
    assert np.all(b_rows["class"][(b_rows["class"] != "unseen") & added] == "new")
    kept = a_rows[a_rows["class"] == "kept"]
    assert np.all(kept["counterpart"] >= 0) and np.all(np.abs(kept["size_change_m"]) < 1.0)
    # the same command again gives the same files
    again = tmp_path / "C2"
    assert run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", again, *untested],
               capsys)[0] == 0
    assert (again / "changes.csv").read_bytes() == (out / "changes.csv").read_bytes()
    # into the same directory: the same output is replaced freely, another needs --overwrite
    assert run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out, *untested],
               capsys)[0] == 0
    other = ["--match", root / "AB" / "match.json", "--out", out, "--min-confidence", "0.5", *untested]
    code, _, err = run([root / "A", root / "B", *other], capsys)
    assert code == 2 and "--overwrite" in err
    assert run([root / "A", root / "B", *other, "--overwrite"], capsys)[0] == 0


def test_the_run_s_warnings_are_kept_in_its_record_and_on_its_plot(toy, tmp_path, capsys):
    """A doubted result is no plain success: what `changes` warned of (here: no images, the segments alone
    decide) stays in changes.json (`warnings`, read back by `read_changes_record`) and in the plot's title; the
    twenty-fourth sweep found "B's images show no relief" only in the log."""
    from sosmatch.database.changes_io import parse_changes_record, read_changes_record
    from sosmatch.workflows.changes import compute, png_title

    root = toy[0]
    out = tmp_path / "C"
    assert run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out], capsys)[0] == 0
    warnings = read_changes_record(out)["warnings"]
    assert any("no surface evidence" in w for w in warnings) and any("no database.db" in w for w in warnings)
    assert json.loads((out / "changes.json").read_text())["warnings"] == warnings
    seen = compute(root / "A", root / "B", root / "AB" / "match.json")
    assert seen.warnings == warnings
    title = png_title(seen.result, seen.warnings)
    assert title.startswith(seen.result.summary()[:20]) and "WARNING: the images of session A" in title
    # a record from before warnings were kept reads as none; a damaged one is named
    doc = json.loads((out / "changes.json").read_text())
    assert parse_changes_record({k: v for k, v in doc.items() if k != "warnings"})["warnings"] == []
    with pytest.raises(InputError, match="warnings must be a list of strings"):
        parse_changes_record({**doc, "warnings": "no relief"})
    with pytest.raises(InputError, match="not a record of `sosmatch changes`"):
        parse_changes_record({**doc, "format": "sosmatch merge v1"})


def test_the_summary_line_is_said_once(toy, tmp_path, capsys, caplog):
    """rev44 D4: the summary went to stderr (INFO) and to stdout (the command's line); `match` says its line once."""
    import logging

    root = toy[0]
    with caplog.at_level(logging.INFO):
        code, line, _ = run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", tmp_path / "C",
                             "--no-plot"], capsys)
    assert code == 0 and line.startswith("changes: ")
    summary = line.removeprefix("changes: ").split(" -> ")[0]
    assert not [r for r in caplog.records if r.levelno >= logging.INFO and summary in r.getMessage()]


def test_min_confidence_one_reports_no_change(toy, tmp_path, capsys):
    root = toy[0]
    out = tmp_path / "C"
    assert run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out, "--min-confidence",
                "1", "--no-plot"], capsys)[0] == 0
    rows = read_changes_csv(out / "changes.csv")
    assert not np.any(np.isin(rows["class"], ["gone", "new"])) and not (out / "changes.png").exists()
    assert run([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", tmp_path / "x",
                "--min-confidence", "2"], capsys)[0] == 2


@pytest.mark.parametrize("epsg", [27700, 32617])
def test_georeferenced_maps_give_geojson(toy, tmp_path, capsys, caplog, epsg):
    """A georeferenced A gives changes.geojson in WGS84; a local frame stamped with a CRS whose area of use lies
    far from its coordinates (UTM 17N: x 166-834 km) gives none, with a warning, as `export` refuses it."""
    root = toy[0]
    geo = tmp_path / "A"
    shutil.copytree(root / "A", geo)
    lmap = read_landmark_map(geo / "landmarks.sosmap")
    write_landmark_map(geo / "landmarks.sosmap", type(lmap)(lmap.positions, lmap.sizes, lmap.origin, epsg))
    out = tmp_path / "C"
    # the map changed (its georeference): the old match no longer names it, a new one does
    _refused([geo, root / "B", "--match", root / "AB" / "match.json", "--out", out], capsys, out, "other maps")
    match = toy_match_json(load_toy_session(geo), toy[3], tmp_path / "match.json")
    code, _, _ = run([geo, root / "B", "--match", match, "--out", out], capsys)
    rows = read_changes_csv(out / "changes.csv")
    assert code == 0 and len(rows)
    if epsg == 32617:
        assert not (out / "changes.geojson").exists() and "no changes.geojson" in caplog.text
        assert "EPSG:32617" in caplog.text
        assert json.loads((out / "changes.json").read_text())["epsg"] == 0
        return
    fc = json.loads((out / "changes.geojson").read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == len(rows)
    props = fc["features"][0]["properties"]
    assert props["class"] in ("kept", "gone", "new", "unseen") and props["session"] == "A"
    lon, lat, _ = fc["features"][0]["geometry"]["coordinates"]
    assert -7.6 < lon < -7.5 and 49.7 < lat < 49.8  # EPSG:27700 near the origin of its grid, off Cornwall
    # heights are A's z as it is (sea level from EXIF altitudes), said where a GIS reader finds it
    assert "not converted to the WGS84 ellipsoidal height" in fc["properties"]["height_reference"]
    # nu34 D5: RTK receivers often report ellipsoidal heights: no claim that may be wrong
    assert "often the ellipsoidal height for RTK" in fc["properties"]["height_reference"]


def test_a_georeferenced_b_against_a_local_a_says_why_there_is_no_geojson(toy, tmp_path, capsys):
    """rev44 D6: B in a CRS, A in a local frame: the verdicts are placed in A's frame, so no changes.geojson, and
    nothing said why. One warning, recorded, naming the order that gives one."""
    root = toy[0]
    geo = tmp_path / "B"
    shutil.copytree(root / "B", geo)
    lmap = read_landmark_map(geo / "landmarks.sosmap")
    write_landmark_map(geo / "landmarks.sosmap", type(lmap)(lmap.positions, lmap.sizes, lmap.origin, 27700))
    match = toy_match_json(toy[2], load_toy_session(geo), tmp_path / "match.json")
    out = tmp_path / "C"
    code, _, err = run([root / "A", geo, "--match", match, "--out", out, "--no-plot"], capsys)
    assert code == 0, err
    assert not (out / "changes.geojson").exists()
    said = [w for w in json.loads((out / "changes.json").read_text())["warnings"] if "no changes.geojson" in w]
    assert len(said) == 1 and "EPSG:27700" in said[0] and "`sosmatch changes B A`" in said[0]


def _refused(args, capsys, out, needle):
    code, line, err = run(args, capsys)
    assert code == 2 and not line and len(err.splitlines()) == 1 and needle in err, err
    assert not out.exists()


def test_bad_inputs_are_one_line_errors_and_write_nothing(toy, tmp_path, capsys):
    root = toy[0]
    out = tmp_path / "C"
    doc = json.loads((root / "AB" / "match.json").read_text())
    for h in doc["hypotheses"]:
        h["accepted"] = False
    refused = tmp_path / "refused.json"
    refused.write_text(json.dumps(doc))
    _refused([root / "A", root / "B", "--match", refused, "--out", out], capsys, out, "no accepted transform")
    _refused([root / "A", root / "B", "--match", root / "AC" / "match.json", "--out", out], capsys, out,
             "computed for other maps")
    _refused([root / "B", root / "A", "--match", root / "AB" / "match.json", "--out", out], capsys, out,
             f"other order (its map A is {root / 'A'})")  # the session given, not the letter "B"
    # a session whose model holds no keyframe poses
    bare = tmp_path / "bare"
    shutil.copytree(root / "B", bare)
    rec = pycolmap.Reconstruction(str(bare / "sparse"))
    empty = pycolmap.Reconstruction()
    for cam in rec.cameras.values():
        empty.add_camera_with_trivial_rig(cam)
    shutil.rmtree(bare / "sparse")
    (bare / "sparse").mkdir()
    empty.write_binary(str(bare / "sparse"))
    _refused([root / "A", bare, "--match", root / "AB" / "match.json", "--out", out], capsys, out, "no keyframes")
    _refused([root / "A", root / "B", "--match", tmp_path / "missing.json", "--out", out], capsys, out, "missing")
    _refused([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out, "--images-a",
              tmp_path / "no_images"], capsys, out, "images directory not found")
    inside = root / "A" / "changes"
    _refused([root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", inside], capsys, inside,
             "input")


def test_python_api_matches_the_command(toy, tmp_path):
    from sosmatch.workflows import changes

    root = toy[0]
    res = changes.run(root / "A", root / "B", root / "AB" / "match.json", tmp_path / "C", plot=False)
    assert res.result.counts()["gone"] == res.result.a.count("gone")
    with pytest.raises(InputError):
        changes.compute(root / "A", root / "B", root / "AC" / "match.json")
    # a transform that does not bring the maps together (an accepted match of the wrong place) is refused
    wrong = yaw_transform(0, (30.0, 20.0, 0.0)).compose(res.a_from_b)
    with pytest.raises(InputError, match="does not bring the maps together"):
        changes.compute(root / "A", root / "B", None, a_from_b=wrong)
    # even a verified alignment is refused when its counterparts are no more frequent than chance
    with pytest.raises(InputError, match="does not bring the maps together"):
        changes.compute(root / "A", root / "B", None, a_from_b=wrong, verified=True)


def test_without_the_images_a_warning_and_the_segments_alone(toy, caplog):
    import logging

    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows.changes import compute

    root = toy[0]
    args = (root / "A", root / "B", root / "AB" / "match.json")
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        seen = compute(*args)  # the toy maps record no image directory
    assert "no surface evidence" in caplog.text
    plain = compute(*args, with_overrides(Params(), {"changes.surface_evidence": False}))
    for side in ("a", "b"):
        mine, theirs = getattr(seen.result, side), getattr(plain.result, side)
        assert np.array_equal(mine.label, theirs.label) and np.array_equal(mine.confidence, theirs.confidence)
    assert seen.sources["images_a"] == seen.sources["images_b"] == ""


def test_a_session_whose_flight_lowered_theta_n_is_compared_where_it_could_have_mapped_a_landmark(toy, tmp_path,
                                                                                                  capsys):
    """`sosmatch map` lowers theta_n where the flight's views allow fewer (run.json counts.min_observations,
    `params.for_flight`): a session mapped with theta_n 2 made landmarks from 3 views, so A's landmarks its
    keyframes saw 3-5 times are compared (changes.min_views 6 is the default theta_n 5 + 1), the others as before."""
    root = toy[0]
    low = tmp_path / "root"
    shutil.copytree(root, low)
    (low / "B" / "run.json").write_text(json.dumps({"counts": {"min_observations": 2}}))
    tables = []
    for base, out in ((root, tmp_path / "configured"), (low, tmp_path / "lowered")):
        assert run([base / "A", base / "B", "--match", base / "AB" / "match.json", "--out", out], capsys)[0] == 0
        rows = read_changes_csv(out / "changes.csv")
        tables.append(rows[(rows["session"] == "A") & (rows["source"] == "landmark")])
    configured, lowered = tables
    assert np.array_equal(configured["views"], lowered["views"])  # B's keyframes seeing each of A's landmarks
    few = (configured["views"] >= 3) & (configured["views"] < 6)
    print(f"{np.sum(few)} of A's landmarks in 3-5 of B's keyframes; unseen {np.sum(configured['class'] == 'unseen')}"
          f" -> {np.sum(lowered['class'] == 'unseen')}")
    assert np.sum(few) >= 3
    assert np.all(configured["evidence"][few] == "views")
    assert not np.any(lowered["evidence"][few] == "views")
    assert np.all(lowered["evidence"][configured["views"] < 3] == "views")
    assert np.mean(lowered["class"][few] == "unseen") < 0.5


# --- the new-user sweep of `sosmatch changes` with bad or unusual inputs (issue 17, "Bad input") ------------------


def test_the_same_session_twice_or_a_copy_of_it_is_refused(toy, tmp_path, cli_error):
    """`changes A A` (even with a match of A against itself, which `match` accepts) compared a map with itself
    and reported "0 gone, 0 new" as a success; it is a mistake, refused like one."""
    root, _, a, *_ = toy
    self_match = toy_match_json(a, a, tmp_path / "AA" / "match.json")
    out = tmp_path / "C"
    assert "A and B are the same session" in cli_error("changes", root / "A", root / "A", "--match", self_match,
                                                       "--out", out)
    # the same directory spelt otherwise, and a copy of it: the same landmark map
    assert "same session" in cli_error("changes", root / "A", root / "A" / ".", "--match", self_match, "--out", out)
    shutil.copytree(root / "A", tmp_path / "copy")
    err = cli_error("changes", root / "A", tmp_path / "copy", "--match", self_match, "--out", out)
    assert f"{tmp_path / 'copy'}: holds the same landmark map as {root / 'A'}" in err
    # with the match of A and B, the refusal names the real problem (it said "computed for other maps")
    assert "same session" in cli_error("changes", root / "A", root / "A", "--match", root / "AB" / "match.json",
                                       "--out", out)
    assert not out.exists()


def test_a_map_without_landmarks_is_refused_by_name(toy, tmp_path, cli_error):
    """It was refused as "the transform does not bring the maps together: 0% of A's 204 compared landmarks"."""
    from sosmatch.database.landmark_map import landmark_map_fingerprint

    root = toy[0]
    empty = tmp_path / "B"
    shutil.copytree(root / "B", empty)
    lmap = read_landmark_map(empty / "landmarks.sosmap")
    write_landmark_map(empty / "landmarks.sosmap", type(lmap)(np.zeros((0, 3)), np.zeros(0), lmap.origin, lmap.epsg))
    header = (empty / "landmarks.csv").read_text().splitlines()[0]
    (empty / "landmarks.csv").write_text(header + "\n")
    doc = json.loads((root / "AB" / "match.json").read_text())  # a match that names the empty map
    doc["map_b"].update(fingerprint=landmark_map_fingerprint(read_landmark_map(empty / "landmarks.sosmap")),
                        landmarks=0)
    for h in doc["hypotheses"]:
        h["associations"] = []
    (tmp_path / "match.json").write_text(json.dumps(doc))
    out = tmp_path / "C"
    err = cli_error("changes", root / "A", empty, "--match", tmp_path / "match.json", "--out", out)
    assert f"{empty / 'landmarks.sosmap'}: landmark map holds no landmarks" in err
    assert not out.exists()


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_session_whose_cameras_do_not_look_at_the_ground_is_named_as_such(toy, tmp_path, cli_error):
    """B's keyframes turned to look up: the footprints printed numpy's RuntimeWarnings (rays that never go down),
    and the refusal blamed the transform ("0% of A's 0 compared landmarks have a counterpart")."""
    root = toy[0]
    up = tmp_path / "B"
    shutil.copytree(root / "B", up)
    rec = pycolmap.Reconstruction(str(up / "sparse"))
    flip = np.diag([1.0, -1.0, -1.0])
    for image in rec.images.values():
        frame = rec.frames[image.frame_id]
        rot = frame.rig_from_world.rotation.matrix()
        center = -rot.T @ frame.rig_from_world.translation
        frame.rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(flip @ rot), -(flip @ rot) @ center)
    rec.write_binary(str(up / "sparse"))
    out = tmp_path / "C"
    err = cli_error("changes", root / "A", up, "--match", root / "AB" / "match.json", "--out", out)
    assert "none of A's landmarks lies where B's keyframes looked" in err and "do not look at the ground" in err
    assert not out.exists()


def test_damaged_match_files_and_folders_say_what_is_wrong(toy, tmp_path, cli_error, capsys):
    root = toy[0]
    out = tmp_path / "C"
    text = (root / "AB" / "match.json").read_text()
    (tmp_path / "empty.json").write_text("")
    (tmp_path / "half.json").write_text(text[: len(text) // 2])
    (tmp_path / "folder").mkdir()
    for path, needle in ((tmp_path / "empty.json", "match file is empty"),
                         (tmp_path / "half.json", "not valid JSON, truncated"),
                         (tmp_path / "folder", f"{tmp_path / 'folder'}: folder holds no match.json")):
        assert needle in cli_error("changes", root / "A", root / "B", "--match", path, "--out", out)
    assert not out.exists()
    # a folder holding match.json (match's --out, a batch pair) is the match
    assert run([root / "A", root / "B", "--match", root / "AB", "--out", out, "--no-plot"], capsys)[0] == 0


def test_files_and_folders_of_the_wrong_kind_are_named(toy, tmp_path, cli_error):
    """A database.db that is a folder was skipped in silence (the segments left out of the evidence); a file given
    as a session or an images folder was "not found"."""
    root = toy[0]
    out = tmp_path / "C"
    match = root / "AB" / "match.json"
    b = tmp_path / "B"
    shutil.copytree(root / "B", b)
    (b / "database.db").mkdir()
    # one line: the warning that the toy sessions have no images no longer comes before the error
    assert f"{b / 'database.db'}: is a folder" in cli_error("changes", root / "A", b, "--match", match, "--out", out)
    assert f"{match}: is a file, not a session directory" in cli_error("changes", root / "A", match, "--match",
                                                                      match, "--out", out)
    assert f"{match}: is a file, not an images directory" in cli_error(
        "changes", root / "A", root / "B", "--match", match, "--out", out, "--images-a", match)
    assert not out.exists()


def test_a_bad_out_is_refused_before_any_work(toy, tmp_path, cli_error):
    """--out that is a file, a folder of the user's, or under a file was refused only after the whole comparison;
    now first: with a match that would be refused too, the error is about --out."""
    root = toy[0]
    doc = json.loads((root / "AB" / "match.json").read_text())
    for h in doc["hypotheses"]:
        h["accepted"] = False
    refused = tmp_path / "refused.json"
    refused.write_text(json.dumps(doc))
    (tmp_path / "file").write_text("mine")
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "notes.txt").write_text("mine")
    for out, needle in ((tmp_path / "file", "output path exists and is not a directory"),
                        (tmp_path / "folder", "is not a `sosmatch changes` output"),
                        (tmp_path / "file" / "sub", "is a file, not a folder")):
        assert needle in cli_error("changes", root / "A", root / "B", "--match", refused, "--out", out)
    assert (tmp_path / "file").read_text() == "mine" and sorted(p.name for p in (tmp_path / "folder").iterdir()) == [
        "notes.txt"]


def test_a_refused_rewrite_leaves_the_earlier_output_whole(toy, tmp_path, cli_error, capsys):
    """A changes.png that is a folder in the output stopped a re-run only after it had replaced changes.csv, so
    the earlier run's changes.json stood beside the new run's table."""
    root = toy[0]
    out = tmp_path / "C"
    args = [root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out]
    assert run(args, capsys)[0] == 0
    before = {name: (out / name).read_bytes() for name in ("changes.csv", "changes.json")}
    (out / "changes.png").unlink()
    (out / "changes.png").mkdir()
    err = cli_error("changes", *args, "--overwrite", "--min-confidence", "0.3")
    assert f"{out / 'changes.png'}: is a directory where `sosmatch changes` writes a file" in err
    assert {name: (out / name).read_bytes() for name in before} == before


def test_a_session_without_its_database_is_said(toy, caplog):
    """Without database.db a session's segments are no evidence and the confidences fall back to the pair's
    re-observation rate: said, not silent (the toy sessions have none)."""
    import logging

    from sosmatch.workflows.changes import compute

    root = toy[0]
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        compute(root / "A", root / "B", root / "AB" / "match.json")
    # named by their folders first (a batch's pair B--C has B as its "session A")
    assert f"{root / 'A'} (session A of the comparison) has no database.db" in caplog.text
    assert f"{root / 'B'} (session B of the comparison) has no database.db" in caplog.text
    # and what that leaves: at the default --min-confidence no claim rests on a map alone (rev44 D3: unsaid)
    assert "below --min-confidence 0.8: no gone claim comes from it" in caplog.text
    assert "below --min-confidence 0.8: no new claim comes from it" in caplog.text


def test_a_session_record_with_entries_of_other_types_is_no_traceback(toy, tmp_path, capsys):
    """run.json with `counts` that is not an object (a hand edit) ended in AttributeError; such entries say nothing,
    as a record without them."""
    root = toy[0]
    b = tmp_path / "B"
    shutil.copytree(root / "B", b)
    (b / "run.json").write_text(json.dumps({"inputs": ["x"], "keyframe_images": 5, "counts": 3}))
    code, line, err = run([root / "A", b, "--match", root / "AB" / "match.json", "--out", tmp_path / "C"], capsys)
    assert code == 0 and line.startswith("changes: ") and "Traceback" not in err


def test_maps_whose_sizes_are_defined_differently_are_compared_with_a_warning(toy, tmp_path, capsys, caplog):
    """rev44 D2: `match` warns when the maps' run.json record different size-defining settings, `changes` compared
    them without a word, though its size_change_m and its counterparts' size test read the same sizes. The note is
    match's (`size_definition_disagreement`), on stderr and in changes.json; none when the settings agree."""
    root = toy[0]
    said = {}
    for case, b_estimator in (("same", "nadir"), ("other", "mean")):
        sessions = []
        for name, estimator in (("A", "nadir"), ("B", b_estimator)):
            copy = tmp_path / f"{name}_{case}"
            shutil.copytree(root / name, copy)
            (copy / "run.json").write_text(json.dumps({"params": {"triangulation": {"size_estimator": estimator},
                                                                  "segmentation": {"backend": "classical"}}}))
            sessions.append(copy)
        out = tmp_path / f"C_{case}"
        caplog.clear()
        code, _, err = run([*sessions, "--match", root / "AB" / "match.json", "--out", out, "--no-plot"], capsys)
        assert code == 0, err
        said[case] = [w for w in json.loads((out / "changes.json").read_text())["warnings"]
                      if "define landmark sizes differently" in w]
        logged = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert [w for w in logged if "define landmark sizes differently" in w] == said[case]
    assert said["same"] == []
    assert len(said["other"]) == 1 and "'nadir' in A, 'mean' in B" in said["other"][0]
    assert "size_change_m" in said["other"][0]


def test_an_unverified_match_is_said_and_out_may_not_lie_among_the_recorded_images(toy, tmp_path, cli_error, caplog):
    """The seventh new-user sweep: `changes` took a --no-verify match without a word (merge warns), and wrote its
    output into the images folder a session's run.json records, which it reads for the surface heights."""
    import logging

    from sosmatch.database.match_io import read_match
    from sosmatch.workflows.changes import compute

    root = toy[0]
    assert read_match(root / "AB" / "match.json").source != "verified"  # the toy match: a window consensus
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        compute(root / "A", root / "B", root / "AB" / "match.json")
    assert "the match was not verified on the full maps" in caplog.text
    a = tmp_path / "A"
    shutil.copytree(root / "A", a)
    (tmp_path / "photos").mkdir()
    (a / "run.json").write_text(json.dumps({"inputs": {"images": str(tmp_path / "photos")}}))
    err = cli_error("changes", a, root / "B", "--match", root / "AB" / "match.json", "--out",
                    tmp_path / "photos" / "chg")
    assert "photos" in err and "input" in err and not (tmp_path / "photos" / "chg").exists(), err


def test_a_merged_model_is_refused(toy, tmp_path, cli_error):
    """The eleventh sweep: a merged season map compared with a flight claimed 79 objects gone on 7.7 ha at
    confidence 0.98 (6 of them near any object), exit 0: a merged model keeps neither its flights' images nor
    their segments, the evidence of change."""
    from sosmatch.workflows import merge

    root, _, a, b, *_ = toy
    merge.run(a.path, b.path, root / "AB" / "match.json", tmp_path / "M")
    match = toy_match_json(a, b, tmp_path / "MB" / "match.json")
    out = tmp_path / "C"
    err = cli_error("changes", tmp_path / "M", root / "B", "--match", match, "--out", out)
    assert f"{tmp_path / 'M'}: a merged model (`sosmatch merge`'s output)" in err and not out.exists()
    # rev46 D4: one that lost its merge.json is refused alike, without naming the file it does not have
    shutil.copytree(tmp_path / "M", tmp_path / "Mx")
    (tmp_path / "Mx" / "merge.json").unlink()
    err = cli_error("changes", tmp_path / "Mx", root / "B", "--match", match, "--out", out)
    assert f"{tmp_path / 'Mx'}: a merged model (`sosmatch merge`'s output)" in err and "merge.json" not in err, err
    assert not out.exists()


def test_the_alignment_control_runs_at_the_match_s_gate_as_merge_runs_it(toy, tmp_path):
    """`changes` judged the alignment at the configured theta_eps (2 m: counterpart gate 3 m), merge and batch at
    the gate of the match that produced it (match.json's theta_eps, `match_io.answer_gate`): a transform 4 m off,
    the landmark scatter of a match that derived theta_eps 3.5 m from its maps, was merged, and refused by
    `changes` as not bringing the maps together. One answer now. The classification keeps its configured gate; where
    the maps scatter beyond it (1 % of A's compared landmarks with a counterpart there) `changes` says so and what
    to set, instead of claiming every object gone (two NAIP maps: 113 gone, 126 new, 7 + 4 kept, exit 0). A
    transform given without its match's gate is judged at the configured one."""
    from sosmatch.database.match_io import read_match
    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows import changes, merge

    _, _, a, b, *_ = toy
    truth = a.session_from_world.compose(b.session_from_world.inverse())

    def match_off(metres):
        transform = yaw_transform(0, (metres, 0.0, 0.0)).compose(truth)
        path = toy_match_json(a, b, tmp_path / f"AB{metres:g}" / "match.json", transform=transform)
        doc = json.loads(path.read_text())
        doc["params"] = {"association": {"distance_tolerance_m": 3.5}}
        path.write_text(json.dumps(doc))
        assert read_match(path).gate_m == 3.5
        return path, transform

    far, off = match_off(4.0)
    merge.run(a.path, b.path, far, tmp_path / "M")  # merge's control passes at the match's gate
    with pytest.raises(InputError, match=r"scatter beyond the counterpart gate .*distance_tolerance_m=3.5; nothing"):
        changes.compute(a.path, b.path, far)
    with pytest.raises(InputError, match="scatter beyond"):  # batch hands its match's gate with the transform
        changes.compute(a.path, b.path, None, a_from_b=off, answer_gate_m=3.5)
    with pytest.raises(InputError, match="does not bring the maps together"):  # a transform from elsewhere
        changes.compute(a.path, b.path, None, a_from_b=off)
    wide = changes.compute(a.path, b.path, far, with_overrides(Params(), {"association.distance_tolerance_m": 3.5}))
    assert wide.result.tolerance_m == wide.control_gate_m == 5.25
    near, _ = match_off(1.5)  # within both gates: compared at 3 m, its control at the match's 5.25 m
    run = changes.compute(a.path, b.path, near)
    assert run.control_gate_m == 5.25 and run.control.rate > 0.9 and run.result.tolerance_m == 3.0
    with open_output_dir(tmp_path / "out", "changes", "x") as out:
        changes.write_outputs(run, out, Params())
    record = json.loads((tmp_path / "out" / "changes.json").read_text())
    assert record["alignment_control"]["gate_m"] == 5.25 and record["counterpart_gate_m"] == 3.0


@pytest.mark.parametrize("quality", [15, 88])
def test_claims_of_a_heavily_compressed_session_are_said_to_be_doubtful(toy, tmp_path, caplog, quality):
    """B at JPEG quality 15 of a place where nothing changed: 11 claims at confidences up to 0.999, exit 0 and no
    word (the 35th new-user sweep). The session's quality (run.json `quality.images.jpeg`, else its images'
    headers) is named with the claims it puts in doubt; at quality 88 nothing is said."""
    import logging

    from sosmatch.plugin.params import ChangeParams, Params, with_overrides
    from sosmatch.workflows.changes import compute

    root = toy[0]
    b = tmp_path / "B"
    shutil.copytree(root / "B", b)
    jpeg = {"quality": quality, "lowest": quality, "samples": 12, "jpeg": 12}
    (b / "run.json").write_text(json.dumps({"quality": {"images": {"jpeg": jpeg}}}))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        run_ = compute(root / "A", b, root / "AB" / "match.json",
                       with_overrides(Params(), {"changes.untested_object_rate": 1.0}))  # no images: untested
    c = run_.result.counts()
    assert c["gone"] + c["new"] > 0  # the toy pair has removed and added objects
    said = [w for w in run_.warnings if "heavily JPEG-compressed" in w]
    if quality < ChangeParams().min_jpeg_quality:
        assert len(said) == 1 and f"{b} (session B of the comparison)" in said[0] and f"quality {quality}," in said[0]
        assert f"{c['gone'] + c['new']} landmark(s)" in said[0] and said[0] in caplog.text
        assert ("gone A#" in said[0]) == (c["gone"] > 0)
    else:
        assert not said


def test_the_images_are_named_by_their_content_not_their_place(tmp_path):
    """nu37 D1: a project moved whole read its images from another directory, so `changes` refused its own output
    as "made from other inputs"; the identity names them by the keyframe digests the map records. The identity of
    before (the directories' paths) is one of the same output's earlier ones."""
    from sosmatch.database.output_markers import versioned_identity
    from sosmatch.plugin.params import Params
    from sosmatch.workflows.changes import ChangesRun, output_identity

    for s in ("A", "B"):
        (tmp_path / s).mkdir()
        (tmp_path / s / "run.json").write_text(json.dumps({"keyframe_images": {f"{s}1.jpg": "0" * 64}}))

    def identity(place):
        sources = {"session_a": str(tmp_path / "A"), "session_b": str(tmp_path / "B"), "map_a": "sha256:a",
                   "map_b": "sha256:b", "images_a": f"{place}/fa", "images_b": f"{place}/fb"}
        return output_identity(ChangesRun(None, Sim3.identity(), 0, sources), Params(), True)

    here, moved = identity("/project"), identity("/project.moved")
    assert here.today == moved.today
    params = Params()
    by_path = versioned_identity(lambda as_dict: {
        "maps": ["sha256:a", "sha256:b"], "a_from_b": Sim3.identity().to_dict(), "changes": as_dict(params.changes),
        "images": ["/project/fa", "/project/fb"], "eps": params.association.distance_tolerance_m, "plot": True})
    assert by_path.today in here.same_as and by_path.today not in moved.same_as


def test_another_output_is_refused_before_the_comparison(toy, tmp_path, cli_error, capsys, monkeypatch):
    """nu37 D1: the refusal of a complete output of other settings came after the whole comparison (5.6 s); its
    identity depends on the inputs and settings alone, so the directory is checked first."""
    import sosmatch.workflows.changes as changes_module

    root = toy[0]
    out = tmp_path / "C"
    args = [root / "A", root / "B", "--match", root / "AB" / "match.json", "--out", out]
    assert run(args, capsys)[0] == 0
    assert run(args, capsys)[0] == 0  # the same output: resumed

    def no_work(*a, **k):
        raise AssertionError("compared before the output directory was checked")

    monkeypatch.setattr(changes_module, "compute", no_work)
    assert "made from other inputs or settings" in cli_error("changes", *args, "--min-confidence", "0.3")


def test_claims_untested_for_a_standing_object_say_so_in_their_confidence(toy, tmp_path, caplog):
    """Without images nothing tests that an object stood where the segments say one went, and most such claims
    are changes of looks (nu37: 19 of 22 false at confidences up to 0.999 on a pair whose images were gone): the
    confidence is the segments' times `untested_object_rate`, the default --min-confidence then reports none,
    and the warning says how to list the candidates. Batch, which has no --images-a, gives its own advice."""
    import logging

    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows.batch.tasks import changes_task
    from sosmatch.workflows.changes import compute

    root = toy[0]
    args = (root / "A", root / "B", root / "AB" / "match.json")
    rate = Params().changes.untested_object_rate
    assert 0 < rate < 1
    segments_alone = compute(*args, with_overrides(Params(), {"changes.untested_object_rate": 1.0,
                                                              "changes.min_confidence": 0.0}))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        untested = compute(*args, with_overrides(Params(), {"changes.min_confidence": 0.0}))
        default = compute(*args)
    assert f"confidence is P(absent | segments) x {rate:g} (changes.untested_object_rate" in caplog.text
    assert "at --min-confidence 0.8 none is reported; lower it below" in caplog.text
    for side, claim in (("a", "gone"), ("b", "new")):
        full, low = getattr(segments_alone.result, side), getattr(untested.result, side)
        claimed = full.label == claim
        assert claimed.sum() >= 3 and np.array_equal(low.label, full.label)
        assert np.allclose(low.confidence[claimed], rate * full.confidence[claimed])
        assert np.max(low.confidence[claimed]) <= rate
        assert not np.any(getattr(default.result, side).label == claim)  # none reaches 0.8
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.changes"):
        changes_task(str(root / "A"), str(root / "B"), str(tmp_path / "batch_changes"),
                     segments_alone.a_from_b.to_dict(), Params())
    assert "batch reads a mapped session's images in the directory its run.json records" in caplog.text
    assert "--images-a" not in caplog.text
