"""Systematic pose errors the images explain (the package doc): a height drift over the capture order, a tilt of
the heights over the ground, one attitude bias; fitted jointly over all checked pairs, robust by pair."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..geometry import Poses
from .matches import PairMatches
from .two_view import essential_matrices, relative_poses, sampson_distances


@dataclass(frozen=True)
class SystematicErrors:
    """Errors of the poses that the images explain as one of a few systematic causes (module doc), with
    cluster-robust standard deviations; NaN when too few pairs were checked to fit them."""

    height_drift_m: float = float("nan")  # camera heights, last image minus first, beyond what the images show
    height_drift_sigma_m: float = float("nan")
    height_tilt_deg: float = float("nan")  # the poses' heights tilted over the ground positions, against the images
    height_tilt_sigma_deg: float = float("nan")
    height_tilt_azimuth_deg: float = float("nan")  # direction (counter-clockwise from +x) in which it rises
    attitude_bias_deg: float = float("nan")  # one rotation all cameras share against the images (its angle)
    attitude_bias_sigma_deg: float = float("nan")
    attitude_bias_axis: tuple[float, float, float] = (float("nan"),) * 3  # in the camera frame (x right, z view)
    parameters: tuple[float, ...] = ()  # (drift / H, slope x, slope y, rotation vector (3)) as fitted
    # Belsley's condition index of the fit (the weighted Jacobian, columns scaled to unit length): how nearly
    # one error can stand in for a mix of the others. A single straight line makes the drift, the tilt along it
    # and a pitch shared by all cameras nearly interchangeable (on exact poses: 46 deg of tilt "found",
    # +-7 deg); a flight over an area or along several headings separates them (measured 3-5)
    condition_index: float = float("nan")
    # whether the fit explains the pairs at all: the F statistic of the nested models (poses as given against
    # poses corrected by the six parameters), each checked pair one observation (its own random pose error moves
    # all its matches alike, so pairs, not matches, are what is independent), its p-value, and the share of the
    # pairs' misfit it removes (R^2 of the pairs). Random pose errors let six free parameters explain a part of
    # the misfit: on correct EKF poses of 40 m flights the fit ran to 121 m of drift and 38 deg of attitude (F
    # 1.9, p 0.13, a quarter explained) or, where 45 pairs share the EKF's slowly varying errors, to 61 m of drift
    # at F 5.9 (p 2e-4: pairs that share images are not independent) with less than half explained. A true
    # systematic error is most of the misfit (a 50 m drift on exact poses: p50 1.85 -> 0.30 px, 97 %; the same
    # drift at 40 m on 11-25 pairs: 83-85 %)
    explained_f: float = float("nan")
    explained_p: float = float("nan")
    explained_share: float = float("nan")

    @property
    def condition_text(self) -> str:
        """The condition index as a person reads it: whole up to a million, beyond in powers of ten (a perfectly
        collinear flight gave a 154-digit number)."""
        ci = self.condition_index
        return f"{ci:.0f}" if not ci >= 1e6 else f"{ci:.0e}".replace("e+", "e")

    def corrected(self, poses: Poses, flying_height_m: float) -> Poses:
        """`poses` with the fitted systematic errors taken off (what the images prefer)."""
        if not self.parameters:
            return poses
        return _apply(poses, np.asarray(self.parameters), flying_height_m)



# the attitude bias reads as a lag along the track when this share (at least) of the shift it gives the view
# direction lies along the track (within ~25 deg of it)
ALONG_TRACK_SHARE = 0.9


def track_in_camera(poses: Poses) -> np.ndarray:
    """The flight direction in the camera frame (x right, z view; unit), the mean of the horizontal steps between
    consecutive images (capture order), each turned into its image's camera frame; NaN when the steps do not
    agree there (mean shorter than half a step: a camera whose yaw does not follow the heading, or a hover)."""
    steps = np.diff(poses.centers, axis=0)
    steps[:, 2] = 0.0
    length = np.linalg.norm(steps, axis=1)
    keep = length > 1e-6 * max(float(np.max(length, initial=0.0)), 1e-12)
    if keep.sum() < 2:
        return np.full(3, np.nan)
    in_camera = np.einsum("nji,nj->ni", poses.rotations[:-1][keep], steps[keep] / length[keep, None])
    mean = in_camera.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return mean / norm if norm >= 0.5 else np.full(3, np.nan)


def lag_along_track_m(errors: SystematicErrors, track_camera: np.ndarray, flying_height_m: float) -> float:
    """The lag of the positions along the track (m; > 0 behind, < 0 ahead) that moves the ground in the images as
    the fitted attitude bias does, when that bias is a pitch along the flight direction (its shift of the view
    direction lies along `track_camera`, `ALONG_TRACK_SHARE`): over flat ground at a constant height H, a pitch
    theta and a lag of H tan(theta) move every ground point alike, and both turn with the heading in the camera
    frame, so the images cannot tell a log time offset or a trigger latency from a wrong attitude. NaN otherwise."""
    w = np.asarray(errors.parameters[3:6] if len(errors.parameters) >= 6 else [np.nan] * 3, np.float64)
    t = np.asarray(track_camera, np.float64)
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(t)) and np.isfinite(flying_height_m)):
        return float("nan")
    z = np.array([0.0, 0.0, 1.0])
    shift = _rotations(w) @ z - z  # the view direction as the images put it, minus as the poses do
    along = float(shift @ t)
    if np.linalg.norm(shift) == 0.0 or abs(along) < ALONG_TRACK_SHARE * float(np.linalg.norm(shift)):
        return float("nan")
    # the images see the ground further ahead than the poses say: the camera was further ahead, the positions behind
    return float(np.sign(along) * flying_height_m * np.tan(np.radians(errors.attitude_bias_deg)))


def _rotations(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of one rotation vector."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(w, np.float64)).as_matrix()


def _apply(poses: Poses, theta: np.ndarray, flying_height_m: float) -> Poses:
    """The poses corrected by systematic-error parameters theta = (drift / H, slope x, slope y, w (3)): heights
    minus the drift (linear in the capture order) and the tilt (linear in the ground position), every rotation
    turned by w in its camera frame."""
    n = len(poses)
    order = np.arange(n) / max(n - 1, 1)
    centers = poses.centers.copy()
    xy = centers[:, :2] - centers[:, :2].mean(axis=0)
    centers[:, 2] -= theta[0] * flying_height_m * order + xy @ theta[1:3]
    return Poses(poses.names, poses.rotations @ _rotations(theta[3:6]), centers)


def _stack(pairs: list[PairMatches]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All inliers in one array: x_a, x_b (M,2), the pair of each (M,), and the pairs' a, b (P,)."""
    x_a = np.concatenate([p.x_a for p in pairs]).reshape(-1, 2)
    x_b = np.concatenate([p.x_b for p in pairs]).reshape(-1, 2)
    of = np.repeat(np.arange(len(pairs)), [p.inliers for p in pairs])
    return x_a, x_b, of, np.array([p.a for p in pairs]), np.array([p.b for p in pairs])


