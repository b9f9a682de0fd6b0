"""What a camera can see of the world: the lens model's reach (`camera_models.fold_radius`: beyond it a polynomial
lens turns back and puts far-away points inside the image), footprints lifted through the lens, and the
segmenter's resolution limit on a view (`changes.in_view`, `observed_area`)."""

import numpy as np

from sosmatch.plugin.camera_models import camera_model, fold_radius
from sosmatch.plugin.changes import detect_changes, in_view, observed_area, resolution_depth
from sosmatch.plugin.evaluation.footprints import FlatGround, border_pixels, footprint_points, footprint_polygons
from sosmatch.plugin.geometry import Camera, Poses, project, rotvec_to_matrix
from sosmatch.plugin.params import ChangeParams
from sosmatch.tools.toy_sessions import change_session, lawnmower, make_spaced_world

NADIR = np.diag([1.0, -1.0, -1.0])
BARREL = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, "OPENCV", (-0.1, 0.0, 0.0, 0.0))


def test_the_fold_radius_is_where_the_radial_polynomial_peaks():
    # r (1 + k1 r^2) peaks at r = 1 / sqrt(-3 k1); with k2 the peak of r (1 + k1 r^2 + k2 r^4)
    assert np.isclose(fold_radius(camera_model("SIMPLE_RADIAL"), (-0.1,)), 1 / np.sqrt(0.3), rtol=1e-6)
    r = np.sqrt(np.roots([5 * 0.01, 3 * -0.2, 1.0]).min())  # 1 + 3 k1 r^2 + 5 k2 r^4 = 0
    assert np.isclose(fold_radius(camera_model("RADIAL"), (-0.2, 0.01)), r, rtol=1e-6)
    # fisheye: theta (1 + k theta^2) peaks at theta = 1 / sqrt(-3 k), r = tan(theta)
    assert np.isclose(fold_radius(camera_model("SIMPLE_RADIAL_FISHEYE"), (-0.3,)), np.tan(1 / np.sqrt(0.9)), rtol=1e-6)
    for name, extra in (("PINHOLE", ()), ("SIMPLE_RADIAL", (0.1,)), ("FOV", (0.9,)), ("EUCM", (0.6, 1.1))):
        assert fold_radius(camera_model(name), extra) == np.inf


def test_points_beyond_the_fold_have_no_pixel_and_no_view():
    # a nadir camera 80 m up: ground beyond 1.83 x 80 m = 146 m from the nadir point lies beyond the turn; at
    # 200-250 m the polynomial brings it back inside the 640 px wide image
    xs = np.array([0.0, 40.0, 200.0, 230.0, 250.0])
    pts = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    uv, depth = project(BARREL, NADIR, np.array([0.0, 0.0, 80.0]), pts)
    assert np.all(np.isfinite(uv[:2])) and np.all(np.isnan(uv[2:]))
    seen, _, _ = in_view(pts, np.full(len(xs), 0.5), Poses(["k"], NADIR[None], np.array([[0.0, 0.0, 80.0]])), [BARREL])
    assert seen[0].tolist() == [True, True, False, False, False]


def test_a_barrel_lens_footprint_is_where_its_border_pixels_look():
    rot, centre = NADIR[None], np.array([[5.0, -3.0, 80.0]])
    pts = footprint_points(BARREL, rot, centre, FlatGround(0.0), per_side=4)[0]
    back, _ = project(BARREL, NADIR, centre[0], pts)
    np.testing.assert_allclose(back, border_pixels(BARREL, 4), atol=1e-4)
    wide = footprint_polygons(BARREL, rot, centre, FlatGround(0.0), per_side=4)[0].area
    narrow = footprint_polygons(BARREL.pinhole(), rot, centre, FlatGround(0.0), per_side=4)[0].area
    assert wide > 1.08 * narrow


def test_a_view_counts_only_where_the_segmenter_could_keep_a_mask_of_the_object():
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r = rotvec_to_matrix(np.array([[np.radians(66.0), 0.0, 0.0]]))[0] @ NADIR  # 66 deg off nadir
    poses = Poses(["k"], r[None], np.array([[0.0, 0.0, 100.0]]))
    pts = np.array([[0.0, 600.0, 0.0], [0.0, 1500.0, 0.0], [0.0, 130.0, 0.0]])
    assert in_view(pts, np.ones(3), poses, [cam])[0][0].tolist() == [True, True, True]
    # a 2 m object (h = 1) 600 m away is a disc of 1.7 px radius: no mask of 100 px, nor one 5 / 3 as large
    # (size ratio 0.5) that would still be taken for it
    assert in_view(pts, np.ones(3), poses, [cam], min_area_px=100.0)[0][0].tolist() == [False, False, True]
    assert in_view(pts, np.ones(3), poses, [cam], min_area_px=100.0, size_tolerance=0.5)[0][0].tolist() == \
        [False, False, True]
    near = np.array([[0.0, 250.0, 0.0]])  # depth 269 m: beyond 177 m (h = 1, 100 px), within 5 / 3 of it
    assert not in_view(near, np.ones(1), poses, [cam], min_area_px=100.0)[0].any()
    assert in_view(near, np.ones(1), poses, [cam], min_area_px=100.0, size_tolerance=0.5)[0].all()
    assert in_view(pts, np.full(3, np.nan), poses, [cam], min_area_px=100.0)[0][0].all()  # unknown size: no limit
    # the footprint is cut at the same depth: 2 h f sqrt(pi / area)
    depth = resolution_depth(1.0, cam, 100.0)
    assert np.isclose(depth, 2 * 500 * np.sqrt(np.pi / 100))
    ground = FlatGround(0.0)
    cut = observed_area(poses, [cam], ground, 1.0, 100.0)
    whole = observed_area(poses, [cam], ground)
    reach = depth * np.hypot(1.0, 240 / 500)  # a ray along the image's top edge reaches that depth farther out
    assert whole.bounds[3] > 1500 and cut.bounds[3] <= reach * 1.001 and cut.area < 0.2 * whole.area
    wider = observed_area(poses, [cam], ground, 1.0, 100.0, 0.5)
    assert np.isclose(resolution_depth(1.0, cam, 100.0, 0.5), depth * 5 / 3) and wider.area > cut.area


def test_a_distorted_flight_does_not_compare_what_lay_beyond_its_lens_reach():
    # B flies x 30..70 with a barrel lens (k1 -0.1, turns 1.83 x 70 m = 128 m from its nadir points); A the whole
    # world. Without the turn B's keyframes "saw" A's landmarks 190-240 m away (folded into the image), and B's
    # lack of them made them gone
    world = make_spaced_world(260, 240.0, (1.0, 4.0), 3)
    present = np.ones(len(world.positions), dtype=bool)
    barrel = Camera(640, 480, 400.0, 400.0, 320.0, 240.0, "SIMPLE_RADIAL", (-0.1,))
    a, _ = change_session(world.positions, world.sizes, present, lawnmower(30, 230, 30, 210, 70, 30, 8), 1)
    b, _ = change_session(world.positions, world.sizes, present, lawnmower(30, 70, 30, 210, 70, 30, 8), 2,
                          camera=barrel)
    from sosmatch.plugin.multisession import Sim3

    res = detect_changes(a, b, Sim3.identity(), ChangeParams(untested_object_rate=1.0), association_tolerance_m=2.0)
    far = np.min(np.linalg.norm(a.positions[:, None, :2] - b.poses.centers[None, :, :2], axis=2), axis=1) > 140.0
    assert far.sum() > 20
    assert np.all(res.a.views[far] == 0) and np.all(res.a.label[far] == "unseen")
