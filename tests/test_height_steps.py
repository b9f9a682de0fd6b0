"""Heights whose reference jumps or drifts (nu34): a step is fitted as a step, not a line through it; the source
that moves is named (plugin.height_drift, workflows.prior_heights, plugin.georegistration). Pure numpy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sosmatch.plugin.georegistration import georegister
from sosmatch.plugin.height_drift import fit_drift, takeoff_altitudes
from sosmatch.workflows.prior_heights import prior_heights

T = np.arange(50) * 3.0  # one flight, an image every 3 s
STEP = T >= 75.0  # frames 25-49


def _three_lines(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A nadir block of 3 lines x 20 images at ~100 m (UTM-sized coordinates), an image every 2 s: true centres,
    rotations (world_from_cam) and capture times."""
    n = 60
    centers = np.column_stack([np.repeat([0.0, 40.0, 80.0], 20), np.tile(np.arange(20) * 10.0, 3),
                               100.0 + rng.normal(0, 0.5, n)]) + [500000.0, 5200000.0, 300.0]
    return centers, np.repeat(np.diag([1.0, -1.0, -1.0])[None], n, axis=0), np.arange(n) * 2.0


def test_a_step_is_fitted_as_a_step_and_a_ramp_as_a_drift():
    """nu34 mAmix1: a 30 m step read as a line put the take-off altitude a quarter of the step off (6.9 m)."""
    rng = np.random.default_rng(0)
    step = fit_drift(T, 400.0 - 30.0 * STEP + rng.normal(0, 0.05, 50), 1.0)
    assert step.kind == "step" and step.change == pytest.approx(-30.0, abs=0.1)
    assert step.reference == pytest.approx(400.0, abs=0.05) and step.step_time == 75.0
    assert step.to_dict()["model"] == "step"
    ramp = fit_drift(T, 400.0 - 30.0 * T / T.max() + rng.normal(0, 0.05, 50), 1.0)
    assert ramp.kind == "drift" and ramp.change == pytest.approx(-30.0, abs=0.2)
    # metres of noise: neither a step nor a drift stands out
    assert fit_drift(T, 400.0 + rng.normal(0, 1.5, 50), 1.0).kind == "constant"
    # a step of 3 noise sigmas is not far enough out of the noise to be taken as one
    assert fit_drift(T, 400.0 - 4.5 * STEP + rng.normal(0, 1.5, 50), 1.0).kind != "step"


def test_the_better_segment_of_a_step_is_the_reference():
    """RTK fixed (2 cm) before, single fixes (1.5 m) after: the fixed segment's level, whatever their lengths;
    without a-priori sigmas the longer segment's."""
    rng = np.random.default_rng(1)
    late = T >= 90.0  # 30 fixed, 20 single
    v = 400.0 - 30.0 * late + np.where(late, rng.normal(0, 1.5, 50), rng.normal(0, 0.02, 50))
    fixed_first = fit_drift(T, v, 1.0, value_sigma=np.where(late, 1.5, 0.02))
    assert fixed_first.kept == "before" and fixed_first.reference == pytest.approx(400.0, abs=0.05)
    fixed_last = fit_drift(T, v, 1.0, value_sigma=np.where(late, 0.02, 1.5))
    assert fixed_last.kept == "after" and fixed_last.reference == pytest.approx(370.0, abs=1.0)
    assert fit_drift(T, v, 1.0).kept == "before"  # 30 against 20


def test_a_step_within_one_flight_gives_one_take_off_altitude_of_one_segment():
    offsets = 448.0 - 30.0 * STEP + np.random.default_rng(2).normal(0, 0.05, 50)
    takeoff, flights = takeoff_altitudes(T, offsets, 1.0)
    assert len(flights) == 1 and flights[0][1].kind == "step"
    assert np.allclose(takeoff, 448.0, atol=0.05)  # not the line's 448 + 30/4


