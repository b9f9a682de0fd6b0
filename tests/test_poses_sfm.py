"""`sosmatch poses`: COLMAP structure from motion on a small geotagged synthetic flight, against exact truth,
and its bad inputs (no GPS, too few images, mixed cameras, damaged metadata). Small images, bounded features."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.exif import read_image_metadata
from sosmatch.database.poses import read_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import rotation_angle_deg
from sosmatch.plugin.params import Params, with_overrides
from sosmatch.tools.cli import main
from sosmatch.workflows import poses as poses_wf
from sosmatch.workflows import sfm as sfm_wf

FAST = {"sfm.max_features": 1500}


def _params() -> Params:
    return with_overrides(Params(), FAST)


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    """26 frames 320x240, DJI tags with 1 m GPS noise, a 30 m GPS altitude drift, line 1's yaw 180 deg off."""
    out = tmp_path_factory.mktemp("sfm") / "flight"
    assert main(["synth", "--out", str(out), "--frames", "26", "--width", "320", "--height", "240", "--world-size",
                 "400", "--line-length", "100", "--geotags", "dji", "--gps-altitude-drift", "30",
                 "--yaw-fault-lines", "1", "-q"]) == 0
    return out


def _strip_metadata(src: Path, dst: Path) -> None:
    """Copy a JPEG without its APP1 (EXIF, XMP) segments."""
    data = src.read_bytes()
    out, i = bytearray(data[:2]), 2
    while data[i] == 0xFF and data[i + 1] not in (0xDA, 0xD9):
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if data[i + 1] != 0xE1:
            out += data[i:i + 2 + length]
        i += 2 + length
    dst.write_bytes(bytes(out + data[i:]))


def test_poses_of_a_geotagged_flight(flight, tmp_path, capsys):
    out = tmp_path / "poses"
    assert main(["poses", str(flight / "images"), "--out", str(out), "--set", "sfm.max_features=1500"]) == 0
    line = capsys.readouterr().out
    assert "26 of 26 images registered (EPSG:" in line and "WARNING" in line
    truth, _ = read_poses_csv(flight / "poses.csv")
    offset = np.array(json.loads((flight / "session.json").read_text())["geo"]["world_to_crs_offset"])
    poses, epsg = read_poses_csv(out / "poses.csv")
    assert epsg == json.loads((flight / "session.json").read_text())["geo"]["epsg"]
    idx = [truth.names.index(n) for n in poses.names]
    err = np.linalg.norm(poses.centers - (truth.centers[idx] + offset), axis=1)
    assert np.median(err) < 1.0 and err.max() < 2.5  # 320x240 frames, 1.5 lines and 1 m GPS noise
    assert np.median(rotation_angle_deg(poses.rotations, truth.rotations[idx])) < 2.0
    report = json.loads((out / "poses.json").read_text())
    assert report["gps_priors_in_bundle_adjustment"]  # heights from RelativeAltitude: consistent priors
    warnings = " ".join(report["warnings"])
    # the 30 m drift is fitted in time (rev53 D2), not seen as a tilt of the heights' plane: said as a drift only
    assert "drifts by +" in warnings and "GPS altitudes, fitted to the block's camera centres, tilt it" not in warnings
    lines = report["comparison"]["contradicting_lines"]
    assert len(lines) == 1 and report["comparison"]["images"][lines[0]["first"]]["name"] == "frame_00019.jpg"
    assert lines[0]["line"] == 1 and "flight line 1 (" in warnings  # synth's number for it (crossings no lines)
    assert (out / "cameras.txt").read_text().count("SIMPLE_RADIAL") == 1
    assert (out / "sparse" / "images.bin").is_file() and (out / "database.db").is_file()
    # the same call again: the finished output stands (nothing recomputed), the same poses
    again = poses_wf.run(flight / "images", out, _params())
    assert again.poses.names == poses.names and np.allclose(again.poses.centers, poses.centers)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2, reason="needs 2 cores")
def test_poses_do_not_depend_on_the_number_of_cores(tmp_path):
    """Determinism: the same photos give the same bytes on any machine (the mapper once used every core: on
    this 12-frame 640x480 flight one core and two gave other poses, e.g. focal lengths 531.632 and 531.634 px
    with the default features)."""
    flight = tmp_path / "flight"
    assert main(["synth", "--out", str(flight), "--frames", "12", "--world-seed", "3", "--geotags", "dji",
                 "-q"]) == 0
    cores = os.sched_getaffinity(0)
    poses_wf.run(flight / "images", tmp_path / "all_cores", _params())
    os.sched_setaffinity(0, {min(cores)})
    try:
        poses_wf.run(flight / "images", tmp_path / "one_core", _params())
    finally:
        os.sched_setaffinity(0, cores)
    for name in ("poses.csv", "cameras.txt"):
        assert (tmp_path / "all_cores" / name).read_bytes() == (tmp_path / "one_core" / name).read_bytes(), name


