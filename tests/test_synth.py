"""The synthetic survey world: determinism, geometric ground truth, seasons, files and the command line."""

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.synth_session import TerrainSampler, load_synth_session
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import pixel_rays, project
from sosmatch.tools.synth import world_cache
from sosmatch.tools.synth.appearance import cast_shadow, lighting
from sosmatch.tools.synth.render import render_view
from sosmatch.tools.synth.scene import build_scene
from sosmatch.tools.synth.world import WorldConfig, get_world
from sosmatch.workflows.synth import SynthConfig, run, session_poses, session_presence

SOSMATCH = str(Path(sys.executable).parent / "sosmatch")
# A small world and small images keep the tests fast; the geometry is the same as at full size.
SMALL = dict(world_seed=3, world_size_m=240.0, frames=8, spacing_m=8.0, width=320, height=240,
             line_length_m=40.0, line_spacing_m=25.0)


@pytest.fixture(scope="module", autouse=True)
def _private_world_cache(tmp_path_factory):
    """The tests' worlds are cached in a temporary directory, not in the user's cache."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOSMATCH_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "S1"
    run(out, SynthConfig(**SMALL))
    return out


def test_same_seed_gives_byte_identical_session(session_dir, tmp_path):
    again = tmp_path / "again"
    run(again, SynthConfig(**SMALL), workers=1)  # the fixture used one thread per core: same bytes
    files = sorted(p.relative_to(session_dir) for p in session_dir.rglob("*") if p.is_file())
    assert len(files) == 2 * 8 + 7 + 1  # + the output marker (sosmatch.database.outputs)
    for rel in files:
        assert (session_dir / rel).read_bytes() == (again / rel).read_bytes(), rel
    # ... and another session seed changes the pixels but not the world.
    other = tmp_path / "other"
    run(other, SynthConfig(**{**SMALL, "session_seed": 5}))
    a = cv2.imread(str(session_dir / "images" / "frame_00000.jpg")).astype(int)
    b = cv2.imread(str(other / "images" / "frame_00000.jpg")).astype(int)
    assert np.abs(a - b).mean() > 1.0
    assert (session_dir / "terrain.npz").read_bytes() == (other / "terrain.npz").read_bytes()


def test_reader_returns_consistent_session(session_dir):
    s = load_synth_session(session_dir)
    assert len(s.poses) == len(s.ekf_poses) == len(s.frames) == 8
    assert s.camera.width == 320 and s.camera.height == 240
    assert math.isclose(2 * math.degrees(math.atan(160 / s.camera.fx)), 65.0, rel_tol=1e-6)
    assert s.meta["config"]["world_seed"] == 3
    # Roughly 100 m above the ground, looking down.
    agl = s.poses.centers[:, 2] - s.terrain.height_at(s.poses.centers[:, 0], s.poses.centers[:, 1])
    assert np.all(np.abs(agl - 100) < 6)
    assert np.all(s.poses.rotations[:, 2, 2] < -0.99)  # camera z axis (forward) points down
    # The EKF poses are noisy but close.
    err = np.linalg.norm(s.ekf_poses.centers - s.poses.centers, axis=1)
    assert 0 < err.mean() < 3.0
    kinds = set(s.objects["kind"])
    assert {"deciduous", "conifer", "building"} <= kinds
    assert np.all(s.objects["radius"] > 0) and np.all(s.objects["height"][s.objects["kind"] != "pond"] > 0)
    # visible ids are exactly the ids in the label images, and only present objects appear.
    present = set(s.objects["id"][s.objects["present"]].tolist())
    for f in s.frames:
        labels = cv2.imread(str(s.label_path(f["name"])), cv2.IMREAD_UNCHANGED)
        assert labels.dtype == np.uint16 and labels.shape == (240, 320)
        ids = set(np.unique(labels).tolist()) - {0}
        assert ids == set(f["visible_object_ids"])
        assert ids <= present


def test_object_top_projects_inside_its_blob(session_dir):
    s = load_synth_session(session_dir)
    by_id = {int(o["id"]): o for o in s.objects}
    checked, inside = 0, 0
    for i, f in enumerate(s.frames):
        labels = cv2.imread(str(s.label_path(f["name"])), cv2.IMREAD_UNCHANGED)
        for oid in f["visible_object_ids"]:
            o = by_id[oid]
            if (labels == oid).sum() < 40:  # cut by the image border or mostly hidden
                continue
            uv, depth = project(s.camera, s.poses.rotations[i], s.poses.centers[i],
                                np.array([[o["x"], o["y"], o["z"]]]))
            col, row = int(uv[0, 0]), int(uv[0, 1])  # pixel centres are at +0.5
            if not (1 <= col < 319 and 1 <= row < 239):
                continue
            checked += 1
            inside += int(np.any(labels[row - 1:row + 2, col - 1:col + 2] == oid))
    assert checked >= 20
    assert inside / checked >= 0.97, (inside, checked)


def test_footprints_are_the_image_corners_on_the_terrain(session_dir):
    s = load_synth_session(session_dir)
    w, h = s.camera.width, s.camera.height
    for i, f in enumerate(s.frames):
        fp = np.array(f["footprint"])
        assert fp.shape == (4, 2)
        pts = np.column_stack([fp, s.terrain.height_at(fp[:, 0], fp[:, 1])])
        uv, depth = project(s.camera, s.poses.rotations[i], s.poses.centers[i], pts)
        assert np.all(depth > 0)
        # footprints are stored with mm precision: at 100 m that is < 0.01 px
        assert np.allclose(uv, [[0, 0], [w, 0], [w, h], [0, h]], atol=0.02), uv
        # a nadir image covers about 127 m x 95 m at 100 m
        assert 100 < np.linalg.norm(fp[1] - fp[0]) < 160 and 75 < np.linalg.norm(fp[3] - fp[0]) < 120


def test_renderer_ground_agrees_with_terrain_file(session_dir):
    s = load_synth_session(session_dir)
    world = get_world(SynthConfig(**SMALL).world_config())
    cfg = SynthConfig(**SMALL)
    scene = build_scene(world, "summer", session_presence(world, cfg))
    light = np.ones_like(scene.dsm)
    res = render_view(scene, light, s.camera, s.poses.rotations[0], s.poses.centers[0])
    ground = res.labels == 0
    hit = res.hit[ground].astype(np.float64)
    z_file = s.terrain.height_at(hit[:, 0], hit[:, 1])
    assert np.percentile(np.abs(hit[:, 2] - z_file), 99) < 0.05
    # and every hit reprojects onto its own pixel (real perspective, not a crop of a flat map)
    rows, cols = np.nonzero(np.ones(res.labels.shape, bool))
    pts = res.hit.reshape(-1, 3).astype(np.float64)
    uv, _ = project(s.camera, s.poses.rotations[0], s.poses.centers[0], pts)
    assert np.percentile(np.abs(uv - np.column_stack([cols + 0.5, rows + 0.5])), 99) < 0.1


def test_tall_objects_lean_outward_off_nadir():
    cfg = SynthConfig(**SMALL)
    world = get_world(cfg.world_config())
    present = session_presence(world, cfg)
    scene = build_scene(world, "summer", present)
    poses = session_poses(world, cfg)
    cam = cfg.camera()
    tall = [o for o, p in zip(world.objects, present) if p and o.height > 8]
    checked = 0
    for i in range(len(poses)):
        r_wc, c = poses.rotations[i], poses.centers[i]
        res = render_view(scene, np.ones_like(scene.dsm), cam, r_wc, c)
        for o in tall:
            if (res.labels == o.id).sum() < 60:
                continue
            (top, base, nadir), _ = project(cam, r_wc, c, np.array([[o.x, o.y, o.top_z], [o.x, o.y, o.ground_z],
                                                                    [c[0], c[1], o.ground_z]]))
            off = base - nadir  # vertical lines radiate from the nadir point of the image
            if np.linalg.norm(off) < 50 or not (0 <= top[0] < cam.width and 0 <= top[1] < cam.height):
                continue
            lean = top - base
            cos = np.dot(lean, off) / (np.linalg.norm(lean) * np.linalg.norm(off))
            assert cos > 0.995  # the top is displaced straight away from the nadir ...
            expected = np.linalg.norm(off) * o.height / (c[2] - o.top_z)  # ... by about r h / (H - h)
            assert abs(np.linalg.norm(lean) - expected) < 0.1 * expected + 0.5
            # and the rendered blob covers the top (a conifer tip may be thinner than a pixel)
            r, q = int(top[1]), int(top[0])
            assert np.any(res.labels[max(r - 1, 0):r + 2, max(q - 1, 0):q + 2] == o.id)
            checked += 1
    assert checked >= 1


def test_an_oblique_survey_looks_ahead_and_its_renders_are_true_perspective():
    """`camera_tilt_deg` (`synth --camera-tilt`): the gimbal tilted forward along the direction of travel, every
    rendered pixel still the projection of its own hit (as at nadir), the footprint reaching ahead of the camera."""
    cfg = SynthConfig(**{**SMALL, "camera_tilt_deg": 30.0, "altitude_m": 40.0})  # its view stays in the small world
    world = get_world(cfg.world_config())
    poses = session_poses(world, cfg)
    view = poses.rotations[:, :, 2]
    off_nadir = np.degrees(np.arccos(-view[:, 2]))
    assert np.all(np.abs(off_nadir - 30.0) < 6.0)  # the tilt, with the airframe's 1.5 deg attitude jitter
    travel = np.diff(poses.centers[:, :2], axis=0)
    ahead = np.sum(view[:-1, :2] * travel, axis=1) / np.linalg.norm(travel, axis=1)
    assert np.all(ahead > 0.3)  # the view leans along the direction of flight
    scene = build_scene(world, "summer", session_presence(world, cfg))
    cam = cfg.camera()
    res = render_view(scene, np.ones_like(scene.dsm), cam, poses.rotations[0], poses.centers[0])
    pts = res.hit.reshape(-1, 3).astype(np.float64)
    uv, depth = project(cam, poses.rotations[0], poses.centers[0], pts)
    rows, cols = np.nonzero(np.ones(res.labels.shape, bool))
    assert np.percentile(np.abs(uv - np.column_stack([cols + 0.5, rows + 0.5])), 99) < 0.1
    # the image's top row sees ground farther ahead than a nadir view's footprint reaches (H tan 32.5 deg)
    top_reach = np.linalg.norm(res.hit[0, :, :2].astype(np.float64) - poses.centers[0, :2], axis=1)
    assert np.median(top_reach) > 1.5 * cfg.altitude_m * math.tan(math.radians(cfg.hfov_deg / 2))
    with pytest.raises(InputError, match=r"camera_tilt_deg \(--camera-tilt\)"):  # the CLI flag named too
        SynthConfig(**{**SMALL, "camera_tilt_deg": 60.0}).validate()


def test_evaluate_measures_how_oblique_a_session_is(session_dir, tmp_path):
    """`evaluate` names an oblique session (its footprint-IoU truth counts far-field overlap): the keyframes' median
    angle from nadir, ~30 deg for `--camera-tilt 30`, ~1 deg for the nadir session."""
    from sosmatch.plugin.params import Params
    from sosmatch.workflows.evaluate.ground_truth import load_ground_truth

    tilted = tmp_path / "T"
    run(tilted, SynthConfig(**{**SMALL, "camera_tilt_deg": 30.0, "altitude_m": 40.0}))
    assert abs(load_ground_truth(Params(), tilted).off_nadir_deg - 30.0) < 4.0
    assert load_ground_truth(Params(), session_dir).off_nadir_deg < 4.0


def test_winter_and_summer_differ_in_look_but_not_in_geometry():
    cfg = SynthConfig(**SMALL)
    world = get_world(cfg.world_config())
    present = session_presence(world, cfg)
    poses = session_poses(world, cfg)
    cam = cfg.camera()
    out = {}
    for season, az, el in (("summer", 150, 55), ("winter", 200, 20)):
        scene = build_scene(world, season, present)
        light = lighting(scene.dsm, world.res, az, el, 0.5)
        out[season] = render_view(scene, light, cam, poses.rotations[3], poses.centers[3])
    s, w = out["summer"], out["winter"]
    assert np.array_equal(s.labels, w.labels)  # same objects at the same pixels
    assert np.allclose(s.hit, w.hit)
    assert (s.labels > 0).sum() > 500
    # snow: the winter frame is much brighter on the ground, and the colours differ everywhere
    ground = s.labels == 0
    assert w.linear[ground].mean() > 2.5 * s.linear[ground].mean()
    assert np.abs(w.linear - s.linear).mean() > 0.1
    # summer vegetation is green, leaf-off winter trees are not
    trees = np.isin(s.labels, [o.id for o in world.objects if o.kind == "deciduous"])
    if trees.sum() > 50:
        sg = s.linear[trees]
        wg = w.linear[trees]
        assert (sg[:, 1] > sg[:, 0]).mean() > 0.8
        assert (wg[:, 1] > wg[:, 0]).mean() < 0.8


def test_objects_change_between_sessions():
    world = get_world(SynthConfig(**SMALL).world_config())
    a = session_presence(world, SynthConfig(**SMALL, session_seed=1))
    b = session_presence(world, SynthConfig(**SMALL, session_seed=2))
    default = np.array([o.default_present for o in world.objects])
    assert 0 < (a != b).sum() < 0.2 * len(a)
    assert (a & ~default).any() or (b & ~default).any()  # some extras added
    assert (default & ~a).any() and (default & ~b).any()  # some removed
    assert np.array_equal(session_presence(world, SynthConfig(**SMALL, session_seed=1, changed_fraction=0.0)),
                          default)


def test_changed_fraction_beyond_the_extras_pool_removes_more_and_adds_every_extra():
    world = get_world(SynthConfig(**SMALL).world_config())
    default = np.array([o.default_present for o in world.objects])
    small = session_presence(world, SynthConfig(**SMALL, session_seed=1, changed_fraction=0.1))
    large = session_presence(world, SynthConfig(**SMALL, session_seed=1, changed_fraction=0.4))
    assert (default & ~large).sum() > 2 * (default & ~small).sum()  # removals keep growing
    assert np.all(large[~default]) and np.all(small[~default])  # the pool is used up at 10 %
    with pytest.raises(InputError, match=r"changed_fraction \(--changed\)"):
        SynthConfig(**SMALL, changed_fraction=0.6).validate()


def test_cast_shadow_length_and_direction():
    res = 0.2
    dsm = np.zeros((400, 400), np.float32)
    dsm[195:205, 195:205] = 10.0  # a 2 m x 2 m, 10 m tall tower
    el = 45.0
    sh = cast_shadow(dsm, res, azimuth_deg=90.0, elevation_deg=el)  # sun in the east: shadow to the west
    row = sh[200]
    west = np.nonzero(row[:195] > 0.5)[0]
    assert len(west) and not (row[206:] > 0.5).any()
    length_m = (195 - west.min()) * res
    assert abs(length_m - 10.0 / math.tan(math.radians(el))) < 0.6
    assert sh[100:150, 100:150].max() == 0  # no shadow elsewhere


def test_terrain_sampler_rays():
    h = np.add.outer(np.arange(50.0), np.arange(60.0)).astype(np.float32) * 0.1  # a plane
    ts = TerrainSampler(h, 10.0, 20.0, 2.0)
    assert math.isclose(float(ts.height_at(10.0 + 2 * 3.5, 20.0 + 2 * 4.0)), 0.1 * (3.5 + 4.0), rel_tol=1e-6)
    o = np.array([[40.0, 50.0, 80.0], [70.0, 60.0, 90.0]])
    d = np.array([[0.1, 0.2, -1.0], [-0.3, 0.0, -1.0]])
    p = ts.intersect_rays(o, d)
    assert np.allclose(p[:, 2], ts.height_at(p[:, 0], p[:, 1]), atol=1e-3)
    assert np.allclose(np.cross(p - o, d), 0, atol=1e-6)


def test_reader_errors(session_dir, tmp_path):
    import shutil

    with pytest.raises(InputError, match="not found"):
        load_synth_session(tmp_path / "nope")
    broken = tmp_path / "broken"
    shutil.copytree(session_dir, broken)
    (broken / "terrain.npz").write_bytes(b"garbage")
    with pytest.raises(InputError, match="terrain.npz"):
        load_synth_session(broken)
    shutil.copy(session_dir / "terrain.npz", broken / "terrain.npz")
    frames = json.loads((broken / "frames.json").read_text())
    (broken / "frames.json").write_text(json.dumps(frames[:-1]))
    with pytest.raises(InputError, match="frames.json"):
        load_synth_session(broken)
    shutil.copy(session_dir / "frames.json", broken / "frames.json")
    (broken / "objects.csv").write_text("id,kind,x,y,z,radius,height,present\n1,tree,1,2,x,1,1,1\n")
    with pytest.raises(InputError, match="objects.csv:2"):
        load_synth_session(broken)


def test_cli_runs_and_rejects_a_flight_outside_the_world(tmp_path):
    out = subprocess.run(
        [SOSMATCH, "synth", "--out", str(tmp_path / "S"), "--world-seed", "3", "--world-size", "240",
         "--frames", "3", "--width", "160", "--height", "120", "--season", "winter", "--flight", "freeform",
         "--line-length", "40", "--shift", "2,-3", "--reverse", "-q"],
        capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert len(list((tmp_path / "S" / "images").glob("*.jpg"))) == 3
    bad = subprocess.run(
        [SOSMATCH, "synth", "--out", str(tmp_path / "T"), "--world-seed", "3", "--world-size", "240",
         "--frames", "3", "--shift", "500,0"], capture_output=True, text=True)
    assert bad.returncode == 2 and "world" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "T").exists()


def test_cli_takes_negative_coordinate_lists_in_the_southern_and_western_hemispheres(tmp_path):
    """`--geo-origin -33.45,-70.66` (Santiago) and `--shift -2,-3`: argparse took each value for an option and
    refused with 'expected one argument'; only the `--geo-origin=-33.45,-70.66` spelling worked."""
    from sosmatch.database.exif import read_image_metadata

    out = subprocess.run(
        [SOSMATCH, "synth", "--out", str(tmp_path / "S"), "--world-seed", "3", "--world-size", "240",
         "--frames", "3", "--width", "160", "--height", "120", "--line-length", "40", "--shift", "-2,-3",
         "--geotags", "exif", "--geo-origin", "-33.45,-70.66", "-q"],
        capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    meta = json.loads((tmp_path / "S" / "session.json").read_text())["config"]
    assert list(meta["shift_m"]) == [-2.0, -3.0]
    tags = read_image_metadata(next((tmp_path / "S" / "images").glob("*.jpg")))
    assert abs(tags.latitude + 33.45) < 0.01 and abs(tags.longitude + 70.66) < 0.01


def test_a_survey_beyond_utm_latitudes_is_rendered_in_ups(tmp_path):
    """`map` reads tags beyond UTM's latitudes in UPS (`geodesy.utm_epsg`), but synth refused an origin beyond
    +-80 deg, so the test bed could not render the flights that path reads (nu25: north Svalbard, Greenland, the
    poles; maps at 86 N, 89.9995 N and 88 S equal the 47 N map to 4 cm)."""
    from sosmatch.database.exif import read_image_metadata

    for origin, epsg in (("86,20", 32661), ("-88,30", 32761)):
        out = subprocess.run(
            [SOSMATCH, "synth", "--out", str(tmp_path / origin), "--world-seed", "3", "--world-size", "240",
             "--frames", "2", "--width", "160", "--height", "120", "--line-length", "40", "--geotags", "exif",
             f"--geo-origin={origin}", "-q"], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        assert f'"epsg": {epsg}' in (tmp_path / origin / "session.json").read_text()
        tags = read_image_metadata(next((tmp_path / origin / "images").glob("*.jpg")))
        assert abs(tags.latitude - float(origin.split(",")[0])) < 0.01


def test_contact_sheet_places_frames_side_by_side(session_dir, tmp_path):
    from sosmatch.workflows.demo import contact_sheet

    out = contact_sheet([session_dir, session_dir], ["a", "b"], tmp_path / "sheet.png", rows=3, scale=0.5)
    sheet = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert sheet.shape == (28 + 3 * 120 + 2 * 4, 2 * 160 + 4, 3)
    # the two columns show the same frames here, so they are identical below the header
    left, right = sheet[28:, :160].astype(int), sheet[28:, 164:].astype(int)
    assert np.abs(left - right).mean() < 1.0 and left.std() > 5


def _small_summer_view_inputs() -> tuple:
    """(scene, poses, camera, uniform light) of the SMALL world's summer session, as `render_view` takes them."""
    cfg = SynthConfig(**SMALL)
    world = get_world(cfg.world_config())
    scene = build_scene(world, "summer", session_presence(world, cfg))
    return scene, session_poses(world, cfg), cfg.camera(), np.ones_like(scene.dsm)


