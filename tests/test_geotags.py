"""EXIF/XMP writing and reading (database.exif), the synthetic world's geotags, heights from RelativeAltitude,
35 mm equivalents of cropped frames and damaged metadata: small files written here."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.cameras import read_cameras_txt, write_cameras_txt
from sosmatch.database.exif import ImageMetadata, read_image_metadata
from sosmatch.database.exif_write import embed_metadata
from sosmatch.database.poses import read_poses_csv
from sosmatch.plugin.geometry import rotation_angle_deg
from sosmatch.tools.cli import main
from sosmatch.workflows import poses_from_exif as pfe
from sosmatch.workflows.image_priors import full_frame_diagonal_px, read_image_priors


def _jpeg(seed: int = 0, size: tuple[int, int] = (64, 48)) -> bytes:
    rng = np.random.default_rng(seed)
    ok, buf = cv2.imencode(".jpg", rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    assert ok
    return buf.tobytes()


def _meta(path, **kw) -> ImageMetadata:
    base = dict(path=path, width=64, height=48, latitude=47.1234567, longitude=-8.7654321, altitude=512.345,
                focal_mm=4.5, focal_35mm=24.0, make="DJI", model="FC1234",
                datetime_original="2024:06:01 10:00:03", subsec_original="45",
                xmp={"GimbalYawDegree": "+12.30", "GimbalPitchDegree": "-89.90", "GimbalRollDegree": "+0.00",
                     "RelativeAltitude": "+80.10"})
    base.update(kw)
    return ImageMetadata(**base)


def test_metadata_round_trip(tmp_path):
    p = tmp_path / "a.jpg"
    meta = _meta(p)
    p.write_bytes(embed_metadata(_jpeg(), meta))
    back = read_image_metadata(p)
    assert back.latitude == pytest.approx(meta.latitude, abs=1e-9)
    assert back.longitude == pytest.approx(meta.longitude, abs=1e-9)
    assert back.altitude == pytest.approx(512.345)
    assert (back.focal_mm, back.focal_35mm, back.make, back.model) == (4.5, 24.0, "DJI", "FC1234")
    assert back.capture_time_s == pytest.approx(1717236003.45)
    assert back.xmp == meta.xmp and back.problems == []
    assert cv2.imdecode(np.frombuffer(p.read_bytes(), np.uint8), cv2.IMREAD_COLOR).shape == (48, 64, 3)


def test_writer_refuses_what_the_reader_drops(tmp_path):
    with pytest.raises(ValueError, match="off the globe"):
        embed_metadata(_jpeg(), _meta(tmp_path / "a.jpg", latitude=95.0))


def test_damaged_exif_and_xmp_are_problems_not_errors(tmp_path):
    p = tmp_path / "a.jpg"
    data = bytearray(embed_metadata(_jpeg(), _meta(p)))
    i = data.find(b"Exif\x00\x00")
    data[i + 10:i + 40] = b"\xab" * 30  # garble the TIFF header's offset of the first IFD, and the IFD
    j = data.find(b"<rdf:Description")
    data[j + 1:j + 5] = b"<<<<"  # XMP no longer well-formed
    p.write_bytes(bytes(data))
    meta = read_image_metadata(p)
    assert not meta.has_gps and meta.xmp == {}
    assert any("EXIF" in q for q in meta.problems) and any("XMP" in q for q in meta.problems)


def test_an_attitude_tag_beyond_one_turn_is_dropped_not_taken_as_a_heading(tmp_path, caplog):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        meta = _meta(img / f"f{k}.jpg", latitude=47.0 + k * 1e-4, longitude=8.0, altitude=480.0,
                     datetime_original=f"2024:06:01 10:00:{2 * k:02d}", subsec_original="",
                     xmp={"GimbalYawDegree": "+45.00", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0"})
        data = embed_metadata(_jpeg(k), meta)
        if k == 2:  # the writer refuses such a tag, so damage the file as a faulty firmware would
            data = data.replace(b'"+45.00"', b'"1e+308"')
        (img / f"f{k}.jpg").write_bytes(data)
    damaged = read_image_metadata(img / "f2.jpg")
    assert "GimbalYawDegree" not in damaged.xmp
    assert any("GimbalYawDegree 1e+308 is not an angle" in q for q in damaged.problems)
    with pytest.raises(ValueError, match="not an angle"):
        embed_metadata(_jpeg(), _meta(tmp_path / "x.jpg", xmp={"GimbalYawDegree": "720.5"}))
    priors = read_image_priors(img)
    assert priors.summary["attitude_sources"]["XMP GimbalYaw/Pitch/RollDegree"] == 3
    assert "f2.jpg" in priors.summary["damaged_metadata"] and "f2.jpg: XMP GimbalYawDegree" in caplog.text


@pytest.mark.parametrize("damage, said", [
    (b'"abc   "', "GimbalPitchDegree abc is not an angle"),  # was left out without a word
    (b'"+87.90"', "GimbalPitchDegree +87.9 puts the camera above the horizon"),  # was taken without a word
    (b'"nan   "', "GimbalPitchDegree nan is not an angle"),
])
def test_every_dropped_or_implausible_gimbal_pitch_is_named_the_same_way(tmp_path, caplog, damage, said):
    """nu59 D3: of three damaged pitch tags only the NaN was named; a non-number fell back to the airframe's
    angles silently and a camera looking at the sky was taken. One test now names each, image and tag."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        meta = _meta(img / f"f{k}.jpg", latitude=47.0 + k * 1e-4, longitude=8.0, altitude=480.0,
                     datetime_original=f"2024:06:01 10:00:{2 * k:02d}", subsec_original="",
                     xmp={"GimbalYawDegree": "0", "GimbalPitchDegree": "-87.90", "GimbalRollDegree": "0",
                          "FlightYawDegree": "0", "FlightPitchDegree": "0", "FlightRollDegree": "0"})
        data = embed_metadata(_jpeg(k), meta)
        if k == 2:  # the writer refuses these, so damage the file in place as a faulty firmware would
            data = data.replace(b'"-87.90"', damage)
        (img / f"f{k}.jpg").write_bytes(data)
    assert "GimbalPitchDegree" not in read_image_metadata(img / "f2.jpg").xmp
    with caplog.at_level(logging.WARNING):
        priors = read_image_priors(img)
    assert f"f2.jpg: XMP {said}" in caplog.text
    assert any(said in q for q in priors.summary["damaged_metadata"]["f2.jpg"])
    with pytest.raises(ValueError, match="above the horizon"):
        embed_metadata(_jpeg(), _meta(tmp_path / "x.jpg", xmp={"GimbalPitchDegree": "45"}))