def _matches_off_the_exact_rule(database: Path) -> dict[tuple[int, int], tuple[int, int]]:
    """The pairs whose raw SIFT matches in `database` differ from COLMAP's own matching rule evaluated exactly
    (integer squared distances over all features: nearest and second nearest, max distance, ratio test, cross
    check, fewer than min_num_inliers dropped), as {(image1, image2): (stored, exact)} match counts."""
    import pycolmap

    sift, min_inliers = pycolmap.FeatureMatchingOptions().sift, pycolmap.TwoViewGeometryOptions().min_num_inliers
    max_sq = 512.0**2 * sift.max_distance**2  # COLMAP's descriptors are normalised to length 512

    def one_way(sq: np.ndarray) -> np.ndarray:
        two = np.argsort(sq, axis=1, kind="stable")[:, :2]
        best = np.take_along_axis(sq, two, axis=1).astype(np.float64)
        ok = (best[:, 0] <= max_sq) & (np.sqrt(best[:, 0]) < sift.max_ratio * np.sqrt(best[:, 1]))
        return np.where(ok, two[:, 0], -1)

    with contextlib.closing(sqlite3.connect(database)) as db:
        desc = {i: np.frombuffer(d, np.uint8).reshape(r, c).astype(np.int64)
                for i, r, c, d in db.execute("SELECT image_id, rows, cols, data FROM descriptors")}
        stored = {divmod(p, 2147483647): np.frombuffer(d or b"", np.uint32).reshape(-1, 2)
                  for p, d in db.execute("SELECT pair_id, data FROM matches")}
    # COLMAP searches exactly (FAISS IndexFlatL2) below 512 features per image, approximately (IVF) above
    assert max(len(d) for d in desc.values()) < 512, "too many features for COLMAP's exact search"
    off = {}
    for (i, j), got in stored.items():
        a, b = desc[i], desc[j]
        sq = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2 * a @ b.T
        fwd, back = one_way(sq), one_way(sq.T)
        rows = np.flatnonzero(fwd >= 0)
        rows = rows[back[fwd[rows]] == rows]
        exact = np.stack([rows, fwd[rows]], axis=1) if len(rows) >= min_inliers else np.zeros((0, 2), np.int64)
        if not np.array_equal(got, exact):
            off[(i, j)] = (len(got), len(exact))
    return off


def test_outputs_do_not_depend_on_the_order_colmap_threads_finish(flight, tmp_path, monkeypatch):
    """Determinism: COLMAP's extraction and matching threads write the database's rows in the order they finish,
    which the machine's load decides; the content is the same, but SQLite's pages were laid out in that order,
    so database.db differed byte for byte run to run (4 of 4 runs on 40 Seneca frames). Here the second run
    writes the features again in reverse image order before matching, as threads finishing otherwise may."""
    first = poses_wf.run(flight / "images", tmp_path / "a", _params())
    match = sfm_wf.match_pairs

    def match_after_rewriting(database, *args, **kwargs):
        # closed before COLMAP opens the file: `with sqlite3.connect()` only commits, and a connection of Python's
        # SQLite left open while pycolmap's own SQLite writes the same file (one process, two libraries: closing
        # either drops the other's POSIX locks) failed once under load with "database disk image is malformed"
        with contextlib.closing(sqlite3.connect(database)) as db, db:
            for table in ("keypoints", "descriptors"):
                rows = db.execute(f"SELECT * FROM {table} ORDER BY image_id DESC").fetchall()
                db.execute(f"DELETE FROM {table}")
                db.executemany(f"INSERT INTO {table} VALUES ({', '.join('?' * len(rows[0]))})", rows)
        return match(database, *args, **kwargs)

    monkeypatch.setattr(sfm_wf, "match_pairs", match_after_rewriting)
    poses_wf.run(flight / "images", tmp_path / "b", _params())
    # the matches are the exact ones in both runs: COLMAP's multi-threaded matcher once lost matches of two pairs
    # in one run here (image 7 with 10: 44 of 170; with 11: none), which moved the poses (see `sfm.match_pairs`)
    for run in ("a", "b"):
        assert _matches_off_the_exact_rule(tmp_path / run / "database.db") == {}, run
    for path in sorted((tmp_path / "a").rglob("*")):
        # poses.json records the stages' timings, and the output's marker its sha256 (beside those of the others)
        if path.is_file() and path.name not in ("poses.json", ".sosmatch-output.json"):
            assert path.read_bytes() == (tmp_path / "b" / path.relative_to(tmp_path / "a")).read_bytes(), path.name
    # (the marker, but for poses.json's sha256, as well)
    a, b = (json.loads((tmp_path / run / ".sosmatch-output.json").read_text()) for run in ("a", "b"))
    a["files"].pop("poses.json"), b["files"].pop("poses.json")
    assert a == b
    assert first.poses.names == poses_wf.load_result(tmp_path / "b").poses.names