def pair_sampson_px(poses: Poses, pairs: list[PairMatches], focal_px: float) -> np.ndarray:
    """Sampson distance (px) of every inlier of `pairs` (concatenated in pair order) under `poses`."""
    x_a, x_b, of, a, b = _stack(pairs)
    rot, t = relative_poses(poses.rotations, poses.centers, a, b)
    return sampson_distances(x_a, x_b, essential_matrices(rot, t)[of]) * focal_px


def fit_systematic_errors(poses: Poses, pairs: list[PairMatches], focal_px: float, flying_height_m: float,
                          noise_px: float, reference_inliers: int = 100, min_pairs: int = 6,
                          rounds: int = 4) -> SystematicErrors:
    """Least squares over every inlier's Sampson distance (px / `noise_px`) for the drift, tilt and attitude bias
    (module doc), robust at the level of pairs: a pair's own random pose error moves all its matches alike, so
    it is the pair, not the match, that is an outlier or not. Each round reweights the pairs by the Cauchy weight
    of their RMS error at 3 x the median pair's (iteratively reweighted least squares, `rounds` rounds); a
    robust loss on single matches instead fits the pairs whose random errors happen to agree (measured: 10 m of
    drift found in exact DJI-tag heights with 1 m horizontal GPS noise). A pair's inliers weigh at most as much
    as `reference_inliers` inliers, so a few richly textured pairs do not decide alone. Standard deviations:
    sandwich covariance clustered by pair."""
    from scipy.optimize import least_squares

    if len(pairs) < min_pairs or not np.isfinite(flying_height_m) or flying_height_m <= 0:
        return SystematicErrors()
    x_a, x_b, of, a, b = _stack(pairs)
    counts = np.bincount(of, minlength=len(pairs))
    per_inlier = np.sqrt(np.minimum(1.0, reference_inliers / np.maximum(counts, 1)))[of]
    n = len(poses)
    order = np.arange(n) / max(n - 1, 1)
    xy = poses.centers[:, :2] - poses.centers[:, :2].mean(axis=0)

    def residuals(theta: np.ndarray) -> np.ndarray:
        centers = poses.centers.copy()
        centers[:, 2] -= theta[0] * flying_height_m * order + xy @ theta[1:3]
        rot, t = relative_poses(poses.rotations @ _rotations(theta[3:6]), centers, a, b)
        r = sampson_distances(x_a, x_b, essential_matrices(rot, t)[of]) * focal_px / noise_px
        return np.nan_to_num(r, nan=1e3) * per_inlier

    norm = np.bincount(of, per_inlier**2, minlength=len(pairs))

    def pair_weights(theta: np.ndarray) -> np.ndarray:
        rms = np.sqrt(np.bincount(of, residuals(theta) ** 2, minlength=len(pairs)) / norm)
        return 1.0 / (1.0 + (rms / (3.0 * max(float(np.median(rms)), 1e-9))) ** 2)

    # bounds keep the fit among explanations that are still a survey (heights tilted < 63 deg, drifting by < 3 H):
    # beyond them a few grossly wrong pairs can be "explained" by near-vertical baselines
    bounds = (np.array([-3.0, -2.0, -2.0, -np.pi, -np.pi, -np.pi]), np.array([3.0, 2.0, 2.0, np.pi, np.pi, np.pi]))
    theta = np.zeros(6)
    w_pair = pair_weights(theta)  # weights from the poses as given: grossly wrong pairs never lead the first solve
    for _ in range(max(1, rounds)):
        scale = np.sqrt(w_pair)[of]
        theta = least_squares(lambda th, scale=scale: residuals(th) * scale, theta, bounds=bounds, diff_step=1e-6,
                              x_scale="jac", max_nfev=100).x
        w_pair = pair_weights(theta)
    r = residuals(theta)
    explained_f, explained_p, share = _explained(r / per_inlier, residuals(np.zeros(6)) / per_inlier, counts,
                                                 w_pair, len(theta))
    jac = _jacobian(residuals, theta, r)
    w = w_pair[of]
    bread = jac.T @ (w[:, None] * jac)
    scores = np.zeros((len(pairs), 6))
    np.add.at(scores, of, (w * r)[:, None] * jac)
    unit = np.sqrt(np.maximum(np.diag(bread), 1e-300))
    eig = np.linalg.eigvalsh(bread / np.outer(unit, unit))
    condition_index = float(np.sqrt(eig[-1] / max(eig[0], 1e-300)))
    inv = np.linalg.pinv(bread)
    cov = inv @ (scores.T @ scores) @ inv
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    slope = theta[1:3]
    g = float(np.hypot(*slope))
    g_sigma = float(np.sqrt(max(slope @ cov[1:3, 1:3] @ slope, 0.0)) / g) if g > 0 else float(np.max(sd[1:3]))
    w_vec = theta[3:6]
    angle = float(np.linalg.norm(w_vec))
    a_sigma = float(np.sqrt(max(w_vec @ cov[3:6, 3:6] @ w_vec, 0.0)) / angle) if angle > 0 else float(np.max(sd[3:6]))
    axis = tuple(float(v) for v in (w_vec / angle if angle > 0 else np.zeros(3)))
    return SystematicErrors(
        height_drift_m=float(theta[0] * flying_height_m), height_drift_sigma_m=float(sd[0] * flying_height_m),
        height_tilt_deg=float(np.degrees(np.arctan(g))),
        height_tilt_sigma_deg=float(np.degrees(g_sigma / (1.0 + g * g))),
        height_tilt_azimuth_deg=float(np.degrees(np.arctan2(slope[1], slope[0]))) if g > 0 else float("nan"),
        attitude_bias_deg=float(np.degrees(angle)), attitude_bias_sigma_deg=float(np.degrees(a_sigma)),
        attitude_bias_axis=axis, parameters=tuple(float(v) for v in theta), condition_index=condition_index,
        explained_f=explained_f, explained_p=explained_p, explained_share=share)