def test_two_pass_march_matches_a_plain_march(monkeypatch):
    """The conservative first pass only skips empty space: a plain march from the top sees the same surface."""
    from sosmatch.tools.synth import render

    scene, poses, cam, light = _small_summer_view_inputs()
    fast = [render_view(scene, light, cam, poses.rotations[i], poses.centers[i]) for i in (0, 5)]
    # an "infinitely high" conservative surface makes every ray start its fine march at the top of the view
    monkeypatch.setattr(render, "conservative_dsm", lambda sc, r: (np.full((4, 4), 1e6, np.float32), 4))
    plain = [render_view(scene, light, cam, poses.rotations[i], poses.centers[i]) for i in (0, 5)]
    for f, p in zip(fast, plain):
        assert (f.labels == p.labels).mean() > 0.998
        assert np.percentile(np.abs(f.hit[..., 2] - p.hit[..., 2]), 99.5) < 0.05


def test_ground_truth_is_the_visible_top_centre(session_dir):
    """objects.csv x, y, z: the centre of the top surface seen from above (where mask centroids triangulate),
    below the apex of trees, at the water level of ponds, and on the ray through a nadir mask's centroid."""
    cfg = SynthConfig(**SMALL)
    world = get_world(cfg.world_config())
    scene = build_scene(world, "summer", session_presence(world, cfg))
    objects = load_synth_session(session_dir).objects
    assert np.array_equal(objects["id"], [o.id for o in world.objects])
    trees = np.isin(objects["kind"], ["deciduous", "conifer"])
    assert trees.sum() >= 10
    assert np.all(objects["z"][trees] < objects["apex_z"][trees] - 0.2)
    assert np.all(objects["z"][trees] > objects["ground_z"][trees] + 1.0)
    ponds = objects["kind"] == "pond"
    assert np.allclose((objects["apex_z"] - objects["ground_z"])[~ponds], objects["height"][~ponds], atol=2e-3)
    assert ponds.any() and np.allclose(objects["z"][ponds], objects["apex_z"][ponds], atol=1e-3)
    # A nadir camera 100 m above each present, unoccluded tree or building: the ray through the centroid of
    # its mask passes within a few decimetres of the ground-truth centre.
    cam = cfg.camera()
    r_wc = np.diag([1.0, -1.0, -1.0])  # camera x east, y south (image down), z down
    checked = 0
    inner = np.all(np.abs(np.column_stack([objects["x"], objects["y"]]) - 120.0) < 50.0, axis=1)  # view inside
    for o in objects[objects["present"] & inner & np.isin(objects["kind"], ["deciduous", "conifer", "building"])][:12]:
        centre = np.array([o["x"], o["y"], o["z"]])
        c = np.array([o["x"] + 3.0, o["y"] - 2.0, o["ground_z"] + 100.0])  # slightly off the object's axis
        res = render_view(scene, np.ones_like(scene.dsm), cam, r_wc, c)
        rows, cols = np.nonzero(res.labels == o["id"])
        if len(rows) < 30:
            continue
        d = pixel_rays(cam, np.array([[cols.mean() + 0.5, rows.mean() + 0.5]]), r_wc)[0]
        d /= np.linalg.norm(d)
        miss = np.linalg.norm(np.cross(centre - c, d))
        assert miss < 0.3, (o["id"], o["kind"], miss)
        checked += 1
    assert checked >= 5


