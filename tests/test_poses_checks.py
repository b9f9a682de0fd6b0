"""Plausibility checks of an SfM block against its EXIF priors (workflows.poses.checks): the focal length."""

from __future__ import annotations

import pytest

from sosmatch.plugin.focal_prior import FocalEstimate, combine_focal
from sosmatch.plugin.geometry import Camera
from sosmatch.workflows.image_cameras import exif_focal_uncertainty
from sosmatch.workflows.poses.checks import focal_length_warnings
from sosmatch.workflows.poses.result import registration_warnings

SOURCE_35 = "FocalLengthIn35mmFilm (full-frame diagonal)"


def _priors(exif: Camera, source: str) -> dict[int, tuple[Camera, str]]:
    return {1: (exif, source)}


def test_exif_focal_uncertainty_counts_the_35mm_rounding():
    cam = Camera(320, 240, 249.6, 249.6, 160.0, 120.0)  # 27 mm equivalent: whole mm are +-1.9 %
    assert exif_focal_uncertainty(cam, SOURCE_35) == pytest.approx(0.027, abs=0.001)
    assert exif_focal_uncertainty(cam, "FocalLength + FocalPlaneX/YRes") == pytest.approx(0.02)


def _warnings(exif: Camera, images_fx: float, images_sigma_rel: float, height_m: float | None = None,
              source: str = SOURCE_35) -> tuple[list[str], FocalEstimate]:
    """The focal check of one camera whose images put f at `images_fx` +- `images_sigma_rel` (and the block at
    the focal length taken from that and EXIF)."""
    est = combine_focal(1, exif.fx, exif_focal_uncertainty(exif, source), images_fx, images_sigma_rel * exif.fx,
                        chi2_of_exif=10.0)
    taken = Camera(320, 240, est.taken_px, est.taken_px, 160.0, 120.0)
    return focal_length_warnings([est], _priors(exif, source), {1: taken}, height_m), est


@pytest.mark.parametrize("sfm_fx, expected", [(263.8, "about 6.0 m too low at the cameras' 105 m"),
                                              (234.0, "about 6.6 m too high at the cameras' 105 m"),
                                              (252.1, None), (237.1, None)])
def test_a_focal_length_off_exif_beyond_its_uncertainty_is_named_with_the_height_error(sfm_fx, expected):
    """nu25: SfM refined a 27 mm equivalent's 249.6 px to 263.8 (+5.7 %, under the old 10 % level): the
    landmarks of the map lay 3.9 m too low at ~100 m and nothing said so. Images that know their focal length
    (+-0.01 %) against EXIF's +-2.7 %: warned beyond two sigmas of the two together, -5.0 % is within them."""
    exif = Camera(320, 240, 249.6, 249.6, 160.0, 120.0)
    warnings, _ = _warnings(exif, sfm_fx, 0.0001, 104.9)
    if expected is None:
        assert warnings == []
    else:
        assert len(warnings) == 1 and expected in warnings[0] and "known to +-2.7 %" in warnings[0]
        assert f"the images' {sfm_fx:.1f} px" in warnings[0] and "EXIF's 249.6 px" in warnings[0]
        assert "degenerate" not in warnings[0]  # that is said beyond 10 % only


def test_a_focal_length_far_off_exif_also_says_the_block_may_be_degenerate():
    """Images that know f to 0.5 % put it 11 % above EXIF's (+-2.7 %): 4.0 sigmas, not yet far enough for
    EXIF to be more probably unrelated than wrong by that much: combined, and the value taken lies so far from
    EXIF's that the block may be degenerate."""
    exif = Camera(320, 240, 249.6, 249.6, 160.0, 120.0)
    warnings, est = _warnings(exif, 249.6 * 1.11, 0.005)
    assert not est.exif_set_aside
    assert len(warnings) == 1 and "+10.6 % off" in warnings[0] and "10.6 % of the cameras' height" in warnings[0]
    assert "degenerate" in warnings[0]


