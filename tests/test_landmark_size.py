"""Nadir-equivalent landmark size: relief displacement of off-nadir views and masks cut by the image border."""

import cv2
import numpy as np
import pytest

from sosmatch.plugin.geometry import Camera, project
from sosmatch.plugin.landmark_size import cut_by_border, mean_size, nadir_size, plane_covariances
from sosmatch.plugin.mask_features import covariance_size

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
NADIR = np.diag([1.0, -1.0, -1.0])  # world_from_camera: looking down, image x east, image y south


def silhouette(center, radius, height, cam_center):
    """Mask of a vertical cylinder (base at z = 0) seen by a nadir camera: the convex hull of its two end
    circles, rasterised; returns (mask centroid, pixel covariance)."""
    a = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    ring = np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], 1)
    pts = np.concatenate([np.column_stack([ring, np.zeros(len(a))]), np.column_stack([ring, np.full(len(a), height)])])
    uv, _ = project(CAM, NADIR, cam_center, pts)
    img = np.zeros((CAM.height, CAM.width), np.uint8)
    hull = cv2.convexHull(np.round(uv * 8).astype(np.int32))
    cv2.fillConvexPoly(img, hull, 1, shift=3)
    ys, xs = np.nonzero(img)
    xy = np.stack([xs + 0.5, ys + 0.5], 1)
    return xy.mean(0), np.cov(xy.T, bias=True)


def flight(lateral_m, n=12, altitude=100.0):
    return np.stack([np.full(n, lateral_m), np.linspace(-45, 45, n), np.full(n, altitude)], 1)


@pytest.mark.parametrize("lateral_m", [0.0, 15.0, 30.0])
def test_nadir_size_removes_relief_displacement_of_a_tall_object(lateral_m):
    radius, height = 3.0, 14.0  # a conifer-like column: its side shows in every off-nadir view
    centers = flight(lateral_m)
    obs = [silhouette((0.0, 0.0), radius, height, c) for c in centers]
    cents = np.array([o[0] for o in obs])
    covs = np.array([o[1] for o in obs])
    point = np.array([0.0, 0.0, height / 2])
    rots = np.repeat(NADIR[None], len(centers), 0)
    # the truth: what a camera straight above sees (its top disc, on the plane of the landmark point)
    above = np.array([[0.0, 0.0, 100.0]])
    _, cov_above = silhouette((0.0, 0.0), radius, height, above[0])
    truth = float(np.sqrt(np.linalg.eigvalsh(plane_covariances(CAM, NADIR[None], above, point, cov_above[None])[0])[1]))
    assert truth == pytest.approx(radius / 2 * 93 / 86, rel=0.04)  # the top disc, 86 m away, on the 93 m plane
    got = nadir_size(CAM, rots, centers, point, cents, covs)
    paper = mean_size(CAM, rots, centers, point, covariance_size(covs))
    assert got == pytest.approx(truth, rel=0.08)
    if lateral_m >= 15:  # oblique views: the paper's mean grows with the side seen, the fit does not
        assert paper > 1.15 * truth


def test_sizes_agree_between_altitudes_and_flight_lines():
    radius, height = 2.5, 10.0
    point = np.array([0.0, 0.0, height / 2])
    sizes = []
    for lateral, altitude in ((5.0, 100.0), (25.0, 100.0), (20.0, 130.0), (40.0, 150.0)):
        centers = flight(lateral, altitude=altitude)
        obs = [silhouette((0.0, 0.0), radius, height, c) for c in centers]
        sizes.append(nadir_size(CAM, np.repeat(NADIR[None], len(centers), 0), centers, point,
                                np.array([o[0] for o in obs]), np.array([o[1] for o in obs])))
    assert max(sizes) / min(sizes) < 1.08


def test_plane_covariance_of_a_nadir_view_is_the_pixel_covariance_in_metres():
    cov_px = np.array([[[40.0, 5.0], [5.0, 10.0]]])
    point = np.array([3.0, -2.0, 20.0])
    center = np.array([[0.0, 0.0, 100.0]])
    got = plane_covariances(CAM, NADIR[None], center, point, cov_px)[0]
    scale = (80.0 / CAM.fx) ** 2  # depth 80 m
    flip = np.diag([1.0, -1.0])  # image y points south
    assert got == pytest.approx(scale * flip @ cov_px[0] @ flip, rel=1e-6)


def test_masks_cut_by_the_border_are_left_out():
    centroids = np.array([[320.0, 240.0], [8.0, 240.0], [320.0, 476.0]])
    covs = np.repeat((np.eye(2) * 25.0)[None], 3, 0)  # sigma 5 px: 2 sigma = 10 px
    assert cut_by_border(CAM, centroids, covs).tolist() == [False, True, True]
    # a view whose mask is cut (half the object) does not pull the size down when enough others remain
    radius, height = 3.0, 0.5
    centers = flight(0.0, n=10)
    obs = [silhouette((0.0, 0.0), radius, height, c) for c in centers]
    cents, covs = np.array([o[0] for o in obs]), np.array([o[1] for o in obs])
    cut_cent, cut_cov = cents.copy(), covs.copy()
    cut_cent[0] = [4.0, 240.0]  # pretend the first view saw it at the border, half of it
    cut_cov[0] = covs[0] * 0.25
    point = np.array([0.0, 0.0, height / 2])
    rots = np.repeat(NADIR[None], len(centers), 0)
    assert nadir_size(CAM, rots, centers, point, cut_cent, cut_cov) == pytest.approx(
        nadir_size(CAM, rots, centers, point, cents, covs), rel=0.03)
