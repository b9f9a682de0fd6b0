"""Image-motion statistics: known shifts of a real textured image, rotation spread, few-track fallback."""

import cv2
import numpy as np
import pytest

from sosmatch.plugin.motion import (
    FALLBACK_MIN_SIGMA_PX,
    homography_displacements,
    image_motion_stats,
    lk_displacements,
)


def _texture(seed: int, shape=(360, 480)) -> np.ndarray:
    """A natural-looking texture: multi-scale blurred noise (corners everywhere, like vegetation from 100 m)."""
    rng = np.random.default_rng(seed)
    img = np.zeros(shape)
    for sigma, weight in [(1.0, 0.5), (3.0, 1.0), (9.0, 1.5)]:
        img += weight * cv2.GaussianBlur(rng.standard_normal(shape), (0, 0), sigma) * sigma
    img = (img - img.min()) / (img.max() - img.min())
    return (img * 255).astype(np.uint8)


def _warp(img: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return cv2.warpAffine(img, matrix, img.shape[::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("shift", [(7.0, 0.0), (-12.5, 9.0), (0.0, 31.0)])
def test_known_translation(shift):
    img = _texture(1)
    moved = _warp(img, np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]]))
    mu, sigma = image_motion_stats(img, moved)
    assert mu == pytest.approx(np.hypot(*shift), abs=0.3)
    assert sigma < 0.5
    disp = lk_displacements(img, moved)
    assert len(disp) > 100
    assert np.median(disp, axis=0) == pytest.approx(shift, abs=0.2)


def test_rotation_spreads_displacements():
    img = _texture(2)
    centre = (img.shape[1] / 2, img.shape[0] / 2)
    moved = _warp(img, cv2.getRotationMatrix2D(centre, 3.0, 1.0))
    mu, sigma = image_motion_stats(img, moved)
    # a 3 degree rotation moves a pixel at radius r by 2 r sin(1.5 deg): from 0 at the centre to ~15 px at corners
    assert 3.0 < mu < 12.0 and sigma > 1.5


def test_deterministic_and_accepts_color_and_float():
    img = _texture(3)
    moved = _warp(img, np.array([[1.0, 0.0, 5.0], [0.0, 1.0, -4.0]]))
    a = image_motion_stats(img, moved)
    assert a == image_motion_stats(img, moved)
    rgb = np.repeat(img[..., None], 3, axis=2)
    assert image_motion_stats(rgb, np.repeat(moved[..., None], 3, axis=2)) == pytest.approx(a, abs=1e-6)
    assert image_motion_stats(img / 255.0, moved / 255.0) == pytest.approx(a, abs=0.05)


def test_few_tracks_falls_back_to_phase_correlation():
    # a smooth blob and a front end allowed only 5 corners: too few tracks, phase correlation still sees the shift
    yy, xx = np.mgrid[0:256, 0:256]
    blob = 200.0 * np.exp(-((xx - 120.0) ** 2 + (yy - 130.0) ** 2) / (2 * 25.0**2))
    moved = 200.0 * np.exp(-((xx - 126.0) ** 2 + (yy - 138.0) ** 2) / (2 * 25.0**2))
    img, img2 = blob.astype(np.uint8), moved.astype(np.uint8)
    assert len(lk_displacements(img, img2, max_corners=5)) < 8
    mu, sigma = image_motion_stats(img, img2, max_corners=5)
    assert mu == pytest.approx(10.0, abs=1.0)
    assert sigma >= FALLBACK_MIN_SIGMA_PX and sigma >= 0.5 * mu - 1e-9
    # a blank pair has no motion to measure: unknown (NaN, so tracking applies no motion gate), not an exception
    blank = np.zeros((64, 64), np.uint8)
    assert all(np.isnan(image_motion_stats(blank, blank)))


def test_unrelated_pair_has_unknown_motion_not_a_phase_correlation_guess():
    # two views sharing no shift (a survey turn, or frames beyond the estimators' reach): phase correlation still
    # returns a peak, but at the noise floor; reporting it as the motion would gate out the true partners
    a, b = _texture(8, shape=(300, 400)), _texture(9, shape=(300, 400))
    assert all(np.isnan(image_motion_stats(a, b)))


def test_large_images_are_downscaled_but_shift_is_in_full_resolution_px():
    img = _texture(4, shape=(1200, 1600))
    moved = _warp(img, np.array([[1.0, 0.0, 20.0], [0.0, 1.0, 0.0]]))
    mu, _ = image_motion_stats(img, moved)
    assert mu == pytest.approx(20.0, abs=0.6)


