"""What a `poses` output depends on (its identity), how its database is published and what it says, without a
structure from motion run where none is needed."""

from __future__ import annotations

import json
import logging
import os
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from PIL import Image

from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import Params, with_overrides
from sosmatch.tools.cli import main
from sosmatch.workflows import poses as poses_wf
from sosmatch.workflows import sfm as sfm_wf


def _folder(tmp_path: Path) -> Path:
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        Image.fromarray(np.full((8, 8, 3), 40 * k, np.uint8)).save(images / f"f{k}.jpg")
    return images


def test_an_edited_telemetry_changes_the_poses_identity_and_its_place_does_not(tmp_path):
    """rev49 D4: the identity keyed the telemetry's path, so `poses` (and `map --images`, and the stages of an
    interrupted run) gave back the result of the file as it was before an edit. Its content keys it now."""
    images = _folder(tmp_path)
    tele = tmp_path / "tele.csv"
    tele.write_text("FileName,Heading\nf0.jpg,090\n")
    st = tele.stat()
    before = poses_wf.identity_of(images, Params(), tele)
    source = poses_wf.PosesFromImages(images, Params(), telemetry=tele)  # `map --images --telemetry`
    source_before = source.identity()
    tele.write_text("FileName,Heading\nf0.jpg,270\n")  # the same size, and the same time below
    os.utime(tele, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert poses_wf.identity_of(images, Params(), tele) != before
    assert source.identity() != source_before
    moved = tmp_path / "moved.csv"
    moved.write_text("FileName,Heading\nf0.jpg,090\n")
    assert poses_wf.identity_of(images, Params(), moved) == before  # the same content elsewhere: the same input
    assert poses_wf.identity_of(images, Params()) != before



def _fd8d3d3_identity(images: Path, tele: Path, **options: object) -> str:
    """The identity sosmatch gave a `poses --telemetry` output until fix130: the telemetry by its path as given."""
    from sosmatch.database.output_markers import fingerprint
    from sosmatch.plugin.params import params_to_dict

    return fingerprint({"images": [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in sorted(images.iterdir())],
                        "sfm": params_to_dict(Params().sfm), "seed": Params().seed,
                        **{k: str(v) for k, v in {"telemetry": tele, **options}.items()}})


def test_a_poses_output_an_earlier_sosmatch_keyed_by_the_telemetry_path_resumes(tmp_path):
    """rev52 D2: fix130 keyed the telemetry by its content, so every `poses --telemetry` output of the version
    before (keyed by its path) was refused as made "from other inputs or settings": an upgrade meant --overwrite
    and the structure from motion again. It is this output: kept, and its marker re-written under today's
    identity (`map --images --telemetry` likewise accepts the map made of it)."""
    from sosmatch.database.code_version import code_versions
    from sosmatch.database.output_markers import output_marker
    from sosmatch.database.outputs import open_output_dir
    from sosmatch.database.poses import format_poses_csv
    from sosmatch.plugin.geometry import Poses

    images = _folder(tmp_path)
    tele = tmp_path / "tele.csv"
    tele.write_text("FileName,Heading\nf0.jpg,090\n")
    options = {"takeoff": None, "sensor": None, "nominal_height_m": poses_wf.NOMINAL_HEIGHT_M}
    old = _fd8d3d3_identity(images, tele, **options)
    today = poses_wf.identity_of(images, Params(), tele, **options)
    assert old != today
    out = tmp_path / "poses"
    with open_output_dir(out, "poses", old) as taken:  # a finished output as that version marked it
        names = [f"f{k}.jpg" for k in range(3)]
        (out / "poses.csv").write_text(format_poses_csv(Poses(names, np.stack([np.eye(3)] * 3),
                                                              np.arange(9.0).reshape(3, 3)), 32618))
        (out / "cameras.txt").write_text("1 PINHOLE 8 8 8 8 4 4\n")
        (out / "poses.json").write_text(f'{{"versions": {json.dumps(code_versions())}}}')
        taken.finish()
    marker = json.loads((out / ".sosmatch-output.json").read_text())
    marker.pop("files", None)  # that version's marker recorded no files (its files written straight, as above)
    (out / ".sosmatch-output.json").write_text(json.dumps(marker))
    assert output_marker(out)["identity"] == old
    result = poses_wf.run(images, out, Params(), telemetry=tele)  # refused before: "other inputs or settings"
    assert result.poses.names == names and output_marker(out)["complete"]
    assert output_marker(out)["identity"] == today
    tele.write_text("FileName,Heading\nf0.jpg,270\n")  # an edit now is another input, as since fix130
    with pytest.raises(InputError, match="overwrite"):
        poses_wf.run(images, out, Params(), telemetry=tele)
    source = poses_wf.PosesFromImages(images, Params(), telemetry=tele)  # `map --images --telemetry`
    assert source.earlier_identities() == (_fd8d3d3_identity(images, tele, **options),)
    assert poses_wf.PosesFromImages(images, Params()).earlier_identities() == ()


def _database(path: Path, clears: int) -> None:
    """One camera, and the pose priors cleared `clears` times, each by a run of its own (`sfm.write_pose_priors`:
    once more in a run resumed after its match stage); each such opening bumps the schema cookie."""
    db = pycolmap.Database.open(path)
    try:
        db.write_camera(pycolmap.Camera(model="PINHOLE", width=8, height=8, params=[8.0, 8.0, 4.0, 4.0],
                                        camera_id=1), use_camera_id=True)
    finally:
        db.close()
    for _ in range(clears):
        db = pycolmap.Database.open(path)
        try:
            db.clear_pose_priors()
        finally:
            db.close()


def test_the_published_database_does_not_count_the_schema_changes_of_its_run(tmp_path):
    """rev49 D5: a run resumed after its match stage wrote the pose priors again, and COLMAP's clear_pose_priors
    bumps SQLite's schema cookie, which VACUUM INTO copies: the published database.db differed from an
    uninterrupted run's in one header byte. The same rows give the same bytes now."""
    for name, clears in (("once", 1), ("resumed", 2)):
        _database(tmp_path / f"{name}.db", clears)
        sfm_wf.publish_database(tmp_path / f"{name}.db", tmp_path / f"{name}_published.db")
        assert not (tmp_path / f"{name}.db").exists()
    once, resumed = ((tmp_path / f"{n}_published.db").read_bytes() for n in ("once", "resumed"))
    assert once == resumed
    con = sqlite3.connect(tmp_path / "once_published.db")
    try:
        assert con.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert con.execute("SELECT COUNT(*) FROM cameras").fetchone() == (1,)
    finally:
        con.close()


def test_images_in_several_separate_models_are_counted_once():
    """rev49 D8: "2 separate model(s) hold 51 images" of 40 distinct ones: COLMAP put 11 in both models."""
    from sosmatch.workflows.poses.job import unregistered_warning

    a = [f"b{k:02d}.jpg" for k in range(40)]
    model = sfm_wf.SfmModel(None, ["x.jpg"] * 3, a, other_models=[a, a[4:15]])
    said = unregistered_warning(model, {n: 1 for n in a}, 43)
    assert "2 separate model(s) hold 40 images" in said and said.startswith("40 of 43 images")


def test_a_warning_of_the_images_metadata_is_logged_once(tmp_path, caplog):
    """rev49 D9: the copies of images were named twice in the log, by the metadata's reader and again by `poses`,
    which logged the reader's warnings with its own (poses.json counts them once, as before)."""
    flight = tmp_path / "flight"
    assert main(["synth", "--out", str(flight), "--frames", "4", "--width", "320", "--height", "240", "--geotags",
                 "dji", "-q"]) == 0
    images = tmp_path / "images"
    images.mkdir()
    for name in sorted(p.name for p in (flight / "images").iterdir())[:3]:
        shutil.copy2(flight / "images" / name, images / name)
    shutil.copy2(images / name, images / name.replace(".jpg", "-Edit.jpg"))
    with caplog.at_level(logging.WARNING):
        result = poses_wf.run(images, tmp_path / "poses", with_overrides(Params(), {"sfm.max_features": 1500}))
    said = [r.getMessage() for r in caplog.records if "repeat another's exposure" in r.getMessage()]
    assert len(said) == 1
    assert sum("repeat another's exposure" in w for w in result.report["warnings"]) == 1