def test_35mm_equivalent_refers_to_the_full_sensor_frame():
    # DJI 16:9 stills are the full-width band of a 4:3 sensor: the 4:3 diagonal, not the 16:9 one
    assert full_frame_diagonal_px(4000, 2250) == pytest.approx(5000.0)
    assert full_frame_diagonal_px(4000, 3000) == pytest.approx(5000.0)
    assert full_frame_diagonal_px(6000, 4000) == pytest.approx(math.hypot(6000, 4000))  # a 3:2 sensor
    assert full_frame_diagonal_px(2250, 4000) == pytest.approx(5000.0)  # portrait
    meta = _meta("x.jpg", width=4000, height=2250, focal_mm=None, focal_35mm=24.0)
    cam, source = pfe.camera_from_metadata(meta)
    assert cam.fx == pytest.approx(24.0 / math.hypot(36, 24) * 5000.0) and "full-frame" in source


def test_heights_from_relative_altitude_and_drift_against_it(tmp_path, caplog):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(12):
        # level flight 80 m above take-off (ground at 400 m); the GPS altitude drifts by 3 m per image
        meta = _meta(img / f"f{k:02d}.jpg", latitude=47.0 + k * 1e-4, longitude=8.0, altitude=480.0 + 3.0 * k,
                     datetime_original=f"2024:06:01 10:00:{2 * k:02d}", subsec_original="",
                     xmp={"GimbalYawDegree": "0", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0",
                          "RelativeAltitude": "+80.00"})
        (img / f"f{k:02d}.jpg").write_bytes(embed_metadata(_jpeg(k), meta))
    priors = read_image_priors(img)
    np.testing.assert_allclose(priors.positions[:, 2], 480.0, atol=1e-6)
    assert "RelativeAltitude" in priors.summary["altitude_source"]
    assert priors.summary["gps_altitude_vs_relative_altitude"]["change_over_flight"] == pytest.approx(33.0)
    assert "drift apart by +33.0 m" in caplog.text  # which of the two moves, only the block can tell
    given = read_image_priors(img, takeoff_altitude_m=100.0)
    np.testing.assert_allclose(given.positions[:, 2], 180.0)