def test_images_without_gps_give_a_local_frame(flight, tmp_path, caplog):
    images = tmp_path / "images"
    images.mkdir()
    for p in sorted((flight / "images").iterdir()):
        _strip_metadata(p, images / p.name)
    assert not read_image_metadata(images / "frame_00000.jpg").has_gps
    result = poses_wf.run(images, tmp_path / "poses", _params())
    assert result.epsg == 0 and "# crs: local" in (tmp_path / "poses" / "poses.csv").read_text()
    assert any("no GPS positions" in w for w in result.warnings)
    assert "registered (local frame)" in result.line()  # the summary `sosmatch poses` prints (once a KeyError)
    # what the vertical rests on and its sigma, as a map of these poses reads them (`poses.result.poses_vertical`)
    source, sigma = poses_wf.result.poses_vertical(result.report)
    assert source and sigma > 0
    # levelled (nadir cameras look down) and metric by the nominal flight height
    assert np.all(result.poses.rotations[:, 2, 2] < -0.98)
    truth, _ = read_poses_csv(flight / "poses.csv")
    step = np.linalg.norm(np.diff(result.poses.centers[:5], axis=0), axis=1)
    assert 4.0 < np.median(step) < 10.0  # 7 m between frames at ~100 m above ground


def test_fewer_than_three_images_is_a_clear_error(flight, tmp_path, capsys):
    images = tmp_path / "images"
    images.mkdir()
    for name in ("frame_00000.jpg", "frame_00001.jpg"):
        shutil.copy(flight / "images" / name, images / name)
    assert main(["poses", str(images), "--out", str(tmp_path / "poses")]) == 2
    err = capsys.readouterr().err
    assert "2 image(s): structure from motion needs at least 3" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "poses" / "poses.csv").exists()


def test_mixed_cameras_get_one_camera_each_and_map_refuses_them(flight, tmp_path, capsys):
    images = tmp_path / "images"
    shutil.copytree(flight / "images", images)
    for p in sorted(images.iterdir())[::3]:  # every third frame from a second, larger camera
        img = cv2.imread(str(p))
        data = cv2.imencode(".jpg", cv2.resize(img, (400, 300)))[1].tobytes()
        p.write_bytes(data)  # no EXIF: another make/model and size
    result = poses_wf.run(images, tmp_path / "poses", _params())
    assert len(result.cameras) == 2
    assert {(c.width, c.height) for c in result.cameras.values()} == {(320, 240), (400, 300)}
    assert main(["map", "--images", str(images), "--out", str(tmp_path / "map"), "--set",
                 "sfm.max_features=1500", "--no-progress"]) == 2
    assert "cameras" in capsys.readouterr().err
    assert not (tmp_path / "map" / "run.json").exists()


def test_damaged_metadata_is_warned_about_and_the_images_still_register(flight, tmp_path):
    images = tmp_path / "images"
    shutil.copytree(flight / "images", images)
    p = images / "frame_00005.jpg"
    data = bytearray(p.read_bytes())
    j = data.find(b"<rdf:Description")
    data[j + 1:j + 5] = b"<<<<"  # the XMP is no longer XML: attitude and RelativeAltitude lost
    p.write_bytes(bytes(data))
    q = images / "frame_00012.jpg"
    data = bytearray(q.read_bytes())
    i = data.find(b"Exif\x00\x00")
    data[i + 14:i + 40] = b"\xab" * 26  # the EXIF is unreadable: no GPS for this one
    q.write_bytes(bytes(data))
    result = poses_wf.run(images, tmp_path / "poses", _params())
    damaged = result.report["priors"]["damaged_metadata"]
    assert set(damaged) == {"frame_00005.jpg", "frame_00012.jpg"}
    assert len(result.poses) == 26 and result.epsg != 0


