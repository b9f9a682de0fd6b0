"""Cameras from EXIF of photos resized or cropped after capture (the forty-second sweep's D1-D3): the EXIF's own
routes to the focal length checked against each other, the crop's scale, and frames of no camera's aspect."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from sosmatch.database.exif import ImageMetadata
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera
from sosmatch.tools.cli import main
from sosmatch.workflows.image_cameras import camera_from_metadata, camera_groups, odd_aspect

# A 1-inch camera as the sweep's: 10.36 mm on a 13.2 mm wide 640 px readout (48.48 px/mm), 27 mm equivalent.
FOCAL_MM, PX_PER_MM, F35 = 10.36, 640 / 13.2, 27.0
TRUE_FX_640 = FOCAL_MM * PX_PER_MM  # 502.3 px at 640 px wide


def _meta(width: int, height: int, exif_size: tuple[int, int] | None, plane: bool = True,
          f35: float | None = F35) -> ImageMetadata:
    return ImageMetadata(Path(f"/x/{width}x{height}.jpg"), width, height, focal_mm=FOCAL_MM,
                         focal_plane_px_per_mm=(PX_PER_MM, PX_PER_MM) if plane else None, focal_35mm=f35,
                         exif_size=exif_size, make="DJI", model="FC")


def test_a_resize_whose_exif_width_was_rewritten_is_refused_naming_both_focal_lengths():
    """D1: 640x480 frames resized to 320x240 with ExifImageWidth rewritten to 320: the focal plane resolution (of
    the 640 px readout) gave fx 502.3 px for 251, and a map 100 m too low passed. The 35 mm figure says 249.6 px:
    the two disagree x2, and which one holds (resize or crop) the EXIF cannot say."""
    with pytest.raises(InputError, match=r"disagree x2\.01: .* gives 502\.3 px, FocalLengthIn35mmFilm 249\.6 px "
                                         r"for the 320x240 file \(ExifImageWidth 320x240\)"):
        camera_from_metadata(_meta(320, 240, (320, 240)))
    # the same resize with ExifImageWidth left at the readout's: both routes agree on the true 251 px
    cam, _ = camera_from_metadata(_meta(320, 240, (640, 480)))
    assert cam.fx == pytest.approx(TRUE_FX_640 / 2, rel=1e-6)
    # an unedited frame: the routes agree within their rounding, no refusal
    assert camera_from_metadata(_meta(640, 480, (640, 480)))[0].fx == pytest.approx(TRUE_FX_640, rel=1e-6)
    # where structure from motion estimates the focal length (not strict), the images decide, with a warning
    cameras, _, _, warnings = camera_groups([_meta(320, 240, (320, 240))], None, strict=False)
    assert warnings and "disagree" in warnings[0] and cameras[0].fx == pytest.approx(1.2 * 320)
    with pytest.raises(InputError, match="disagree"):
        camera_groups([_meta(320, 240, (320, 240))], None, strict=True)


def test_a_one_sided_crop_keeps_the_pixel_pitch_and_says_its_principal_point_is_unknown():
    """D3: 80 px cut from the right of a 640x480 readout (EXIF unchanged): a crop keeps the pixel pitch, so fx is
    the readout's (scaling by width gave x0.875), and the principal point is unknown, said in a warning."""
    meta = _meta(560, 480, (640, 480))
    cam, _ = camera_from_metadata(meta)
    assert cam.fx == pytest.approx(TRUE_FX_640, rel=1e-6)
    _, _, _, warnings = camera_groups([meta], None, strict=True)
    assert len(warnings) == 1 and "principal point is unknown" in warnings[0] and "640x480" in warnings[0]
    # without ExifImageWidth (the sweep's synth frames: FocalLength and the 35 mm figure only), the 7:6 aspect says it
    bare = _meta(560, 480, None, plane=False)
    assert "aspect (1.167) no camera makes" in (odd_aspect(bare) or "")
    _, _, _, warnings = camera_groups([bare], None, strict=True)
    assert len(warnings) == 1 and "principal point is unknown" in warnings[0]