def _tags(n, flag, sigma):
    return np.full(n, flag), np.full(n, sigma)


def test_prior_heights_name_the_jumping_gps_and_keep_the_fixed_datum():
    """nu34 D1: RTK fixed (ellipsoidal) then single fixes (orthometric, 30 m lower): one datum, the fixed one's."""
    rng = np.random.default_rng(3)
    rel = 100.0 + rng.normal(0, 0.1, 50)
    alt = 448.0 + rel - 30.0 * STEP + np.where(STEP, rng.normal(0, 1.5, 50), 0.0)
    flags = np.where(STEP, 16, 50)
    sigma = np.where(STEP, 1.5, 0.02)
    names = [f"frame_{i:05d}.jpg" for i in range(50)]
    ph = prior_heights(alt, rel, np.ones(50, bool), T, names, flags, sigma, None)
    assert np.allclose(ph.heights, 448.0 + rel, atol=0.1) and ph.consistent
    assert len(ph.warnings) == 1 and "jumps by -30" in ph.warnings[0] and "frame_00025.jpg" in ph.warnings[0]
    assert "RtkFlag 50 -> 16" in ph.warnings[0] and "drift" not in ph.warnings[0]


def test_an_rtk_fixed_altitude_is_preferred_to_a_drifting_barometer():
    """nu34 D4: RTK heights of 2 cm, RelativeAltitude drifting +2.5 m: the barometer is named, the GPS kept."""
    rng = np.random.default_rng(4)
    truth = 100.0 + rng.normal(0, 0.5, 50)
    alt = 420.0 + truth + rng.normal(0, 0.02, 50)
    rel = truth + 2.5 * T / T.max()
    names = [f"f{i}.jpg" for i in range(50)]
    ph = prior_heights(alt, rel, np.ones(50, bool), T, names, *_tags(50, 50, 0.02), None)
    assert np.array_equal(ph.heights, alt) and "RTK fixed" in ph.source and ph.consistent
    assert len(ph.warnings) == 1 and ph.warnings[0].startswith("the XMP RelativeAltitude (barometric) drifts by +2.5")
    # without RTK tags the priors cannot tell which moves, and do not blame the GPS
    ph = prior_heights(alt, rel, np.ones(50, bool), T, names, *_tags(50, -1, np.nan), None)
    assert "RelativeAltitude" in ph.source and "drift apart by -2.5" in ph.warnings[0]
    assert "the GPS altitude drifts" not in ph.warnings[0]


def test_georegister_holds_the_block_to_one_side_of_a_step_in_the_heights():
    """GPS heights (no RelativeAltitude) 30 m lower from the middle of the flight on: the block on the first
    half's datum (its longer side), not on a line through the step; the jump is said as a jump."""
    rng = np.random.default_rng(5)
    centers, rots, times = _three_lines(rng)
    n = len(times)
    to_sfm = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    sfm_c, sfm_r = (centers - centers.mean(0)) @ to_sfm.T * 0.05, np.einsum("ij,njk->nik", to_sfm, rots)
    gps = centers + rng.normal(0, 0.05, centers.shape)
    gps[35:, 2] -= 30.0
    geo = georegister(sfm_c, sfm_r, gps, rots, np.ones(n, bool), times)
    dz = geo.transform.apply(sfm_c)[:, 2] - centers[:, 2]
    # (0.3 before rev53 D2's mend: the heights' plane now has a drift in time, which takes up part of the step, and
    # on three lines flown one way time is a linear function of position: the vertical is the tags', 0.5 deg, and
    # the heights' remains tilt it by ~0.3 deg, 0.48 m at the block's edge, within that sigma)
    assert np.abs(dz).max() < 0.6
    assert geo.height_offset.kind == "step"
    assert any("GPS altitude jumps by -30" in w and "36 of 60" in w for w in geo.warnings)
    assert not any("drifts by" in w for w in geo.warnings)


