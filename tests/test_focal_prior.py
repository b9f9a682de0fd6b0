"""An SfM block's focal length weighed against EXIF's (plugin.focal_prior, workflows.poses.focal): real pycolmap
bundle adjustments on reconstructions built here."""

from __future__ import annotations

import math

import numpy as np
import pycolmap
import pytest

from sosmatch.plugin.focal_prior import combine_focal, images_focal_sigma, residual_variance
from sosmatch.plugin.geometry import Camera, project, rotation_angle_deg, rotvec_to_matrix
from sosmatch.workflows.poses.checks import focal_length_warnings
from sosmatch.workflows.poses.focal import weigh_focal_lengths

TRUE_F = 500.0
SOURCE = "FocalLength + FocalPlaneX/YResolution"  # a lens marking: +-2 %
ORIGIN = np.array([486000.0, 5207000.0, 0.0])


def test_a_flat_profile_leaves_the_exif_value_and_a_steep_one_the_images():
    assert math.isinf(images_focal_sigma(530.0, 100.0, 500.0, 100.0, 0.1))  # holding costs nothing
    sigma = images_focal_sigma(530.0, 100.0, 500.0, 100.0 + 0.1 * 900.0, 0.1)  # chi-square 900 -> 30 / 30
    assert sigma == pytest.approx(1.0)
    flat = combine_focal(1, 500.0, 0.02, 530.0, math.inf, 0.0)
    assert flat.taken_px == 500.0 and flat.images_weight == 0.0
    steep = combine_focal(1, 500.0, 0.02, 530.0, 1.0, 900.0)  # EXIF +-10 px against the images' +-1
    assert steep.taken_px == pytest.approx(530.0 - 30.0 / 101.0)
    assert steep.images_weight == pytest.approx(100.0 / 101.0)
    equal = combine_focal(1, 500.0, 0.02, 530.0, 10.0, 9.0)
    assert equal.taken_px == pytest.approx(515.0) and equal.taken_sigma_px == pytest.approx(10.0 / math.sqrt(2))
    assert residual_variance(300.0, 100, 50) == pytest.approx(2.0)
    assert math.isnan(residual_variance(0.0, 100, 50))


def _nadir(heading_deg: float) -> np.ndarray:
    h = np.radians(heading_deg)
    top = np.array([np.sin(h), np.cos(h), 0.0])
    y, z = -top, np.array([0.0, 0.0, -1.0])
    return np.stack([np.cross(y, z), y, z], axis=1)