@pytest.mark.parametrize("end", [False, True])
def test_one_damaged_relative_altitude_is_named_and_replaced_not_a_camera_10_km_down(tmp_path, caplog, end):
    """nu59 D4: RelativeAltitude -9999 in one image put its camera at z -9581 m, exit 0, and the only warning blamed
    the GPS ("jumps 2 times ... wrong fixes"). The barometric value is now judged against its neighbours and the
    GPS altitude, named, and replaced by its neighbours'; a climb the GPS follows is no damage."""
    img = tmp_path / "images"
    img.mkdir()
    bad = 11 if end else 5
    for k in range(12):
        climb = 45.0 if k == 8 else 0.0  # one image 45 m higher: the GPS says so too, no damage
        rel = -9999.0 if k == bad else 80.0 + climb
        meta = _meta(img / f"f{k:02d}.jpg", latitude=47.0 + k * 1e-4, longitude=8.0, altitude=480.0 + climb,
                     datetime_original=f"2024:06:01 10:00:{2 * k:02d}", subsec_original="",
                     xmp={"GimbalYawDegree": "0", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0",
                          "RelativeAltitude": f"{rel:+.2f}"})
        (img / f"f{k:02d}.jpg").write_bytes(embed_metadata(_jpeg(k), meta))
    with caplog.at_level(logging.WARNING):
        priors = read_image_priors(img)
    expected = np.where(np.arange(12) == 8, 525.0, 480.0)
    np.testing.assert_allclose(priors.positions[:, 2], expected, atol=1e-6)
    assert "RelativeAltitude" in priors.summary["altitude_source"]
    rel_said = [r.getMessage() for r in caplog.records if "RelativeAltitude (barometric) far off" in r.getMessage()]
    assert len(rel_said) == 1 and f"f{bad:02d}.jpg (-9999 m against 80, 80 m)" in rel_said[0]
    assert "f08.jpg" not in rel_said[0]  # (the 45 m climb in 2 s is the track check's to name, GPS and all)
    assert not any(f"f{bad:02d}.jpg" in r.getMessage() for r in caplog.records if "GPS jumps" in r.getMessage())
    assert any(f"f{bad:02d}.jpg" in w for w in priors.summary["warnings"])
    given = read_image_priors(img, takeoff_altitude_m=400.0)  # the take-off altitude given: the same value taken
    np.testing.assert_allclose(given.positions[:, 2], expected, atol=1e-6)



def test_a_damaged_relative_altitude_of_interleaved_flights_takes_its_own_neighbours():
    """rev59 D2: two flights whose capture times interleave are ordered one after the other, so the times are not
    increasing; interpolating in them over all images gave the damaged image the other flight's value (100 m)."""
    from sosmatch.workflows.prior_heights import relative_altitude_spikes

    rel = np.array([100.0, 100.0, 100.0, 100.0, 60.0, -9999.0, 60.0, 60.0])
    times = np.array([0.0, 2.0, 4.0, 6.0, 1.0, 3.0, 5.0, 7.0])
    fixed, said = relative_altitude_spikes(rel, np.full(8, 500.0), times, [f"f{k}" for k in range(8)])
    assert said is not None and "f5" in said
    np.testing.assert_allclose(fixed, [100, 100, 100, 100, 60, 60, 60, 60])