def test_a_jump_in_heights_whose_fixes_are_left_out_is_said():
    """nu34 mAmix2: the second battery's single fixes (metres off horizontally: left out) carried heights 30 m
    off (another datum read as another take-off height); the block followed the others, and no line said so."""
    rng = np.random.default_rng(6)
    centers, rots, times = _three_lines(rng)
    n = len(times)
    gps = centers + rng.normal(0, 0.05, centers.shape)
    gps[40:, :2] += rng.normal(0, 3.0, (20, 2))  # single fixes: left out of the horizontal fit
    reference = centers[:, 2] - 30.0 * (times >= 80.0)
    geo = georegister(centers - centers.mean(0), rots, gps, rots, np.ones(n, bool), times, reference)
    dz = geo.transform.apply(centers - centers.mean(0))[:, 2] - centers[:, 2]
    assert np.abs(dz).max() < 0.2
    assert any("jump by -30" in w and "left out" in w and "41 of 60" in w for w in geo.warnings)


def test_a_drifting_barometer_is_named_against_the_block_when_the_gps_holds():
    """nu34 D4 without RTK tags: the priors cannot tell which source moves; the block can, and the warning
    names the barometer (the GPS altitude does not drift against the block)."""
    rng = np.random.default_rng(7)
    centers, rots, times = _three_lines(rng)
    n = len(times)
    gps = centers + rng.normal(0, 0.1, centers.shape)
    reference = centers[:, 2] + 2.5 * times / times.max() + rng.normal(0, 0.05, n)
    geo = georegister(centers - centers.mean(0), rots, gps, rots, np.ones(n, bool), times, reference)
    assert any(w.startswith("the relative altitude (barometric) drifts by +2.5") for w in geo.warnings)
    assert not any("GPS altitude drifts" in w for w in geo.warnings)


def test_a_drift_of_altitudes_in_whole_metres_is_not_a_step():
    """rev23: altitudes recorded in whole metres leave most residuals about a segment's median exactly 0 (MAD 0),
    so a 4 m drift 'stood out' as a datum jump in 30 % of flights. The residuals' resolution bounds their noise."""
    rng = np.random.default_rng(1)
    t = np.arange(80) * 3.0
    kinds = [fit_drift(t, np.round(100 + rng.normal(0, 0.1, 80) + 4.0 * t / t[-1]), 1.0).kind for _ in range(50)]
    assert kinds.count("step") == 0 and kinds.count("drift") == 50
    jump = np.round(100 + rng.normal(0, 0.3, 80) + np.where(t >= 120.0, 30.0, 0.0))  # a true jump, whole metres
    fit = fit_drift(t, jump, 1.0)
    assert fit.kind == "step" and fit.change == pytest.approx(30.0, abs=1.0)


def test_a_flight_after_a_jump_of_the_datum_rejoins_the_level_it_shares():
    """rev23: battery 1 loses its RTK fix (+30 m) and battery 2 regains it: the second flight's take-off altitude
    is the first flight's level before the jump, not another home point."""
    rng = np.random.default_rng(0)
    t = np.r_[np.arange(40) * 3.0, 400 + np.arange(40) * 3.0]
    offsets = 300 + rng.normal(0, 0.3, len(t))
    offsets[25:40] += 30.0
    _, flights = takeoff_altitudes(t, offsets, 1.0)
    assert len(flights) == 1


def test_an_rtk_image_without_an_altitude_keeps_its_barometric_height():
    n = 40
    t = np.arange(n) * 3.0
    rel = np.full(n, 60.0)
    alt = 300 + rel + np.random.default_rng(0).normal(0, 0.02, n)
    alt[5] = np.nan
    ph = prior_heights(alt, rel, np.ones(n, bool), t, [f"i{k}.jpg" for k in range(n)], np.full(n, 50),
                       np.full(n, 0.02), None)
    assert "RTK" in ph.source and ph.heights[5] == pytest.approx(360.0, abs=0.1)