def _block(relief_m: float, tilt_deg: float, model_f: float, seed: int = 0,
           stretch_scale: tuple[float, ...] = (), second_camera: int = 0,
           norths: tuple[float, ...] = (0.0, 35.0)) -> pycolmap.Reconstruction:
    """Two flight lines at 80 m over points with `relief_m` of height spread, cameras tilted by `tilt_deg` (std),
    observed with 0.5 px noise by a camera of TRUE_F; the model holds the true poses and the camera at
    `model_f`, its points intersected with that focal length (as an SfM block that found `model_f`).
    `stretch_scale`: an error correlated along the flight, each contiguous stretch of images (as many as
    values) seeing its image coordinates scaled about the centre by 1 + that value. `second_camera`: the first
    that many images are of a camera 2 (the same intrinsics). `norths`: the lines' offsets (one: a corridor)."""
    rng = np.random.default_rng(seed)
    true_cam = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    centers, rots = [], []
    for line, north in enumerate(norths):
        for k in range(14):
            centers.append(ORIGIN + [k * 10.0, north, 80.0])
            turn = rotvec_to_matrix(rng.normal(0, np.radians(tilt_deg), (1, 3)))[0] if tilt_deg else np.eye(3)
            rots.append(turn @ _nadir(90 if line == 0 else 270))
    pts = ORIGIN + np.column_stack([rng.uniform(-30, 160, 500), rng.uniform(-35, 70, 500),
                                    rng.uniform(0, relief_m, 500) if relief_m else np.zeros(500)])
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480,
                                                    params=[model_f, 320.0, 240.0, 0.0], camera_id=1))
    if second_camera:
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480,
                                                        params=[model_f, 320.0, 240.0, 0.0], camera_id=2))
    obs: dict[int, list] = {}
    for i, (r, c) in enumerate(zip(rots, centers)):
        uv, depth = project(true_cam, r, c, pts)
        idx = np.flatnonzero((depth > 0) & (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480))
        uvn = uv[idx] + rng.normal(0, 0.5, (len(idx), 2))
        if stretch_scale:
            uvn = (uvn - [320.0, 240.0]) * (1.0 + stretch_scale[i * len(stretch_scale) // 28]) + [320.0, 240.0]
        im = pycolmap.Image(name=f"f{i:03d}.jpg", camera_id=2 if i < second_camera else 1, image_id=i + 1,
                            points2D=pycolmap.Point2DList([pycolmap.Point2D(p) for p in uvn]))
        rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(pycolmap.Rotation3d(r.T), -r.T @ c))
        for k, j in enumerate(idx):
            obs.setdefault(int(j), []).append((i, k, uvn[k]))
    kinv = np.linalg.inv(np.array([[model_f, 0, 320.0], [0, model_f, 240.0], [0, 0, 1]]))
    for track_obs in obs.values():
        if len(track_obs) < 3:
            continue
        a, b = np.zeros((3, 3)), np.zeros(3)
        for i, _, uv in track_obs:
            d = rots[i] @ kinv @ np.array([uv[0], uv[1], 1.0])
            m = np.eye(3) - np.outer(d, d) / (d @ d)
            a += m
            b += m @ (centers[i] - ORIGIN)
        track = pycolmap.Track()
        for i, k, _ in track_obs:
            track.add_element(i + 1, k)
        rec.add_point3D(np.linalg.solve(a, b) + ORIGIN, track)
    return rec


def _ground(rec: pycolmap.Reconstruction) -> float:
    return float(np.median([p.xyz[2] for p in rec.points3D.values()]))


def test_over_flat_ground_seen_straight_down_the_exif_focal_length_is_taken():
    """nu25: a flat, nadir block left its focal length free and SfM moved it +5.7 % (the ground 4-6 m low): the
    images cannot tell f from the depths, so the EXIF value is kept and the ground comes back up."""
    rec = _block(relief_m=0.0, tilt_deg=0.0, model_f=TRUE_F * 1.06)
    assert _ground(rec) < -4.0  # the block as SfM left it: 6 % of 80 m below the true ground
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    estimates, changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0)
    (est,) = estimates
    assert est.images_sigma_px > 2 * est.exif_sigma_px  # the images know f worse than the lens marking
    assert changed and abs(est.taken_px / TRUE_F - 1) < 0.02
    assert rec.cameras[1].params[0] == pytest.approx(est.taken_px)
    assert abs(_ground(rec)) < 1.6  # within 2 % of the 80 m


def test_with_relief_and_tilted_views_the_images_focal_length_stands_against_a_wrong_exif_one():
    """Relief and tilts break the trade of f against depth: the images know f to a fraction of a per cent and a
    6 % wrong EXIF value moves it by less than the two know it together: the block is left as it was."""
    rec = _block(relief_m=30.0, tilt_deg=4.0, model_f=TRUE_F)
    before = [im.cam_from_world().translation.copy() for im in rec.images.values()]
    wrong = Camera(640, 480, TRUE_F * 1.06, TRUE_F * 1.06, 320.0, 240.0)
    estimates, changed = weigh_focal_lengths(rec, {1: (wrong, SOURCE)}, anchor_sigma_m=3.0)
    (est,) = estimates
    assert est.images_weight > 0.95 and est.chi2_of_exif > 100
    assert abs(est.taken_px / TRUE_F - 1) < 0.005
    assert not changed and rec.cameras[1].params[0] == TRUE_F
    assert all(np.array_equal(b, im.cam_from_world().translation) for b, im in zip(before, rec.images.values()))


