"""The poses' unit and frame: against the images' own GPS fixes (`plugin.pose_check.gps`, the map's pose check),
poses not in metres (feet, an unscaled reconstruction) are refused, a georeference in the wrong UTM zone or
hemisphere is named, and good poses pass, on arrays and on a rendered flight with EXIF geotags; Earth-centred
(ECEF) poses, as COLMAP's model_aligner writes them, are mapped in their UTM zone (`plugin.geodesy`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sosmatch.database.poses import read_poses_csv, write_poses_csv
from sosmatch.plugin.geodesy import ECEF_RADIUS_RANGE_M, ecef_to_grid, looks_like_ecef, topocentric_to_grid
from sosmatch.plugin.geometry import Poses
from sosmatch.plugin.params import PoseCheckParams
from sosmatch.plugin.pose_check.gps import compare_with_gps, fix_jitter_m, stale_fixes
from sosmatch.plugin.pose_check.verdict import judge_gps
from sosmatch.tools.cli import main


def _lawnmower(lines: int = 5, per_line: int = 12, length: float = 150.0, spacing: float = 30.0) -> np.ndarray:
    xs = np.linspace(0.0, length, per_line)
    rows = [np.column_stack([xs if k % 2 == 0 else xs[::-1], np.full(per_line, k * spacing),
                             np.full(per_line, 100.0)]) for k in range(lines)]
    return np.vstack(rows)


def _fixes(centers_m: np.ndarray, sigma: float, seed: int = 0, yaw_deg: float = 0.0,
           offset: tuple[float, float] = (500_000.0, 4_500_000.0)) -> np.ndarray:
    """GPS fixes of cameras at `centers_m` (metres): a rotated, shifted grid with noise `sigma` per axis."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    xy = centers_m[:, :2] @ np.array([[c, s], [-s, c]]) + np.asarray(offset)
    return xy + np.random.default_rng(seed).normal(0.0, sigma, xy.shape)


@pytest.mark.parametrize("unit, factor", [("feet", 3.28084), ("centimetres", 100.0)])
def test_poses_in_another_unit_are_refused_and_named(unit: str, factor: float) -> None:
    truth = _lawnmower()
    gps = compare_with_gps(truth * factor, _fixes(truth, 2.0, yaw_deg=30.0))
    assert gps is not None and gps.scale == pytest.approx(factor, rel=0.02)
    assert gps.unit_factor == unit
    verdict = judge_gps(gps, PoseCheckParams())
    assert len(verdict.refusals) == 1 and f"poses in {unit}?" in verdict.refusals[0]


def test_an_unscaled_reconstruction_is_refused_without_a_unit() -> None:
    truth = _lawnmower()
    gps = compare_with_gps(truth * 0.0731, _fixes(truth, 2.0, yaw_deg=-75.0))
    assert gps is not None and gps.unit_factor == ""
    refusal = judge_gps(gps, PoseCheckParams()).refusals[0]
    assert "0.07" in refusal and "unscaled reconstruction" in refusal


def test_metres_with_a_noisy_receiver_and_wrong_fixes_pass() -> None:
    truth = _lawnmower()
    fixes = _fixes(truth, 3.0, seed=1)
    fixes[::7] += 400.0  # one fix in seven far off (jumps): the robust fit leaves them out
    gps = compare_with_gps(truth, fixes)
    assert gps is not None and gps.scale == pytest.approx(1.0, abs=0.05)
    assert gps.inliers >= 0.8 * gps.fixes
    verdict = judge_gps(gps, PoseCheckParams())
    assert not verdict.refusals and not verdict.warnings


def test_a_short_flight_with_a_noisy_receiver_proves_no_scale() -> None:
    """20 % too long over a 30 m track with 6 m noise: the scale is uncertain, so no refusal on it."""
    truth = _lawnmower(lines=2, per_line=8, length=30.0, spacing=10.0)
    gps = compare_with_gps(truth * 1.2, _fixes(truth, 6.0, seed=2))
    assert gps is not None and gps.scale_sigma > 0.1
    assert not judge_gps(gps, PoseCheckParams()).refusals


