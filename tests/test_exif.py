"""EXIF GPS + XMP attitude -> poses and intrinsics, on small JPEGs written here (no shared data)."""

from __future__ import annotations

import io
import json
import logging
import math
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from sosmatch.database.cameras import read_cameras_txt
from sosmatch.database.exif import read_image_metadata
from sosmatch.database.poses import read_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.gps_track import frozen_fix, gps_jumps, off_nadir_deg
from sosmatch.plugin.params import Params
from sosmatch.tools.cli import main
from sosmatch.workflows import poses_from_exif as pfe
from sosmatch.workflows.image_positions import doubtful_fixes
from sosmatch.workflows.image_priors import read_image_priors


def _dms(deg: float) -> tuple:
    deg = abs(deg)
    d = int(deg)
    m = int((deg - d) * 60)
    s = (deg - d - m / 60) * 3600
    return (IFDRational(d, 1), IFDRational(m, 1), IFDRational(round(s * 10000), 10000))


def write_jpeg(path: Path, lat: float | None, lon: float | None, alt: float = 300.0, xmp: dict | None = None,
               size: tuple = (400, 300), focal: float = 4.3, fp_res: float = 16393.44, exif_size: tuple = (4000, 3000),
               xmp_as_elements: bool = False, when: str | None = None, orientation: int | None = None) -> None:
    rng = np.random.default_rng(zlib.crc32(path.name.encode()))  # different content per file name
    img = Image.fromarray(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    exif = Image.Exif()
    exif[0x010F] = "TestMake"
    exif[0x0110] = "TestMake Cam"
    if orientation is not None:
        exif[0x0112] = orientation
    sub = exif.get_ifd(0x8769)
    sub[0x920A] = IFDRational(round(focal * 100), 100)
    sub[0xA20E] = IFDRational(round(fp_res * 100), 100)
    sub[0xA20F] = IFDRational(round(fp_res * 100), 100)
    sub[0xA210] = 2
    sub[0xA002], sub[0xA003] = exif_size
    if when is not None:
        sub[0x9003] = when  # DateTimeOriginal
    if lat is not None:
        gps = exif.get_ifd(0x8825)
        gps[1] = "N" if lat >= 0 else "S"
        gps[2] = _dms(lat)
        gps[3] = "E" if lon >= 0 else "W"
        gps[4] = _dms(lon)
        gps[5] = 0
        gps[6] = IFDRational(round(alt * 1000), 1000)
    buf = io.BytesIO()
    img.save(buf, "JPEG", exif=exif.tobytes(), quality=80)
    data = buf.getvalue()
    if xmp:
        if xmp_as_elements:
            body = "".join(f"<drone-dji:{k}>{v}</drone-dji:{k}>" for k, v in xmp.items())
            desc = f"<rdf:Description rdf:about='' xmlns:drone-dji='http://www.dji.com/drone-dji/1.0/'>{body}"
            desc += "</rdf:Description>"
        else:
            attrs = " ".join(f'Camera:{k}="{v}"' for k, v in xmp.items())
            desc = f"<rdf:Description rdf:about='' xmlns:Camera='http://pix4d.com/camera/1.0/' {attrs}/>"
        packet = ("<?xpacket begin='' id='W5M0MpCehiHzreSzNTczkc9d'?><x:xmpmeta xmlns:x='adobe:ns:meta/'>"
                  "<rdf:RDF xmlns:rdf='http://www.w3.org/1999/02/22-rdf-syntax-ns#'>" + desc +
                  "</rdf:RDF></x:xmpmeta><?xpacket end='w'?>").encode()
        payload = b"http://ns.adobe.com/xap/1.0/\x00" + packet
        seg = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
        data = data[:2] + seg + data[2:]
    path.write_bytes(data)


def test_metadata_gps_focal_and_xmp(tmp_path):
    p = tmp_path / "a.jpg"
    write_jpeg(p, 41.0346708, -83.3057253, 281.69, {"Heading": "70.5", "PitchAngle": "2.5", "RollAngle": "-3.0"})
    m = read_image_metadata(p)
    assert m.latitude == pytest.approx(41.0346708, abs=1e-7)
    assert m.longitude == pytest.approx(-83.3057253, abs=1e-7)
    assert m.altitude == pytest.approx(281.69, abs=1e-3)
    assert m.focal_mm == pytest.approx(4.3)
    assert m.exif_size == (4000, 3000)
    assert m.focal_plane_px_per_mm[0] == pytest.approx(16393.44 / 25.4)
    assert m.xmp_float("Heading") == (70.5, "Heading")
    assert m.xmp_float("RollAngle")[0] == -3.0


def test_intrinsics_scaled_to_file_size(tmp_path):
    p = tmp_path / "a.jpg"
    write_jpeg(p, 41.0, -83.0, size=(400, 300))
    cam, source = pfe.camera_from_metadata(read_image_metadata(p))
    # 4.3 mm on a 4000 px / (16393.44 px/inch) = 6.198 mm sensor, file 400 px wide.
    assert cam.fx == pytest.approx(4.3 / (4000 / 16393.44 * 25.4) * 400, rel=1e-4)
    assert (cam.cx, cam.cy) == (200.0, 150.0)
    assert "FocalPlane" in source


def test_intrinsics_of_a_frame_turned_to_portrait_keep_the_sensor_focal_length(tmp_path):
    """A 4:3 readout turned by 90 degrees by software (300x400 file, EXIF still 4000x3000): the file's width is the
    readout's height, so the focal length in pixels is that of the landscape file (the old code scaled by
    300 / 4000 and gave 0.75 of it, with a warning about a crop)."""
    landscape, portrait = tmp_path / "l.jpg", tmp_path / "p.jpg"
    write_jpeg(landscape, 41.0, -83.0, size=(400, 300))
    write_jpeg(portrait, 41.0, -83.0, size=(300, 400))
    cam_l, _ = pfe.camera_from_metadata(read_image_metadata(landscape))
    cam_p, source = pfe.camera_from_metadata(read_image_metadata(portrait))
    assert (cam_p.width, cam_p.height, cam_p.cx, cam_p.cy) == (300, 400, 150.0, 200.0)
    assert cam_p.fx == pytest.approx(cam_l.fx, rel=1e-9) and cam_p.fy == pytest.approx(cam_l.fy, rel=1e-9)
    assert "turned by 90 degrees" in source


def test_a_focal_plane_resolution_of_another_readout_is_refused_not_taken(tmp_path):
    """nu16: frames downscaled after the camera wrote its EXIF, whose ExifImageWidth was dropped or rewritten to
    the new size, were taken as the readout: Seneca's 1200 px frames got fx 2775 px for 833, and a map 30-140 m
    too low passed as ok. A focal plane resolution that puts the image on a sensor narrower than any survey
    camera's is refused naming the cause; a 35 mm equivalent focal length stands in when there is one."""
    from sosmatch.workflows.image_cameras import MIN_SENSOR_WIDTH_MM

    stale = tmp_path / "stale.jpg"
    write_jpeg(stale, 41.0, -83.0, size=(400, 300), exif_size=(400, 300))  # 400 px at 645 px/mm: a 0.62 mm sensor
    with pytest.raises(InputError, match=r"on a 0.62 mm sensor, narrower than any survey camera's: the image was "
                                         r"downscaled .*ExifImageWidth rewritten; .*\): give the sensor width"):
        pfe.camera_from_metadata(read_image_metadata(stale))
    assert 400 / (16393.44 / 25.4) < MIN_SENSOR_WIDTH_MM < 4000 / (16393.44 / 25.4)
    cam, _ = pfe.camera_from_metadata(read_image_metadata(stale), sensor_width_mm=6.2)
    assert cam.fx == pytest.approx(4.3 / 6.2 * 400)
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        write_jpeg(img / f"s{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0, exif_size=(400, 300))
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p.csv")]) == 2
    assert not (tmp_path / "p.csv").exists()


def test_digital_zoom_multiplies_the_focal_length_and_makes_another_camera(tmp_path, capsys):
    """nu16: EXIF DigitalZoomRatio was ignored: frames zoomed x2 in the camera got half their focal length, and a
    folder of zoomed and unzoomed frames one camera. The ratio multiplies fx, and zoomed frames are another
    camera: `poses-from-exif`, which writes one camera, refuses the mix naming both focal lengths."""
    img = tmp_path / "images"
    img.mkdir()
    write_jpeg(img / "a.jpg", 47.0, -99.0, 500.0, {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"})
    write_jpeg(img / "b.jpg", 47.0, -99.0 + 1e-4, 500.0, {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"})
    plain = read_image_metadata(img / "a.jpg")
    with Image.open(img / "b.jpg") as im:  # the same frame, zoomed x2 in the camera
        exif = im.getexif()
        exif.get_ifd(0x8769)[0xA404] = IFDRational(2, 1)
        im.save(img / "b.jpg", exif=exif.tobytes(), quality=80)
    zoomed = read_image_metadata(img / "b.jpg")
    assert zoomed.digital_zoom == 2.0 and plain.digital_zoom is None
    assert zoomed.camera_key != plain.camera_key
    cam_plain, _ = pfe.camera_from_metadata(plain)
    cam_zoomed, source = pfe.camera_from_metadata(zoomed)
    assert cam_zoomed.fx == pytest.approx(2.0 * cam_plain.fx) and "x2 digital zoom" in source
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p.csv")]) == 2
    assert "2 cameras of different focal lengths" in capsys.readouterr().err


def test_images_lacking_a_focal_length_take_their_cameras(tmp_path, caplog):
    """nu16: one image of a camera without FocalLength refused the whole folder with "the images carry no focal
    length at all" though the others carried it. Such images take their camera's (one warning counts them)."""
    from sosmatch.workflows.image_cameras import camera_groups

    for k in range(4):
        write_jpeg(tmp_path / f"f{k}.jpg", 47.0, -99.0, focal=4.3 if k % 2 else 0.0)
    metas = [read_image_metadata(tmp_path / f"f{k}.jpg") for k in range(4)]
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_cameras"):
        cameras, index, _, _ = camera_groups(metas, None, strict=True)
    assert len(cameras) == 1 and list(index) == [0, 0, 0, 0]
    assert cameras[0].fx == pytest.approx(pfe.camera_from_metadata(metas[1])[0].fx)
    assert any("2 of its images have no usable focal length" in r.getMessage() for r in caplog.records)


def _camera_dirs(R):  # noqa: N803
    return R[:, 0], R[:, 1], R[:, 2]  # image x, image y (down), optical axis in world


def test_attitude_conventions_basic_directions():
    # Level aircraft heading east, camera fixed looking down, image top towards the nose.
    R = pfe.camera_rotations([90.0], [0.0], [0.0], "top_forward")[0]
    x, y, z = _camera_dirs(R)
    np.testing.assert_allclose(z, [0, 0, -1], atol=1e-12)  # looks down
    np.testing.assert_allclose(-y, [1, 0, 0], atol=1e-12)  # image top points east (the nose)
    np.testing.assert_allclose(x, [0, -1, 0], atol=1e-12)  # image right = right wing = south
    # Nose up by 10 degrees swings the downward optical axis forwards (east when heading east).
    z_up = pfe.camera_rotations([90.0], [10.0], [0.0], "top_forward")[0][:, 2]
    assert z_up[0] > 0.17 and z_up[2] < -0.98
    # Right wing down (positive roll) tilts the optical axis to the left (north when heading east).
    z_roll = pfe.camera_rotations([90.0], [0.0], [10.0], "top_forward")[0][:, 2]
    assert z_roll[1] > 0.17
    # DJI gimbal: pitch -90 is nadir, yaw 0 puts the image top north.
    Rg = pfe.camera_rotations([0.0], [-90.0], [0.0], "gimbal")[0]
    np.testing.assert_allclose(Rg[:, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(-Rg[:, 1], [0, 1, 0], atol=1e-12)
    for name in pfe.FIXED_MOUNTS:
        Rm = pfe.camera_rotations([33.0], [4.0], [-7.0], name)[0]
        np.testing.assert_allclose(Rm @ Rm.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(Rm) == pytest.approx(1.0)


def test_meridian_convergence_is_measured():
    # West of the central meridian (northern hemisphere) true north leans east of grid north (meridians converge).
    e, n, az = pfe.geographic_to_grid(np.array([41.0]), np.array([-83.3]), 32617)
    assert 300000 < e[0] < 310000 and 4.54e6 < n[0] < 4.55e6
    assert az[0] == pytest.approx((-81.0 - -83.3) * math.sin(math.radians(41.0)), abs=0.05)


def test_poses_from_images_dji_gimbal_and_files(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="sosmatch.workflows.poses_from_exif")
    img = tmp_path / "images"
    img.mkdir()
    lats = 47.0 + np.arange(4) * 1e-4  # flying north, ~11 m apart
    for k, lat in enumerate(lats):
        write_jpeg(img / f"f{k}.jpg", lat, -99.0 + 1e-6, 500.0 + k,
                   {"GimbalYawDegree": "+0.0", "GimbalPitchDegree": "-90.0", "GimbalRollDegree": "0.0",
                    "FlightYawDegree": "1.0", "FlightPitchDegree": "0", "FlightRollDegree": "0"},
                   xmp_as_elements=True)
    out = tmp_path / "out" / "poses.csv"
    res = pfe.run(img, out)
    poses, epsg = read_poses_csv(out)
    assert epsg == 32614 and res.summary["crs"] == "EPSG:32614"
    assert poses.names == [f"f{k}.jpg" for k in range(4)]
    steps = np.diff(poses.centers, axis=0)
    np.testing.assert_allclose(np.linalg.norm(steps[:, :2], axis=1), 11.12, atol=0.1)
    np.testing.assert_allclose(steps[:, 2], 1.0, atol=1e-6)
    # Nadir; image top = true north, which in the grid is rotated by the meridian convergence.
    np.testing.assert_allclose(poses.rotations[:, :, 2], [[0, 0, -1]] * 4, atol=1e-9)
    top = -poses.rotations[0][:, 1]
    conv = res.summary["meridian_convergence_deg"]
    assert math.degrees(math.atan2(top[0], top[1])) == pytest.approx(conv, abs=1e-6)
    assert res.summary["attitude_sources"] == {"XMP GimbalYaw/Pitch/RollDegree": 4}
    assert res.gimbal_attitudes  # a refinement of these poses is judged by the tilt the gimbal holds
    # the map of these tags says what would fit them better when the pose check finds them loose (26th sweep)
    assert pfe.map_inputs_from_images(img).remedy == pfe.UNREFINED_REMEDY
    # the tags carry no lens model: said once per reading, at info level (26th sweep: a barrel lens, no word)
    assert any("no lens model" in r.getMessage() and r.levelname == "INFO" for r in caplog.records)
    cams = read_cameras_txt(out.parent / "cameras.txt")
    assert cams[1].width == 400 and cams[1].fx == pytest.approx(277.5, rel=1e-2)


def test_telemetry_and_course_fallbacks(tmp_path):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0)  # flying east, no XMP
    res = pfe.poses_from_images(img)
    assert res.summary["attitude_sources"] == {"course from neighbours (level, nadir)": 3}
    assert not res.gimbal_attitudes
    top = -res.poses.rotations[:, :, 1]
    np.testing.assert_allclose(top[:, 0], 1.0, atol=1e-6)  # image top along the flight direction (east)
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,Heading,PitchAngle,RollAngle\n" + "".join(f"f{k}.jpg,90,0,10\n" for k in range(3)))
    res2 = pfe.poses_from_images(img, telemetry=tele)
    assert res2.summary["attitude_sources"] == {"telemetry CSV": 3}
    assert res2.poses.rotations[0][1, 2] > 0.17  # rolled right: optical axis tilts north (left of east)
    # the eighth new-user sweep: a telemetry file whose names match no image was ignored without a word; now the
    # names match case-insensitively (a copy of the frames as .JPG) and a file of other images is an error
    tele.write_text("FileName,Heading,PitchAngle,RollAngle\n" + "".join(f"F{k}.JPG,90,0,10\n" for k in range(3)))
    assert pfe.poses_from_images(img, telemetry=tele).summary["attitude_sources"] == {"telemetry CSV": 3}
    tele.write_text("FileName,Heading,PitchAngle,RollAngle\n" + "".join(f"shot_{k}.jpg,90,0,10\n" for k in range(3)))
    with pytest.raises(InputError, match="none of its 3 rows names an image"):
        pfe.poses_from_images(img, telemetry=tele)


def _four_images_flying_east(tmp_path: Path) -> tuple[Path, object]:
    """Four EXIF-tagged images 7.6 m apart flying east at 47 N, and their poses from those tags alone."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0)
    return img, pfe.poses_from_images(img)


def test_telemetry_positions_take_precedence_over_the_exif_gps(tmp_path, caplog):
    """The thirteenth sweep: a telemetry CSV's positions (a PPK solution, the autopilot's log) were ignored
    wherever the images had EXIF GPS. The user's file now wins, as OpenDroneMap's geo.txt does; the log says how far
    it moved the positions, and warns when that is another flight's or another datum's distance."""
    img, exif = _four_images_flying_east(tmp_path)
    tele = tmp_path / "telemetry.csv"

    def shifted(north_m: float) -> None:
        rows = "".join(f"f{k}.jpg,90,0,0,{47.0 + north_m / 111_320.0!r},{-99.0 + k * 1e-4!r},512.5\n" for k in range(4))
        tele.write_text("FileName,Heading,PitchAngle,RollAngle,GPSLatitude,GPSLongitude,GPSAltitude\n" + rows)

    shifted(3.0)  # a PPK correction of 3 m north, 12.5 m in height
    with caplog.at_level(logging.INFO, logger="sosmatch.workflows.image_positions"):
        res = pfe.poses_from_images(img, telemetry=tele)
    assert res.summary["position_sources"] == {"telemetry CSV": 4}
    moved = res.poses.centers - exif.poses.centers
    np.testing.assert_allclose(moved[:, 1], 3.0, atol=0.05)
    np.testing.assert_allclose(moved[:, 2], 12.5, atol=1e-6)
    assert any("differ by 3.0 m" in r.getMessage() and r.levelno == logging.INFO for r in caplog.records)
    caplog.clear()
    shifted(300.0)  # another datum, or the log of another flight with the same file names
    with caplog.at_level(logging.INFO, logger="sosmatch.workflows.image_positions"):
        res = pfe.poses_from_images(img, telemetry=tele)
    assert any("another flight" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)
    # rev38: the warning was in the log only; the summary's warnings are what poses.json / run.json record
    assert any("differ by 300.0 m" in w and "another flight" in w for w in res.summary["warnings"])
    shifted(2000.0)  # beyond any GPS error or datum: refused (image_positions.TELEMETRY_REFUSE_M)
    with pytest.raises(InputError, match=r"telemetry.csv: its positions lie 2000 m from the images' own EXIF GPS"):
        pfe.poses_from_images(img, telemetry=tele)


def test_telemetry_on_another_continent_is_refused_unless_the_exif_fixes_are_frozen(tmp_path, capsys):
    """rev38: Seneca's telemetry with its longitudes unsigned (the W in a column the reader did not read) moved
    every image 14,000 km from its own EXIF GPS, to China; one log line said so and the poses were written, exit 0.
    Now that is one line naming the file, exit 2, nothing written. A camera whose own fixes all lie at one point
    (no lock) is what such a file mends: its positions are taken, with a warning the summary records."""
    img, _ = _four_images_flying_east(tmp_path)  # 47 N, 99 W
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,GPSLatitude,GPSLongitude,GPSAltitude\n"
                    + "".join(f"f{k}.jpg,47.0,{99.0 - k * 1e-4!r},500\n" for k in range(4)))  # the sign lost
    out = tmp_path / "o" / "poses.csv"
    assert main(["poses-from-exif", str(img), "--telemetry", str(tele), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{tele}: its positions lie " in err and "drop its lat/lon columns" in err
    assert not out.exists() and not (out.parent / "cameras.txt").exists()
    frozen = tmp_path / "frozen"
    frozen.mkdir()
    for k in range(4):
        write_jpeg(frozen / f"f{k}.jpg", 47.05, -99.0, 500.0)  # a stale fix 5.6 km north of the flight
    tele.write_text("FileName,GPSLatitude,GPSLongitude,GPSAltitude\n"
                    + "".join(f"f{k}.jpg,47.0,{-99.0 + k * 1e-4!r},500\n" for k in range(4)))
    res = pfe.poses_from_images(frozen, telemetry=tele)
    assert res.summary["position_sources"] == {"telemetry CSV": 4}
    assert any("all lie at one point" in w for w in res.summary["warnings"])


def test_telemetry_that_mends_partly_stale_exif_gps_is_taken_and_a_wrong_file_still_refused(tmp_path, capsys):
    """rev39: the camera's receiver held a stale fix 5 km north for the first 6 of 10 images, then locked; the
    autopilot's log, right everywhere, lay 5 km from the EXIF at the median and was refused, the remedy named
    (dropping its positions) keeping the wrong ones. The EXIF fixes held while the telemetry moves are no
    measurement: left out, the telemetry agrees with the rest and is taken, the warning counting the stale fixes.
    A file with its longitudes unsigned disagrees with every plausible fix of the same images: still refused,
    and the remedy for wrong EXIF GPS (copies of the images without GPS tags) takes the file."""
    img, bare = tmp_path / "images", tmp_path / "bare"
    img.mkdir()
    bare.mkdir()
    for k in range(10):
        lat = 47.045 if k < 6 else 47.0 + k * 1e-4  # a stale fix 5 km north, then the receiver's lock
        write_jpeg(img / f"f{k}.jpg", lat, -99.0, 500.0, when=f"2026:06:01 10:00:{2 * k:02d}")
        write_jpeg(bare / f"f{k}.jpg", None, None, when=f"2026:06:01 10:00:{2 * k:02d}")
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,GPSLatitude,GPSLongitude,GPSAltitude\n"
                    + "".join(f"f{k}.jpg,{47.0 + k * 1e-4!r},-99.0,500\n" for k in range(10)))
    res = pfe.poses_from_images(img, telemetry=tele)
    assert res.summary["position_sources"] == {"telemetry CSV": 10}
    said = [w for w in res.summary["warnings"] if str(tele) in w]
    assert len(said) == 1 and "6 of the images' own EXIF fixes lie more than 1000 m" in said[0]
    assert "5 stale" in said[0] and "agrees with 4 of the 4 plausible" in said[0], said
    unsigned = tmp_path / "unsigned.csv"
    unsigned.write_text(tele.read_text().replace(",-99.0,", ",99.0,"))
    out = tmp_path / "o" / "poses.csv"
    assert main(["poses-from-exif", str(img), "--telemetry", str(unsigned), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{unsigned}: its positions lie " in err, err
    assert "at 4 of 4 images (left out: 5 stale, 1 beyond a jump)" in err
    assert err.endswith("copies of the images without GPS tags") and not out.exists()
    res = pfe.poses_from_images(bare, telemetry=tele)  # that remedy: the file's positions are taken
    assert res.summary["position_sources"] == {"telemetry CSV": 10}


def test_doubtful_fixes_stale_runs_and_the_far_side_of_a_jump():
    """`doubtful_fixes`: a run held at one point while the reference moves is stale after its first fix; with
    capture times, the smaller part of a track cut by a jump the aircraft cannot fly is the doubtful one."""
    ref = np.column_stack([np.zeros(10), np.arange(10) * 10.0])
    t = np.arange(10) * 2.0
    fixes = ref.copy()
    fixes[:4] = [0.0, 5000.0]  # stale
    stale, jumped = doubtful_fixes(fixes, ref, t)
    assert stale.tolist() == [False, True, True, True] + [False] * 6 and jumped.tolist() == [True] + [False] * 9
    fixes = ref + np.array([[3000.0, 0.0]] * 3 + [[0.0, 0.0]] * 7)  # three moving fixes 3 km east, then the right ones
    stale, jumped = doubtful_fixes(fixes, ref, t)
    assert not stale.any() and jumped.tolist() == [True] * 3 + [False] * 7
    stale, jumped = doubtful_fixes(fixes, ref, np.full(10, np.nan))  # no times: no speed, no jump judged
    assert not stale.any() and not jumped.any()
    assert doubtful_fixes(np.zeros((5, 2)), ref[:5], t[:5])[0].all()  # all at one point


def test_telemetry_rows_without_a_fix_leave_the_exif_gps(tmp_path, caplog):
    """rev14/rev15: rows logged before the receiver's lock (lat/lon 0,0, "nan", empty) took precedence over the
    images' valid EXIF GPS, put the flight at 0,0 and broke `poses-from-exif`. Such rows are no fix now: their
    images keep their own GPS, and the log counts them."""
    img, exif = _four_images_flying_east(tmp_path)
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,Heading,PitchAngle,RollAngle,GPSLatitude,GPSLongitude,GPSAltitude\n"
                    "f0.jpg,90,0,0,0,0,0\nf1.jpg,90,0,0,nan,nan,nan\nf2.jpg,90,0,0,0.0,0.0,\n"
                    f"f3.jpg,90,0,0,{47.0 + 3.0 / 111_320.0!r},{-99.0 + 3e-4!r},500\n")
    with caplog.at_level(logging.WARNING, logger="sosmatch.database.telemetry_io"):
        res = pfe.poses_from_images(img, telemetry=tele)
    assert res.summary["position_sources"] == {"EXIF GPS": 3, "telemetry CSV": 1}
    np.testing.assert_allclose(res.poses.centers[:3] - exif.poses.centers[:3], 0.0, atol=1e-6)
    assert res.poses.centers[3, 1] - exif.poses.centers[3, 1] == pytest.approx(3.0, abs=0.05)
    assert any("3 rows hold no GPS fix" in r.getMessage() for r in caplog.records)


def test_telemetry_hemisphere_columns_sign_its_coordinates(tmp_path):
    """rev38: a telemetry CSV of unsigned coordinates beside GPSLatitudeRef / GPSLongitudeRef columns (exiftool's
    -csv keeps EXIF's values so) was read as north and east: Seneca, in Ohio, was posed in China with exit 0. The
    refs now sign the values; a ref that is no hemisphere, or contradicts a signed value, is refused."""
    from sosmatch.database.telemetry_io import read_telemetry_csv

    img, exif = _four_images_flying_east(tmp_path)  # 47 N, 99 W
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,GPSLatitude,GPSLatitudeRef,GPSLongitude,GPSLongitudeRef,GPSAltitude\n"
                    + "".join(f"f{k}.jpg,47.0,N,{99.0 - k * 1e-4!r},{'W' if k else 'West'},500\n" for k in range(4)))
    res = pfe.poses_from_images(img, telemetry=tele)
    assert res.summary["position_sources"] == {"telemetry CSV": 4} and res.epsg == exif.epsg
    np.testing.assert_allclose(res.poses.centers, exif.poses.centers, atol=1e-3)
    south = tmp_path / "south.csv"
    south.write_text("filename,lat,lat_ref,lon,lon_ref\na.jpg,33.9,S,-70.6,W\nb.jpg,33.9,s,70.6,E\n")
    rows = read_telemetry_csv(south)
    assert (rows["a.jpg"]["lat"], rows["a.jpg"]["lon"], rows["b.jpg"]["lon"]) == (-33.9, -70.6, 70.6)
    south.write_text("filename,lat,lat_ref,lon,lon_ref\na.jpg,33.9,X,70.6,W\n")
    with pytest.raises(InputError, match="lat_ref 'X' is not N or S"):
        read_telemetry_csv(south)
    south.write_text("filename,lat,lat_ref,lon,lon_ref\na.jpg,33.9,S,-70.6,E\n")
    with pytest.raises(InputError, match="negative beside lon_ref 'E'"):
        read_telemetry_csv(south)


def test_heights_from_telemetry_and_exif_share_one_datum(tmp_path, caplog):
    """rev16: a telemetry CSV whose altitudes are above the ellipsoid (30 m over the EXIF's sea-level ones) that
    covers only some images left the others at their EXIF altitude: the flight's heights jumped by 30 m between
    images. The offset is measured on the images with both and the EXIF heights take it; with no image to
    measure it on, a warning says so."""
    img, exif = _four_images_flying_east(tmp_path)
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,Heading,PitchAngle,RollAngle,GPSLatitude,GPSLongitude,GPSAltitude\n"
                    + "".join(f"f{k}.jpg,90,0,0,47.0,{-99.0 + k * 1e-4!r},{530.0 + k * 0.2!r}\n" for k in range(2)))
    with caplog.at_level(logging.INFO, logger="sosmatch.workflows.image_positions"):
        res = pfe.poses_from_images(img, telemetry=tele)
    np.testing.assert_allclose(res.poses.centers[:, 2] - exif.poses.centers[:, 2], 30.1, atol=0.11)
    assert any("+30.1 m" in r.getMessage() and "one vertical datum" in r.getMessage() for r in caplog.records)
    bare = tmp_path / "bare"
    bare.mkdir()
    for k in range(4):
        write_jpeg(bare / f"f{k}.jpg", 47.0 if k >= 2 else None, -99.0 + k * 1e-4, 500.0)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="sosmatch.workflows.image_positions"):
        pfe.poses_from_images(bare, telemetry=tele)
    assert any("no image has both" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)


def test_the_utm_zone_is_the_flights_not_its_first_images(tmp_path):
    """Two flights of one site on a zone boundary took the zone of their first image, so one starting west of it
    and one east were mapped in two zones (and `match` called a label wrong). The zone is the flight's median
    fix's now; across the antimeridian the median stays there."""
    from sosmatch.workflows.image_positions import median_position

    img = tmp_path / "images"
    img.mkdir()
    for k, lon in enumerate((5.9995, 6.001, 6.002, 6.003, 6.004)):  # starts in zone 31, flies in 32
        write_jpeg(img / f"f{k}.jpg", 47.0, lon, 500.0)
    assert pfe.poses_from_images(img).epsg == 32632
    lat, lon = median_position(np.array([10.0, 10.0, 10.0]), np.array([179.9995, -179.9995, -179.999]))
    assert lat == 10.0 and lon == pytest.approx(-179.9995)


def test_images_of_two_places_in_one_folder_are_a_clear_error(tmp_path, capsys):
    """Images of a flight in France and one in Australia in one folder were projected into the first image's UTM
    zone without a word: the Australian ones got meaningless coordinates, and `map` refused the result as a
    mirrored flight. A fix far outside the zone's area is an error naming an image; a site on a zone boundary
    (lon 6.0 E, zones 31 and 32) is not."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        write_jpeg(img / f"a{k}.jpg", 47.0, 5.998 + k * 1e-3, 500.0)  # across the boundary of zones 31 and 32
    assert pfe.poses_from_images(img).epsg == 32631
    for k in range(3):
        write_jpeg(img / f"b{k}.jpg", -33.9, 151.2 + k * 1e-4, 50.0)
    with pytest.raises(InputError, match=r"3 of 7 images' GPS fixes lie more than 100 km outside where EPSG:3263[12] "
                                         r"\(WGS 84 / UTM zone 3[12]N\) is used \(e.g. b0.jpg at -33.9000, "
                                         r"151.2000\): images of two places"):
        pfe.poses_from_images(img)
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p.csv")]) == 2
    assert not (tmp_path / "p.csv").exists()


def test_flights_beyond_utm_latitudes_take_polar_stereographic(tmp_path, capsys):
    """A flight at 85.5 N (nu15): UTM is not defined there, so its zone's area check said "images of two places
    in one folder" and no --epsg the tool suggested worked. It takes UPS North (EPSG:32661) now; an --epsg of a
    UTM zone is "one place, in a CRS made for another" naming UPS; a polar stereographic that stretches
    distances there (EPSG:3413, 2.9 % at 85.5 N) is refused before any pose is written, where `map` refused the
    written poses before."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(5):
        write_jpeg(img / f"p{k}.jpg", 85.5 + k * 2e-4, 10.0, 300.0,
                   {"Heading": "0", "PitchAngle": "0", "RollAngle": "0"})
    priors = pfe.poses_from_images(img)
    assert priors.epsg == 32661
    north_step = np.diff(priors.poses.centers[:, :2], axis=0)
    assert np.allclose(np.linalg.norm(north_step, axis=1), 22.3, atol=0.2)  # 2e-4 deg of latitude, UPS scale ~0.994
    with pytest.raises(InputError, match=r"one place, in a CRS made for another; give the --epsg of its place, "
                                         r"e.g. EPSG:32661 \(WGS 84 / UPS North \(N,E\)\)"):
        pfe.poses_from_images(img, epsg=32632)
    out = tmp_path / "p.csv"
    assert main(["poses-from-exif", str(img), "--epsg", "3413", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "EPSG:3413" in err and "stretches distances" in err and "EPSG:32661" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["poses-from-exif", str(img), "--out", str(out)]) == 0 and out.exists()
    # just past UTM's limit a flight keeps its zone, as it always did (rev18: a site at 80.001 S flown before and
    # after would be in two CRSs)
    from sosmatch.plugin.geodesy import utm_epsg

    assert utm_epsg(-80.001, 21.0) == 32734 and utm_epsg(84.2, 10.0) == 32632 and utm_epsg(-81.0, 21.0) == 32761


def test_missing_gps_is_a_clear_error(tmp_path, capsys):
    img = tmp_path / "images"
    img.mkdir()
    write_jpeg(img / "a.jpg", 47.0, -99.0)
    write_jpeg(img / "b.jpg", None, None)
    with pytest.raises(InputError, match="1 of 2 images have no GPS"):
        pfe.poses_from_images(img)
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p.csv")]) == 2
    assert "no GPS position" in capsys.readouterr().err
    assert not (tmp_path / "p.csv").exists()


def test_cli_writes_files(tmp_path, capsys):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(2):
        write_jpeg(img / f"f{k}.jpg", -33.0 - k * 1e-4, 151.0, 50.0,
                   {"Heading": "180", "PitchAngle": "0", "RollAngle": "0"})
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "s" / "poses.csv")]) == 0
    poses, epsg = read_poses_csv(tmp_path / "s" / "poses.csv")
    assert epsg == 32756  # southern hemisphere, zone 56
    assert (tmp_path / "s" / "cameras.txt").exists()
    assert '"telemetry CSV"' not in capsys.readouterr().out


def test_macos_appledouble_files_beside_the_images_are_not_images(tmp_path, capsys):
    """A folder copied by macOS onto an SD card or exFAT drive holds a hidden `._NAME.jpg` (AppleDouble metadata,
    a few kB, not a JPEG) beside every image: it stopped poses-from-exif ("cannot identify image file") and made
    segment fail on every one of them. Hidden files are not images, for every command that lists a folder."""
    from sosmatch.database.images import list_images
    from sosmatch.workflows.image_priors import list_images as photo_list

    img = tmp_path / "images"
    img.mkdir()
    for k in range(2):
        write_jpeg(img / f"f{k}.jpg", -33.0 - k * 1e-4, 151.0, 50.0,
                   {"Heading": "180", "PitchAngle": "0", "RollAngle": "0"})
        (img / f"._f{k}.jpg").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        " + bytes(4000))
    (img / ".DS_Store").write_bytes(bytes(64))
    assert [p.name for p in list_images([img])] == ["f0.jpg", "f1.jpg"]
    assert [p.name for p in photo_list(img)] == ["f0.jpg", "f1.jpg"]
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "s" / "poses.csv")]) == 0, capsys.readouterr()
    assert read_poses_csv(tmp_path / "s" / "poses.csv")[0].names == ["f0.jpg", "f1.jpg"]


def test_images_whose_names_do_not_follow_the_flight_are_read_in_capture_order(tmp_path):
    """Renamed files (names in another order than the capture times): the course over ground of images without
    attitude tags came from their neighbours by name, i.e. from frames across the survey (Seneca's 30 frames under
    shuffled names: orientations up to 37 deg off those of the same frames in order), and the poses were listed
    by name. The images are read in capture order."""
    from sosmatch.workflows.image_priors import read_image_priors

    img = tmp_path / "images"
    img.mkdir()
    names = ["c.jpg", "a.jpg", "d.jpg", "b.jpg"]  # taken in this order, flying north 20 m per image
    for k, name in enumerate(names):
        write_jpeg(img / name, 41.0 + k * 20 / 111_000, -83.0, 300.0, when=f"2024:05:01 10:00:{10 * k:02d}")
    priors = read_image_priors(img)
    assert priors.names == names
    ok = priors.attitude_kind == "course"
    assert ok.all()
    # level nadir, headed along the course: the image top (-y of the camera) points north everywhere
    top = -priors.rotations[:, :, 1]
    assert np.all(top[:, 1] > 0.99), top


def test_images_of_one_capture_second_are_read_along_their_path(tmp_path, caplog):
    """The nu25 sweep: names shuffled, and several images per DateTimeOriginal (two a second in whole seconds; or
    one instant on every image, a tool that rewrote the dates). A stable sort on the times kept the shuffled names'
    order within each second (or everywhere): course over ground and poses across the survey, no word. Within a
    time the images are read along the path through their positions, with a warning."""
    from sosmatch.workflows.image_priors import read_image_priors

    rng = np.random.default_rng(0)
    n = 40
    names = [f"DJI_{k:04d}.jpg" for k in rng.choice(np.arange(1000, 9999), n, replace=False)]  # taken in this order
    cases = {"burst": (lambda k: f"2024:05:01 10:00:{k // 2:02d}", "share their capture time", [names]),
             # one instant orders nothing: the path runs from an end of the line, either one
             "same": (lambda k: "2024:05:01 10:00:00", "carry one capture time", [names, names[::-1]])}
    for case, (stamp, said, read_as) in cases.items():
        img = tmp_path / case
        img.mkdir()
        for k, name in enumerate(names):  # flying north 20 m per image
            write_jpeg(img / name, 41.0 + k * 20 / 111_000, -83.0, 300.0, size=(64, 48), when=stamp(k))
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            priors = read_image_priors(img)
        assert priors.names in read_as, case
        assert said in caplog.text, case
        top = -priors.rotations[:, :, 1]  # headed along the course: north (south when read backwards)
        assert np.all(np.abs(top[:, 1]) > 0.99), case


def test_refine_option_runs_and_keeps_poses_without_tie_points(tmp_path):
    # Independent noise images share no tie points: refinement must leave the EXIF poses where they are.
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0,
                   {"Heading": "90", "PitchAngle": "1", "RollAngle": "-2"})
    plain = pfe.poses_from_images(img)
    res = pfe.run(img, tmp_path / "poses.csv", refine=True)
    assert res.summary["refinement"]["images"] == 3 and res.summary["refinement"]["points"] == 0
    assert "no tie points" in res.summary["refinement"]["warnings"][0]  # said, not passed off as a refinement
    np.testing.assert_allclose(res.poses.centers, plain.poses.centers, atol=1e-6)
    poses, _ = read_poses_csv(tmp_path / "poses.csv")
    np.testing.assert_allclose(poses.rotations, plain.poses.rotations, atol=1e-9)


def test_map_with_pose_source_exif_reads_them_from_exif(tmp_path, capsys):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 3e-4, 500.0,
                   {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"})
    # noise images give no landmarks: the map is refused (one line, exit 2) but run.json records it all
    assert main(["map", "--images", str(img), "--pose-source", "exif", "--out", str(tmp_path / "s"),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "map refused: the map has no landmarks" in err and len(err.strip().splitlines()) == 1
    run = json.loads((tmp_path / "s" / "run.json").read_text())
    assert run["verdict"]["status"] == "refused"
    assert run["inputs"]["poses"].startswith("EXIF/XMP of") and run["epsg"] == 32614
    assert run["counts"]["keyframes"] == 3
    # the same poses through a pose CSV give the same keyframes and the same georeference
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p" / "poses.csv")]) == 0
    assert main(["map", "--images", str(img), "--poses", str(tmp_path / "p" / "poses.csv"), "--out",
                 str(tmp_path / "s2"), "--no-progress"]) == 2
    run2 = json.loads((tmp_path / "s2" / "run.json").read_text())
    assert run2["keyframes"] == run["keyframes"] and run2["map_origin"] == run["map_origin"]
    capsys.readouterr()
    assert main(["map", "--out", str(tmp_path / "s3")]) == 2
    assert "give --poses, or --images" in capsys.readouterr().err
    # options of the other pose source are refused, not silently ignored
    assert main(["map", "--images", str(img), "--poses", str(tmp_path / "p" / "poses.csv"), "--refine",
                 "--out", str(tmp_path / "s4")]) == 2
    assert "apply only without --poses" in capsys.readouterr().err
    assert main(["map", "--images", str(img), "--camera", str(tmp_path / "p" / "cameras.txt"),
                 "--out", str(tmp_path / "s5")]) == 2
    assert "need --poses" in capsys.readouterr().err and not (tmp_path / "s5").exists()


def test_images_without_attitude_whose_orientations_cannot_be_solved_are_an_error(tmp_path, capsys):
    """No attitude tags and no tie points (noise images): the headings would be the course over ground, a guess;
    one line names the cause, and nothing is written."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0)  # flying east, no XMP
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p" / "poses.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "3 of 3 images have no attitude tags and their orientations could not be solved from tie points (no " \
           "tie points" in err and "sosmatch poses" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "p" / "poses.csv").exists()
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "p" / "poses.csv"), "--refine"]) == 2
    assert "have no attitude tags and their orientations could not be solved" in capsys.readouterr().err
    assert main(["map", "--images", str(img), "--pose-source", "exif", "--out", str(tmp_path / "s"),
                 "--no-progress"]) == 2
    assert "have no attitude tags and their orientations could not be solved" in capsys.readouterr().err


def test_the_advice_for_a_missing_focal_length_is_one_that_can_be_followed(tmp_path):
    """Images with their EXIF stripped: the error advised --sensor-width-mm (useless without a focal length in
    mm: the same error came back) "or a cameras.txt" (poses-from-exif takes none)."""
    from dataclasses import replace

    from sosmatch.workflows.image_priors import camera_from_metadata

    write_jpeg(tmp_path / "a.jpg", 47.0, -99.0)
    meta = read_image_metadata(tmp_path / "a.jpg")
    bare = replace(meta, focal_mm=None, focal_plane_px_per_mm=None, focal_35mm=None)
    with pytest.raises(InputError, match="no focal length at all") as err:
        camera_from_metadata(bare, sensor_width_mm=6.2)
    assert "sosmatch poses" in str(err.value) and "--sensor-width-mm" not in str(err.value)
    no_plane = replace(meta, focal_plane_px_per_mm=None, focal_35mm=None)
    with pytest.raises(InputError, match="--sensor-width-mm"):
        camera_from_metadata(no_plane)


# The ninth new-user sweep's drone folders: a frozen fix, a jump, tags without their hemisphere, Parrot tags and
# cameras tagged to look at the horizon (`plugin.gps_track`).
NADIR = {"GimbalYawDegree": "+0.0", "GimbalPitchDegree": "-90.0", "GimbalRollDegree": "0.0"}


def test_frozen_fix_jumps_and_off_nadir():
    east, north = np.arange(20.0) * 10.0, np.zeros(20)
    times = np.arange(20.0) * 2.0  # 5 m/s
    assert not frozen_fix(east, north) and gps_jumps(east, north, times) == []
    assert frozen_fix(np.full(5, 3.0) + [0, 0.2, 0, 0, 0.1], np.full(5, 7.0))
    assert not frozen_fix(np.full(2, 3.0), np.full(2, 7.0))  # two images: not a flight to judge
    north[7] = 300.0  # one fix 300 m off the line: the jump in and the jump out are named
    assert [(i, j) for i, j, _, _ in gps_jumps(east, north, times)] == [(6, 7), (7, 8)]
    assert gps_jumps(east, north, np.full(20, np.nan)) == []  # no times: no speed
    assert gps_jumps(east, north, np.full(20, 5.0)) == []  # one clock stamp on every frame: no speed either
    north[7] = 0.0
    height = np.full(20, 281.0)
    height[12] = -281.0  # GPSAltitudeRef 1 on one image: 562 m under its neighbours
    assert gps_jumps(east, north, times) == []
    assert [(i, j) for i, j, _, _ in gps_jumps(east, north, times, height)] == [(11, 12), (12, 13)]
    height[12] = np.nan  # no altitude: judged horizontally
    assert gps_jumps(east, north, times, height) == []
    # a fast flight (25 m/s, frames 2 s apart) and a turn between lines 60 m apart: no jump
    east2 = np.r_[np.arange(10.0) * 50.0, 450.0 - np.arange(10.0) * 50.0]
    north2 = np.r_[np.zeros(10), np.full(10, 60.0)]
    assert gps_jumps(east2, north2, np.arange(20.0) * 2.0) == []
    down = np.diag([1.0, -1.0, -1.0])[None]  # camera z along world -z
    side = np.array([[[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]])  # camera z horizontal
    assert off_nadir_deg(down)[0] == pytest.approx(0.0) and off_nadir_deg(side)[0] == pytest.approx(90.0)


def _flight(img, n=6, lat0=47.0, xmp=NADIR, same=False):
    img.mkdir()
    for k in range(n):
        lat = lat0 + (0 if same else k * 1e-4)
        write_jpeg(img / f"f{k}.jpg", lat, 8.0, 500.0, xmp, xmp_as_elements=True,
                   when=f"2026:06:01 10:00:{2 * k:02d}")


def test_poses_from_exif_refuses_a_frozen_fix_and_cameras_tagged_at_the_horizon(tmp_path):
    _flight(tmp_path / "frozen", same=True)
    with pytest.raises(InputError, match="lie at one point"):
        pfe.run(tmp_path / "frozen", tmp_path / "o1" / "poses.csv")
    horizon = {"GimbalYawDegree": "+0.0", "GimbalPitchDegree": "0.0", "GimbalRollDegree": "0.0"}
    _flight(tmp_path / "horizon", xmp=horizon)
    with pytest.raises(InputError, match="from straight down"):
        pfe.run(tmp_path / "horizon", tmp_path / "o2" / "poses.csv")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    oblique = {"GimbalYawDegree": "+0.0", "GimbalPitchDegree": "-25.0", "GimbalRollDegree": "0.0"}
    _flight(tmp_path / "oblique", xmp=oblique)  # 65 deg from nadir: an oblique survey still looks at the ground
    res = pfe.run(tmp_path / "oblique", tmp_path / "o3" / "poses.csv")
    assert res.summary["tags_median_off_nadir_deg"] == pytest.approx(65.0, abs=0.1)
    assert not any("straight down" in w for w in res.summary["warnings"])


def test_a_jump_is_named_and_parrot_tags_are_gimbal_angles(tmp_path, caplog):
    img = tmp_path / "jump"
    img.mkdir()
    parrot = {"CameraYawDegree": "+0.0", "CameraPitchDegree": "-90.0", "CameraRollDegree": "0.0"}
    for k in range(6):  # 11 m every 2 s, f3 300 m east
        write_jpeg(img / f"f{k}.jpg", 47.0 + k * 1e-4, 8.0 + (0.004 if k == 3 else 0.0), 500.0, parrot,
                   xmp_as_elements=True, when=f"2026:06:01 10:00:{2 * k:02d}")
    res = pfe.run(img, tmp_path / "o" / "poses.csv")
    assert [j[:2] for j in res.summary["gps_jumps"]] == [["f2.jpg", "f3.jpg"], ["f3.jpg", "f4.jpg"]]
    untimed = tmp_path / "untimed"
    untimed.mkdir()
    for k in range(6):  # the same fixes without capture times: no speed, so no jump is judged
        write_jpeg(untimed / f"f{k}.jpg", 47.0 + k * 1e-4, 8.0 + (0.004 if k == 3 else 0.0), 500.0, parrot,
                   xmp_as_elements=True)
    assert pfe.run(untimed, tmp_path / "u" / "poses.csv").summary["gps_jumps"] == []
    assert any("GPS jumps 2 time(s)" in w and "f2.jpg -> f3.jpg" in w for w in res.summary["warnings"])
    assert res.summary["attitude_sources"] == {"XMP CameraYaw/Pitch/RollDegree (Parrot)": 6}
    np.testing.assert_allclose(res.poses.rotations[:, :, 2], [[0, 0, -1]] * 6, atol=1e-9)


def test_a_damaged_parrot_camera_angle_is_left_out_like_a_gimbal_one(tmp_path):
    """rev38: Parrot's CameraYaw/Pitch/RollDegree were not among the checked angle tags, so a yaw of 1e300 was
    taken as a heading (an arbitrary one) and never listed as damaged; the writer took it too."""
    from sosmatch.database.exif_write import encode_exif

    img = tmp_path / "parrot"
    img.mkdir()
    for k in range(4):
        yaw = "1e300" if k == 2 else "+0.0"
        write_jpeg(img / f"f{k}.jpg", 47.0 + k * 1e-4, 8.0, 500.0,
                   {"CameraYawDegree": yaw, "CameraPitchDegree": "-90.0", "CameraRollDegree": "0.0"},
                   xmp_as_elements=True)
    meta = read_image_metadata(img / "f2.jpg")
    assert "CameraYawDegree" not in meta.xmp and any("CameraYawDegree" in p for p in meta.problems)
    priors = read_image_priors(img)
    assert list(priors.summary["damaged_metadata"]) == ["f2.jpg"]
    assert priors.attitude_kind[priors.names.index("f2.jpg")] == "course"  # its other sources, not the damaged yaw
    meta.xmp["CameraPitchDegree"] = "-1e300"
    with pytest.raises(ValueError, match="CameraPitchDegree"):
        encode_exif(meta)


def test_a_gps_position_without_its_hemisphere_is_left_out(tmp_path):
    from PIL import Image

    src = tmp_path / "a.jpg"
    write_jpeg(src, -33.9, -70.6, 500.0)  # Santiago: S and W
    meta = read_image_metadata(src)
    assert meta.latitude == pytest.approx(-33.9, abs=1e-6) and meta.longitude == pytest.approx(-70.6, abs=1e-6)
    with Image.open(src) as im:
        exif = im.getexif()
        gps = exif.get_ifd(0x8825)
        del gps[1], gps[3]  # GPSLatitudeRef, GPSLongitudeRef
        im.save(tmp_path / "b.jpg", exif=exif.tobytes())
    meta = read_image_metadata(tmp_path / "b.jpg")
    assert meta.latitude is None and any("without its hemisphere" in p for p in meta.problems)


def _with_gps(src: Path, dst: Path, **tags: tuple) -> None:
    """`src` saved as `dst` with the given GPS IFD tags (by id: lat=2, lon=4) replaced."""
    with Image.open(src) as im:
        exif = im.getexif()
        gps = exif.get_ifd(0x8825)
        gps.update({{"lat": 2, "lon": 4}[k]: v for k, v in tags.items()})
        im.save(dst, exif=exif.tobytes())


def test_a_gps_rational_0_over_0_is_no_fix_or_named_not_a_position_off_the_globe(tmp_path, capsys):
    """rev38: Pillow reads a rational 0/0 as NaN, so a GPS switched off (every part 0/0) and seconds written 0/0
    beside valid degrees and minutes were both "GPS position nan, nan is off the globe". All 0/0 is no fix (as
    0, 0 is: no problem listed); a partial 0/0 leaves the position out with a problem naming the tag and part."""
    empty = (IFDRational(0, 0),) * 3
    minutes = (IFDRational(46, 1), IFDRational(599569, 10000), IFDRational(0, 0))  # degrees, decimal minutes, 0/0
    src = tmp_path / "src.jpg"
    write_jpeg(src, 47.0, 8.0, 500.0)
    _with_gps(src, tmp_path / "off.jpg", lat=empty, lon=empty)
    off = read_image_metadata(tmp_path / "off.jpg")
    assert off.latitude is None and off.longitude is None and off.problems == []
    _with_gps(src, tmp_path / "sec.jpg", lat=minutes)
    sec = read_image_metadata(tmp_path / "sec.jpg")
    assert sec.latitude is None and sec.longitude is None
    assert sec.problems == ["GPSLatitude seconds 0/0 (a rational without a value): GPS position left out"]
    img = tmp_path / "flight"
    img.mkdir()
    for k in range(3):
        write_jpeg(src, 47.0 + k * 1e-4, 8.0, 500.0)
        _with_gps(src, img / f"f{k}.jpg", lat=minutes, lon=minutes)
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "o" / "poses.csv")]) == 2
    err = capsys.readouterr().err
    assert "here GPSLatitude seconds 0/0, GPSLongitude seconds 0/0" in err and "nan" not in err


def test_telemetry_with_semicolons_and_omega_phi_kappa(tmp_path, caplog):
    from sosmatch.database.telemetry_io import read_telemetry_csv

    semi = tmp_path / "t.csv"
    semi.write_text("FileName;Heading;PitchAngle;RollAngle\nf0.jpg;70.5;2.5;-2.9\nf1.jpg;70,5;2,5;-2,9\n")
    row = {"yaw": 70.5, "pitch": 2.5, "roll": -2.9}
    assert read_telemetry_csv(semi) == {"f0.jpg": row, "f1.jpg": row}  # decimal commas of ';' locales too
    from sosmatch.database.telemetry_io import telemetry_rows

    tele = {"A.JPG": {"yaw": 1.0}, "b.jpg": {"yaw": 2.0}, "B.JPG": {"yaw": 3.0}}
    assert telemetry_rows(tele, ["a.jpg", "b.jpg", "B.jpg"], semi, "imgs") == [{"yaw": 1.0}, {"yaw": 2.0}, {}]
    opk = tmp_path / "o.csv"
    opk.write_text("filename,latitude,longitude,altitude,omega,phi,kappa\nf0.jpg,47,8,500,1,2,3\n")
    assert read_telemetry_csv(opk) == {"f0.jpg": {"lat": 47.0, "lon": 8.0, "alt": 500.0}}
    assert "omega/phi/kappa columns" in caplog.text



def test_refine_without_tie_points_keeps_the_priors_and_prints_strict_json(tmp_path, capsys):
    """nu16: `poses-from-exif --refine` on images that give no tie points said "the poses are the priors,
    unrefined" while the adjustment had moved every camera by one 1.95 m, and its summary held NaN, which
    strict JSON parsers (JavaScript's JSON.parse) reject. The priors are the answer now, and the summary has
    null where there is no number."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(5):  # random pixels: nothing ties two images together
        write_jpeg(img / f"r{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0,
                   {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"})
    assert main(["poses-from-exif", str(img), "--out", str(tmp_path / "plain" / "poses.csv")]) == 0
    capsys.readouterr()
    assert main(["poses-from-exif", str(img), "--refine", "--out", str(tmp_path / "refined" / "poses.csv")]) == 0

    def no_constants(name: str) -> None:
        raise AssertionError(f"{name} in the summary")

    json.loads(capsys.readouterr().out, parse_constant=no_constants)
    plain, _ = read_poses_csv(tmp_path / "plain" / "poses.csv")
    refined, _ = read_poses_csv(tmp_path / "refined" / "poses.csv")
    np.testing.assert_allclose(refined.centers, plain.centers, atol=1e-6)


def test_portrait_files_of_a_landscape_readout_do_not_take_its_attitude_tags(tmp_path, caplog):
    """nu16: portrait files (a landscape readout turned by 90 degrees by software, the EXIF as the camera wrote
    it) took the tags' heading unchanged: their poses were 90 degrees off with no warning, and `map` refused the
    result as a tilted ground. The direction of the turn is not recorded, so such images' headings are left to
    the images, as for images without tags, and a warning says why."""
    from sosmatch.workflows.image_priors import read_image_priors

    img = tmp_path / "images"
    img.mkdir()
    tags = {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"}
    for k in range(4):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0, tags, size=(300, 400) if k % 2 else (400, 300))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        priors = read_image_priors(img)
    assert list(priors.attitude_from_tags) == [True, False, True, False]
    assert any("2 of 4 images are their camera's readout turned by 90 degrees" in r.getMessage()
               for r in caplog.records)
    assert "no EXIF Orientation tag" in caplog.text


def test_portrait_files_with_an_orientation_tag_are_said_to_carry_it(tmp_path, caplog):
    """nu53 L2: portrait files whose EXIF Orientation 8 turns them back to the readout's aspect in viewers were
    warned about as "which way the pixels were turned is not recorded". The tag is named, and that sosmatch does
    not apply it; a 180 deg tag is read and named in refusals (`orientation_note`)."""
    from sosmatch.database.exif import orientation_note, read_orientation
    from sosmatch.workflows.image_priors import read_image_priors

    img = tmp_path / "images"
    img.mkdir()
    tags = {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"}
    for k in range(4):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0, tags, size=(300, 400) if k % 2 else (400, 300),
                   orientation=8 if k % 2 else 1)
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.image_priors"):
        priors = read_image_priors(img)
    assert list(priors.attitude_from_tags) == [True, False, True, False]
    assert [m.orientation for m in priors.metas] == [1, 8, 1, 8] and read_orientation(img / "f1.jpg") == 8
    assert "their EXIF Orientation 8 turns them back to the readout's aspect in viewers, a turn sosmatch does not " \
           "apply" in caplog.text and "not recorded" not in caplog.text
    assert orientation_note([1, None, 1]) is None
    assert orientation_note([3, 3, 1, 6]) == ("3 of 4 images carry EXIF Orientation 3 (turned 180 deg by viewers, 2), "
                                              "6 (turned 90 deg clockwise by viewers, 1), which sosmatch does not "
                                              "apply: pixels stored turned from the camera's view contradict their "
                                              "tags and poses")


def test_map_and_poses_take_the_projected_crs_of_the_poses(tmp_path, capsys, monkeypatch):
    """The twenty-fifth sweep: `match` advised mapping two flights of one site across a UTM zone edge in one CRS
    (`--epsg`), which only poses-from-exif offered. `map` (EXIF and structure-from-motion pose sources) and `poses`
    take it; the default (each flight's zone) keeps the identity of sessions mapped before the option."""
    from sosmatch.workflows import poses as poses_workflow
    from sosmatch.workflows.poses import job

    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):  # at the edge of zones 14 and 15, in 14 by their median fix
        write_jpeg(img / f"f{k}.jpg", 47.0, -96.0005 + k * 3e-4, 500.0,
                   {"Heading": "90", "PitchAngle": "0", "RollAngle": "0"})
    assert main(["map", "--images", str(img), "--pose-source", "exif", "--epsg", "32615", "--out",
                 str(tmp_path / "s"), "--no-progress"]) == 2  # noise images: refused, but run.json records the CRS
    assert json.loads((tmp_path / "s" / "run.json").read_text())["epsg"] == 32615
    capsys.readouterr()
    assert main(["map", "--images", str(img), "--poses", str(tmp_path / "s" / "run.json"), "--epsg", "32615",
                 "--out", str(tmp_path / "s2")]) == 2
    assert "--epsg apply only without --poses" in capsys.readouterr().err
    assert main(["map", "--images", str(img), "--pose-source", "exif", "--epsg", "4326", "--out",
                 str(tmp_path / "s3")]) == 2
    assert "--epsg: EPSG:4326 (WGS 84) is not a projected CRS" in capsys.readouterr().err
    # structure from motion: the priors it georegisters on are read in the chosen CRS
    seen = []

    def stop(image_dir, work, params, identity, *args, **kwargs):
        seen.append(args[-1].epsg)  # the priors, read in the chosen CRS
        raise InputError("stop here")

    monkeypatch.setattr(job, "compute_poses", stop)
    for argv in (["map", "--images", str(img), "--epsg", "32615", "--out", str(tmp_path / "s4"), "--no-progress"],
                 ["poses", str(img), "--epsg", "32615", "--out", str(tmp_path / "p")]):
        assert main(argv) == 2 and "stop here" in capsys.readouterr().err
    assert seen == [32615, 32615]
    plain = poses_workflow.PosesFromImages(img, Params())
    assert plain.identity() == job.identity_of(img, Params(), telemetry=None, takeoff=None, sensor=None,
                                               nominal_height_m=job.NOMINAL_HEIGHT_M)
    assert poses_workflow.PosesFromImages(img, Params(), epsg=32615).identity() != plain.identity()


def test_embedded_exif_is_one_app1_segment_with_a_tiff_header(tmp_path):
    """`embed_metadata` (the synthetic world's geotagger) writes "Exif\\0\\0" then the TIFF header, as a camera
    does: Pillow's own identifier in front of the TIFF bytes made "Exif\\0\\0Exif\\0\\0MM...", which Pillow read
    but strict readers (exiftool, COLMAP) do not (nu35)."""
    import io

    from PIL import Image

    from sosmatch.database.exif import ImageMetadata
    from sosmatch.database.exif_write import embed_metadata

    buf = io.BytesIO()
    Image.new("L", (32, 24), 128).save(buf, "JPEG")
    meta = ImageMetadata(tmp_path / "a.jpg", 32, 24, latitude=41.5, longitude=-83.25, altitude=300.0, focal_mm=4.5,
                         make="DJI", model="FC6310")
    data = embed_metadata(buf.getvalue(), meta)
    assert data[2:4] == b"\xff\xe1"
    payload = data[6:6 + int.from_bytes(data[4:6], "big") - 2]
    assert payload[:6] == b"Exif\x00\x00" and payload[6:10] in (b"MM\x00*", b"II*\x00")
    (tmp_path / "a.jpg").write_bytes(data)
    back = read_image_metadata(tmp_path / "a.jpg")
    assert back.latitude == pytest.approx(41.5, abs=1e-6) and back.longitude == pytest.approx(-83.25, abs=1e-6)
    assert back.focal_mm == pytest.approx(4.5) and back.make == "DJI"


def test_a_take_off_altitude_beyond_the_earth_is_refused_before_any_work():
    """nu45: `poses --takeoff-altitude 1e9` ran the whole structure from motion, then the pose writer's ValueError
    was a traceback (exit 1); 1e7 m was taken."""
    from sosmatch.plugin.errors import InputError
    from sosmatch.workflows.image_priors import check_prior_options

    check_prior_options("top_forward", None, None, -420.0)  # the Dead Sea shore
    for bad in (1e9, 1e7, -2e5, float("nan")):
        with pytest.raises(InputError, match="take-off altitude"):
            check_prior_options("top_forward", None, None, bad)


def test_an_empty_list_of_images_is_a_user_error():
    """nu45: `poses_from_images([])` (the README's Python call) was an IndexError."""
    from sosmatch.plugin.errors import InputError
    from sosmatch.workflows.poses_from_exif import poses_from_images

    with pytest.raises(InputError, match="no images given"):
        poses_from_images([])


def test_a_telemetry_log_joined_one_row_off_is_refused_naming_the_shift(tmp_path, capsys):
    """nu53 H1: a log whose FileName column slipped one row gives every image its neighbour's position, a capture
    step off (Seneca: 32.7 m), and was taken with an INFO line; the map was then published 32 m off, verdict ok.
    Pairing the rows with the fixes one image away explains the offset to within the GPS noise: refused in one line
    naming the shift. The same rows joined right, and a log offset by a receiver's bias, are taken."""
    img = tmp_path / "images"
    img.mkdir()
    # 15 m steps at 47 N, one capture every 2 s: a line east, then one back west 30 m north (a row shift moves the
    # positions forward on both lines, a constant offset along one line backward on the other)
    n, step_deg = 12, 2e-4
    lat = [47.0 if k < n // 2 else 47.0 + 30.0 / 111_320.0 for k in range(n)]
    lon = [-99.0 + (k if k < n // 2 else n - 1 - k) * step_deg for k in range(n)]
    for k in range(n):
        write_jpeg(img / f"f{k}.jpg", lat[k], lon[k], 500.0, when=f"2024:05:01 10:00:{2 * k:02d}")
    tele = tmp_path / "telemetry.csv"

    def log(shift: int, north_m: float = 0.0) -> None:
        rows = "".join(f"f{k}.jpg,{lat[(k - shift) % n] + north_m / 111_320.0!r},{lon[(k - shift) % n]!r},500\n"
                       for k in range(n))
        tele.write_text("FileName,GPSLatitude,GPSLongitude,GPSAltitude\n" + rows)

    log(1)  # each image holds the row of the image before it (the last row wraps to the first)
    out = tmp_path / "o" / "poses.csv"
    assert main(["poses-from-exif", str(img), "--telemetry", str(tele), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{tele}: its rows look shifted by 1 image(s)" in err
    assert "1 earlier in capture order" in err and "by FileName" in err and not out.exists()
    log(-2)
    with pytest.raises(InputError, match="shifted by 2 image.* 2 later"):
        pfe.poses_from_images(img, telemetry=tele)
    for north_m in (0.0, 4.0):  # joined right; a PPK log 4 m off the camera's fixes: taken, no warning
        log(0, north_m)
        res = pfe.poses_from_images(img, telemetry=tele)
        assert res.summary["position_sources"] == {"telemetry CSV": n}
        assert not any("differ by" in w for w in res.summary["warnings"])
    log(0, north_m=20.0)  # 20 m off, no whole number of rows: beyond the 10 m the noise explains, a warning
    said = [w for w in pfe.poses_from_images(img, telemetry=tele).summary["warnings"] if "differ by 20.0 m" in w]
    assert len(said) == 1 and "beyond the 10 m the GPS noise explains" in said[0]


def test_a_correct_log_beside_repeated_fixes_or_a_one_way_offset_is_no_row_shift():
    """rev47: fixes repeating their predecessor (a 1 Hz receiver under a 2 Hz camera) matched the neighbour's row
    at every other image, and a correct log was refused as shifted; so was an RTK log one step north of a
    northbound corridor (a constant offset along a line flown one way is a shift to the positions). A repeated fix
    is no measurement of its capture, and a shift is said only where lines flown both ways agree on it."""
    from sosmatch.workflows.image_positions import flown_both_ways, rows_shifted

    rng = np.random.default_rng(3)
    track = np.column_stack([np.zeros(60), 6.0 * np.arange(60)]) + rng.normal(0.0, 1.0, (60, 2))
    held = track.copy()
    held[1::2] = held[0::2]  # each fix written on two images
    order = np.arange(60)
    assert rows_shifted(held, track, order)[0] == 0  # the log right beside them: no shift
    assert rows_shifted(track, np.roll(track, 1, axis=0), order)[0] == -1  # the same log one row off: a shift
    corridor = np.column_stack([np.zeros(40), 12.0 * np.arange(40)])
    assert not flown_both_ways(corridor)
    assert flown_both_ways(np.vstack([corridor, corridor[::-1] + [40.0, 0.0]]))
    from sosmatch.workflows.image_positions import telemetry_against_exif

    to_ll = np.array([1.0 / 111_320.0, 1.0 / (111_320.0 * np.cos(np.radians(47.0)))])
    exif_ll = np.array([47.0, -99.0]) + (corridor + rng.normal(0.0, 1.0, corridor.shape))[:, ::-1] * to_ll
    rtk_ll = np.array([47.0, -99.0]) + (corridor + [0.0, 12.0])[:, ::-1] * to_ll
    said = telemetry_against_exif("rtk.csv", exif_ll, rtk_ll, np.arange(40.0))  # warned, not refused
    assert len(said) == 1 and "beyond the 10 m the GPS noise explains" in said[0]


def test_a_copied_log_one_row_off_is_seen_on_short_capture_steps():
    """A log that copies the camera's own fixes (one receiver's values, joined to the wrong images) matches the
    neighbours' fixes to the centimetre, so a shift of its rows is seen however short the step: a synthetic
    session's 7.2 m steps with 2 m of GPS noise were below the 10 m a second receiver's noise would need. A second
    receiver's log of the same flight (its own noise and a 3 m bias), joined right, is no shift."""
    from sosmatch.workflows.image_positions import rows_shifted

    rng = np.random.default_rng(7)
    xs = np.arange(0.0, 60.0, 6.0)
    truth = np.vstack([np.column_stack([xs if k % 2 == 0 else xs[::-1], np.full(len(xs), 30.0 * k)])
                       for k in range(4)])
    exif = truth + rng.normal(0.0, 2.0, truth.shape)
    order = np.arange(len(truth))
    assert rows_shifted(exif, np.roll(exif, 1, axis=0), order)[0] == -1  # each image holds the previous row
    assert rows_shifted(exif, exif, order)[0] == 0
    for seed in range(20):
        other = truth + [3.0, 0.0] + np.random.default_rng(seed).normal(0.0, 0.5, truth.shape)
        assert rows_shifted(exif, other, order)[0] == 0, seed


def test_two_sizes_in_equal_numbers_name_both_groups_not_a_full_frame_as_the_odd_one(tmp_path):
    """nu53 L3: frames with a 160x120 thumbnail beside each were refused naming a full frame as the odd image
    ("IMG_0486.jpg: image is 1200x900 ... (40 160x120, 40 1200x900)"): on a tie each size is named with an example."""
    for k in range(2):
        write_jpeg(tmp_path / f"f{k}.jpg", 47.0 + k * 1e-4, -99.0)
        write_jpeg(tmp_path / f"f{k}_thumb.jpg", 47.0 + k * 1e-4, -99.0, size=(160, 120))
    with pytest.raises(InputError) as err:
        pfe.poses_from_images(tmp_path)
    said = str(err.value)
    assert said.startswith(f"{tmp_path}: the folder's images are of 2 sizes, as many of each")
    assert "2 400x300, e.g. f0.jpg" in said and "2 160x120, e.g. f0_thumb.jpg" in said
    write_jpeg(tmp_path / "f2.jpg", 47.0 + 2e-4, -99.0)  # no tie: the odd one is named
    with pytest.raises(InputError, match=r"f\d_thumb\.jpg: image is 160x120; .* \(3 400x300, 2 160x120\)"):
        pfe.poses_from_images(tmp_path)


def _telemetry_poses(tmp_path: Path) -> tuple[Path, Path, Path]:
    """Three geotagged images, a telemetry CSV of their attitudes, and `poses-from-exif --telemetry` of them."""
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        write_jpeg(img / f"f{k}.jpg", 47.0, -99.0 + k * 1e-4, 500.0)
    tele = tmp_path / "telemetry.csv"
    tele.write_text("FileName,Heading,PitchAngle,RollAngle\n" + "".join(f"f{k}.jpg,090,0,0\n" for k in range(3)))
    out = tmp_path / "out" / "poses.csv"
    pfe.run(img, out, telemetry=tele)
    return img, tele, out


def test_an_edited_telemetry_is_another_input_whatever_its_size_and_time(tmp_path):
    """rev49 D4: the telemetry keyed an output by its size and time here, by its path in `poses`: an edit that kept
    both (a copy with `cp -p`, a tool that restores the time) was the same input. Its content keys it now, as in
    `poses` (`output_markers.input_identity`): the poses of the old file are not replaced without --overwrite."""
    import os

    img, tele, out = _telemetry_poses(tmp_path)
    before = out.read_text()
    st = tele.stat()
    tele.write_text("FileName,Heading,PitchAngle,RollAngle\n" + "".join(f"f{k}.jpg,270,0,0\n" for k in range(3)))
    os.utime(tele, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert tele.stat().st_size == st.st_size
    with pytest.raises(InputError, match="overwrite"):
        pfe.run(img, out, telemetry=tele)
    assert out.read_text() == before
    pfe.run(img, out, telemetry=tele, overwrite=True)
    assert out.read_text() != before  # the headings of the edited file


def test_poses_an_earlier_sosmatch_keyed_by_the_telemetry_size_and_time_are_this_output(tmp_path):
    """rev52 D2: the files of `poses-from-exif --telemetry` an earlier sosmatch recorded with the telemetry keyed
    by its size and time (until fix130) were refused after the upgrade as made "from other inputs or settings".
    They are this output: written again, recorded under today's identity."""
    from sosmatch.database.output_files import FILES_REGISTRY
    from sosmatch.database.output_markers import fingerprint
    from sosmatch.workflows.image_priors import list_images

    img, tele, out = _telemetry_poses(tmp_path)
    registry = out.parent / FILES_REGISTRY
    today = json.loads(registry.read_text())["files"]["poses.csv"]["identity"]
    st = tele.stat()
    old = fingerprint({"images": [[str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns] for p in list_images(img)],
                       "telemetry": [st.st_size, st.st_mtime_ns],
                       "options": [pfe.DEFAULT_MOUNT, pfe.DEFAULT_PITCH_SIGN, pfe.DEFAULT_ROLL_SIGN, None, None, False,
                                   3.0, 5.0, "colmap"]})
    record = json.loads(registry.read_text())
    for entry in record["files"].values():  # as that version recorded them
        entry["identity"] = old
    registry.write_text(json.dumps(record))
    pfe.run(img, out, telemetry=tele)  # refused before
    assert {e["identity"] for e in json.loads(registry.read_text())["files"].values()} == {today}


def test_images_below_half_of_their_own_tie_points_are_left_out_of_the_poses_and_named(tmp_path):
    """nu58 D2: two Seneca cameras ~140 deg off their heading explained 7 of 17 / 7 of 18 of their own tie points
    (below half, within chance: the refinement stands) and were written to poses.csv and mapped with a warning
    only; such images are left out (their per-image lists too) and named. An image on fewer than 5 observations
    (it keeps its starting pose) and one without any are kept."""
    from sosmatch.plugin.geometry import Camera, Poses
    from sosmatch.workflows.pose_refinement.judge import RefinementStats

    names = [f"IMG_{k}.jpg" for k in range(5)]
    centers = np.column_stack([np.arange(5) * 20.0, np.zeros(5), np.full(5, 100.0)])
    result = pfe.ExifPoses(Poses(names, np.repeat(np.eye(3)[None], 5, axis=0), centers), 32618,
                           Camera(400, 300, 300.0, 300.0, 200.0, 150.0), {"images_without_attitude": 5},
                           headings_guessed=np.ones(5, bool), capture_times=[0.0, 1.0, 2.0, 3.0, 4.0],
                           orientations=[1, 1, 1, 1, None])
    nan = float("nan")
    stats = RefinementStats(images=5, points=200, observations=900, reprojection_rmse_before_px=3.0,
                            reprojection_rmse_after_px=0.6, reprojection_median_before_px=2.0,
                            reprojection_median_after_px=0.4, position_change_mean_m=1.0, position_change_max_m=2.0,
                            rotation_change_mean_deg=1.0, rotation_change_max_deg=2.0, iterations=2, seconds=1.0,
                            converged=True, explained_share=0.95,
                            explained_share_by_image=(0.98, 7 / 17, 0.0, nan, 0.39),
                            observations_by_image=(300, 17, 3, 0, 18))
    left = pfe.leave_out_unexplained(result, stats, tmp_path)
    assert left == ["IMG_1.jpg", "IMG_4.jpg"] and result.summary["left_out"] == left
    assert result.poses.names == ["IMG_0.jpg", "IMG_2.jpg", "IMG_3.jpg"]
    assert np.allclose(result.poses.centers[:, 0], [0.0, 40.0, 60.0])
    assert result.capture_times == [0.0, 2.0, 3.0] and result.orientations == [1, 1, 1]
    assert len(result.headings_guessed) == 3
    (said,) = result.summary["warnings"]
    assert said.startswith("2 of 5 images left out: their refined poses explain less than half of their own tie "
                           "points (IMG_1.jpg (41% of 17), IMG_4.jpg (39% of 18))")