@pytest.mark.parametrize("size", [(640, 480), (600, 400), (640, 360), (640, 400), (640, 512), (480, 480),
                                  (336, 256), (480, 640)])
def test_frames_of_a_cameras_aspect_are_not_called_cropped(size):
    meta = _meta(*size, None, plane=False)
    assert odd_aspect(meta) is None
    assert camera_groups([meta], None, strict=True)[3] == []


def test_a_zoomed_frame_whose_35mm_figure_includes_the_zoom_is_not_refused():
    """rev26: the 35 mm figure of a frame zoomed x2 in the camera often includes the zoom (54 mm for 27), the focal
    plane route does not (the zoom is applied afterwards): the two were compared unlike and the frame refused."""
    for f35 in (2 * F35, F35):  # the zoom in the 35 mm figure, or not: either is the camera's own EXIF
        meta = _meta(640, 480, (640, 480), f35=f35)
        meta.digital_zoom = 2.0
        cam, source = camera_from_metadata(meta)
        assert cam.fx == pytest.approx(2 * TRUE_FX_640, rel=1e-6) and "x2 digital zoom" in source
    meta = _meta(640, 480, (640, 480), f35=4 * F35)  # beyond either reading: still refused
    meta.digital_zoom = 2.0
    with pytest.raises(InputError, match="disagree"):
        camera_from_metadata(meta)


REAL_SENSOR_SIZES = [
    (640, 512), (336, 256), (382, 288), (160, 120),  # thermal cores
    (1280, 960), (1600, 1300), (2064, 1544), (2464, 2056), (4112, 3008),  # multispectral and their pans
    (4032, 3024), (4000, 2250),  # phones
    (5472, 3648), (4000, 3000), (5280, 3956), (4096, 2160), (3840, 2160), (5120, 2700), (2048, 1080),  # DJI
    (1920, 1200), (1920, 1080),
]


@pytest.mark.parametrize("size", REAL_SENSOR_SIZES)
def test_no_real_sensors_frame_is_called_cropped_by_either_check(size):
    """rev26: odd_aspect (2 %) called DJI's DCI 4K and MicaSense pans cropped, cropped_frames (0.5 %, another
    list) the 336x256 thermal core and the P4 Multispectral's 1600x1300: one list and tolerance for both."""
    from sosmatch.workflows.poses.checks import cropped_frames

    w, h = size
    for width, height in ((w, h), (h, w)):
        assert odd_aspect(_meta(width, height, None, plane=False)) is None
        assert cropped_frames([Camera(width, height, 1.0, 1.0, width / 2, height / 2)]) == []


def test_a_seven_by_six_crop_is_called_cropped_by_both_checks():
    from sosmatch.workflows.poses.checks import cropped_frames

    assert odd_aspect(_meta(560, 480, None, plane=False)) is not None
    assert cropped_frames([Camera(560, 480, 1.0, 1.0, 280.0, 240.0)]) == ["560x480"]