def test_no_comparison_without_enough_fixes_or_with_a_frozen_receiver() -> None:
    truth = _lawnmower()
    few = np.full((len(truth), 2), np.nan)
    few[:4] = truth[:4, :2]
    assert compare_with_gps(truth, few) is None
    frozen = np.tile([[500_000.0, 4_500_000.0]], (len(truth), 1))
    assert compare_with_gps(truth, frozen) is None
    assert not judge_gps(None, PoseCheckParams()).refusals


def test_a_georeference_far_from_the_fixes_is_named() -> None:
    truth = _lawnmower() + np.array([500_000.0, 4_500_000.0, 0.0])
    fixes = _fixes(truth, 2.0, offset=(0.0, 0.0))
    good = compare_with_gps(truth, fixes, fixes)
    assert good is not None and good.offset_m < 5.0
    assert not judge_gps(good, PoseCheckParams()).warnings
    south = truth + np.array([0.0, 10_000_000.0, 0.0])  # the same zone's southern false northing
    far = compare_with_gps(south, fixes, fixes)
    warning = judge_gps(far, PoseCheckParams()).warnings[0]
    assert "10,000 km" in warning and "hemisphere" in warning
    assert not judge_gps(far, PoseCheckParams()).refusals  # the map itself is sound: its georeference is named


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.05, 20.0), yaw=st.floats(-180.0, 180.0), sigma=st.floats(0.0, 5.0),
       seed=st.integers(0, 2**16))
def test_the_scale_is_recovered_and_only_a_wrong_one_refused(scale: float, yaw: float, sigma: float,
                                                              seed: int) -> None:
    truth = _lawnmower()
    gps = compare_with_gps(truth * scale, _fixes(truth, sigma, seed, yaw))
    assert gps is not None
    assert abs(math.log(gps.scale / scale)) <= 3.0 * gps.scale_sigma + 1e-6
    refused = bool(judge_gps(gps, PoseCheckParams()).refusals)
    if abs(math.log(scale)) <= math.log1p(0.1):
        assert not refused
    if abs(math.log(scale)) > math.log1p(0.1) + 4.0 * gps.scale_sigma:
        assert refused


@pytest.fixture(scope="module")
def geotagged(tmp_path_factory) -> Path:
    """24 frames 320x240 with EXIF GPS (1 m noise), two passes at 100 m."""
    out = tmp_path_factory.mktemp("gpscheck") / "flight"
    assert main(["synth", "--out", str(out), "--frames", "24", "--width", "320", "--height", "240", "--world-size",
                 "400", "--line-length", "100", "--geotags", "exif", "-q"]) == 0
    return out


def _write(flight: Path, out: Path, scale: float = 1.0, epsg: int | None = None) -> Path:
    """The flight's true poses scaled by `scale`; with `epsg`, in the UTM grid of its geotags' origin (the world's
    centre) but labelled EPSG:`epsg`."""
    poses, _ = read_poses_csv(flight / "poses.csv")
    config = json.loads((flight / "session.json").read_text())["config"]
    centers, rotations = poses.centers, poses.rotations
    label = 0
    if epsg is not None:
        half = config["world_size_m"] / 2
        lat, lon = config["geotag_origin_latlon"]
        centers, grid_rot, label = topocentric_to_grid(centers - [half, half, 0.0], (lat, lon, 0.0))
        rotations = np.einsum("nij,njk->nik", grid_rot, rotations)
        label = epsg or label
    write_poses_csv(out, Poses(poses.names, rotations, centers * scale), epsg=label)
    return out


def test_map_refuses_poses_in_feet_before_any_work(geotagged: Path, tmp_path: Path, cli_error) -> None:
    """Poses in feet are a wrong input, refused from the images' EXIF alone: one line naming the pose file, and
    nothing written (before, the refusal came after the whole map was made, segmentation included)."""
    feet = _write(geotagged, tmp_path / "feet.csv", scale=3.28084)
    message = cli_error("map", "--images", geotagged / "images", "--poses", feet, "--camera",
                        geotagged / "cameras.txt", "--out", tmp_path / "m", "-q")
    assert "not in metres" in message and "feet?" in message and "feet.csv" in message
    assert not (tmp_path / "m").exists()
    # with refusal off the map is made and says so in its verdict, as for any refused map
    assert main(["map", "--images", str(geotagged / "images"), "--poses", str(feet), "--camera",
                 str(geotagged / "cameras.txt"), "--out", str(tmp_path / "k"), "--set", "quality.refuse=false",
                 "-q"]) == 0
    verdict = json.loads((tmp_path / "k" / "run.json").read_text())["verdict"]
    assert verdict["status"] == "accepted_despite_refusals" and any("not in metres" in r for r in verdict["refusals"])


