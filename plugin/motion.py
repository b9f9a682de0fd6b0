"""Image-motion statistics between consecutive keyframes (the method spec 1.4).

SOS-Match gates track candidates on how far a mask centroid moved compared with how far the image moved:
`| |m_i - m_j| - mu_p | / sigma_p < theta_v`. `mu_p` and `sigma_p` are the mean and standard deviation of the
pixel displacement of generic feature tracks between the two keyframes, as a visual-inertial front end would
provide. Here: Shi-Tomasi corners in the previous keyframe, pyramidal Lucas-Kanade into the current one, kept only
if tracking back lands within `_FB_MAX_PX` of the start (forward-backward check), which removes the tracks that
slid along edges or off occlusions. LK is deterministic (no RANSAC, no random sampling).

LK needs small motion. Survey flights that trigger the camera every 30-40 m (Seneca: 250-470 px between frames,
changing heading in turns) defeat it even at 5 pyramid levels. So when fewer than `MIN_LK_FRACTION` of the corners
survive as LK tracks, the second estimator matches ORB features (cross-checked) and keeps those consistent with one
RANSAC homography (OpenCV's RANSAC uses a fixed seed, so the result is deterministic); the ground is near-planar at
survey height, so one homography describes the image motion and its inliers' displacements give `mu_p`, `sigma_p`.

The statistics are magnitudes of displacements in the pixel frame the tracking compares centroids in. With a lens
(`camera` not a pinhole), tracking sees undistorted centroids (`mask_features.undistort_features`), so the track
ends found on the real, distorted images are undistorted through the same camera model before their displacements
are measured: otherwise `mu_p` and `sigma_p` describe a differently scaled image (barrel distortion shortens the
motion towards the edges) and the spread of the distortion itself inflates `sigma_p`.

Last fallback when neither finds enough tracks (water, fog, snow, motion blur, no overlap in a turn): the global
shift from phase correlation gives `mu_p`, and `sigma_p` is set wide (`max(FALLBACK_MIN_SIGMA_PX, 0.5 mu_p)`)
because a blind front end should loosen the motion gate rather than reject every candidate. Phase correlation
always returns its highest peak, even when the pair shares no global shift; its response (the normalised peak of
the cross-power spectrum, near 1 for a clean shift) says whether the peak is one. Below `MIN_PHASE_RESPONSE` the
motion is unknown and both statistics are NaN: tracking then applies no motion gate to that step (the epipolar,
cheirality, size and SIFT gates still hold). Measured on Seneca: 72 of 165 consecutive pairs (300-550 px apart)
fell through to phase correlation, whose peaks (response 0.005-0.013, the noise floor) put the motion at 13-370 px,
and the gate built on them rejected the true partners.
"""

from __future__ import annotations

import functools
import logging

import cv2
import numpy as np

from .geometry import Camera
from .image_matching import cross_checked_matches, gray_u8, homography_inliers, orb_features

logger = logging.getLogger(__name__)

MIN_TRACKS = 8  # below this the LK statistics are too noisy to gate on; use the fallback
# LK on a motion beyond its pyramid's reach loses nearly every corner, and the few forward-backward-consistent
# survivors are chance locks on repeated texture (measured: 17 of 400 on a 240 px shift, all wrong). A healthy pair
# keeps most corners, so fewer than this fraction of the corners found means "LK failed".
MIN_LK_FRACTION = 0.1
FALLBACK_MIN_SIGMA_PX = 2.0
# a clean global shift concentrates the normalised cross-power spectrum in one peak (response 0.94 for a blurred
# blob moved by 10 px); pairs without one sit at the noise floor (~0.01 on 1200x900 frames of a survey). Below
# this, the peak is not a measurement and the motion is reported unknown.
MIN_PHASE_RESPONSE = 0.1
_FB_MAX_PX = 1.0  # forward-backward consistency for a kept LK track (px at the working resolution)
_WORK_MAX_DIM = 1024  # larger images are downscaled for speed; displacements are scaled back