def test_a_focal_length_far_off_exif_that_the_images_know_sets_exif_aside():
    """Images that know f to 0.1 % put it 24 % above EXIF's (+-2.7 %): EXIF's value is named as not about
    these pixels, the images' used."""
    exif = Camera(320, 240, 249.6, 249.6, 160.0, 120.0)
    warnings, est = _warnings(exif, 310.0, 0.001)
    assert est.exif_set_aside and len(warnings) == 1 and "does not describe these images" in warnings[0]
    assert "(+24.2 %)" in warnings[0] and "19.5 % of the cameras' height" in warnings[0]


def test_a_compromise_between_contradicting_focal_lengths_is_not_passed_as_agreement():
    """The images put f 5.2 % above EXIF's and know it to +-1.2 %, EXIF to +-2 %: the focal length taken is a
    compromise 3.8 % above EXIF's, within the old check's level (the focal length taken against two of EXIF's
    sigmas), which said nothing though one of the two sources is wrong by more than it admits and the landmarks
    lie 3.8 m (EXIF right) or 1.3 m (images right) off at 100 m. The two are 2.2 sigmas of their difference
    apart: said, naming both and the height error of each."""
    exif = Camera(320, 240, 249.6, 249.6, 160.0, 120.0)
    source = "FocalLength + FocalPlaneX/YRes"
    warnings, est = _warnings(exif, 249.6 * 1.052, 0.012, 100.0, source)
    assert abs(est.taken_px / exif.fx - 1) < 2 * 0.02  # within what the old check let pass
    assert len(warnings) == 1 and "by 2.2 sigmas" in warnings[0] and "known to +-2.0 %" in warnings[0]
    assert "if the EXIF one is right the landmarks lie about 3.8 m too low" in warnings[0]
    assert "if the images' is, about 1.3 m too high" in warnings[0]
    # images that know f no better than EXIF does, as far off it: within what the two know together
    assert _warnings(exif, 249.6 * 1.052, 0.02, 100.0, source)[0] == []


def test_the_focal_warning_reaches_the_map_like_the_georegistrations():
    """poses.json kept the focal check's warning in its top-level `warnings`, which the map does not read: `map
    --images` and `map --poses DIR/poses.csv` reported a plain "ok" over landmarks 4-6 m off in height."""
    said = "camera 1: the images and EXIF contradict each other on the focal length by 3.4 sigmas"
    report = {"georegistration": {"warnings": ["a lag"]}, "focal_length_warnings": [said],
              "warnings": ["a lag", said, "3 image(s) are oriented more than 10 deg away from their tags"]}
    assert registration_warnings(report) == ["poses: a lag", f"poses: {said}"]
    assert registration_warnings({"focal_length_warnings": "not a list"}) == []


def _local_block(turn_deg: float, reversed_line: int | None = None):
    """Two flight lines (east, then back west) of 8 nadir images each whose tags are right (the yaw along the
    track), and the same block as structure from motion leaves it in a local frame: turned by `turn_deg` about
    the vertical. `reversed_line`: that line's tags are 180 deg off (a real contradiction)."""
    import math
    from types import SimpleNamespace

    import numpy as np

    from sosmatch.plugin.attitude import camera_rotations
    from sosmatch.plugin.geometry import Poses

    n = 16
    east = np.r_[np.arange(8) * 10.0, 70.0 - np.arange(8) * 10.0]
    north = np.r_[np.zeros(8), np.full(8, 40.0)]
    yaw = np.r_[np.full(8, 90.0), np.full(8, 270.0)]
    rng = np.random.default_rng(0)
    truth = camera_rotations(yaw, np.full(n, -90.0), np.zeros(n), "gimbal", 1.0, 1.0, np.zeros(n))
    tags_yaw = yaw + rng.normal(0.0, 1.0, n)  # right tags, 1 deg of noise
    if reversed_line is not None:
        tags_yaw[8 * reversed_line:8 * reversed_line + 8] += 180.0
    tags = camera_rotations(tags_yaw, np.full(n, -90.0), np.zeros(n), "gimbal", 1.0, 1.0, np.zeros(n))
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    centers = np.column_stack([east, north, np.full(n, 100.0)]) @ turn.T
    names = [f"f{k:02d}.jpg" for k in range(n)]
    priors = SimpleNamespace(positions=np.full((n, 3), np.nan), times_s=np.arange(n, dtype=float) * 2.0,
                             rotations=tags, attitude_from_tags=np.ones(n, bool), names=names)
    return priors, np.arange(n), Poses(names, np.einsum("ij,njk->nik", turn, truth), centers)