def test_survey_sized_motion_uses_the_homography_fallback():
    # a survey camera triggered every ~35 m moves the image by ~40 % of its height and turns a little: LK loses the
    # corners, ORB + one RANSAC homography still measures the motion
    img = _texture(5, shape=(600, 800))
    matrix = cv2.getRotationMatrix2D((400.0, 300.0), 4.0, 1.0)
    matrix[:, 2] += (30.0, 240.0)
    moved = _warp(img, matrix)
    truth = np.linalg.norm(_grid_motion(matrix), axis=1)
    assert len(lk_displacements(img, moved)) < 0.1 * 400  # LK has lost (nearly) all of its 400 corners
    disp = homography_displacements(img, moved)
    assert len(disp) >= 16
    mu, sigma = image_motion_stats(img, moved)
    # the matches cover the overlap only, so compare with the motion of points that stay inside the frame
    assert abs(mu - truth.mean()) < 0.1 * truth.mean()
    assert sigma < 3.0 * truth.std() + 5.0
    assert (mu, sigma) == image_motion_stats(img, moved)  # deterministic (OpenCV's RANSAC has a fixed seed)


def _grid_motion(matrix: np.ndarray, shape=(600, 800)) -> np.ndarray:
    """Displacements of a pixel grid under an affine warp, for the grid points that stay inside the image."""
    yy, xx = np.mgrid[0:shape[0]:10, 0:shape[1]:10]
    pts = np.stack([xx.ravel(), yy.ravel()], 1).astype(float)
    moved = pts @ matrix[:, :2].T + matrix[:, 2]
    inside = (moved[:, 0] >= 0) & (moved[:, 0] < shape[1]) & (moved[:, 1] >= 0) & (moved[:, 1] < shape[0])
    return (moved - pts)[inside]


def test_few_corners_all_tracked_is_not_an_lk_failure():
    # a low-texture pair: only a dozen corners exist, and LK tracks every one of them; that is a healthy LK
    # result (the failure test is relative to the corners found, not to the 400 requested)
    img = np.full((240, 320), 90, np.uint8)
    rng = np.random.default_rng(6)
    for x, y in rng.integers(20, 200, (12, 2)):
        cv2.rectangle(img, (int(x), int(y)), (int(x) + 9, int(y) + 7), 230, -1)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    moved = _warp(img, np.array([[1.0, 0.0, 4.0], [0.0, 1.0, 3.0]]))
    disp = lk_displacements(img, moved)
    assert 8 <= len(disp) < 40
    mu, sigma = image_motion_stats(img, moved)
    mag = np.linalg.norm(disp, axis=1)
    assert (mu, sigma) == (float(mag.mean()), float(mag.std()))  # LK's own statistics, no fallback
    assert mu == pytest.approx(5.0, abs=0.3) and sigma < 0.5