def _same_files(a: Path, b: Path) -> None:
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


def test_world_cache_is_transparent_and_rebuilds_corrupt_entries(tmp_path, monkeypatch):
    cfg = SynthConfig(**{**SMALL, "frames": 3})
    wcfg = cfg.world_config()
    monkeypatch.setenv("SOSMATCH_CACHE_DIR", str(tmp_path / "cache"))
    get_world.cache_clear()
    run(tmp_path / "cold", cfg)  # builds the world and writes the entry
    entry = world_cache.entry_dir(wcfg)
    assert entry.parent.parent == tmp_path / "cache"
    assert (entry / "world.json").exists() and (entry / "albedo_summer.json").exists()
    assert world_cache.load_world(wcfg) is not None
    get_world.cache_clear()
    run(tmp_path / "warm", cfg)  # loads it
    _same_files(tmp_path / "cold", tmp_path / "warm")
    # Corrupt entries: a flipped byte in the terrain, a truncated albedo: both rebuilt, same session.
    terrain = bytearray((entry / "terrain.npy").read_bytes())
    terrain[-5] ^= 0x40
    (entry / "terrain.npy").write_bytes(bytes(terrain))
    (entry / "albedo_summer.npy").write_bytes((entry / "albedo_summer.npy").read_bytes()[:1000])
    assert world_cache.load_world(wcfg) is None
    get_world.cache_clear()
    run(tmp_path / "rebuilt", cfg)
    _same_files(tmp_path / "cold", tmp_path / "rebuilt")
    assert world_cache.load_world(wcfg) is not None  # rewritten
    assert world_cache.load_albedo(entry, "summer", (wcfg.cells, wcfg.cells)) is not None
    # Without a cache: the same bytes again.
    monkeypatch.setenv("SOSMATCH_CACHE_DIR", "off")
    assert world_cache.entry_dir(wcfg) is None
    get_world.cache_clear()
    run(tmp_path / "uncached", cfg)
    _same_files(tmp_path / "cold", tmp_path / "uncached")
    get_world.cache_clear()
    # Every world setting is part of the key.
    keys = {world_cache.world_key(c) for c in (wcfg, WorldConfig(seed=4, size_m=240.0), WorldConfig(seed=3),
                                               WorldConfig(seed=3, size_m=240.0, relief_m=4.0))}
    assert len(keys) == 4