def _explained(fitted: np.ndarray, given: np.ndarray, counts: np.ndarray, w_pair: np.ndarray,
               parameters: int) -> tuple[float, float, float]:
    """F test of the fitted systematic errors against none (`SystematicErrors.explained_f`) on the residuals of
    every inlier (concatenated by pair, `counts` each) as fitted and as given. Each pair is one observation: the
    median of its squared residuals (a few matches that fit the fundamental matrix but no pose, 30 px off, would
    otherwise decide a pair's mean: measured on exact poses), weighted by the fit's final robust weight of the
    pair so that pairs set aside as grossly wrong do not decide it either way. (F, p-value, the share of the
    given misfit the fit removes); NaN when there are too few pairs."""
    from scipy.stats import f as f_distribution

    dof = len(counts) - parameters
    if dof < 1:
        return float("nan"), float("nan"), float("nan")
    cuts = np.cumsum(counts)[:-1]
    rss_given, rss_fitted = (float(np.sum(w_pair * [np.median(v**2) for v in np.split(r, cuts)]))
                             for r in (given, fitted))
    gain = max(rss_given - rss_fitted, 0.0)
    share = gain / rss_given if rss_given > 0.0 else float("nan")
    if rss_fitted <= 0.0:
        return float("inf"), 0.0, share
    f_stat = gain / parameters / (rss_fitted / dof)
    return float(f_stat), float(f_distribution.sf(f_stat, parameters, dof)), float(share)


def _jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
              step: float = 1e-6) -> np.ndarray:
    """Forward-difference Jacobian (M, len(x))."""
    jac = np.empty((len(f0), len(x)))
    for k in range(len(x)):
        dx = np.zeros_like(x)
        dx[k] = step * max(1.0, abs(x[k]))
        jac[:, k] = (fun(x + dx) - f0) / dx[k]
    return jac
