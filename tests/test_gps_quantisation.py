"""Fixes rounded to a coarse grid of latitude/longitude, or repeated while the aircraft flies on: found from the
fixes themselves, said once, and counted as GPS noise (`plugin.gps_track.quantisation`, nu42 D5)."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sosmatch.database.exif import ImageMetadata
from sosmatch.database.exif_write import embed_metadata
from sosmatch.plugin.gps_track import grid_step, quantisation, with_quantisation
from sosmatch.workflows import poses_from_exif as pfe
from sosmatch.workflows.image_positions import coarse_fixes

LAT0, LON0 = 43.2, 11.3


def _track(n: int = 50, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A lawnmower flight's fixes (degrees) with 1 m of receiver noise: 5 lines of 10 images 12 m apart."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    east = np.where((k // 10) % 2 == 0, k % 10, 9 - k % 10) * 12.0 + rng.normal(0, 1.0, n)
    north = (k // 10) * 40.0 + rng.normal(0, 1.0, n)
    return LAT0 + north / 111_320.0, LON0 + east / (111_320.0 * math.cos(math.radians(LAT0)))


NADIR = {"GimbalYawDegree": "+0.0", "GimbalPitchDegree": "-90.0", "GimbalRollDegree": "0.0"}


def write_jpeg(path: Path, lat: float, lon: float, alt: float, seconds: int) -> None:
    """A small textured JPEG with EXIF GPS, a 35 mm focal length, a capture time and DJI gimbal angles."""
    rng = np.random.default_rng(seconds)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)).save(buf, "JPEG", quality=80)
    meta = ImageMetadata(path, 160, 120, latitude=lat, longitude=lon, altitude=alt, focal_mm=4.5, focal_35mm=24.0,
                         make="TestMake", model="Cam", datetime_original=f"2026:06:01 10:{seconds // 60:02d}:"
                         f"{seconds % 60:02d}", xmp=dict(NADIR))
    path.write_bytes(embed_metadata(buf.getvalue(), meta))


def _en(lat: np.ndarray, lon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (lon - LON0) * 111_320.0 * math.cos(math.radians(LAT0)), (lat - LAT0) * 111_320.0


def test_the_grid_of_rounded_fixes_is_measured_from_them():
    lat, lon = _track()
    assert quantisation(lat, lon) is None  # full precision
    assert quantisation(np.round(lat, 6), np.round(lon, 6)) is None  # 0.1 m: far below any receiver's noise
    q = quantisation(np.trunc(lat * 1e4) / 1e4, np.trunc(lon * 1e4) / 1e4)
    assert q is not None and q.step_lat_deg == pytest.approx(1e-4) and q.step_lon_deg == pytest.approx(1e-4)
    assert q.step_north_m == pytest.approx(11.13, abs=0.01) and q.step_east_m == pytest.approx(8.115, abs=0.01)
    assert q.sigma_m == pytest.approx(11.132 / math.sqrt(12.0), abs=1e-3)
    # whole arc seconds (a DMS export): a grid of 1/3600 deg, not assumed to be decimal
    q = quantisation(np.round(lat * 3600) / 3600, np.round(lon * 3600) / 3600)
    assert q is not None and q.step_lat_deg == pytest.approx(1 / 3600)
    # a regular synthetic line lies on the grid of its own spacing without having been rounded
    assert grid_step(47.0 + np.arange(6) * 1e-4, 1e-5)[1] is False  # type: ignore[index]
    assert quantisation(47.0 + np.arange(6) * 1e-4, np.full(6, 8.0)) is None


def test_a_coarse_grid_is_one_warning_and_more_gps_noise():
    lat, lon = _track()
    lat4, lon4 = np.trunc(lat * 1e4) / 1e4, np.trunc(lon * 1e4) / 1e4
    text, facts = coarse_fixes(lat4, lon4, *_en(lat4, lon4))
    assert text is not None and "grid of 0.0001 x 0.0001 deg" in text and "11.1 m north x 8.1 m east" in text
    assert facts["sigma_m"] == pytest.approx(3.214, abs=1e-3)
    assert with_quantisation(3.0, {"gps_quantisation": facts}) == pytest.approx(math.hypot(3.0, 3.214), abs=1e-3)
    assert with_quantisation(3.0, {"gps_quantisation": None}) == 3.0
    # 5 decimals (1.1 m): recorded and counted, no warning (0.3 m against metres of receiver noise)
    lat5, lon5 = np.round(lat, 5), np.round(lon, 5)
    text, facts = coarse_fixes(lat5, lon5, *_en(lat5, lon5))
    assert text is None and facts["sigma_m"] == pytest.approx(1.113 / math.sqrt(12.0), abs=1e-3)
    assert coarse_fixes(lat, lon, *_en(lat, lon)) == (None, None)


def test_repeated_fixes_warn_only_while_the_aircraft_moves():
    lat, lon = _track()
    stale_lat, stale_lon = lat.copy(), lon.copy()
    stale_lat[1::2], stale_lon[1::2] = lat[::2], lon[::2]  # a receiver at half the camera's rate
    text, facts = coarse_fixes(stale_lat, stale_lon, *_en(stale_lat, stale_lon))
    assert text is not None and "25 of 50 images repeat the previous image's GPS fix" in text
    assert facts["repeated_fixes"] == 25 and facts["sigma_m"] > 3.0
    # hovering: the fixes move by the receiver's noise only, and some repeat exactly
    rng = np.random.default_rng(5)
    hover_lat = LAT0 + rng.normal(0, 0.7, 30) / 111_320.0
    hover_lon = LON0 + rng.normal(0, 0.7, 30) / 111_320.0
    hover_lat[1::3], hover_lon[1::3] = hover_lat[::3], hover_lon[::3]
    assert coarse_fixes(hover_lat, hover_lon, *_en(hover_lat, hover_lon)) == (None, None)


def test_poses_from_exif_and_map_say_the_grid_and_the_refinement_counts_it(tmp_path, monkeypatch):
    lat, lon = _track(12)
    img = tmp_path / "rounded"
    img.mkdir()
    for k in range(12):
        write_jpeg(img / f"f{k:02d}.jpg", math.trunc(lat[k] * 1e4) / 1e4, math.trunc(lon[k] * 1e4) / 1e4, 500.0,
                   2 * k)
    res = pfe.run(img, tmp_path / "o" / "poses.csv")
    said = [w for w in res.summary["warnings"] if "lie on a grid of 0.0001 x 0.0001 deg" in w]
    assert len(said) == 1 and res.summary["gps_quantisation"]["step_north_m"] == pytest.approx(11.132, abs=1e-3)
    # the map's verdict says it too, not only a log line
    assert any("lie on a grid" in w for w in pfe.map_inputs_from_images(img).warnings)
    # the refinement's GPS prior includes the rounding
    seen = {}

    def fake_refine(paths, poses, camera, position_sigma_m, *args, **kwargs):
        seen["sigma"] = position_sigma_m
        raise ValueError("stop here")

    import sosmatch.workflows.pose_refinement as refinement

    monkeypatch.setattr(refinement, "refine_poses_from_images", fake_refine)
    with pytest.raises(ValueError, match="stop here"):
        pfe._refine(res, img, 3.0)
    assert seen["sigma"] == pytest.approx(math.hypot(3.0, 11.132 / math.sqrt(12.0)), abs=1e-3)


def test_bursts_and_brackets_at_one_place_are_no_slow_receiver():
    """rev26: three shots at each waypoint (a burst, or AEB's three exposure times) repeat one fix because they are
    at one place; they were said to be a receiver lagging 25 m and added 7.25 m of GPS noise."""
    rng = np.random.default_rng(0)
    east = np.repeat(np.arange(30) * 25.0 + rng.normal(0, 0.5, 30), 3)
    north = np.repeat(rng.normal(0, 0.5, 30), 3)
    lat, lon = LAT0 + north / 111_320.0, LON0 + east / (111_320.0 * math.cos(math.radians(LAT0)))
    # a burst: 0.3 s between its shots, 6 s from one waypoint to the next
    burst_t = np.repeat(np.arange(30) * 6.6, 3) + np.tile([0.0, 0.3, 0.6], 30)
    assert coarse_fixes(lat, lon, east, north, burst_t) == (None, None)
    # AEB: the three exposures in one clock second, their exposure times differ
    aeb_t, aeb_e = np.repeat(np.arange(30) * 5.0, 3), np.tile([1 / 250, 1 / 500, 1 / 1000], 30)
    assert coarse_fixes(lat, lon, east, north, aeb_t, aeb_e) == (None, None)
    assert coarse_fixes(lat, lon, east, north, None, aeb_e) == (None, None)  # without times too


def test_a_slow_receiver_and_a_grid_are_still_found_with_times_and_exposures():
    lat, lon = _track()
    times, exposures = np.arange(50) * 2.0, np.full(50, 1 / 500)  # a capture every 2 s, 12 m apart
    stale_lat, stale_lon = lat.copy(), lon.copy()
    stale_lat[1::2], stale_lon[1::2] = lat[::2], lon[::2]  # a receiver at half the camera's rate
    text, facts = coarse_fixes(stale_lat, stale_lon, *_en(stale_lat, stale_lon), times, exposures)
    assert text is not None and "25 of 50 images repeat" in text and facts["sigma_m"] > 3.0
    # nu42: fixes rounded to 1e-4 deg
    lat4, lon4 = np.trunc(lat * 1e4) / 1e4, np.trunc(lon * 1e4) / 1e4
    text, facts = coarse_fixes(lat4, lon4, *_en(lat4, lon4), times, exposures)
    assert text is not None and "grid of 0.0001 x 0.0001 deg" in text
    assert facts["sigma_m"] == pytest.approx(3.214, abs=1e-3)


def test_a_fix_repeated_within_rounding_is_a_repeat():
    """A receiver at half the camera's rate whose repeated fixes differ from the first by 1e-9 m (interpolated
    telemetry, a conversion's rounding): `repeated_fixes` counted only exact repeats, so none."""
    from sosmatch.plugin.gps_track import repeated_fixes

    east, north = np.arange(20) * 5.0 + 523_456.0, np.full(20, 4_712_345.0)
    east[1::2] = east[::2] + 1e-9
    north[1::2] += 2e-9
    count, step = repeated_fixes(east, north)
    assert count == 10 and step == pytest.approx(10.0)