def test_errors_correlated_along_the_flight_do_not_pass_for_knowledge_of_the_focal_length():
    """nu32's calm wind flights and nu26's wide cameras: the misfit's curvature claimed f to 0.8-2 % and the
    images' optimum was 3-6 % off (landmark heights 4-6 m off, nothing said), because the errors are correlated
    along the flight. Here each stretch of the flight sees its image scaled by its own -4 to +16 %: the
    curvature claims far less than the stretches' scatter, the jackknife over them sees it, and the EXIF value
    holds where the curvature alone kept most of the error."""
    scales = (0.16, -0.02, 0.14, -0.04, 0.12, 0.0)  # mean +6 %
    rec = _block(relief_m=5.0, tilt_deg=1.5, model_f=TRUE_F, stretch_scale=scales)
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    order = sorted(im.name for im in rec.images.values())
    (est,), changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0, order=order)
    assert est.images_px / TRUE_F - 1 > 0.03  # the images' optimum follows the correlated error
    assert est.blocks == 6 and est.blocks_sigma_px > 2 * est.curvature_sigma_px  # the curvature is optimistic
    assert est.images_sigma_px == est.blocks_sigma_px
    by_curvature = combine_focal(1, TRUE_F, 0.02, est.images_px, est.curvature_sigma_px, est.chi2_of_exif)
    assert by_curvature.taken_px / TRUE_F - 1 > 0.04  # what the curvature alone took
    assert changed and abs(est.taken_px / TRUE_F - 1) < 0.025
    assert est.disagreement_sigmas < 2.0


def test_where_the_images_optimum_is_near_the_exif_value_no_jackknife_is_run():
    """No sigma of the images could move the block by half of the taken one: the extra adjustments are saved."""
    rec = _block(relief_m=0.0, tilt_deg=2.0, model_f=TRUE_F)
    exif = Camera(640, 480, TRUE_F * 1.002, TRUE_F * 1.002, 320.0, 240.0)
    (est,), changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0)
    assert est.blocks == 0 and math.isnan(est.blocks_sigma_px) and est.images_sigma_px == est.curvature_sigma_px


def test_cameras_without_an_exif_focal_length_are_left_alone():
    rec = _block(relief_m=0.0, tilt_deg=0.0, model_f=TRUE_F * 1.06)
    assert weigh_focal_lengths(rec, {}, anchor_sigma_m=3.0) == ([], False)
    assert rec.cameras[1].params[0] == TRUE_F * 1.06


def test_a_camera_with_two_focal_lengths_keeps_its_aspect():
    """rev21: holding f set fx and fy to one value, so a PINHOLE / OPENCV camera with fy != fx lost its aspect."""
    rec = _block(relief_m=0.0, tilt_deg=0.0, model_f=TRUE_F * 1.06)
    rec.cameras[1] = pycolmap.Camera(model="PINHOLE", width=640, height=480,
                                     params=[TRUE_F * 1.06, TRUE_F * 1.06 * 1.01, 320.0, 240.0], camera_id=1)
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    (est,), changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0)
    fx, fy = rec.cameras[1].params[:2]
    assert changed and fx == pytest.approx(est.taken_px) and fy / fx == pytest.approx(1.01, abs=1e-9)


def test_a_flight_too_short_for_the_jackknife_holds_exif_and_says_it_could_not_check_it():
    """rev23: with fewer than 9 images the jackknife had no three stretches and returned an infinite sigma, so a
    wrong EXIF value was taken and nothing said. A camera that short has no honest sigma for its focal length
    (nu53's H2, below): EXIF's value is held, and the images' contradicting optimum is said, not taken."""
    rec = _block(relief_m=30.0, tilt_deg=4.0, model_f=TRUE_F)
    for image_id in sorted(rec.images)[8:]:
        rec.deregister_frame(rec.images[image_id].frame_id)
    wrong = Camera(640, 480, TRUE_F * 1.06, TRUE_F * 1.06, 320.0, 240.0)
    (est,), changed = weigh_focal_lengths(rec, {1: (wrong, SOURCE)}, anchor_sigma_m=3.0)
    assert est.blocks == 0 and math.isnan(est.blocks_sigma_px) and est.exif_unchecked
    assert est.images_sigma_px == est.curvature_sigma_px and abs(est.images_px / TRUE_F - 1) < 0.01
    assert changed and est.taken_px == wrong.fx and rec.cameras[1].params[0] == pytest.approx(wrong.fx)
    assert est.images_weight == 0.0 and est.disagreement_sigmas > 2.0 and est.to_dict()["exif_unrelated"] is None
    (said,) = focal_length_warnings([est], {1: (wrong, SOURCE)}, {1: _cam(rec)}, 80.0)
    assert "not enough images of this camera to check its EXIF focal length" in said
    assert f"EXIF's {wrong.fx:.1f} px" in said and f"{est.images_px:.1f} px (-5." in said and "too low" in said
    assert "probably resized" not in said and "does not describe" not in said