def _working_pair(prev_gray: np.ndarray, cur_gray: np.ndarray,
                  same_size: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Both keyframes as uint8 gray, downscaled by one factor (from `prev`) so the larger side is at most
    `_WORK_MAX_DIM`; returns (prev, cur, scale). Displacements measured on them divide by `scale`."""
    prev = gray_u8(prev_gray)
    cur = gray_u8(cur_gray)
    if same_size and prev.shape != cur.shape:
        raise ValueError(f"keyframes differ in size: {prev.shape} vs {cur.shape}")
    scale = min(1.0, _WORK_MAX_DIM / max(prev.shape))
    if scale < 1.0:
        size = (max(1, round(prev.shape[1] * scale)), max(1, round(prev.shape[0] * scale)))
        prev = cv2.resize(prev, size, interpolation=cv2.INTER_AREA)
        cur = cv2.resize(cur, size, interpolation=cv2.INTER_AREA)
    return prev, cur, scale


@functools.lru_cache(maxsize=4)
def _hanning_window(shape: tuple[int, int]) -> np.ndarray:
    """The phase-correlation window for a (rows, cols) working image. A map's keyframes share one size, so it is
    built once rather than per pair; read-only because the cached array is shared."""
    window = cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_64F)
    window.setflags(write=False)
    return window


def lk_displacements(prev_gray: np.ndarray, cur_gray: np.ndarray, max_corners: int = 400) -> np.ndarray:
    """Displacement vectors (N,2) in px (full resolution) of forward-backward-consistent LK corner tracks."""
    start, end, _ = _lk_tracks(*_working_pair(prev_gray, cur_gray, same_size=True), max_corners)
    return end - start


def _lk_tracks(prev: np.ndarray, cur: np.ndarray, scale: float,
               max_corners: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(start, end) pixels (N,2 each, full resolution) of the tracks of `lk_displacements` on a working pair made
    by `_working_pair` (a caller that needs it for several estimators shrinks the full-size frames once), and the
    number of corners it started from."""
    min_distance = max(5.0, min(prev.shape) / 40.0)  # spread corners over the image, not on one textured patch
    corners = cv2.goodFeaturesToTrack(prev, maxCorners=int(max_corners), qualityLevel=0.01,
                                      minDistance=min_distance, blockSize=7)
    if corners is None or len(corners) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2)), 0
    p0 = corners.astype(np.float32).reshape(-1, 1, 2)
    lk = dict(winSize=(21, 21), maxLevel=4, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, None, **lk)
    if p1 is None:
        return np.zeros((0, 2)), np.zeros((0, 2)), len(corners)
    p0r, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, **lk)
    fb = np.linalg.norm((p0r - p0).reshape(-1, 2), axis=1)
    h, w = prev.shape
    end = p1.reshape(-1, 2)
    inside = (end[:, 0] >= 0) & (end[:, 0] < w) & (end[:, 1] >= 0) & (end[:, 1] < h)
    keep = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < _FB_MAX_PX) & inside
    start = p0.reshape(-1, 2)[keep].astype(np.float64) / scale
    return start, end[keep].astype(np.float64) / scale, len(corners)


def homography_displacements(prev_gray: np.ndarray, cur_gray: np.ndarray, max_features: int = 1500,
                             ransac_px: float = 3.0) -> np.ndarray:
    """Displacement vectors (N,2) in px (full resolution) of cross-checked ORB matches that agree with one RANSAC
    homography (large-motion fallback for `lk_displacements`). Empty when fewer than `MIN_TRACKS` agree."""
    start, end = _homography_tracks(*_working_pair(prev_gray, cur_gray), max_features, ransac_px)
    return end - start