def test_without_images_or_with_an_output_inside_the_input(tmp_path):
    with pytest.raises(InputError, match="image directory not found"):
        poses_wf.run(tmp_path / "missing", tmp_path / "out")


def test_images_the_incremental_mapper_leaves_out_are_registered_by_the_global_mapper(tmp_path, capsys):
    """Frames 40 m apart at 80 m with 8 deg of attitude jitter (a fixed wing's survey, as Seneca's turns): COLMAP's
    incremental mapper grows one model from a seed pair and leaves 3 of 30 images out (Seneca's first 30 frames:
    18 registered, the rest in three small models). The global mapper on the same matches registers all of them,
    as close to the truth; without it the images left out are listed with their strongest link."""
    flight = tmp_path / "F"
    assert main(["synth", "--out", str(flight), "--frames", "30", "--width", "320", "--height", "240", "--spacing",
                 "40", "--altitude", "80", "--attitude-jitter", "8", "--line-length", "250", "--geotags", "exif",
                 "--world-size", "500", "--world-seed", "5", "-q"]) == 0
    truth, _ = read_poses_csv(flight / "poses.csv")
    offset = np.array(json.loads((flight / "session.json").read_text())["geo"]["world_to_crs_offset"])

    def errors(out: Path) -> tuple[np.ndarray, np.ndarray]:
        poses, _ = read_poses_csv(out / "poses.csv")
        idx = [truth.names.index(n) for n in poses.names]
        return (np.linalg.norm(poses.centers - (truth.centers[idx] + offset), axis=1),
                rotation_angle_deg(poses.rotations, truth.rotations[idx]))

    alone = tmp_path / "incremental"
    assert main(["poses", str(flight / "images"), "--out", str(alone), "--set",
                 "sfm.global_when_incomplete=false"]) == 0
    report = json.loads((alone / "poses.json").read_text())
    left = report["unregistered"]
    assert left and report["mapper"] == "incremental"
    assert set(report["unregistered_strongest_link_inliers"]) == set(left)
    assert any("could not be registered" in w and "inliers with any one of them" in w for w in report["warnings"])

    out = tmp_path / "P"
    assert main(["poses", str(flight / "images"), "--out", str(out)]) == 0
    assert "30 of 30 images registered" in capsys.readouterr().out
    report = json.loads((out / "poses.json").read_text())
    assert report["mapper"] == "global" and len(report["incremental_registered"]) == 30 - len(left)
    assert report["registered_only_by_global_mapper"] == sorted(left)
    assert any("registered only by COLMAP's global mapper" in w for w in report["warnings"])
    centres, rotations = errors(out)
    kept_centres, kept_rotations = errors(alone)
    print(f"incremental {30 - len(left)} of 30: {np.median(kept_centres):.2f} m, {np.median(kept_rotations):.2f} deg; "
          f"global 30: {np.median(centres):.2f} m, {np.median(rotations):.2f} deg (median)")
    assert np.median(centres) < 1.5 * np.median(kept_centres) and centres.max() < 4.0
    assert np.median(rotations) < 1.5 * np.median(kept_rotations) and rotations.max() < 3.0


def test_images_left_out_leave_the_model_and_the_poses(flight, tmp_path):
    """The ninth new-user sweep: the global mapper placed Seneca frames 2000 km off their GPS fix and they were
    published. Images left out (`job._without_images`: weakly tied and off their fix) leave poses.csv and the
    sparse model alike, with their observations."""
    import pycolmap

    from sosmatch.workflows.poses.job import _without_images

    out = tmp_path / "poses"
    assert main(["poses", str(flight / "images"), "--out", str(out), "--set", "sfm.max_features=1500", "-q"]) == 0
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    poses, _ = read_poses_csv(out / "poses.csv")
    gone = ["frame_00003.jpg", "frame_00010.jpg"]
    observed = sum(1 for p in rec.points3D.values() for el in p.track.elements
                   if rec.images[el.image_id].name in gone)
    assert observed > 0

    class Model:
        reconstruction = rec

    kept = _without_images(Model(), poses, gone)
    assert len(kept) == len(poses) - 2 and not set(gone) & set(kept.names)
    assert {im.name for im in rec.images.values() if im.has_pose} == set(kept.names)
    assert not any(rec.images[el.image_id].name in gone for p in rec.points3D.values() for el in p.track.elements)
    i = poses.names.index(kept.names[5])
    assert np.array_equal(kept.centers[5], poses.centers[i])