def test_a_few_images_with_a_correlated_error_do_not_overrule_a_right_exif_focal_length():
    """nu53 H2: 3 frames exported at 800x600 with their EXIF (right: 555 px) measured 629 px, +-1.2 % by the
    misfit's curvature, too few images for the jackknife that would have shown the curvature optimistic: EXIF
    was set aside as "probably resized" and the poses written 5 m high (one 12000x9000 frame: 45 m low). Here 8
    images all see their frame scaled by +12 % (an error they share, as one short stretch of flight does): the
    curvature claims a fraction of a per cent for a value 12 % off; EXIF's right value is kept."""
    rec = _block(relief_m=30.0, tilt_deg=4.0, model_f=TRUE_F, stretch_scale=(0.12,))
    for image_id in sorted(rec.images)[8:]:
        rec.deregister_frame(rec.images[image_id].frame_id)
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    (est,), changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0)
    assert est.images_px / TRUE_F - 1 > 0.08 and est.curvature_sigma_px < 0.02 * TRUE_F  # confidently wrong
    assert est.exif_unchecked and not est.exif_set_aside
    assert changed and est.taken_px == TRUE_F and rec.cameras[1].params[0] == pytest.approx(TRUE_F)


def test_a_few_images_held_at_their_exif_focal_length_move_in_depth_not_the_block():
    """nu53 H2, one 12000 px frame among 1200 px ones: held at EXIF's focal length 3.6 times the one SfM had
    left it at, with its centre tied where SfM had put it (45 m low), it tilted the whole block by 4 deg. A
    camera of 2 images held at an EXIF value 20 % off their own: they move in depth, the other camera's 26
    images stay where they were (tied: 3.8 deg, 1.3 m)."""
    rec = _block(relief_m=30.0, tilt_deg=4.0, model_f=TRUE_F, second_camera=2)
    before = {i: (im.cam_from_world().rotation.matrix(), im.projection_center()) for i, im in rec.images.items()}
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    short = Camera(640, 480, 0.8 * TRUE_F, 0.8 * TRUE_F, 320.0, 240.0)
    estimates, changed = weigh_focal_lengths(rec, {1: (exif, SOURCE), 2: (short, SOURCE)}, anchor_sigma_m=3.0)
    one, two = estimates
    assert not one.exif_unchecked and two.exif_unchecked and changed
    assert rec.cameras[2].params[0] == pytest.approx(0.8 * TRUE_F) and abs(two.images_px / TRUE_F - 1) < 0.01
    main = sorted(rec.images)[2:]
    turn = rotation_angle_deg(np.stack([before[i][0] for i in main]),
                              np.stack([rec.images[i].cam_from_world().rotation.matrix() for i in main]))
    moved = [np.linalg.norm(before[i][1] - rec.images[i].projection_center()) for i in main]
    assert np.max(turn) < 1.5 and np.median(moved) < 0.5
    assert all(np.linalg.norm(before[i][1] - rec.images[i].projection_center()) > 8.0 for i in sorted(rec.images)[:2])


def _cam(rec: pycolmap.Reconstruction) -> Camera:
    f = float(rec.cameras[1].params[0])
    return Camera(640, 480, f, f, 320.0, 240.0)


