"""Footprints: the border rays land on the terrain and project back onto the image border; IoU of known shapes."""

import numpy as np
import shapely

from sosmatch.plugin.evaluation.footprints import (
    FlatGround,
    HeightField,
    border_pixels,
    footprint_points,
    intersect_rays,
)
from sosmatch.plugin.evaluation.footprints import footprint_polygons as polys_of
from sosmatch.plugin.evaluation.iou import iou_matrix
from sosmatch.plugin.geometry import Camera, project


def _tilted_poses(n=5, seed=1, altitude=100.0):
    rng = np.random.default_rng(seed)
    rots, centers = [], []
    for _ in range(n):
        roll, pitch, yaw = rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25), rng.uniform(-np.pi, np.pi)
        nadir = np.diag([1.0, -1.0, -1.0])
        cz, sz = np.cos(yaw), np.sin(yaw)
        rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
        ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
        rots.append(rz @ rx @ ry @ nadir)
        centers.append([rng.uniform(-50, 50), rng.uniform(-50, 50), altitude + rng.uniform(-5, 5)])
    return np.array(rots), np.array(centers)


CAM = Camera(640, 480, 500.0, 520.0, 321.0, 239.0)


def _check_on_border(terrain, tol_px=1e-3):
    rots, centers = _tilted_poses()
    pts = footprint_points(CAM, rots, centers, terrain, per_side=6)
    border = border_pixels(CAM, 6)
    for r, c, p in zip(rots, centers, pts):
        assert np.allclose(p[:, 2], terrain(p[:, 0], p[:, 1]), atol=1e-4)  # on the ground
        uv, depth = project(CAM, r, c, p)
        assert np.all(depth > 0)
        assert np.abs(uv - border).max() < tol_px  # and seen exactly at the border pixel it was cast through


def test_flat_ground_footprint_projects_onto_image_border():
    _check_on_border(FlatGround(3.0))


def test_flat_nadir_footprint_is_the_expected_rectangle():
    cam = Camera(400, 300, 200.0, 200.0, 200.0, 150.0)
    poly = polys_of(cam, np.diag([1.0, -1.0, -1.0])[None], np.array([[10.0, 20.0, 50.0]]), FlatGround(0.0))[0]
    # Half-widths: 50 m * 200 px / 200 px = 50 m, 50 * 150 / 200 = 37.5 m.
    assert np.isclose(poly.area, 100 * 75, rtol=1e-9)
    assert np.allclose(poly.bounds, [-40, -17.5, 60, 57.5])


def test_height_field_footprint_lies_on_terrain_and_projects_onto_border():
    x = np.linspace(-300, 300, 121)
    xx, yy = np.meshgrid(x, x)
    z = 8 * np.sin(xx / 25) * np.cos(yy / 40) + 0.02 * xx
    terrain = HeightField(z, x0=-300.0, y0=-300.0, dx=5.0, dy=5.0)
    _check_on_border(terrain, tol_px=1e-2)


def test_height_field_bilinear_matches_grid_and_plane():
    x = np.arange(5.0)
    xx, yy = np.meshgrid(x, x)
    hf = HeightField(2 * xx + 3 * yy + 1, 10.0, 20.0, 2.0, 2.0)  # a plane: bilinear is exact
    px, py = np.array([10.0, 13.3, 17.9]), np.array([20.0, 21.1, 27.5])
    assert np.allclose(hf(px, py), 2 * (px - 10) / 2 + 3 * (py - 20) / 2 + 1)


def test_iou_of_known_polygons():
    sq = shapely.box(0, 0, 2, 2)
    a = np.array([sq, shapely.box(10, 10, 11, 11)], dtype=object)
    b = np.array([shapely.box(1, 0, 3, 2), sq, shapely.box(50, 50, 51, 51)], dtype=object)
    iou = iou_matrix(a, b)
    assert iou.shape == (2, 3)
    assert np.isclose(iou[0, 0], 2 / 6) and np.isclose(iou[0, 1], 1.0)
    assert np.all(iou[1] == 0) and iou[0, 2] == 0


def test_iou_matches_rasterised_estimate_on_random_quads():
    rng = np.random.default_rng(3)
    polys = []
    for _ in range(6):
        c = rng.uniform(0, 6, 2)
        ang = np.sort(rng.uniform(0, 2 * np.pi, 4))
        polys.append(shapely.Polygon(c + np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(1, 3)))
    polys = np.array(polys, dtype=object)
    iou = iou_matrix(polys[:3], polys[3:])
    g = np.linspace(-4, 10, 400)
    gx, gy = np.meshgrid(g, g)
    inside = np.stack([shapely.contains_xy(p, gx, gy) for p in polys])
    for i in range(3):
        for j in range(3):
            inter = np.count_nonzero(inside[i] & inside[3 + j])
            union = np.count_nonzero(inside[i] | inside[3 + j])
            assert abs(iou[i, j] - inter / union) < 0.02


def test_rays_reaching_a_flat_stretch_at_the_lowest_height_hit_it():
    # a height field whose minimum is a flat plateau (as a grid of ground estimates clamped at its lowest
    # value): the last sample of the march lies exactly on it, and must count as a hit
    z = np.full((20, 20), -3.7629933986058024)
    z[:5] = 0.87  # a higher strip
    field = HeightField(z, 0.0, 0.0, 10.0, 10.0)
    origins = np.array([[100.0, 150.0, 99.5], [120.0, 160.0, 99.5]])
    dirs = np.array([[-0.3, 0.2, -0.963], [0.1, -0.1, -1.0]])
    hits = intersect_rays(origins, dirs, field, max_range_m=2000.0)
    np.testing.assert_allclose(hits[:, 2], field(hits[:, 0], hits[:, 1]), atol=1e-6)
    assert np.all(np.linalg.norm(hits - origins, axis=1) < 200)
