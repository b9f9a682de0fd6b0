"""Metric size of a landmark from its mask observations: what the size descriptor depends on, and the correction.

The paper's size is h_S = mean over observations of h_px * depth / f, with h_px = sqrt(lambda_max) of the mask's
pixel covariance. Measured on synthetic sessions against the rendered object regions (BENCHMARKS.md, "Landmark
sizes"), that number depends on how the object was seen, not only on the object:

- **Observation angle (relief displacement).** A tall object seen off-nadir shows its side: the visible region
  is the top plus the side displaced away from the nadir point, so the region stretches along the radial image
  direction by about (vertical extent) x tan(off-nadir angle). A conifer's sqrt(lambda_max) grows from 1.0 x R/2
  seen from above to 1.8 x R/2 beyond 24 degrees off-nadir, a deciduous crown's to 1.3 x; the extent across the
  radial direction does not change (0.9-1.0 x R/2 at every angle). Which views a track holds depends on the
  flight: the pass it came from, the line spacing, crossing directions. This was the largest source of size
  disagreement between maps of one object (relative difference r of common landmarks: median 0.09-0.11).
- **Masks cut by the image border** lose part of the object: smaller, and their centroid moves inward.
- **Pixel size, working resolution, blur and boundary pixels**: the masks' sqrt(lambda_max) matches the rendered
  object region's within 0-5 % at 0.20 and 0.26 m/px alike (median over well-segmented objects), because
  lambda is a second moment of the whole region and a boundary band of about a pixel changes it by
  ~2 x band / radius for objects >= 8 px in radius. What the size did depend on was the segmenter's working
  pixel: at a fixed 400 px it covered 0.32 m at 100 m and 0.42 m at 130 m, where neighbouring crowns merged and
  boundaries took coarser pixels (crowns 4-16 % larger at 130 m). The map now keeps the working pixel no
  coarser than `SegmentationParams.classical_ground_resolution_m` (from the flying height it measures), which
  removes that term at its source rather than correcting sizes afterwards.
- **Depth** converts pixels to metres at the landmark point, which for a tall object lies a few metres below its
  visible top: depth ratios of 1.02-1.04 at 80-150 m, the same for every session flown at a similar altitude.

The correction (`nadir_size`): every observation's mask covariance is mapped to metres on the horizontal plane
through the landmark (the inverse of the image Jacobian of that plane at the landmark: depth, focal length and
camera tilt in one step), and the observations are fitted jointly by

    Sigma_k = Sigma_0 + (e_1 t_k + e_2 t_k^2) u_k u_k^T,   t_k = tan(theta_k)

with Sigma_0 the object's footprint covariance seen from straight above, theta_k the off-nadir angle of the
view and u_k the horizontal direction from the camera to the landmark (relief displacement points away from the
nadir). An object's side adds a band of width ~ (vertical extent) x t_k along u_k to its silhouette: the radial
variance grows about linearly while the band is narrower than the object and quadratically beyond (a 14 m column
of radius 3 m: 2.9, 4.2, 5.7, 7.5, 9.5 m^2 at t = 0.04 ... 0.40), hence two relief terms, both >= 0; linear least
squares in (Sigma_0, e_1, e_2). The landmark's size
is sqrt(lambda_max(Sigma_0)): the paper's descriptor as a nadir view would give it. Observations cut by the
image border are left out when at least `min_observations` others remain. On the synthetic maps this halved the
size disagreement of common landmarks (summer 100 m vs 130 m: median r 0.086 -> 0.04, inside theta_r = 0.2:
81 -> 92 %).
"""

from __future__ import annotations

import numpy as np

from .geometry import Camera

SIZE_ESTIMATORS = ("nadir", "mean")


def plane_covariances(camera: Camera, rotations_wc: np.ndarray, centers: np.ndarray, point: np.ndarray,
                      covariances_px: np.ndarray) -> np.ndarray:
    """(n, 2, 2) pixel covariances mapped to metres on the horizontal plane through `point` (world x, y).

    J = d(pixel) / d(world x, y) of that plane at the point's projection; Sigma_plane = J^-1 Sigma_px J^-T."""
    r_cw = np.transpose(np.asarray(rotations_wc, np.float64), (0, 2, 1))
    p = np.einsum("nij,nj->ni", r_cw, np.asarray(point, np.float64)[None, :] - np.asarray(centers, np.float64))
    z = p[:, 2:3]
    f = np.array([camera.fx, camera.fy])
    # d(u, v)/dX = f (R_xy / z - p_xy R_z / z^2), restricted to world x, y (columns 0, 1 of R_cw)
    jac = f[None, :, None] * (r_cw[:, :2, :2] / z[:, :, None] - p[:, :2, None] * r_cw[:, 2:3, :2] / z[:, :, None] ** 2)
    inv = np.linalg.inv(jac)
    return inv @ np.asarray(covariances_px, np.float64) @ np.transpose(inv, (0, 2, 1))


