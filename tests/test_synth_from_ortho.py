"""Sessions rendered from an orthophoto: a small GeoTIFF written here, exact projection of known marks."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import rasterio

from sosmatch.database.cameras import read_cameras_txt
from sosmatch.database.poses import read_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import project
from sosmatch.tools.cli import main
from sosmatch.tools.ortho_session import footprint, plan_path
from sosmatch.workflows.synth_from_ortho import read_orthophoto
from sosmatch.workflows.synth_from_ortho import run as synth_from_ortho

X0, Y0, RES = 500000.0, 5200000.0, 5.0
MARKS = [(120, 80), (300, 150), (200, 220), (60, 250), (330, 40)]  # (col, row) of bright squares


def write_geotiff(path, crs="EPSG:32614", w=400, h=300):
    rng = np.random.default_rng(1)
    img = (rng.integers(40, 90, (3, h, w))).astype(np.uint8)  # dim texture
    for k, (c, r) in enumerate(MARKS):
        img[:, r - 2:r + 3, c - 2:c + 3] = 0
        img[k % 3, r - 2:r + 3, c - 2:c + 3] = 255  # a 25 m square of one pure colour
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=3, dtype="uint8", crs=crs,
                       transform=rasterio.Affine(RES, 0.0, X0, 0.0, -RES, Y0)) as dst:
        dst.write(img)
    return path


def mark_world(c, r):
    return np.array([X0 + RES * (c + 0.5), Y0 - RES * (r + 0.5), 0.0])


def test_rendered_marks_land_where_the_poses_project_them(tmp_path):
    tif = write_geotiff(tmp_path / "o.tif")
    out = tmp_path / "s"
    summary = synth_from_ortho(tif, out, path="lawnmower", gsd_m=2.0, width=320, height=240, hfov_deg=60,
                               max_tilt_deg=4.0, seed=3)
    poses, epsg = read_poses_csv(out / "poses.csv")
    cam = read_cameras_txt(out / "cameras.txt")[1]
    assert epsg == 32614 and summary["frames"] == len(poses) >= 6
    assert cam.width == 320 and cam.fx == pytest.approx(160 / np.tan(np.radians(30)))
    frames = json.loads((out / "frames.json").read_text())
    assert [f["name"] for f in frames] == poses.names
    hits = 0
    for i, name in enumerate(poses.names):
        img = cv2.imread(str(out / "images" / name))[:, :, ::-1].astype(int)
        for k, (c, r) in enumerate(MARKS):
            uv, depth = project(cam, poses.rotations[i], poses.centers[i], mark_world(c, r)[None])
            u, v = uv[0]
            if depth[0] <= 0 or not (8 <= u < cam.width - 8 and 8 <= v < cam.height - 8):
                continue
            # The brightest pixel of the mark's colour near the predicted spot is within 1.5 px of it.
            chan = img[:, :, k % 3] - img.sum(axis=2) / 3
            y0, x0 = int(v) - 8, int(u) - 8
            win = chan[y0:y0 + 17, x0:x0 + 17]
            yy, xx = np.nonzero(win > 0.6 * win.max())
            centre = np.array([xx.mean() + x0 + 0.5, yy.mean() + y0 + 0.5])
            assert np.linalg.norm(centre - uv[0]) < 1.5, (name, k, centre, uv[0])
            hits += 1
            # The footprint polygon contains the mark.
            from shapely.geometry import Point, Polygon
            assert Polygon(frames[i]["footprint"]).buffer(1.0).contains(Point(mark_world(c, r)[:2]))
    assert hits >= 10
    session = json.loads((out / "session.json").read_text())
    assert session["epsg"] == 32614 and session["ground_z"] == 0.0
    # The synthetic-session reader (used by mapping and evaluation) accepts it.
    synth_session = pytest.importorskip("sosmatch.database.synth_session")
    loaded = synth_session.load_synth_session(out)
    assert loaded.poses.names == poses.names and len(loaded.objects) == 0
    assert loaded.terrain.height_at(poses.centers[0, 0], poses.centers[0, 1]) == 0.0


def test_same_arguments_give_the_same_poses_and_two_dates_share_them(tmp_path):
    a = synth_from_ortho(write_geotiff(tmp_path / "a.tif"), tmp_path / "sa", path="line", gsd_m=2.0,
                         width=160, height=120, frames=5)
    b = synth_from_ortho(write_geotiff(tmp_path / "b.tif"), tmp_path / "sb", path="line", gsd_m=2.0,
                         width=160, height=120, frames=5)
    assert a["frames"] == b["frames"] == 5
    assert (tmp_path / "sa" / "poses.csv").read_text() == (tmp_path / "sb" / "poses.csv").read_text()


def test_plan_keeps_footprints_inside_and_overlapping():
    from sosmatch.tools.ortho_session import camera_for, make_poses
    cam = camera_for(640, 480, 60.0)
    bounds = (0.0, 0.0, 4670.0, 3620.0)
    centers, heads = plan_path(bounds, cam, 2.5 * cam.fx, "lawnmower")
    poses = make_poses(centers, heads)
    for i in range(len(poses)):
        fp = footprint(cam, poses.rotations[i], poses.centers[i])
        assert fp[:, 0].min() >= -1e-6 and fp[:, 0].max() <= 4670 + 1e-6
        assert fp[:, 1].min() >= -1e-6 and fp[:, 1].max() <= 3620 + 1e-6
    # A point in the middle is seen by at least 6 frames.
    mid = np.array([[2335.0, 1810.0, 0.0]])
    seen = sum(
        bool(np.all((uv := project(cam, poses.rotations[i], poses.centers[i], mid)[0][0]) >= 0)
             and uv[0] < cam.width and uv[1] < cam.height) for i in range(len(poses)))
    assert seen >= 6


@pytest.mark.parametrize("kind", ["lawnmower", "line", "cross"])
def test_a_few_frames_of_a_plan_beyond_the_limit_are_made(kind):
    """rev55 D3: `--gsd 0.1 --frames 3` on a NAIP raster was refused for the ~3.5e5 frames of the whole plan; the
    limit is on the frames made, which are the first ones of the plan (cut without building the rest)."""
    from sosmatch.tools.ortho_session import camera_for

    cam = camera_for(320, 240, 60.0)
    bounds = (0.0, 0.0, 4670.0, 3620.0)
    full, full_heads = plan_path(bounds, cam, 0.5 * cam.fx, kind)
    assert len(full) > 200
    for frames in (3, 150):
        centers, heads = plan_path(bounds, cam, 0.5 * cam.fx, kind, max_frames=frames, max_plan_frames=160)
        assert np.array_equal(centers, full[:frames]) and np.array_equal(heads, full_heads[:frames])
    with pytest.raises(ValueError, match="would hold"):
        plan_path(bounds, cam, 0.5 * cam.fx, kind, max_frames=170, max_plan_frames=160)


def test_a_gsd_far_finer_than_the_raster_is_warned_of(tmp_path, caplog):
    """rev55 D7: --gsd 0.1 on a 5 m/px raster (50x upsampling) rendered without a word; at 2x (the default's
    ratio) nothing is said."""
    tif = write_geotiff(tmp_path / "geo.tif")
    args = dict(path="line", width=160, height=120, frames=2)
    with caplog.at_level("WARNING"):
        synth_from_ortho(tif, tmp_path / "fine", gsd_m=0.5, **args)
    assert "views at 0.5 m/px upsample the orthophoto's 5 m/px 10x" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        synth_from_ortho(tif, tmp_path / "ok", gsd_m=2.5, **args)
    assert "upsample" not in caplog.text


def test_errors_are_user_errors(tmp_path, capsys):
    tif = write_geotiff(tmp_path / "geo.tif", crs="EPSG:4326")
    with pytest.raises(InputError, match="projected CRS"):
        read_orthophoto(tif)
    small = write_geotiff(tmp_path / "small.tif", w=40, h=30)
    assert main(["synth-from-ortho", str(small), "--out", str(tmp_path / "x"), "--gsd", "5"]) == 2
    assert "smaller than one footprint" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("flags, fragment", [
    (["--offset", "nan"], "offset must be a finite number"),  # was: ValueError traceback from the pose writer
    (["--heading", "inf"], "heading must be a finite number"),  # was: 'math domain error'
    (["--gsd", "nan"], "gsd must be a finite number"),  # was: 'arange: cannot compute length'
    (["--frame-spacing", "-5"], "frame spacing must be positive"),  # was: IndexError traceback
    (["--frame-spacing", "0"], "frame spacing must be positive"),  # was: the default spacing, silently
    (["--frame-spacing", "1e-6"], "the flight plan would hold"),  # was: MemoryError (32.6 GiB)
    (["--line-spacing", "1e-6"], "the flight plan would hold"),  # was: MemoryError (24 GiB)
    (["--max-tilt", "90"], "max tilt must be between 0 and 45"),  # was: MemoryError (2.96 EiB)
    (["--max-tilt", "-5"], "max tilt must be between 0 and 45"),  # was: rendered, exit 0
    (["--frames", "-3"], "frames must be between 1 and"),  # was: rendered, exit 0
    (["--ekf-position-sigma", "-1"], "ekf sigmas must be >= 0"),  # was: rendered, exit 0
    (["--seed", "-1"], "seed must be >= 0"),  # was: ValueError traceback from numpy
    (["--offset", "100000"], "look at ground outside the orthophoto"),  # was: black images, exit 0
])
def test_settings_that_cannot_make_a_session_are_one_line(tmp_path, cli_error, flags, fragment):
    tif = write_geotiff(tmp_path / "geo.tif")
    err = cli_error("synth-from-ortho", tif, "--out", tmp_path / "x", "--gsd", "2", "--width", "160", "--height",
                    "120", *flags)
    assert fragment in err and not (tmp_path / "x").exists()


def test_altitude_and_gsd_together_are_refused(tmp_path, capsys):
    """nu45: `--altitude 100 --gsd 2.5` rendered at 100 m (0.18 m/px): --gsd was silently ignored. Each sets the
    other, so the pair is a usage error (and an InputError from Python), with nothing written."""
    tif = write_geotiff(tmp_path / "geo.tif")
    with pytest.raises(SystemExit) as stop:
        main(["synth-from-ortho", str(tif), "--out", str(tmp_path / "x"), "--altitude", "100", "--gsd", "2.5"])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1 and "--gsd: not allowed with argument --altitude" in err
    with pytest.raises(InputError, match="not both"):
        synth_from_ortho(tif, tmp_path / "x", altitude_m=100.0, gsd_m=2.5)
    assert not (tmp_path / "x").exists()
    summary = synth_from_ortho(tif, tmp_path / "y", path="line", width=160, height=120, frames=2)  # neither: 2.5
    assert summary["gsd_m"] == pytest.approx(2.5)


def test_an_image_without_georeference_is_one_line_without_rasterio_s_warning(tmp_path):
    """In a process of its own, as a user runs it (pytest would catch the warning): before, rasterio's
    NotGeoreferencedWarning and its source line stood above the error."""
    import subprocess
    import sys

    import cv2

    cv2.imwrite(str(tmp_path / "plain.tif"), np.zeros((300, 400, 3), np.uint8))
    run = subprocess.run([sys.executable, "-c", "import sys; from sosmatch.tools.cli import main; sys.exit(main())",
                          "synth-from-ortho", str(tmp_path / "plain.tif"), "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "projected CRS" in run.stderr