@pytest.mark.parametrize("home_step", [15.0, 0.0])
def test_two_batteries_from_two_home_points_take_their_own_take_off_altitude(tmp_path, caplog, home_step):
    """The nu20 sweep: a folder of two batteries, the second taken off from ground 15 m higher (its
    RelativeAltitude 15 m lower at the same GPS altitude). One line through both read the step as a GPS drift
    (+16 m) and put the second flight's cameras 15 m low; the map said "ok". Each flight now has its own take-off
    altitude; two flights from one home point keep one (the receiver's wander is no second home)."""
    img = tmp_path / "images"
    img.mkdir()
    rng = np.random.default_rng(3)
    for battery in range(2):
        for k in range(12):
            name = f"b{battery}_{k:02d}.jpg"
            # 80 m above the first home (ground at 400 m); GPS altitude noise 1 m; the second battery 30 min later
            meta = _meta(img / name, latitude=47.0 + k * 1e-4, longitude=8.0 + battery * 1e-4,
                         altitude=480.0 + rng.normal(0.0, 1.0),
                         datetime_original=f"2024:06:01 10:{30 * battery:02d}:{2 * k:02d}", subsec_original="",
                         xmp={"GimbalYawDegree": "0", "GimbalPitchDegree": "-90", "GimbalRollDegree": "0",
                              "RelativeAltitude": f"{80.0 - battery * home_step:+.2f}"})
            (img / name).write_bytes(embed_metadata(_jpeg(k), meta))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        priors = read_image_priors(img)
    heights = priors.positions[:, 2]
    np.testing.assert_allclose(heights, 480.0, atol=1.5)  # both flights at their true heights
    flights = priors.summary["flights"]
    if home_step:
        assert [f["first_image"] for f in flights] == ["b0_00.jpg", "b1_00.jpg"]
        assert [f["images"] for f in flights] == [12, 12]
        assert flights[1]["takeoff_altitude_m"] - flights[0]["takeoff_altitude_m"] == pytest.approx(15.0, abs=1.5)
        assert "2 flights whose take-off altitudes differ" in caplog.text
        assert "drifts" not in caplog.text
    else:
        assert flights is None and "flights" not in caplog.text


def test_a_camera_clock_reset_is_named(tmp_path, caplog):
    """The nu20 sweep: the second half of a folder dated 2000-01-01 (a clock reset) reordered the flight with an
    INFO line only."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(8):
        stamp = f"2024:06:01 10:00:{2 * k:02d}" if k < 4 else f"2000:01:01 00:00:{2 * k:02d}"
        meta = _meta(img / f"f{k:02d}.jpg", latitude=47.0 + k * 1e-4, longitude=8.0, datetime_original=stamp,
                     subsec_original="")
        (img / f"f{k:02d}.jpg").write_bytes(embed_metadata(_jpeg(k), meta))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        read_image_priors(img)
    assert "jump back by 8918.4 days from f03.jpg to f04.jpg (a camera clock reset?)" in caplog.text


def test_dji_xmp_position_is_read_where_the_exif_gps_was_stripped(tmp_path, caplog):
    """nu58 D3: DJI images whose EXIF GPS an editor stripped still carry drone-dji:GpsLatitude/GpsLongitude
    (some firmware: "GpsLongtitude") and AbsoluteAltitude; they were called "no GPS position" and `poses` built
    an ungeoreferenced frame. Where both exist and part by more than a few metres, it is said."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(6):
        lon_tag = "GpsLongtitude" if k == 5 else "GpsLongitude"
        meta = _meta(img / f"f{k:02d}.jpg", latitude=None, longitude=None, altitude=None,
                     datetime_original=f"2024:06:01 10:00:{2 * k:02d}", subsec_original="",
                     xmp={"GpsLatitude": f"{47.0 + k * 1e-4:+.10f}", lon_tag: "-8.5000000000",
                          "AbsoluteAltitude": "+512.300", "RelativeAltitude": "+80.10", "GimbalYawDegree": "0",
                          "GimbalPitchDegree": "-90", "GimbalRollDegree": "0"})
        (img / f"f{k:02d}.jpg").write_bytes(embed_metadata(_jpeg(k), meta))
    back = read_image_metadata(img / "f05.jpg")
    assert (back.latitude, back.longitude, back.altitude) == (pytest.approx(47.0005), -8.5, 512.3)
    assert back.sources["position"] == "XMP drone-dji:GpsLatitude/GpsLongitude"
    priors = read_image_priors(img)
    assert priors.summary["position_sources"] == {"XMP drone-dji:GpsLatitude/GpsLongitude": 6}
    assert priors.summary["crs"] == "EPSG:32629" and np.isfinite(priors.positions).all()
    # the EXIF GPS is kept where both are; 30 m between them is named
    meta = _meta(img / "f00.jpg", latitude=47.0, longitude=-8.5 + 4e-4, altitude=512.3,
                 datetime_original="2024:06:01 10:00:00", subsec_original="",
                 xmp={"GpsLatitude": "+47.0", "GpsLongitude": "-8.5", "GimbalYawDegree": "0",
                      "GimbalPitchDegree": "-90", "GimbalRollDegree": "0"})
    (img / "f00.jpg").write_bytes(embed_metadata(_jpeg(0), meta))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        priors = read_image_priors(img)
    assert priors.summary["position_sources"] == {"EXIF GPS": 1, "XMP drone-dji:GpsLatitude/GpsLongitude": 5}
    assert "1 of 1 images hold a DJI XMP position" in caplog.text and "(up to 30.4 m, f00.jpg)" in caplog.text
    assert any("hold a DJI XMP position" in w for w in priors.summary["warnings"])
    # where a telemetry file's row gives the position, the XMP is not held against it as "EXIF GPS"
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,GPSLatitude,GPSLongitude,GPSAltitude\nf00.jpg,47.0,-8.4996,512.3\n")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        priors = read_image_priors(img, telemetry=tele)
    assert "DJI XMP position" not in caplog.text