def test_world_cache_keeps_the_most_recently_used_entries(tmp_path):
    import os

    for i in range(5):
        (tmp_path / f"w{i}").mkdir()
        (tmp_path / f"w{i}" / "world.json").write_text("{}")
        os.utime(tmp_path / f"w{i}" / "world.json", (1000 + i, 1000 + (i * 7) % 5))  # used order: w0 w3 w1 w4 w2
    (tmp_path / "broken").mkdir()  # no world.json: oldest
    removed = world_cache.prune(tmp_path, keep=3)
    assert sorted(p.name for p in removed) == ["broken", "w0", "w3"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w1", "w2", "w4"]


def test_a_world_cache_entry_another_run_wrote_first_is_used_without_a_warning(tmp_path, monkeypatch, caplog):
    """Two `synth` runs of one new world at once (the nu51 sweep): both build it and the second's rename finds the
    first's entry in place. Complete and equal, it is the cache working: no warning ("cannot write the world cache
    X: X: exists and is a directory; not replaced" before), the entry used. A different entry there still warns,
    naming the path once."""
    import contextlib
    import logging
    import shutil

    wcfg = WorldConfig(seed=3, size_m=240.0)
    monkeypatch.setenv("SOSMATCH_CACHE_DIR", str(tmp_path / "cache"))
    get_world.cache_clear()
    world = get_world(wcfg)
    get_world.cache_clear()
    entry = world_cache.entry_dir(wcfg)
    other = tmp_path / "other_run"
    shutil.move(entry, other)  # what the other run will have written
    real = world_cache.atomic_path

    @contextlib.contextmanager
    def racing(path, *args, **kwargs):
        with real(path, *args, **kwargs) as tmp:
            yield tmp
            shutil.copytree(other, path)  # the other run renames its entry into place first

    monkeypatch.setattr(world_cache, "atomic_path", racing)
    with caplog.at_level(logging.DEBUG, logger=world_cache.__name__):
        world_cache.save_world(world)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text
    assert "another run wrote the world cache" in caplog.text
    assert world.cache_entry == entry and world_cache.load_world(wcfg) is not None
    # a genuine failure: what stands there is not this world's entry
    shutil.rmtree(entry)
    (other / "world.json").write_text("{}")
    caplog.clear()
    world_cache.save_world(world)
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 1 and said[0].count(str(entry)) == 1 and "not replaced" in said[0], said


def test_object_ids_the_evaluation_counts_by_are_checked(session_dir, tmp_path):
    """frames.json's visible_object_ids and objects.csv's ids are what the evaluation counts sightings and kinds
    by. Before: an id 'x' was a ValueError traceback out of `evaluate`, 1.5 counted as object 1, and a second
    objects.csv row of one id silently replaced the first."""
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(session_dir, broken)
    frames = json.loads((session_dir / "frames.json").read_text())
    for bad in (["x"], [1.5], [True], [0], [70000]):
        frames[1]["visible_object_ids"] = bad
        (broken / "frames.json").write_text(json.dumps(frames))
        with pytest.raises(InputError, match="frames.json: frame 'frame_00001.jpg': visible_object_ids must be"):
            load_synth_session(broken)
    shutil.copy(session_dir / "frames.json", broken / "frames.json")
    lines = (session_dir / "objects.csv").read_text().splitlines()
    (broken / "objects.csv").write_text("\n".join(lines + [lines[2]]) + "\n")
    with pytest.raises(InputError, match="is listed more than once"):
        load_synth_session(broken)


def test_wrong_types_from_python_are_input_errors():
    """The eighth new-user sweep, from Python: SynthConfig(width=320.5) passed its checks and failed in the
    renderer ("slice indices must be integers"), width="320" with a TypeError inside validate()."""
    from sosmatch.plugin.errors import InputError
    from sosmatch.workflows.synth import SynthConfig

    for kwargs, fragment in (({"width": 320.5}, "width must be an integer"), ({"width": "320"}, "an integer"),
                             ({"shift_m": ("a", 1)}, "a list of numbers"), ({"reverse": 1}, "true or false")):
        with pytest.raises(InputError, match=fragment):
            SynthConfig(**kwargs).validate()
    SynthConfig(altitude_m=80, shift_m=[1, 2], sun_azimuth_deg=None).validate()  # ints for floats, lists: fine


def test_point_remap_beyond_opencvs_row_limit_samples_every_point():
    """cv2.remap takes fewer than 32767 rows: the ray march's rows of 512 points exceed that above 16.7 M points
    (a 20 MP frame), so `_remap_points` remaps in blocks of rows; every point still gets its own sample."""
    from sosmatch.tools.synth.render import _remap_points

    src = np.arange(64 * 100, dtype=np.float32).reshape(64, 100)
    rows = 32768  # one past OpenCV's limit
    r = np.arange(rows, dtype=np.int32)[:, None]
    x, y = (np.arange(512, dtype=np.int32)[None, :] * 7 + r) % 100, r % 64  # every row of points differs
    maps = np.empty((rows, 512, 2), np.float32)
    maps[..., 0], maps[..., 1] = x, y  # integer raster points: the bilinear sample is the value there
    out = _remap_points(src, maps.reshape(-1, 2))
    assert out.shape == (rows * 512,) and np.array_equal(out.reshape(rows, 512), src[y, x])


def test_rendering_in_blocks_of_rows_is_byte_identical(monkeypatch):
    """The blocks of rows change nothing: a frame rendered with tiny blocks equals one rendered in one call."""
    from sosmatch.tools.synth import render

    scene, poses, cam, light = _small_summer_view_inputs()
    whole = render_view(scene, light, cam, poses.rotations[2], poses.centers[2])
    remap = render._remap_points
    monkeypatch.setattr(render, "_remap_points", lambda src, maps: remap(src, maps, max_rows=3))
    blocks = render_view(scene, light, cam, poses.rotations[2], poses.centers[2])
    for field in ("linear", "labels", "hit"):
        assert np.array_equal(getattr(whole, field), getattr(blocks, field)), field


def test_a_demo_too_short_to_map_is_refused_before_rendering(tmp_path, cli_error):
    """nu45: `demo --frames 1` rendered both sessions, then failed in map ("only 1 image(s) have a pose"; 2-5
    frames: "the map has no landmarks"). The fewest frames follow from theta_n and the keyframe spacing: a landmark
    needs theta_n + 1 keyframes (6 at the defaults, the demo's frames lying 7 m apart, beyond the 2 m interval)."""
    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows.demo import DemoContext, fewest_frames

    demo = DemoContext(tmp_path / "unused", 80)
    theta_n = Params().triangulation.min_observations
    assert fewest_frames(demo.summer, Params()) == fewest_frames(demo.winter, Params()) == theta_n + 1
    assert fewest_frames(demo.summer, with_overrides(Params(), {"triangulation.min_observations": 3})) == 4
    # frames 1.5 m apart: a keyframe every second frame (3 m of travel >= 2 m)
    assert fewest_frames(SynthConfig(spacing_m=1.5), Params()) == 2 * theta_n + 1
    for frames in (1, theta_n):
        err = cli_error("demo", "--out", tmp_path / "d", "--frames", frames)
        assert f"--frames {frames} is too few to map" in err and f"give at least {theta_n + 1} frames" in err
        assert not (tmp_path / "d").exists()


def test_demo_replaces_its_output_with_overwrite_as_every_command(tmp_path, cli_error, capsys):
    """nu54 M3: `demo` took --force where every other command (and README's Errors section) takes --overwrite.
    --overwrite now; --force still works (scripts), unlisted."""
    from sosmatch.database.output_markers import fingerprint
    from sosmatch.database.outputs import open_output_dir
    from sosmatch.tools.cli import build_parser, main

    with open_output_dir(tmp_path / "d", "demo", fingerprint({"frames": 99})) as taken:  # a demo of other frames
        taken.finish()
    err = cli_error("demo", "--out", tmp_path / "d", "--frames", 30)
    assert "use --overwrite" in err and "--force" not in err
    parser = build_parser()
    for flag in ("--overwrite", "--force"):
        assert parser.parse_args(["demo", flag]).overwrite is True
    assert parser.parse_args(["demo"]).overwrite is False
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    usage = capsys.readouterr().out
    assert "--overwrite" in usage and "--force" not in usage