def test_check_poses_on_good_and_on_misplaced_georeferenced_poses(geotagged: Path, tmp_path: Path,
                                                                    capsys) -> None:
    good = _write(geotagged, tmp_path / "utm.csv", epsg=0)
    assert main(["check-poses", "--images", str(geotagged / "images"), "--poses", str(good), "--camera",
                 str(geotagged / "cameras.txt"), "--out", str(tmp_path / "good.json"), "-q"]) == 0
    figures = json.loads((tmp_path / "good.json").read_text())["pose_check"]["gps"]
    assert figures["scale"] == pytest.approx(1.0, abs=0.05) and figures["offset_m"] < 5.0
    assert "GPS" not in " ".join(json.loads((tmp_path / "good.json").read_text())["verdict"]["warnings"])
    capsys.readouterr()
    south = _write(geotagged, tmp_path / "south.csv", epsg=32732)  # the north's zone 32 labelled south
    assert main(["check-poses", "--images", str(geotagged / "images"), "--poses", str(south), "--camera",
                 str(geotagged / "cameras.txt"), "-q"]) == 0
    assert "10,000 km from the images' own GPS fixes" in capsys.readouterr().out


def test_a_path_that_does_not_follow_the_fixes_is_named_not_given_a_unit() -> None:
    """Poses paired with the wrong images (shuffled): the similarity explains nothing, so its "scale" (5-18 here)
    is no unit; one warning says the path does not follow the fixes, and nothing is refused on it."""
    truth = _lawnmower()
    for seed in range(3):
        shuffled = truth[np.random.default_rng(seed).permutation(len(truth))]
        gps = compare_with_gps(shuffled, _fixes(truth, 2.0))
        verdict = judge_gps(gps, PoseCheckParams())
        assert gps is not None and gps.explained < 0.5
        assert not verdict.refusals and "does not follow" in verdict.warnings[0]


def _ecef(flight: Path) -> Poses:
    """The flight's true poses in Earth-centred coordinates (EPSG:4978), through its geotags' origin."""
    from sosmatch.plugin.geodesy import topocentric_frame

    poses, _ = read_poses_csv(flight / "poses.csv")
    config = json.loads((flight / "session.json").read_text())["config"]
    half = config["world_size_m"] / 2
    lat, lon = config["geotag_origin_latlon"]
    origin, ecef_from_enu = topocentric_frame(lat, lon, 0.0)
    centers = origin + (poses.centers - [half, half, 0.0]) @ ecef_from_enu.T
    return Poses(poses.names, np.einsum("ij,njk->nik", ecef_from_enu, poses.rotations), centers)