def test_mixed_cameras_are_grouped_and_gps_is_optional(tmp_path):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        (img / f"a{k}.jpg").write_bytes(embed_metadata(_jpeg(k), _meta(img / f"a{k}.jpg")))
        other = _meta(img / f"b{k}.jpg", width=80, height=60, model="Other", latitude=None, longitude=None)
        (img / f"b{k}.jpg").write_bytes(embed_metadata(_jpeg(k, (80, 60)), other))
    priors = read_image_priors(img)
    assert len(priors.cameras) == 2 and priors.camera_index.tolist() == [0, 0, 0, 1, 1, 1]
    assert priors.has_gps.tolist() == [True] * 3 + [False] * 3
    assert [c["images"] for c in priors.summary["cameras"]] == [3, 3]


def test_synth_geotags_match_the_truth(tmp_path, capsys):
    out = tmp_path / "S"
    assert main(["synth", "--out", str(out), "--frames", "30", "--width", "160", "--height", "120",
                 "--geotags", "dji", "--yaw-fault-lines", "1", "--gps-altitude-drift", "20",
                 "--world-size", "400"]) == 0
    capsys.readouterr()
    session = json.loads((out / "session.json").read_text())
    offset = np.array(session["geo"]["world_to_crs_offset"])
    lines = np.array(session["geo"]["flight_lines"])
    truth, _ = read_poses_csv(out / "poses.csv")
    exif = pfe.poses_from_images(out / "images")
    assert exif.epsg == session["geo"]["epsg"]
    err = exif.poses.centers - (truth.centers + offset)
    assert np.abs(err[:, :2]).max() < 5.0 and np.std(err[:, :2]) < 2.0  # 1 m GPS noise
    assert np.abs(err[:, 2]).max() < 1.0  # heights from RelativeAltitude: the GPS drift is not in them
    angle = rotation_angle_deg(exif.poses.rotations, truth.rotations)
    assert np.all(angle[lines == 1] > 175.0) and np.all(angle[lines != 1] < 5.0)
    assert exif.camera.fx == pytest.approx(truth_fx := 80.0 / math.tan(math.radians(32.5)), rel=0.03), truth_fx


def test_images_without_attitude_tags_get_orientations_from_the_images_not_the_course(tmp_path, capsys, caplog):
    """EXIF GPS only (no attitude tags): the course over ground is a guess for the heading, tens of degrees off
    at the line turns. `map --pose-source exif` (and poses-from-exif) solve the orientations from tie points with
    the GPS positions as priors instead of mapping on the guess."""
    out = tmp_path / "S"
    assert main(["synth", "--out", str(out), "--frames", "24", "--width", "320", "--height", "240",
                 "--line-length", "56", "--geotags", "exif", "--world-size", "400", "--world-seed", "5"]) == 0
    capsys.readouterr()
    lines = np.array(json.loads((out / "session.json").read_text())["geo"]["flight_lines"])
    truth, _ = read_poses_csv(out / "poses.csv")
    priors = read_image_priors(out / "images")
    assert priors.summary["images_without_attitude"] == 24
    at_turns = priors.summary["images_at_turns_without_attitude"]
    assert 0 < at_turns <= np.sum(lines == -1) + 4  # the corners of the turns, not the straight lines
    guess = rotation_angle_deg(priors.rotations, truth.rotations)
    assert guess.max() > 20.0  # the course at a corner: the mean of the line's and the turn's directions

    from sosmatch.workflows.poses_from_exif import map_inputs_from_images

    caplog.clear()
    with caplog.at_level(logging.INFO):
        inputs = map_inputs_from_images(out / "images")
    # one warning about the missing attitude, and it says what is done (no second one calling the course the pose;
    # the vertical's rule, `nadir_tilt_warning`, may add its own: these lines flown one after the other leave the
    # tilt across them to the nadir assumption once the GPS altitude may drift, as `sosmatch poses` says too)
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING and "attitude" in r.getMessage()
            and "GPS heights fix the tilt" not in r.getMessage()]
    assert len(said) == 1 and "solved from the images" in said[0], said
    solved = rotation_angle_deg(inputs.poses.rotations, truth.rotations)
    print(f"course headings {np.median(guess):.1f} / {guess.max():.1f} deg -> solved {np.median(solved):.2f} / "
          f"{solved.max():.2f} deg (median / max)")
    assert solved.max() < 5.0 and np.median(solved) < 0.5 * np.median(guess)
    assert "orientations of the 24 images without attitude tags solved from tie points" in inputs.sources["poses"]