def _jpeg(path: Path, size: tuple[int, int], exif_size: tuple[int, int], k: int,
          dji: dict[str, str] | None = None, zoom: int = 1, focal_mm: float | None = None, model: str = "FC") -> None:
    """A JPEG of the 1-inch camera's EXIF at `size`, north of 47 N by `k` seconds, with DJI XMP `dji`, its lens
    zoomed optically by `zoom` (FocalLength and the 35 mm figure multiplied), FocalLength `focal_mm` instead of
    the camera's (the 35 mm figure kept), of DJI model `model`."""
    img = Image.fromarray(np.random.default_rng(k).integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "DJI", model
    sub = exif.get_ifd(0x8769)
    sub[0x920A] = IFDRational(round((focal_mm or FOCAL_MM) * zoom * 100), 100)
    sub[0xA20E] = sub[0xA20F] = IFDRational(round(PX_PER_MM * 10 * 100), 100)  # px per cm
    sub[0xA210] = 3
    sub[0xA405] = int(F35) * zoom
    sub[0xA002], sub[0xA003] = exif_size
    gps = exif.get_ifd(0x8825)
    gps[1], gps[3], gps[5] = "N", "E", 0
    gps[2] = (IFDRational(47, 1), IFDRational(0, 1), IFDRational(k * 10000, 10000))
    gps[4] = (IFDRational(8, 1), IFDRational(0, 1), IFDRational(0, 1))
    gps[6] = IFDRational(500, 1)
    buf = io.BytesIO()
    img.save(buf, "JPEG", exif=exif.tobytes(), quality=80)
    data = buf.getvalue()
    if dji:
        attrs = " ".join(f"drone-dji:{k}='{v}'" for k, v in dji.items())
        packet = ("<?xpacket begin=''?><x:xmpmeta xmlns:x='adobe:ns:meta/'><rdf:RDF "
                  "xmlns:rdf='http://www.w3.org/1999/02/22-rdf-syntax-ns#'><rdf:Description rdf:about='' "
                  f"xmlns:drone-dji='http://www.dji.com/drone-dji/1.0/' {attrs}/></rdf:RDF></x:xmpmeta>"
                  "<?xpacket end='w'?>").encode()
        payload = b"http://ns.adobe.com/xap/1.0/\x00" + packet
        data = data[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + data[2:]
    path.write_bytes(data)


def test_poses_from_exif_refuses_contradicting_exif_and_writes_nothing(tmp_path, capsys):
    images = tmp_path / "images"
    images.mkdir()
    for k in range(4):
        _jpeg(images / f"f{k}.jpg", (320, 240), (320, 240), k)
    out = tmp_path / "p" / "poses.csv"
    assert main(["poses-from-exif", str(images), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "f0.jpg" in err[0] and "disagree x2.01" in err[0]
    assert not out.exists()


def test_a_map_whose_ground_lies_far_from_the_recorded_height_above_take_off_is_said():
    """D1/D2: a focal length x2 (resize) or x0.75 (centre crop, EXIF unchanged) puts the map's cameras 203 or 77 m
    above its ground where DJI's RelativeAltitude records 100 m: the warning names both heights and the focal
    length the recorded one implies. Within the take-off ground's and the EXIF's tolerance nothing is said, nor
    without recorded heights."""
    from sosmatch.workflows.map.recorded_height import height_against_takeoff

    rel = np.full(20, 100.0)
    said = height_against_takeoff(203.0, rel, 502.3)
    assert said is not None and "203 m above its ground" in said and "100 m above the take-off" in said
    assert "103 m below the take-off point" in said and "x2.03" in said and "would be 247.4" in said
    assert "cannot be told apart" in said  # neither cause asserted
    assert "hill" in said
    low = height_against_takeoff(77.0, rel, 374.4) or ""
    assert "23 m above the take-off point (a take-off in a valley)" in low and "x0.77" in low
    assert height_against_takeoff(104.0, rel, 502.3) is None
    assert height_against_takeoff(85.0, rel, 502.3) is None
    assert height_against_takeoff(440.0, np.full(20, 400.0), 502.3) is None  # 10 % of a high flight
    assert height_against_takeoff(203.0, np.full(20, np.nan), 502.3) is None


def test_match_repeats_the_maps_own_take_off_verdict_and_no_other():
    """rev26: the run.json record carried a ground offset whenever a height existed, and match judged it without
    the map's rules: a take-off 150 m above the survey (RelativeAltitude -50) or only 10 of 50 keyframes
    recording a height left the map silent and made match warn. The record now carries the map's verdict."""
    from sosmatch.workflows.map.recorded_height import ground_off_beyond, height_against_takeoff, takeoff_record

    for height, rel in ((100.0, np.full(50, -50.0)), (60.0, np.r_[np.full(10, 100.0), np.full(40, np.nan)])):
        assert height_against_takeoff(height, rel, 3000.0) is None
        assert ground_off_beyond(takeoff_record(height, rel)) is None
    record = takeoff_record(203.0, np.full(20, 100.0))
    assert record is not None and record["beyond"] is True and ground_off_beyond(record) == pytest.approx(-103.0)
    # a run.json written before the verdict was recorded: no warning
    assert ground_off_beyond({k: v for k, v in record.items() if k != "beyond"}) is None


def test_the_flying_height_against_take_off_is_measured_to_the_ground_not_the_canopy():
    """rev26: the map's flying height runs to the landmarks' median, and over a forest they are tree tops: a
    correct flight at 100 m over 25 m trees read 75 m, "focal length x0.75 off". The ground under a keyframe is
    a low quantile of the landmarks it sees."""
    from sosmatch.workflows.map.recorded_height import ground_flying_height, height_against_takeoff

    rng = np.random.default_rng(0)
    centers = np.c_[np.arange(10) * 20.0, np.zeros(10), np.full(10, 100.0)]
    xy = rng.uniform(0, 180, (400, 2))
    z = np.where(rng.random(400) < 0.8, 25.0, 0.0) + rng.normal(0, 0.3, 400)  # 80 % canopy, 20 % ground
    positions = np.c_[xy, z]
    observed = [np.flatnonzero(np.abs(centers[:, 0] - x) < 40) for x in xy[:, 0]]
    height = ground_flying_height(positions, observed, centers)
    assert height == pytest.approx(100.0, abs=1.5)
    assert height_against_takeoff(height, np.full(10, 100.0), 3000.0) is None
    assert np.isnan(ground_flying_height(np.zeros((0, 3)), [], centers))


def test_recorded_heights_read_the_dji_relative_altitude(tmp_path):
    from sosmatch.workflows.map.recorded_height import recorded_heights

    plain = tmp_path / "plain.jpg"
    _jpeg(plain, (64, 48), (64, 48), 0)
    tagged = tmp_path / "tagged.jpg"
    _jpeg(tagged, (64, 48), (64, 48), 0, {"RelativeAltitude": "+99.80"})
    heights = recorded_heights([tagged, plain, tmp_path / "missing.jpg"])
    assert heights[0] == pytest.approx(99.8) and np.isnan(heights[1]) and np.isnan(heights[2])


def test_match_names_a_vertical_move_that_inherits_a_maps_ground_off_its_recorded_heights(tmp_path):
    """nu42 D1: match moved B 102.6 m vertically by a map 100 m low, within two height datums' difference, and
    said nothing. The map records its ground against its RelativeAltitude (run.json "height_above_takeoff");
    match names a vertical move made beside a map whose ground lies beyond the tolerance."""
    import json

    from sosmatch.workflows.map.recorded_height import takeoff_record
    from sosmatch.workflows.match.answer_warnings import _takeoff_height_warning

    class Shift:
        def apply(self, p: np.ndarray) -> np.ndarray:
            return p + np.array([0.0, 0.0, -102.6])

    class Answer:
        associations = np.array([[0, 0], [1, 1], [2, 2]])
        transform = Shift()

    points = np.zeros((3, 3))
    a, b = tmp_path / "a", tmp_path / "b"
    for d, height in ((a, 203.0), (b, 100.5)):
        d.mkdir()
        (d / "run.json").write_text(json.dumps({"height_above_takeoff": takeoff_record(height, np.full(5, 100.0))}))
    said = _takeoff_height_warning(Answer(), points, a, b)
    assert said is not None and "-102.6 m vertically" in said and f"{a}'s ground lies 103 m below" in said
    assert str(b) not in said
    (a / "run.json").write_text(json.dumps({"height_above_takeoff": takeoff_record(104.0, np.full(5, 100.0))}))
    assert _takeoff_height_warning(Answer(), points, a, b) is None
    assert _takeoff_height_warning(Answer(), points, tmp_path / "x.sosmap", b) is None


def test_a_map_on_exif_intrinsics_repeats_their_warnings(tmp_path):
    """D3: a 7:6 frame's unknown principal point was logged by poses-from-exif, but `map --pose-source exif`'s
    verdict (run.json) did not carry it: the map's only word was a shared attitude error."""
    from sosmatch.workflows.poses_from_exif import map_inputs_from_images

    images = tmp_path / "images"
    images.mkdir()
    nadir = {"GimbalYawDegree": "0", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0",
             "RelativeAltitude": "100"}
    for k in range(4):
        _jpeg(images / f"f{k}.jpg", (560, 480), (640, 480), k, nadir)  # 80 px cut off, EXIF unchanged
    inputs = map_inputs_from_images(images)
    assert any("principal point is unknown" in w for w in inputs.warnings)


def test_a_given_sensor_width_spans_the_files_long_side_either_way_up():
    """rev38: --sensor-width-mm divided into the file's width, for a portrait file the sensor's short side: fx
    25 % short (2188 px for 2917). A sensor's width is its long side, which the file's long side spans."""
    landscape = ImageMetadata(Path("/x/l.jpg"), 4000, 3000, focal_mm=4.5)
    portrait = ImageMetadata(Path("/x/p.jpg"), 3000, 4000, focal_mm=4.5)
    truth = 4.5 / 6.17 * 4000
    for meta in (landscape, portrait):
        cam, source = camera_from_metadata(meta, sensor_width_mm=6.17)
        assert cam.fx == pytest.approx(truth, rel=1e-9) and cam.fy == cam.fx and "given sensor width" in source


def _zoomed(meta: ImageMetadata, zoom: float) -> ImageMetadata:
    meta.focal_mm *= zoom
    meta.focal_35mm = meta.focal_35mm * zoom if meta.focal_35mm else None
    return meta


def test_one_camera_at_two_focal_lengths_is_two_cameras():
    """rev38: an optical zoom (or another lens on one body) keeps make, model and size; its frames at 502 and
    1005 px became one camera of the median 749 px, wrong for every image. Each setting is a camera of its own,
    and tag-rounding differences (within FOCAL_GROUP_TOLERANCE) stay one camera."""
    metas = [_zoomed(_meta(640, 480, (640, 480)), 2.0 if k % 2 else 1.0) for k in range(6)]
    metas.append(_zoomed(_meta(640, 480, (640, 480)), 1.004))  # the tag's rounding: the unzoomed camera
    cameras, index, sources, warnings = camera_groups(metas, None, strict=True)
    assert [c.fx for c in cameras] == pytest.approx([TRUE_FX_640, 2 * TRUE_FX_640], rel=0.005)
    assert index.tolist() == [0, 1, 0, 1, 0, 1, 0] and len(sources) == 2 and warnings == []
    # the images' order does not change the grouping (settings in the order of their first images)
    cameras_r, index_r, _, _ = camera_groups(metas[::-1], None, strict=True)
    assert [c.fx for c in cameras_r] == pytest.approx([TRUE_FX_640, 2 * TRUE_FX_640], rel=0.005)
    assert index_r.tolist() == [0, 1, 0, 1, 0, 1, 0]


def _focal(focal_mm: float | None, f35: float | None, plane: bool = False) -> ImageMetadata:
    return ImageMetadata(Path(f"/x/{focal_mm}_{f35}.jpg"), 640, 480, focal_mm=focal_mm,
                         focal_plane_px_per_mm=(640 / 6.2, 640 / 6.2) if plane else None, focal_35mm=f35,
                         exif_size=(640, 480), make="DJI", model="FC")


def test_a_focal_length_tag_that_spreads_continuously_is_one_camera(caplog):
    """rev39: FocalLength 4.91-4.97 mm (1.2 %, in steps of 0.2 %) of one camera was cut where a value first lay
    1 % above the group's shortest: two cameras 0.7 % apart, and map refused the folder. Settings are split at
    gaps only: the spread is one camera at the median, in any image order, with a warning naming the spread;
    a gap of more than the tolerance between two such spreads is two settings."""
    focals = [4.91 + 0.06 * k / 9 for k in (3, 0, 7, 9, 1, 5, 8, 2, 6, 4)]
    metas = [_focal(f, None, plane=True) for f in focals]
    fxs = [camera_from_metadata(m)[0].fx for m in metas]
    for order in (metas, metas[::-1], metas[3:] + metas[:3]):
        with caplog.at_level("WARNING", logger="sosmatch.workflows.image_cameras"):
            cameras, index, _, _ = camera_groups(order, None, strict=True)
        assert len(cameras) == 1 and set(index.tolist()) == {0}
        assert cameras[0].fx == pytest.approx(float(np.median(fxs)), rel=1e-12)
    assert any("focal lengths spread over" in r.getMessage() and "no gap between zoom settings" in r.getMessage()
               for r in caplog.records)
    # the same spread beside another 1.5 % above it (a gap): two settings, whatever the order
    upper = [_focal(f * 1.015 * 1.012, None, plane=True) for f in focals]
    cameras, index, _, _ = camera_groups(upper + metas, None, strict=True)
    assert len(cameras) == 2 and index.tolist() == [0] * 10 + [1] * 10


def test_a_35mm_figure_one_millimetre_apart_is_its_rounding_not_a_zoom_step(caplog):
    """rev39: a 35 mm tag alternating 24/25 mm (one value, 24.5, rounded to whole millimetres) became two cameras.
    A whole-millimetre figure is a value +-0.5 mm: one unit apart is one setting (one camera at the median), two
    units apart are two. Where FocalLength (a rational) is there, it tells the settings apart instead."""
    alternating = [_focal(None, 24 + k % 2) for k in range(6)]
    with caplog.at_level("WARNING", logger="sosmatch.workflows.image_cameras"):
        cameras, index, _, _ = camera_groups(alternating, None, strict=True)
    assert len(cameras) == 1 and set(index.tolist()) == {0}
    assert not caplog.records  # the tag's rounding, not a spread to warn of
    with_focal = [_focal(4.5, 24 + k % 2) for k in range(6)]  # DJI: FocalLength 4.5 throughout
    assert len(camera_groups(with_focal, None, strict=True)[0]) == 1
    two_units = [_focal(None, 24 + 2 * (k % 2)) for k in range(6)]
    cameras, index, _, _ = camera_groups(two_units, None, strict=True)
    assert len(cameras) == 2 and index.tolist() == [0, 1] * 3
    # FocalLength 4.5 / 4.7 mm (4.4 %) behind 35 mm figures 24 / 25: two settings
    stepped = [_focal(4.5 + 0.2 * (k % 2), 24 + k % 2) for k in range(6)]
    cameras, index, _, _ = camera_groups(stepped, None, strict=True)
    assert len(cameras) == 2 and index.tolist() == [0, 1] * 3
    # FocalLength 1.1 % apart behind one 35 mm figure: apart by FocalLength, of one fx: one camera, not two
    same_fx = [_focal(4.5 + 0.05 * (k % 2), 25) for k in range(6)]
    cameras, _, _, _ = camera_groups(same_fx, None, strict=True)
    assert len(cameras) == 1


def test_an_image_without_a_focal_length_beside_a_zoom_is_not_given_a_setting():
    """Images without a usable focal length take their camera's; at two settings, which is theirs is unknown:
    refused where the intrinsics are final (strict), else a camera of their own that structure from motion
    estimates from the 1.2 x guess."""
    bare = ImageMetadata(Path("/x/bare.jpg"), 640, 480, make="DJI", model="FC")
    one = [_meta(640, 480, (640, 480)), bare]
    cameras, index, _, _ = camera_groups(one, None, strict=True)  # one setting: it takes that one
    assert len(cameras) == 1 and index.tolist() == [0, 0]
    two = [_meta(640, 480, (640, 480)), _zoomed(_meta(640, 480, (640, 480)), 2.0), bare]
    with pytest.raises(InputError, match=r"bare\.jpg: no usable focal length .* at 2 focal lengths"):
        camera_groups(two, None, strict=True)
    cameras, index, sources, warnings = camera_groups(two, None, strict=False)
    assert index.tolist() == [0, 1, 2] and cameras[2].fx == pytest.approx(1.2 * 640)
    assert "none in EXIF" in sources[2] and len(warnings) == 1 and "1 images" in warnings[0]


def test_poses_from_exif_refuses_a_zoomed_flight_instead_of_averaging_it(tmp_path, capsys):
    """rev38 r1_zoom end to end: poses-from-exif wrote fx 748.8 px for every image of a flight alternating 2x
    optical zoom, exit 0; one camera file cannot hold both: refused in one line naming both focal lengths."""
    images = tmp_path / "images"
    images.mkdir()
    for k in range(4):
        _jpeg(images / f"f{k}.jpg", (640, 480), (640, 480), k, zoom=2 if k % 2 else 1)
    out = tmp_path / "p" / "poses.csv"
    assert main(["poses-from-exif", str(images), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "2 cameras of different focal lengths (fx 502, 1005 px" in err[0]
    assert not out.exists()
    # map takes one camera: its structure from motion path refuses before any work, naming both settings
    assert main(["map", "--images", str(images), "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "2 cameras (640x480 fx 502 px, 640x480 fx 1005 px)" in err[-1]


NADIR = {"GimbalYawDegree": "0", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0", "RelativeAltitude": "100"}


def test_poses_from_exif_keeps_a_jittering_focal_length_one_camera_at_the_median(tmp_path, caplog):
    """rev39 end to end: FocalLength jittering by 1.4 % became two cameras, poses-from-exif warned "2 camera
    makes/models ... of one focal length" and wrote the first one's fx for all. Now one camera, the median."""
    images = tmp_path / "images"
    images.mkdir()
    focals = [10.30, 10.44, 10.33, 10.41, 10.36, 10.38]
    for k, f in enumerate(focals):
        _jpeg(images / f"f{k}.jpg", (640, 480), (640, 480), k, NADIR, focal_mm=f)
    out = tmp_path / "p" / "poses.csv"
    assert main(["poses-from-exif", str(images), "--out", str(out)]) == 0
    assert not any("makes/models" in r.getMessage() for r in caplog.records)
    assert any("focal lengths spread over" in r.getMessage() for r in caplog.records)
    fx = float((out.parent / "cameras.txt").read_text().split("PINHOLE")[1].split()[2])
    assert fx == pytest.approx(float(np.median(focals)) * PX_PER_MM, rel=1e-3)


def test_poses_from_exif_names_what_sets_cameras_of_one_focal_length_apart(tmp_path, caplog):
    """Two models within the tolerance of one focal length: the warning names the models (not "of one focal
    length" for what a zoom split) and the camera written is the images' median, not the first image's camera."""
    images = tmp_path / "images"
    images.mkdir()
    for k in range(5):
        _jpeg(images / f"f{k}.jpg", (640, 480), (640, 480), k, NADIR, focal_mm=10.40 if k == 0 else None,
              model="FC2" if k == 0 else "FC")
    out = tmp_path / "p" / "poses.csv"
    assert main(["poses-from-exif", str(images), "--out", str(out)]) == 0
    assert any("2 camera makes/models (DJI FC, DJI FC2) in one folder, their focal lengths within 1 %"
               in r.getMessage() for r in caplog.records)
    fx = float((out.parent / "cameras.txt").read_text().split("PINHOLE")[1].split()[2])
    assert fx == pytest.approx(TRUE_FX_640, rel=1e-3)


def _canon(width: int, exif_width: int) -> ImageMetadata:
    """Seneca's Canon tags (4.3 mm on a 4000 px readout at 645.41 px/mm: 6.198 mm wide; no 35 mm figure), the file
    `width` px wide (4:3) and ExifImageWidth `exif_width` (an export that rewrites it: the file's)."""
    return ImageMetadata(Path(f"/x/{width}.jpg"), width, width * 3 // 4, focal_mm=4.3,
                         focal_plane_px_per_mm=(645.41, 645.41), exif_size=(exif_width, exif_width * 3 // 4),
                         make="Canon", model="Canon PowerShot ELPH 300 HS")


def test_a_resize_that_puts_a_photo_sensor_below_any_real_one_is_refused():
    """rev38 r6: a 2000 px export of Seneca's Canon with ExifImageWidth rewritten to 2000 read as a 3.1 mm sensor
    (over the 3 mm floor) and got fx 2775 px for 1387, silently. 1.5 um pixels are a photo sensor's, and none is
    narrower than 1/3.2" (4.5 mm): refused. Thermal cores (12 um pixels) keep the 3 mm floor."""
    truth = 4.3 / (4000 / 645.41)
    assert camera_from_metadata(_canon(4000, 4000))[0].fx == pytest.approx(truth * 4000, rel=1e-9)
    assert camera_from_metadata(_canon(1200, 4000))[0].fx == pytest.approx(truth * 1200, rel=1e-9)  # Seneca's files
    assert camera_from_metadata(_canon(2000, 4000))[0].fx == pytest.approx(truth * 2000, rel=1e-9)
    with pytest.raises(InputError, match=r"on a 3\.10 mm sensor, .*ExifImageWidth rewritten; 1\.5 um pixels are a "
                                         r"photo sensor's, none narrower than 4\.5 mm\): give the sensor width"):
        camera_from_metadata(_canon(2000, 2000))
    # a 320 px thermal core at 12 um (3.84 mm) is a real one
    core = ImageMetadata(Path("/x/t.jpg"), 320, 256, focal_mm=9.1, focal_plane_px_per_mm=(1000 / 12, 1000 / 12),
                         exif_size=(320, 256))
    assert camera_from_metadata(core)[0].fx == pytest.approx(9.1 * 1000 / 12, rel=1e-9)


def test_the_pair_distance_cap_is_the_widest_settings_footprint():
    """Structure from motion caps image pairs at the footprint diagonal; of a zoom's cameras (one size) the first
    one's was taken: a flight whose first frame was at the long setting cut its wide frames' pairs at half their
    overlap. The widest view sets the cap, whichever camera comes first."""
    from types import SimpleNamespace

    from sosmatch.workflows.sfm import footprint_diagonal_m

    wide = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    long_ = Camera(640, 480, 1000.0, 1000.0, 320.0, 240.0)
    rel = np.full(4, 100.0)
    expected = 1.5 * 100.0 * 800.0 / 500.0
    for cameras in ([wide, long_], [long_, wide]):
        priors = SimpleNamespace(relative_altitude=rel, cameras=cameras)
        assert footprint_diagonal_m(priors) == pytest.approx(expected)


def test_images_without_a_focal_length_are_said_once_without_advice_for_another_command():
    """nu53 L3: `poses --telemetry` on images without EXIF warned "no usable focal length in EXIF (no usable
    focal length in EXIF (...); ...: take poses and intrinsics from structure from motion (`sosmatch poses`) ...)"
    while running `sosmatch poses`: the reason nested in itself and the refusal's advice in a warning."""
    bare = ImageMetadata(Path("/x/bare.jpg"), 320, 240)
    cameras, _, _, warnings = camera_groups([bare], None, strict=False)
    (said,) = warnings
    assert said.count("no usable focal length") == 1 and "EXIF stripped?" in said
    assert "sosmatch poses" not in said and "starting from 384 px" in said and cameras[0].fx == 384.0
    with pytest.raises(InputError, match=r"bare\.jpg: no usable focal length .*stripped\?\); take poses") as err:
        camera_groups([bare], None, strict=True)
    assert str(err.value).count("no usable focal length") == 1