def test_earth_centred_poses_are_mapped_in_their_utm_zone(geotagged: Path, tmp_path: Path, capsys) -> None:
    """COLMAP's model_aligner with GPS references writes ECEF coordinates: metres, but z is not up. Before, the map
    was refused as a 42 deg tilted block and "not in metres" (0.74 x, the track's horizontal shadow); now the poses
    are converted to their UTM zone exactly and everything downstream sees a level frame."""
    ecef = _ecef(geotagged)
    utm = read_poses_csv(_write(geotagged, tmp_path / "utm.csv", epsg=0))
    assert looks_like_ecef(ecef.centers, ecef.rotations)
    assert not looks_like_ecef(utm[0].centers, utm[0].rotations)
    # a local frame whose "northing" is at the Earth's radius, cameras looking along -z: not ECEF
    far_north = utm[0].centers + [0.0, 6_370_000.0 - utm[0].centers[:, 1].mean(), 0.0]
    radius = np.linalg.norm(far_north, axis=1)
    assert np.all((radius >= ECEF_RADIUS_RANGE_M[0]) & (radius <= ECEF_RADIUS_RANGE_M[1]))
    assert not looks_like_ecef(far_north, utm[0].rotations)
    grid, rotations, epsg = ecef_to_grid(ecef.centers, ecef.rotations)
    assert epsg == utm[1] == 32632
    np.testing.assert_allclose(grid, utm[0].centers, atol=2e-3)
    np.testing.assert_allclose(rotations, utm[0].rotations, atol=1e-6)
    write_poses_csv(tmp_path / "ecef.csv", ecef, epsg=0)
    out = tmp_path / "check.json"
    assert main(["check-poses", "--images", str(geotagged / "images"), "--poses", str(tmp_path / "ecef.csv"),
                 "--camera", str(geotagged / "cameras.txt"), "--out", str(out), "-q"]) == 0
    figures = json.loads(out.read_text())["pose_check"]
    assert figures["gps"]["scale"] == pytest.approx(1.0, abs=0.05) and figures["gps"]["offset_m"] < 5.0
    assert capsys.readouterr().out.startswith("ok:")


def test_a_handful_of_fixes_warns_but_never_refuses() -> None:
    """rev14: with 5 fixes the robust fit kept 3 that agreed by chance, measured their noise far too small and
    refused true poses 19 % of the time. Fewer than MIN_FIXES_TO_REFUSE agreeing fixes only warn, however clear."""
    from sosmatch.plugin.pose_check.verdict import MIN_FIXES_TO_REFUSE

    truth = _lawnmower(lines=1, per_line=MIN_FIXES_TO_REFUSE - 1, length=60.0)
    gps = compare_with_gps(truth * 3.28084, _fixes(truth, 0.5, seed=4))
    verdict = judge_gps(gps, PoseCheckParams())
    assert gps is not None and gps.inliers < MIN_FIXES_TO_REFUSE
    assert not verdict.refusals and "too few to prove" in verdict.warnings[0]
    many = _lawnmower(lines=2, per_line=MIN_FIXES_TO_REFUSE, length=60.0)
    assert judge_gps(compare_with_gps(many * 3.28084, _fixes(many, 0.5, seed=4)),
                     PoseCheckParams()).refusals


def test_a_site_within_its_receivers_jitter_is_too_small_not_another_flight() -> None:
    """rev15: true poses of an 8 x 4 m site with a 3 m receiver were told "poses of another flight?" (the fixes'
    own jitter is most of their spread). The jitter is measured from the fixes alone: such a flight is too small
    to check, and the summary line says so instead of printing a scale."""
    truth = _lawnmower(lines=2, per_line=8, length=8.0, spacing=4.0)
    for seed in range(5):
        gps = compare_with_gps(truth, _fixes(truth, 3.0, seed=seed))
        assert gps is not None and gps.too_small and gps.fix_noise_m == pytest.approx(3.0, rel=0.6)
        assert not judge_gps(gps, PoseCheckParams()).warnings
    big = _lawnmower()  # the same receiver over 150 x 120 m: not too small, and the path follows
    assert not compare_with_gps(big, _fixes(big, 3.0)).too_small