def test_a_single_straight_line_without_attitude_tags_keeps_its_cameras_looking_down(tmp_path):
    """One straight line of GPS fixes leaves the block's roll about the line free: position priors cannot tell a
    camera looking down from one looking sideways with the whole block turned about the line. The COLMAP
    adjustment came back rolled by 89.5 deg and the refinement was refused (a corridor survey could not be mapped
    from its EXIF); the prior attitudes (level, nadir) now set that one rotation, and that is said as `sosmatch
    poses` says it (`georegistration.nadir_tilt_warning`; fix139: it was silent), in the map's warnings too."""
    out = tmp_path / "S"
    assert main(["synth", "--out", str(out), "--frames", "30", "--width", "320", "--height", "240",
                 "--line-length", "300", "--geotags", "exif", "--world-size", "400", "--world-seed", "5", "-q"]) == 0
    lines = np.array(json.loads((out / "session.json").read_text())["geo"]["flight_lines"])
    assert len(set(lines[lines >= 0].tolist())) == 1  # one line, no turn

    from sosmatch.workflows.poses_from_exif import map_inputs_from_images

    inputs = map_inputs_from_images(out / "images")
    truth, _ = read_poses_csv(out / "poses.csv")
    solved = rotation_angle_deg(inputs.poses.rotations, truth.rotations)
    assert solved.max() < 5.0, solved
    assert any("long axis" in w and "rests on the camera looking straight down" in w for w in inputs.warnings)