def _homography_tracks(prev: np.ndarray, cur: np.ndarray, scale: float, max_features: int = 1500,
                       ransac_px: float = 3.0, camera: Camera | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) pixels (N,2 each, full resolution) of the matches of `homography_displacements` on a working
    pair made by `_working_pair`. With a lens (`camera` not a pinhole) the matches are undistorted first and the
    homography is fitted to (and the pixels returned in) `camera.pinhole()`: a plane maps by a homography between
    pinhole images only, and on distorted pixels the RANSAC threshold would cut the image's rim, where the lens
    bends the motion most."""
    none = (np.zeros((0, 2)), np.zeros((0, 2)))
    f0, f1 = orb_features(prev, max_features), orb_features(cur, max_features)
    if len(f0) < MIN_TRACKS or len(f1) < MIN_TRACKS:
        return none
    matches = cross_checked_matches(f0.descriptors, f1.descriptors)
    if len(matches) < 2 * MIN_TRACKS:
        return none
    p0 = f0.points[matches[:, 0]].astype(np.float64) / scale
    p1 = f1.points[matches[:, 1]].astype(np.float64) / scale
    if camera is not None and not camera.is_pinhole:
        p0, p1 = camera.undistort_points(p0), camera.undistort_points(p1)
    # fitted at the working resolution, where `ransac_px` is meant
    keep = homography_inliers((p0 * scale).astype(np.float32), (p1 * scale).astype(np.float32), ransac_px)
    if keep is None or int(keep.sum()) < 2 * MIN_TRACKS:
        return none  # too few agreeing matches: a chance homography, not the image motion
    return p0[keep], p1[keep]


def image_motion_stats(prev_gray: np.ndarray, cur_gray: np.ndarray, max_corners: int = 400,
                       camera: Camera | None = None) -> tuple[float, float]:
    """Mean and standard deviation (px) of the image motion between two consecutive keyframes.

    `mu_p`, `sigma_p` are the mean and (population) standard deviation of the displacement magnitudes of LK corner
    tracks. Deterministic. With fewer than `MIN_TRACKS` tracks, falls back to ORB + homography, then to phase
    correlation (module docstring); (NaN, NaN) when none of them measures a motion. `camera`: the lens the
    images were taken through; when it is not a pinhole the displacements are measured between undistorted track
    ends, in pixels of `camera.pinhole()` (the frame of the undistorted centroids tracking compares).
    The phase-correlation shift stays as measured: it is a global estimate with a wide sigma, and the lens scale is
    1 at the principal point.
    """
    # one working pair (<= _WORK_MAX_DIM px) for all three estimators: shrinking 12 MP frames once per pair instead
    # of once per estimator, and running phase correlation on the full-size frames as float64 cost most of `map`'s
    # time and memory at native resolution (4000x3000: 1.8 GB peak). Same size-check as LK alone had.
    prev, cur, scale = _working_pair(prev_gray, cur_gray, same_size=True)
    start, end, n_corners = _lk_tracks(prev, cur, scale, max_corners)
    if camera is not None and not camera.is_pinhole and len(start):
        start, end = camera.undistort_points(start), camera.undistort_points(end)
    if len(start) < max(MIN_TRACKS, MIN_LK_FRACTION * n_corners):
        start, end = _homography_tracks(prev, cur, scale, camera=camera)  # undistorted already
    if len(start) >= MIN_TRACKS:
        mag = np.linalg.norm(end - start, axis=1)
        return float(mag.mean()), float(mag.std())
    # the global shift of the working pair, scaled back to full-resolution px (scale 1, i.e. frames at or below
    # the working size, is the same computation on the same pixels as before)
    (dx, dy), response = cv2.phaseCorrelate(prev.astype(np.float64), cur.astype(np.float64),
                                            _hanning_window(prev.shape))
    mu = float(np.hypot(dx, dy)) / scale
    if not response >= MIN_PHASE_RESPONSE:  # also NaN (a blank pair)
        logger.debug("only %d tracks and no phase-correlation peak (response %.3f): motion unknown", len(start),
                     response)
        return float("nan"), float("nan")
    sigma = max(FALLBACK_MIN_SIGMA_PX, 0.5 * mu)
    logger.debug("only %d LK tracks; phase correlation shift %.1f px (response %.2f)", len(start), mu, response)
    return mu, float(sigma)


def views_per_pass(motion_px: np.ndarray, directions_cam: np.ndarray, width: int, height: int) -> float:
    """How many consecutive keyframes see a ground point on one pass of the flight: the image's extent along the
    direction of motion (the chord through the centre of the width x height image along it) over the image motion
    between the keyframes, the median over the steps whose motion was measured (NaN: none was).

    `motion_px` (K,): mu_p of each step (`image_motion_stats`; NaN or <= 0: unknown); `directions_cam` (K, 2): the
    direction of travel of each step in the camera's image axes (x right, y down; from the poses)."""
    motion = np.asarray(motion_px, dtype=np.float64)
    d = np.asarray(directions_cam, dtype=np.float64).reshape(-1, 2)
    norm = np.linalg.norm(d, axis=1)
    ok = np.isfinite(motion) & (motion > 0) & (norm > 0)
    if not ok.any():
        return float("nan")
    u = np.abs(d[ok] / norm[ok, None])
    with np.errstate(divide="ignore"):
        chord = np.minimum(np.where(u[:, 0] > 0, width / u[:, 0], np.inf),
                           np.where(u[:, 1] > 0, height / u[:, 1], np.inf))
    return float(np.median(chord / motion[ok]))