def test_the_receivers_jitter_ignores_repeated_fixes_and_images_without_one() -> None:
    """rev16: bracketed exposures (three images, one fix) and images left out (no fix, stale) made the steps of a
    steady flight read as jitter: a straight pass shot with bracketing was "too small to check", a flight with
    every third fix missing read its 0.5 m receiver as metres. Repeats are one fix, and the neighbours of a
    gap are weighed by the real spacing."""
    line = np.column_stack([np.linspace(0.0, 300.0, 31), np.zeros(31), np.full(31, 80.0)])
    fixes = _fixes(line, 0.5, seed=2)
    alone = fix_jitter_m(fixes)
    assert alone == pytest.approx(0.5, rel=0.35)
    assert fix_jitter_m(np.repeat(fixes, 3, axis=0)) == pytest.approx(alone, rel=1e-9)
    kept = np.arange(31) % 3 != 2
    assert fix_jitter_m(fixes[kept], np.flatnonzero(kept)) == pytest.approx(0.5, rel=0.35)
    with_gaps = fixes.copy()
    with_gaps[~kept] = np.nan
    gps = compare_with_gps(line, with_gaps)
    assert gps is not None and gps.fix_noise_m == pytest.approx(0.5, rel=0.35)
    # a sample of a long flight (the pose check reads at most 300 images' EXIF): every 3rd or 4th image
    places = np.cumsum(np.r_[0, np.tile([3, 4], 15)])
    flight = np.column_stack([places * 5.0, np.zeros(len(places)), np.full(len(places), 80.0)])
    exact = _fixes(flight, 0.0)
    sampled = compare_with_gps(flight, exact, index=places)
    assert sampled.fix_noise_m < 1e-6 < compare_with_gps(flight, exact).fix_noise_m
    bracketed = np.repeat(line[:5], 3, axis=0)  # a 40 m pass, five positions, exact EXIF poses
    gps = compare_with_gps(bracketed, np.repeat(_fixes(line[:5], 0.0), 3, axis=0))
    assert gps is not None and not gps.too_small and gps.follows(0.5)


def test_a_fit_of_few_fixes_does_not_bound_the_receivers_jitter() -> None:
    """rev18: the fitted path's noise bounded the jitter from 5-12 fixes, where the robust fit keeps the few that
    agree and measures half the receiver's noise: a 10 m pass with 12 fixes of a 5 m receiver was judged, and
    its correct poses refused as "0.44 x ... not in metres". With fewer than 10 inliers the fit bounds nothing,
    and beyond it never below a receiver's wander."""
    n, size = 12, 10
    rng = np.random.default_rng([34, n, size, 7])
    truth = np.column_stack([np.linspace(0, size, n), rng.normal(0, 0.3, n), np.full(n, 60.0)])
    gps = compare_with_gps(truth, truth[:, :2] + [5e5, 4.5e6] + rng.normal(0, 5.0, (n, 2)))
    assert gps is not None and gps.too_small
    assert not judge_gps(gps, PoseCheckParams()).refusals
    refused = 0
    for seed in range(100):
        rng = np.random.default_rng([seed, n, size, 7])
        truth = np.column_stack([np.linspace(0, size, n), rng.normal(0, 0.3, n), np.full(n, 60.0)])
        gps = compare_with_gps(truth, truth[:, :2] + [5e5, 4.5e6] + rng.normal(0, 5.0, (n, 2)))
        refused += bool(judge_gps(gps, PoseCheckParams()).refusals)
    assert refused == 0


def test_unsteady_fixes_are_named_not_another_flight() -> None:
    """rev16: when most fixes scatter metres off (a receiver jumping between solutions, multipath) while the rest
    follow the path closely, fewer than half lay within the fit's noise although the path explained all of
    their spread, and the warning said "poses of another flight?". It names the unsteady fixes now; shuffled
    poses still get "another flight". (The jumps are 25 m: the fit's noise is floored at a receiver's wander,
    GNSS_WANDER_M, so jumps of 8 m lie within it and the unit is checked, nu53 M4.)"""
    truth = _lawnmower()
    rng = np.random.default_rng(0)
    fixes = truth[:, :2] + rng.normal(0.0, 0.3, (len(truth), 2))
    unsteady = rng.random(len(truth)) < 0.6
    fixes[unsteady] += rng.normal(0.0, 25.0, (int(unsteady.sum()), 2))
    gps = compare_with_gps(truth, fixes)
    warnings = judge_gps(gps, PoseCheckParams()).warnings
    assert gps is not None and gps.inliers < 0.5 * gps.fixes and gps.explained > 0.9
    assert len(warnings) == 1 and "unsteady fixes" in warnings[0] and "another flight" not in warnings[0]
    shuffled = truth[np.random.default_rng(3).permutation(len(truth))]
    warnings = judge_gps(compare_with_gps(shuffled, _fixes(truth, 0.3)), PoseCheckParams()).warnings
    assert len(warnings) == 1 and "another flight" in warnings[0]