@pytest.mark.parametrize("exif, exif_rel, images, images_sigma", [
    (502.3, 0.02, 246.8, 6.0),  # nu42 rc_rs50_upd: resized by half, EXIF's width updated (315 px was taken)
    (374.4, 0.027, 511.9, 9.4),  # nu42 cropc: a centre crop, the 35 mm equivalent of the cropped frame (448)
])
def test_an_exif_focal_length_contradicted_far_beyond_both_uncertainties_is_set_aside_not_averaged(
        exif, exif_rel, images, images_sigma):
    """Two estimates 10-20 sigmas apart cannot be averaged: the blend is a value both exclude (the landmarks
    22 m low and 7 m high). The images measure these pixels; EXIF's value is taken for not being about them."""
    est = combine_focal(1, exif, exif_rel, images, images_sigma, chi2_of_exif=1000.0)
    assert est.disagreement_sigmas > 9 and est.exif_set_aside and est.exif_unrelated > 0.999
    assert est.taken_px == images and est.taken_sigma_px == images_sigma and est.images_weight == 1.0
    assert est.to_dict()["exif_set_aside"] is True


def test_a_contradiction_within_what_the_images_sigma_may_hide_still_combines():
    """s47's cases stay as they were: nu26 D_wide80 (images +4.4 % claiming 1.2 %, EXIF -1.2 % +- 2 %: 2.4
    sigmas, the images the wrong one), a flat block whose images know f to 4 %, one that knows nothing of it."""
    wide = combine_focal(1, 355.4 * 0.988, 0.02, 355.4 * 1.044, 355.4 * 0.012, chi2_of_exif=19.9)
    assert not wide.exif_set_aside and wide.exif_unrelated < 0.01
    assert wide.images_px > wide.taken_px > wide.exif_px
    flat = combine_focal(1, 249.6, 0.027, 249.6 * 1.054, 249.6 * 0.039, chi2_of_exif=2.0)
    assert not flat.exif_set_aside and flat.taken_px < 249.6 * 1.03
    none = combine_focal(1, 500.0, 0.02, 250.0, math.inf, 0.0)
    assert not none.exif_set_aside and none.taken_px == 500.0 and none.exif_unrelated == 0.0


def test_an_exif_focal_length_of_another_image_size_leaves_the_block_as_the_images_made_it():
    """A block whose images know f (relief, tilted views) against an EXIF value twice it (the files halved after
    capture, the tag not): the images' value is taken and the block stays as it was, byte for byte."""
    rec = _block(relief_m=30.0, tilt_deg=4.0, model_f=TRUE_F)
    before = [im.cam_from_world().translation.copy() for im in rec.images.values()]
    stale = Camera(640, 480, TRUE_F * 2, TRUE_F * 2, 320.0, 240.0)
    (est,), changed = weigh_focal_lengths(rec, {1: (stale, SOURCE)}, anchor_sigma_m=3.0)
    assert est.exif_set_aside and est.taken_px == est.images_px and abs(est.taken_px / TRUE_F - 1) < 0.005
    assert not changed and rec.cameras[1].params[0] == TRUE_F
    assert all(np.array_equal(b, im.cam_from_world().translation) for b, im in zip(before, rec.images.values()))


def test_a_corridor_held_at_its_exif_focal_length_keeps_its_attitude():
    """The centre ties hold a block's gauge but not a single line's roll about itself: the held-focal adjustment
    of a corridor turned it 2.7 deg off the registered vertical (rev49 D1, s_line); the turn is undone."""
    rec = _block(relief_m=0.0, tilt_deg=0.0, model_f=TRUE_F * 1.06, norths=(0.0,))
    true_r = {i: np.asarray(im.cam_from_world().rotation.matrix()).T for i, im in rec.images.items()}
    exif = Camera(640, 480, TRUE_F, TRUE_F, 320.0, 240.0)
    _, changed = weigh_focal_lengths(rec, {1: (exif, SOURCE)}, anchor_sigma_m=3.0)
    assert changed
    u, _, vt = np.linalg.svd(sum(np.asarray(im.cam_from_world().rotation.matrix()).T @ true_r[i].T
                                 for i, im in rec.images.items()))
    assert rotation_angle_deg(u @ vt, np.eye(3)) < 0.05  # the common turn (the chordal mean)