def test_a_local_frame_is_compared_with_the_tags_up_to_its_unknown_yaw():
    """nu42 D6: GPS only in sidecars, so `poses` made a local frame, and every line's right tags were said to
    contradict the images by +147 deg: the local frame's yaw is arbitrary."""
    from sosmatch.workflows.poses.checks import _compare

    priors, index, poses = _local_block(147.0)
    warnings: list[str] = []
    summary = _compare(priors, index, poses, warnings, local_frame=True)
    assert warnings == [] and summary["contradicting_lines"] == []
    assert summary["local_frame_turned_to_tags_deg"] == pytest.approx(-147.0, abs=1.0)
    assert summary["rotation_to_tags_median_deg"] < 3.0
    # a georegistered frame's yaw is known: the same turn is a contradiction there
    assert _compare(priors, index, poses, [], local_frame=False)["contradicting_lines"]
    # one line of reversed tags is still found in a local frame
    priors, index, poses = _local_block(147.0, reversed_line=1)
    warnings = []
    summary = _compare(priors, index, poses, warnings, local_frame=True)
    assert [ln["line"] for ln in summary["contradicting_lines"]] == [1] and len(warnings) == 1


def test_an_exif_focal_length_set_aside_is_named_as_wrong_with_its_likely_cause():
    """nu42 rc_rs50_upd: EXIF's 502.3 px against the images' 246.8 +- 6 px: the images' value is used and the
    one warning says EXIF's is not about these pixels (resized or cropped after capture) and where it would have
    put the landmarks."""
    exif = Camera(640, 480, 502.3, 502.3, 320.0, 240.0)
    source = "FocalLength + FocalPlaneX/YRes"
    est = combine_focal(1, exif.fx, exif_focal_uncertainty(exif, source), 246.8, 6.0, chi2_of_exif=2391.0)
    taken = Camera(640, 480, est.taken_px, est.taken_px, 320.0, 240.0)
    (warning,) = focal_length_warnings([est], _priors(exif, source), {1: taken}, 122.0)
    assert "EXIF's focal length (502.3 px" in warning and "does not describe these images" in warning
    assert "they measure 246.8 px" in warning and "the images' 246.8 px was used" in warning
    assert "resized or cropped after capture" in warning
    assert f"about {122.0 * (502.3 / 246.8 - 1):.1f} m too low" in warning


def test_the_local_frame_yaw_of_many_images_takes_memory_linear_in_them():
    """rev26: `frame_yaw_deg` compared every offset with every other (N x N float64 and bool matrices: 3.2 GB at
    20 000 tagged images without GPS). 50 000 images, four fifths turned by 40 deg, one fifth by 200 deg (a line
    of reversed tags): the answer is the majority's, within a bounded memory (the matrices: 22 GB)."""
    import tracemalloc

    import numpy as np

    from sosmatch.plugin.flight_lines import frame_yaw_deg

    def nadir(heading_deg: np.ndarray) -> np.ndarray:
        a = np.radians(heading_deg + 90.0)  # the camera's -y axis (image top) along the heading
        c, s = np.cos(a), np.sin(a)
        rz = np.zeros((len(a), 3, 3))
        rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
        return rz @ np.diag([1.0, -1.0, -1.0])

    rng = np.random.default_rng(7)
    n = 50_000
    heading = rng.uniform(-180.0, 180.0, n)
    turn = np.where(np.arange(n) % 5 == 0, 200.0, 40.0) + rng.normal(0.0, 2.0, n)
    registered, tags = nadir(heading), nadir(heading + turn)
    tracemalloc.start()
    try:
        yaw = frame_yaw_deg(registered, tags)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert yaw == pytest.approx(40.0, abs=0.2)
    assert peak < 50e6  # a few arrays of N; the N x N matrices were 22 GB