def test_north_east_down_poses_are_named_mirrored() -> None:
    """rev14: poses in north-east-down (a proper rotation of east-north-up whose horizontal plane is mirrored)
    were told "poses of another flight?", and the map was refused as cameras below the ground. A similarity with
    a reflection fits them: the refusal names the axes."""
    truth = _lawnmower()
    ned = truth[:, [1, 0, 2]] * [1.0, 1.0, -1.0]
    refusal = judge_gps(compare_with_gps(ned, _fixes(truth, 2.0, yaw_deg=20.0)), PoseCheckParams()).refusals[0]
    assert "mirror image" in refusal and "north-east-down" in refusal
    assert not judge_gps(compare_with_gps(truth, _fixes(truth, 2.0)), PoseCheckParams()).warnings


def test_a_far_georeference_is_named_even_when_the_path_does_not_follow() -> None:
    """rev15: the early return for a path that does not follow the fixes hid the offset, which needs no fit."""
    truth = _lawnmower() + np.array([500_000.0, 4_500_000.0, 0.0])
    fixes = _fixes(truth, 2.0, offset=(0.0, 0.0))
    shuffled = truth[np.random.default_rng(0).permutation(len(truth))] + [0.0, 10_000_000.0, 0.0]
    warnings = judge_gps(compare_with_gps(shuffled, fixes, fixes), PoseCheckParams()).warnings
    assert len(warnings) == 2 and "10,000 km" in warnings[0] and "does not follow" in warnings[1]


def test_a_receiver_drifting_along_one_line_does_not_refuse_true_poses() -> None:
    """rev14: 12 m of drift along a 100 m line reads as a scale of 0.89 with no residual to show it (the fit
    absorbs it); true poses were refused. The scale's uncertainty has a floor of a receiver's wander."""
    line = np.column_stack([np.linspace(0.0, 100.0, 20), np.zeros(20), np.full(20, 80.0)])
    fixes = line[:, :2] + np.column_stack([np.linspace(0.0, 12.0, 20), np.zeros(20)])
    fixes += np.random.default_rng(1).normal(0.0, 0.3, fixes.shape)
    gps = compare_with_gps(line, fixes)
    assert gps.scale == pytest.approx(0.89, abs=0.02)
    assert not judge_gps(gps, PoseCheckParams()).refusals
    assert judge_gps(compare_with_gps(line * 3.28084, fixes), PoseCheckParams()).refusals  # feet still are


def test_fixes_held_by_a_receiver_without_lock_are_left_out() -> None:
    """rev14: a receiver that held its first position (centimetres of jitter) for the first 60 % of a flight made
    true poses "another flight's". Those fixes are stale and left out; the rest measure the scale."""
    truth = _lawnmower(lines=4, per_line=10, length=80.0, spacing=20.0)
    fixes = _fixes(truth, 1.0, seed=3)
    held = int(0.6 * len(truth))
    fixes[:held] = fixes[0] + np.random.default_rng(3).normal(0.0, 0.05, (held, 2))
    gps = compare_with_gps(truth, fixes)
    assert gps.stale == held - 1 and gps.fixes == len(truth) - held + 1
    assert gps.scale == pytest.approx(1.0, abs=0.05)
    verdict = judge_gps(gps, PoseCheckParams())
    assert not verdict.refusals and not verdict.warnings
    hover = np.column_stack([np.random.default_rng(4).normal(0.0, 0.2, (30, 2)), np.full(30, 50.0)])
    assert not stale_fixes(hover[:, :2], hover[:, :2] + [0.01, 0.0]).any()  # still cameras, still fixes: kept