def _through_lens(world: np.ndarray, camera, offset: tuple[float, float]) -> np.ndarray:
    """The real camera's image of a flat textured `world` seen straight down, the pinhole image's pixel (0, 0) at
    world pixel `offset`: each distorted pixel samples the world where its ray lands (the world is larger than
    the view, so no border is ever sampled)."""
    yy, xx = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    src = camera.undistort_points(np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], 1)) - 0.5  # COLMAP: centre 0.5
    maps = (src + np.asarray(offset)).reshape(camera.height, camera.width, 2).astype(np.float32)
    return cv2.remap(world, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


@pytest.mark.parametrize("shift", [(0.0, 25.0), (30.0, 240.0)])  # LK's range; the survey-sized homography fallback
def test_motion_through_a_lens_is_measured_in_undistorted_pixels(shift):
    # Tracking compares undistorted centroids, so the motion it is gated on must be measured in the same frame: a
    # pure translation of the ground is one shift in the pinhole image, but barrel distortion (k1 = -0.1) shrinks
    # it towards the rim of the real image, biasing mu_p low and inflating sigma_p
    from sosmatch.plugin.geometry import Camera

    lens = Camera(800, 600, 500.0, 500.0, 400.0, 300.0, model="SIMPLE_RADIAL", extra=(-0.1,))
    world = _texture(7, shape=(1200, 1400))
    a = _through_lens(world, lens, (300.0, 300.0))
    b = _through_lens(world, lens, (300.0 - shift[0], 300.0 - shift[1]))
    if shift[1] > 100:
        assert len(lk_displacements(a, b)) < 0.1 * 400  # the fallback is what measures this one
    mu_u, sigma_u = image_motion_stats(a, b, camera=lens)
    mu_d, sigma_d = image_motion_stats(a, b)
    truth = np.hypot(*shift)
    assert mu_u == pytest.approx(truth, rel=0.01, abs=0.3)
    assert sigma_u < 1.0
    assert abs(mu_d - truth) > 2.0 * abs(mu_u - truth) and sigma_d > 2.0 * sigma_u  # the frame mix it replaces
    assert image_motion_stats(a, b, camera=lens.pinhole()) == (mu_d, sigma_d)  # a pinhole changes nothing


def test_views_per_pass_is_the_image_extent_along_the_motion_over_the_motion():
    from sosmatch.plugin.motion import views_per_pass

    forward = np.array([[0.0, -1.0]] * 3)  # image top forward: the motion runs along the 480 px side
    assert views_per_pass(np.array([88.0, 88.0, np.nan]), forward, 640, 480) == pytest.approx(480 / 88)
    sideways = np.array([[1.0, 0.0]] * 2)  # a camera turned by 90 degrees: along the 640 px side
    assert views_per_pass(np.array([80.0, 80.0]), sideways, 640, 480) == pytest.approx(8.0)
    diagonal = np.array([[1.0, 1.0]])  # the chord through the centre ends on the shorter side's border
    assert views_per_pass(np.array([10.0]), diagonal, 640, 480) == pytest.approx(480 * np.sqrt(2) / 10)
    assert np.isnan(views_per_pass(np.array([np.nan, 0.0]), forward[:2], 640, 480))


def test_theta_n_follows_the_views_a_flight_gives():
    """theta_n (5) is at most half the keyframes that see a point on one pass and at least 2: unchanged at 100 m
    (13.6 views), 3 at 60 m (7.9), 2 at 40 m (5.4) and on a survey (2-3 views); never raised; the paper preset and
    an unknown image motion keep it."""
    from sosmatch.plugin.params import Params, for_flight, preset_params, with_overrides

    params = Params()
    assert for_flight(params, 13.6) is params and for_flight(params, float("nan")) is params
    assert for_flight(params, 7.9).triangulation.min_observations == 3
    assert for_flight(params, 5.4).triangulation.min_observations == 2
    assert for_flight(params, 2.5).triangulation.min_observations == 2
    # landmarks from a few views along a line: wrong tracks far off the ground are filtered where theta_n is lowered
    assert params.triangulation.height_outlier_sigmas == 0.0
    assert for_flight(params, 5.4).triangulation.height_outlier_sigmas == 6.0
    own = with_overrides(params, {"triangulation.height_outlier_sigmas": 4.0})
    assert for_flight(own, 5.4).triangulation.height_outlier_sigmas == 4.0  # a user's value is kept
    paper = preset_params("paper")
    assert for_flight(paper, 5.4) is paper


def _blob_pair(size: int, shift: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A smooth blob (too few corners for LK or ORB: phase correlation measures it) and the blob moved."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    r = size / 10.0

    def blob(cx, cy):
        return (200.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * r**2))).astype(np.uint8)

    c = 0.47 * size
    return blob(c, c), blob(c + shift[0], c + shift[1])


def test_phase_correlation_at_or_below_the_working_size_is_unchanged():
    # frames at or below the working size: exactly the full-frame phase correlation the fallback always ran
    a, b = _blob_pair(256, (6.0, 8.0))
    window = cv2.createHanningWindow(a.shape[::-1], cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(a.astype(np.float64), b.astype(np.float64), window)
    mu, sigma = image_motion_stats(a, b, max_corners=5)
    assert mu == float(np.hypot(dx, dy))
    assert sigma == max(FALLBACK_MIN_SIGMA_PX, 0.5 * mu)
    assert image_motion_stats(a, b, max_corners=5) == (mu, sigma)  # the cached window changes nothing


def test_large_frames_phase_correlate_on_the_working_pair(monkeypatch):
    # native-resolution frames: phase correlation runs on the <= 1024 px working pair (not on the full frames as
    # float64, which cost most of `map`'s time and memory at 4000x3000), the frames are shrunk once per pair, and
    # the shift is still in full-resolution px
    from sosmatch.plugin import motion

    a, b = _blob_pair(2048, (24.0, 32.0))
    sizes, shrinks = [], []
    phase, working = cv2.phaseCorrelate, motion._working_pair
    monkeypatch.setattr(motion.cv2, "phaseCorrelate", lambda p, c, w: sizes.append(p.shape) or phase(p, c, w))
    monkeypatch.setattr(motion, "_working_pair", lambda *args, **kw: shrinks.append(1) or working(*args, **kw))
    mu, _ = image_motion_stats(a, b, max_corners=5)
    assert sizes and max(max(s) for s in sizes) <= motion._WORK_MAX_DIM
    assert len(shrinks) == 1
    assert mu == pytest.approx(40.0, abs=2.0)