def _turned_copy(src, dst) -> None:
    """The images of `src` with their pixels turned by 90 degrees clockwise (a camera mounted sideways, a portrait
    export) and their EXIF kept as written (GPS, no attitude tags)."""
    from sosmatch.database.images import image_files

    dst.mkdir()
    for p in image_files(src):
        turned = cv2.rotate(cv2.imread(str(p), cv2.IMREAD_COLOR), cv2.ROTATE_90_CLOCKWISE)
        ok, buf = cv2.imencode(".jpg", turned, [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        (dst / p.name).write_bytes(embed_metadata(buf.tobytes(), read_image_metadata(p)))


def test_images_turned_by_90_degrees_without_attitude_tags_get_their_headings_from_the_image_motion(
        tmp_path, capsys, caplog):
    """Pixels turned by 90 degrees and no attitude tags: the course over ground puts the image top forward, 90
    degrees off, and a refinement from tie points does not turn a camera that far (it ended 90 deg off with
    warnings, exit 0). The direction of motion the image pairs show, against the GPS track, gives the heading;
    and a refinement started 90 degrees off explains too few of the images' tie points to pass its judgement."""
    from sosmatch.workflows.pose_refinement import RefinementRejected, refine_poses_from_images
    from sosmatch.workflows.poses_from_exif import _image_paths, map_inputs_from_images, poses_from_images

    out = tmp_path / "S"  # frames 30 m apart as a survey flies them (Seneca: 24-30 m at 70 m above ground)
    assert main(["synth", "--out", str(out), "--frames", "24", "--width", "320", "--height", "240", "--spacing", "30",
                 "--line-length", "150", "--geotags", "exif", "--world-size", "400", "--world-seed", "5"]) == 0
    capsys.readouterr()
    truth, _ = read_poses_csv(out / "poses.csv")
    turned = tmp_path / "turned"
    _turned_copy(out / "images", turned)
    # camera axes after the turn: x' = -y, y' = x (the old image top is the new right)
    truth_turned = truth.rotations @ np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

    course = poses_from_images(turned)
    assert np.median(rotation_angle_deg(course.poses.rotations, truth_turned)) > 60.0  # the guess is 90 deg off
    # the check measures what the images show: started on the course, the refinement is refused
    # the check measures what the images show: started on the course, the refinement leaves cameras turned
    # against their own tie points, and is refused (it was accepted with warnings, some cameras 179 deg off)
    with pytest.raises(RefinementRejected, match="explain less than half of their own tie points"):
        refine_poses_from_images(_image_paths(turned, course.poses), course.poses, course.camera)

    with caplog.at_level(logging.INFO):
        inputs = map_inputs_from_images(turned)
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "from the image motion: turned" in said
    solved = rotation_angle_deg(inputs.poses.rotations, truth_turned[[truth.names.index(n) for n in
                                                                      inputs.poses.names]])
    print(f"turned images: course {np.median(rotation_angle_deg(course.poses.rotations, truth_turned)):.1f} deg "
          f"-> solved {np.median(solved):.2f} / {solved.max():.2f} deg (median / max)")
    assert solved.max() < 5.0


def test_map_images_reads_each_file_metadata_once(tmp_path, capsys, monkeypatch):
    """`map --images` without poses: the images' EXIF is read once per file (`read_image_priors`); putting the
    frames in flight order takes the capture times from there instead of reading every file again."""
    import sosmatch.database.exif as exif_module
    import sosmatch.workflows.image_priors as priors_module
    from sosmatch.workflows.poses_from_exif import map_inputs_from_images

    out = tmp_path / "S"
    assert main(["synth", "--out", str(out), "--frames", "12", "--width", "320", "--height", "240",
                 "--geotags", "dji", "--world-size", "400", "--world-seed", "5", "-q"]) == 0
    capsys.readouterr()
    reads: list[str] = []

    def counted(path, *args, **kwargs):
        reads.append(Path(path).name)
        return read_image_metadata(path, *args, **kwargs)

    monkeypatch.setattr(exif_module, "read_image_metadata", counted)
    monkeypatch.setattr(priors_module, "read_image_metadata", counted)
    inputs = map_inputs_from_images(out / "images")
    assert len(inputs.poses) == 12
    assert sorted(reads) == sorted(set(reads)) and len(reads) == 12


def test_a_camera_whose_focal_length_the_exif_contradicts_is_named(tmp_path, capsys, caplog):
    """The thirteenth sweep: cameras.txt with the focal length 15-30 % off (a 35 mm-equivalent taken for the real
    one) mapped with exit 0, every landmark 15-30 m above or below the ground, while the images' EXIF said
    otherwise. `map` compares them."""
    from sosmatch.workflows.map.inputs import load_inputs

    out = tmp_path / "S"
    assert main(["synth", "--out", str(out), "--frames", "4", "--width", "160", "--height", "120",
                 "--geotags", "exif", "--world-size", "400", "-q"]) == 0
    capsys.readouterr()
    with caplog.at_level("WARNING"):
        load_inputs(out / "images", out / "poses.csv", out / "cameras.txt")
    assert "EXIF" not in caplog.text
    cam = read_cameras_txt(out / "cameras.txt")[1]
    wrong = tmp_path / "cameras.txt"
    write_cameras_txt(wrong, {1: dataclasses.replace(cam, fx=cam.fx * 0.8, fy=cam.fy * 0.8)})
    with caplog.at_level("WARNING"):
        inputs = load_inputs(out / "images", out / "poses.csv", wrong)
    assert f"{wrong}: its focal length" in caplog.text and "-20 % off the one the images' EXIF gives" in caplog.text
    # nu45: it was only logged; the map's verdict (run.json, a batch's report) is built from the inputs' warnings
    assert any("-20 % off the one the images' EXIF gives" in w for w in inputs.warnings)


def test_capture_times_in_the_variants_software_writes():
    """nu41: DateTimeOriginal "2026-05-02 10:00:00" (dashes) gave no time at all, and OffsetTimeOriginal was never
    read: the camera clock's zone, to order flights of cameras set to different zones."""
    from sosmatch.database.exif import ImageMetadata

    def meta(stamp, offset=""):
        return ImageMetadata("x.jpg", 8, 8, datetime_original=stamp, offset_time=offset)

    ten = 1777716000.0  # 2026-05-02 10:00:00
    for stamp in ("2026:05:02 10:00:00", "2026-05-02 10:00:00", "2026/05/02 10:00:00", "2026-05-02T10:00:00",
                  "2026:05:02 10:00"):
        assert meta(stamp).capture_time_s == pytest.approx(ten), stamp
    assert meta("2026-05-02T10:00:00.25").capture_time_s == pytest.approx(ten + 0.25)
    for stamp in ("", "0000:00:00 00:00:00", "2026:13:02 10:00:00", "2026:02:30 10:00:00", "    :  :     :  :  "):
        assert meta(stamp).capture_time_s is None, stamp
    assert meta("2026:05:02 10:00:00").capture_time_utc is None  # no zone said
    assert meta("2026:05:02 19:00:00", "+09:00").capture_time_utc == (pytest.approx(ten), "DateTimeOriginal + its zone")
    assert meta("2026:05:02 04:30:00", "-0530").capture_time_utc[0] == pytest.approx(ten)
    assert meta("2026-05-02T12:00:00+02:00").capture_time_utc[0] == pytest.approx(ten)
    assert meta("2026-05-02T10:00:00Z").capture_time_utc[0] == pytest.approx(ten)
    assert meta("2026:05:02 10:00:00", "   :  ").capture_time_utc is None  # a blank offset says nothing


def test_a_yaw_fault_on_a_line_the_flight_does_not_have_is_refused(tmp_path, cli_error):
    """nu45: `--yaw-fault-lines 99` on a one-line flight rendered a session without any fault, exit 0: a test of
    `sosmatch poses` on it passed for want of a fault. Refused before the scene is built, nothing written."""
    err = cli_error("synth", "--out", tmp_path / "S", "--frames", "3", "--width", "64", "--height", "48",
                    "--world-size", "400", "--geotags", "dji", "--yaw-fault-lines", "0,99")
    assert "--yaw-fault-lines 99: the flight has no such line" in err and "flight line(s): 0)" in err
    assert not (tmp_path / "S").exists()


def test_the_same_place_flown_a_day_later_in_one_folder_is_two_flights_not_a_clock_reset(tmp_path, caplog):
    """nu58 D6: a folder holding the flight and its repeat the next day (the repeat's files named B_*, so listed
    first) was warned of as "a camera clock reset?" with "fix the dates". The time order is right there: it is two
    flights of one place, which are named, with how to map them apart. (A clock reset mid-flight, whose later
    frames carry on over new ground, keeps its wording: `test_a_camera_clock_reset_is_named`.) rev56 D3: the same
    folder with the repeat named so that it is listed last (times in the listed order) said nothing and was
    mapped as one flight: the warning is the same whatever the names."""
    for first, prefix in (("f00.jpg", "B_"), ("f00.jpg", "z_")):
        img = tmp_path / prefix / "images"
        img.mkdir(parents=True)
        for day, pre in ((1, ""), (2, prefix)):
            for k in range(6):
                meta = _meta(img / f"{pre}f{k:02d}.jpg", latitude=47.0 + k * 1e-4 + day * 1e-6, longitude=8.0,
                             datetime_original=f"2024:06:0{day} 10:00:{2 * k:02d}", subsec_original="")
                (img / f"{pre}f{k:02d}.jpg").write_bytes(embed_metadata(_jpeg(k), meta))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
            priors = read_image_priors(img)
        assert "clock reset" not in caplog.text and "fix the dates" not in caplog.text
        assert ("the folder holds 2 flights of one place (2024-06-01 10:00, 2024-06-02 10:00, camera clock; 6 + 6 "
                f"images, e.g. {first} and {prefix}f00.jpg)") in caplog.text, prefix
        assert "put each flight in its own folder" in caplog.text
        assert [p.name for p in priors.paths[:2]] == ["f00.jpg", "f01.jpg"]  # ordered by capture time, as before
    # one flight with a pause of hours that goes on over new ground: no flights of one place
    from sosmatch.workflows.image_positions import flights_of_one_place

    xy = np.c_[np.arange(20) * 10.0, np.zeros(20)]
    t = np.r_[np.arange(10) * 2.0, np.arange(10) * 2.0 + 7200.0]
    assert flights_of_one_place(t, xy, [f"f{k}" for k in range(20)]) is None
    assert flights_of_one_place(t, np.r_[xy[:10], xy[:10]], [f"f{k}" for k in range(20)]) is not None