def test_the_unit_is_measured_in_the_fixes_own_utm_zone() -> None:
    """rev15: the scale was measured against the fixes in the poses' labelled CRS, so a wrong label measured the
    wrong grid. True poses in their zone 32 (EPSG:32632), but labelled as zone 30, three zones west, where their
    grid stretches lengths by 0.9 %: the unit is still measured in zone 32, the label only moves the offset."""
    from pyproj import Transformer

    from sosmatch.plugin.geodesy import geographic_to_grid

    truth = _lawnmower() + [500_000.0, 5_540_000.0, 0.0]
    lon, lat = Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True).transform(truth[:, 0], truth[:, 1])
    zone30 = np.column_stack(geographic_to_grid(lat, lon, 32630)[:2])
    fixes = _fixes(truth, 0.0, offset=(0.0, 0.0))
    gps = compare_with_gps(truth, fixes, zone30)
    assert gps.scale == pytest.approx(1.0, abs=1e-6) and gps.offset_m > 100_000
    stretched = compare_with_gps(truth, zone30)  # what measuring in the labelled grid read
    assert abs(stretched.scale - 1.0) > 0.005


def test_a_corridor_with_receiver_jumps_is_not_refused_as_mirrored() -> None:
    """rev16: a straight corridor fits its mirror image as well as itself; when a receiver's jumps failed the
    inlier share, correct poses were refused as mirrored. A mirror must now fit clearly better than the proper fit."""
    line = np.column_stack([np.linspace(0.0, 300.0, 60), np.r_[np.zeros(30), np.full(30, 5.0)], np.full(60, 80.0)])
    fixes = line[:, :2] + np.random.default_rng(0).normal(0.0, 0.3, (60, 2))
    fixes[28:] += [13.6, -4.7]  # the receiver jumps by 14 m half-way
    gps = compare_with_gps(line, fixes)
    assert gps.explained > 0.9
    assert not judge_gps(gps, PoseCheckParams()).refusals


def test_poses_a_capture_step_off_their_own_fixes_are_named_against_the_noise() -> None:
    """nu53 H1: poses from a log joined one row off lay 32.5 m from the images' own fixes, 19 x their noise, and
    the check was silent below its fixed 50 m. The offset is judged against the noise (4 x, never under 10 m):
    every correct flight of 0.5-5 m receiver noise stays silent, a step of 20-30 m on a 2 m receiver is named."""
    truth = _lawnmower() + np.array([500_000.0, 4_500_000.0, 0.0])  # steps of 13.6 m along 30 m-spaced lines
    for sigma in (0.5, 2.0, 5.0):
        for seed in range(5):
            fixes = _fixes(truth, sigma, seed=seed, offset=(0.0, 0.0))
            good = compare_with_gps(truth, fixes, fixes - sigma * np.array([0.7, 0.7]))  # plus a receiver's bias
            assert good is not None and not judge_gps(good, PoseCheckParams()).warnings, (sigma, seed)
    fixes = _fixes(truth, 2.0, offset=(0.0, 0.0))
    for step in (20.0, 30.0):
        shifted = compare_with_gps(truth + [step, 0.0, 0.0], fixes, fixes)
        warning = judge_gps(shifted, PoseCheckParams()).warnings[0]
        assert f"lie {step:.0f} m from the images' own GPS fixes" in warning and "one row off" in warning


def test_poses_that_sit_exactly_on_some_fixes_are_checked_for_their_unit() -> None:
    """nu53 M4: EXIF poses a refinement left at their priors sit exactly on their fixes, so the fit measured a
    noise of 1 mm, counted every camera it moved by a metre an outlier, skipped the unit check and blamed
    "unsteady fixes", while the summary said "does not follow". The fit's noise is floored at a receiver's
    wander: the unit is checked (and refused in feet); the line names no contradiction."""
    truth = _lawnmower()
    fixes = _fixes(truth, 2.0, seed=3, offset=(0.0, 0.0))
    refined = np.column_stack([fixes, truth[:, 2]])
    moved = np.random.default_rng(4).random(len(truth)) < 0.6  # the refinement moved 60 % of them
    refined[moved, :2] += np.random.default_rng(5).normal(0.0, 1.0, (int(moved.sum()), 2))
    gps = compare_with_gps(refined, fixes)
    assert gps is not None and gps.follows(PoseCheckParams().min_gps_agreement)
    verdict = judge_gps(gps, PoseCheckParams())
    assert not verdict.warnings and not verdict.refusals
    feet = compare_with_gps(refined * 3.28084, fixes)
    assert "poses in feet?" in judge_gps(feet, PoseCheckParams()).refusals[0]