def test_poses_another_sosmatch_made_are_kept_with_a_word_and_remade_with_overwrite(flight, tmp_path, caplog):
    """A finished `poses` output of the same images and settings is kept as it stands (nothing recomputed); one
    an earlier sosmatch made was kept without a word (the identity keys the settings, not the code), and
    --overwrite did not compute it again. poses.json now records its maker."""
    import logging

    from sosmatch.database.code_version import code_versions

    out = tmp_path / "poses"
    poses_wf.run(flight / "images", out, _params())
    record = out / "poses.json"
    report = json.loads(record.read_text())
    assert report["versions"] == code_versions()
    del report["versions"]  # as poses.json of sosmatch before it recorded its maker
    record.write_text(json.dumps(report))
    marker = json.loads((out / ".sosmatch-output.json").read_text())
    del marker["files"]  # nor did its marker record the files (else the edit above is a change of poses.json)
    (out / ".sosmatch-output.json").write_text(json.dumps(marker))
    with caplog.at_level(logging.WARNING):
        poses_wf.run(flight / "images", out, _params())
    said = [r.getMessage() for r in caplog.records if "kept as made by" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{out}: kept as made by an earlier sosmatch") and \
        "--overwrite" in said[0]
    assert "versions" not in json.loads(record.read_text())  # kept as it was
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        poses_wf.run(flight / "images", out, _params(), overwrite=True)
    assert json.loads(record.read_text())["versions"] == code_versions()
    assert not [r for r in caplog.records if "kept as made by" in r.getMessage()]


def test_stages_of_an_interrupted_run_another_sosmatch_made_are_said_or_redone(flight, tmp_path, caplog):
    """An interrupted `poses` run resumes its finished stages (features and matches) and an extraction's database;
    the identity keys the settings, not the code, so those another sosmatch made were reused without a word, and
    --overwrite reused them too. Now: said once, and made again with `renew_other_versions` (--overwrite)."""
    import logging

    from sosmatch.database.code_version import code_versions

    work = tmp_path / "work"
    identity = poses_wf.identity_of(flight / "images", _params())
    poses_wf.compute_poses(flight / "images", work, _params(), identity)
    stages_file = work / "stages.json"
    stages = json.loads(stages_file.read_text())
    assert stages["match"]["versions"] == code_versions() == stages["database"]["versions"]

    def interrupted_by_an_earlier_sosmatch() -> None:  # killed before the mapping, by a version that recorded none
        for name in ("match", "database"):
            stages[name].pop("versions", None)
        stages.pop("result", None)
        stages_file.write_text(json.dumps(stages))
        shutil.copyfile(work / "result" / "database.db", work / "database.db")  # the run moves it when it ends

    interrupted_by_an_earlier_sosmatch()
    with caplog.at_level(logging.WARNING):
        again = poses_wf.compute_poses(flight / "images", work, _params(), identity)
    said = [r.getMessage() for r in caplog.records if "kept as made by" in r.getMessage()]
    assert len(said) == 1 and "features and matches of an interrupted run" in said[0] and "--overwrite" in said[0]
    assert "versions" not in json.loads(stages_file.read_text())["match"]  # reused: not extracted or matched again
    assert len(again.poses.names) == 26 and "key" not in json.loads((again.out_dir / "poses.json").read_text())[
        "matching"]

    stages = json.loads(stages_file.read_text())
    interrupted_by_an_earlier_sosmatch()
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        poses_wf.compute_poses(flight / "images", work, _params(), identity, renew_other_versions=True)
    assert not [r for r in caplog.records if "kept as made by" in r.getMessage()]
    stages = json.loads(stages_file.read_text())
    assert stages["match"]["versions"] == code_versions() == stages["database"]["versions"]  # made again

    # killed during the extraction by an earlier sosmatch (no record of its database): made again, not resumed
    stages.pop("match"), stages.pop("result"), stages.pop("database")
    stages_file.write_text(json.dumps(stages))
    shutil.copyfile(work / "result" / "database.db", work / "database.db")
    poses_wf.compute_poses(flight / "images", work, _params(), identity)
    stages = json.loads(stages_file.read_text())
    assert stages["database"]["versions"] == code_versions() == stages["match"]["versions"]