def border_sides(camera: Camera, centroids: np.ndarray, covariances_px: np.ndarray,
                 sigmas: float = 2.0) -> np.ndarray:
    """(n, 2, 2) bool, [mask, axis (x, y), side (low, high)]: whether the mask's `sigmas`-sigma extent reaches past
    that border of `camera`'s image, [0, width] x [0, height]. The one test of "cut by the image border": it
    holds in the image the masks were segmented in, so a lens camera's masks are tested in the real (distorted)
    image (`mask_features.undistort_features` keeps the answer beside the undistorted masks, whose pinhole
    rectangle is not the real image's border: barrel distortion pushes that border outward, pincushion inward)."""
    c = np.asarray(centroids, np.float64).reshape(-1, 2)
    ext = sigmas * np.sqrt(np.maximum(np.diagonal(np.asarray(covariances_px, np.float64).reshape(-1, 2, 2),
                                                  axis1=1, axis2=2), 0))
    lo, hi = c - ext, c + ext
    return np.stack([lo < 0, hi > np.array([camera.width, camera.height], np.float64)], axis=2)


def cut_by_border(camera: Camera, centroids: np.ndarray, covariances_px: np.ndarray, sigmas: float = 2.0) -> np.ndarray:
    """(n,) True where the mask's `sigmas`-sigma extent reaches past the image border: a mask cut by it
    (`border_sides` on any side)."""
    return border_sides(camera, centroids, covariances_px, sigmas).any(axis=(1, 2))


def fit_nadir_covariance(plane_cov: np.ndarray, directions: np.ndarray, tan_theta: np.ndarray) -> np.ndarray:
    """Sigma_0 (2, 2) of the relief model Sigma_k = Sigma_0 + (e_1 t_k + e_2 t_k^2) u_k u_k^T (t = tan theta),
    linear least squares with e_1, e_2 >= 0 (relief only stretches a region).

    plane_cov (n, 2, 2), directions (n, 2) unit horizontal directions camera -> landmark, tan_theta (n,)."""
    from scipy.optimize import lsq_linear

    s = np.asarray(plane_cov, np.float64)
    u = np.asarray(directions, np.float64)
    t = np.asarray(tan_theta, np.float64)
    n = len(s)
    a = np.zeros((3 * n, 5))
    a[0::3, 0] = a[1::3, 1] = a[2::3, 2] = 1.0
    for col, tt in ((3, t), (4, t * t)):
        a[0::3, col], a[1::3, col], a[2::3, col] = tt * u[:, 0] ** 2, tt * u[:, 0] * u[:, 1], tt * u[:, 1] ** 2
    y = np.stack([s[:, 0, 0], s[:, 0, 1], s[:, 1, 1]], axis=1).ravel()
    # scale the unknowns alike (m^2), so that the solver's tolerance means the same for every object size
    scale = max(float(np.abs(y).max(initial=0.0)), 1e-12)
    sol = lsq_linear(a, y / scale, bounds=([-np.inf] * 3 + [0.0, 0.0], [np.inf] * 5), method="bvls").x * scale
    return np.array([[sol[0], sol[1]], [sol[1], sol[2]]])


def nadir_size(camera: Camera, rotations_wc: np.ndarray, centers: np.ndarray, point: np.ndarray,
               centroids: np.ndarray, covariances_px: np.ndarray, min_observations: int = 3,
               cut: np.ndarray | None = None) -> float:
    """Metric size sqrt(lambda_max(Sigma_0)) of a landmark at `point` from its n mask observations (module doc).

    rotations_wc (n, 3, 3) and centers (n, 3): world_from_camera poses of the observing keyframes; centroids
    (n, 2) and covariances_px (n, 2, 2): the masks in COLMAP pixels of the pinhole `camera`. `cut` (n,): which
    observations the real image's border cuts (`MaskFeatures.border`, tested where the masks were segmented);
    None: `cut_by_border` against `camera`'s own image, right only for a camera without distortion. Falls back
    to the mean of the observations' own sqrt(lambda_max) on the plane when the fit is degenerate (fewer than 2
    observations, a non-positive Sigma_0)."""
    cov = plane_covariances(camera, rotations_wc, centers, point, covariances_px)
    keep = ~(cut_by_border(camera, centroids, covariances_px) if cut is None else np.asarray(cut, bool))
    if np.count_nonzero(keep) < max(2, min_observations):
        keep = np.ones(len(cov), bool)
    cov = cov[keep]
    per_obs = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, 1], 0.0))
    if len(cov) < 2:
        return float(per_obs.mean()) if len(per_obs) else float("nan")
    d = np.asarray(point, np.float64)[None, :2] - np.asarray(centers, np.float64)[keep, :2]
    horiz = np.linalg.norm(d, axis=1)
    height = np.abs(np.asarray(centers, np.float64)[keep, 2] - float(point[2]))
    u = d / np.maximum(horiz, 1e-9)[:, None]
    sigma0 = fit_nadir_covariance(cov, u, horiz / np.maximum(height, 1e-9))
    lam = np.linalg.eigvalsh(sigma0)
    if not lam[1] > 0:
        return float(per_obs.mean())
    return float(np.sqrt(lam[1]))


def mean_size(camera: Camera, rotations_wc: np.ndarray, centers: np.ndarray, point: np.ndarray,
              sizes_px: np.ndarray) -> float:
    """The paper's metric size: mean over observations of h_px x depth / f (depth of `point`, f = sqrt(fx fy))."""
    r_cw = np.transpose(np.asarray(rotations_wc, np.float64), (0, 2, 1))
    depth = np.einsum("nj,nj->n", r_cw[:, 2, :], np.asarray(point, np.float64)[None, :] - np.asarray(centers))
    return float(np.mean(np.asarray(sizes_px, np.float64) * depth / np.sqrt(camera.fx * camera.fy)))
