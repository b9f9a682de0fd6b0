"""Robust least squares of positions in the plane (pure numpy): least median of squares over minimal samples,
then least squares on the inliers of the measured noise, iterated. One loop for every fit of the georegistration
(the block's similarity to the GPS fixes, and the same with the GPS lag as a fifth unknown), so that they judge
inliers and measure their noise alike. And the delete-one-group jackknife (`jackknife_sigma`) by which an
estimate from a flight's images is judged where their errors are correlated along it (the GPS lag over the
passes, the focal length over stretches of the flight).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

import numpy as np

# quantiles of chi-square with 2 degrees of freedom: a horizontal residual's squared length over sigma^2
CHI2_2DOF_99 = 9.2103  # 99 %: the inlier radius
CHI2_2DOF_MEDIAN = 1.3863  # the median: sigma from the least median of squares
CHI2_2DOF_9999 = 18.4207  # 99.99 %: beyond it a measurement is wrong, not noisy
CHI2_2DOF_9973 = 11.8290  # 99.73 % (3 sigma in one dimension)
CHI2_1DOF_9973 = 9.0  # (3 sigma)^2: the same level in one dimension

Model = TypeVar("Model")


def lmeds_then_least_squares(
    candidates: Iterable[Model | None],
    solve: Callable[[np.ndarray], Model | None],
    residuals: Callable[[Model], np.ndarray],
    count: int,
    unknowns: int,
    min_points: int,
    min_sigma: float,
) -> tuple[Model, np.ndarray, float] | None:
    """The robust fit of `count` 2-D measurements: (model, inliers (count,) bool, per-axis sigma), or None when no
    candidate was valid.

    `candidates` are models solved from minimal samples (None: a degenerate sample); the one with the least median
    of squared `residuals` (horizontal distances, (count,)) starts, its sigma from that median. Then, up to ten
    times: the inliers are the residuals within the 99 % radius of sigma, the model is `solve`d on them (a bool
    mask; None, or fewer than `min_points` inliers, stops with the last model), and sigma is measured on them over
    their 2 x inliers - `unknowns` degrees of freedom; until the inliers no longer change. Sigma is at least
    `min_sigma`."""
    best, best_med = None, math.inf
    for candidate in candidates:
        if candidate is None:
            continue
        med = float(np.median(residuals(candidate) ** 2))
        if med < best_med:
            best, best_med = candidate, med
    if best is None:
        return None
    model, inliers = best, np.ones(count, bool)
    sigma = max(math.sqrt(best_med / CHI2_2DOF_MEDIAN), min_sigma)
    for _ in range(10):
        new = residuals(model) ** 2 <= CHI2_2DOF_99 * sigma**2
        refit = solve(new) if new.sum() >= min_points else None
        if refit is None:
            break
        model = refit
        r = residuals(model)
        sigma = max(math.sqrt(float(np.sum(r[new] ** 2)) / max(2 * int(new.sum()) - unknowns, 1)), min_sigma)
        if np.array_equal(new, inliers):
            break
        inliers = new
    return model, inliers, sigma


def jackknife_sigma(leave_one_out: Sequence[float] | np.ndarray) -> float:
    """The delete-one-group jackknife's standard error of an estimate from its values with each group left out
    in turn: sqrt((g - 1) / g * sum (v_i - mean)^2). inf with fewer than 3 groups (one or two leave-one-out
    values say nothing of the scatter) or a value that is not finite (without that group the estimate is not
    determined)."""
    v = np.asarray(leave_one_out, dtype=np.float64).reshape(-1)
    if len(v) < 3 or not np.all(np.isfinite(v)):
        return math.inf
    g = len(v)
    return math.sqrt((g - 1) / g * float(np.sum((v - v.mean()) ** 2)))
