"""How likely the other session would have mapped a landmark like this one: a logistic re-observation model
fitted on the pair itself."""

from __future__ import annotations

import numpy as np


def reobservation_features(sizes: np.ndarray, views: np.ndarray, heights: np.ndarray,
                           support: np.ndarray | None) -> np.ndarray:
    """(N, 4) features of how findable a landmark is: log size, log views by the other session, height above
    the ground (clipped to -2..15 m) and log of its own observations (a long track is a stable object; a
    6-view track a marginal one that the other session may well have missed too). Unknown sizes take the
    median size, unknown support the median support."""
    s = np.asarray(sizes, dtype=np.float64)
    ok = np.isfinite(s) & (s > 0)
    s = np.where(ok, s, float(np.median(s[ok])) if np.any(ok) else 1.0)
    sup = np.ones(len(s)) if support is None else np.asarray(support, dtype=np.float64)
    return np.column_stack([np.log(s), np.log(np.maximum(views, 1)),
                            np.clip(np.nan_to_num(heights, nan=0.0), -2.0, 15.0), np.log(np.maximum(sup, 1))])


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1.0, iterations: int = 50) -> np.ndarray:
    """Weights (intercept first) of a logistic regression P(y | x), by Newton's method on standardised features
    with a ridge penalty on the slopes: deterministic, and finite on a separable or tiny sample."""
    x = np.asarray(x, dtype=np.float64).reshape(len(y), -1)
    y = np.asarray(y, dtype=np.float64)
    mu, sd = x.mean(0), x.std(0)
    sd = np.where(sd > 0, sd, 1.0)
    z = np.column_stack([np.ones(len(y)), (x - mu) / sd])
    w = np.zeros(z.shape[1])
    w[0] = np.log((y.sum() + 1.0) / (len(y) - y.sum() + 1.0))
    penalty = np.diag([0.0] + [ridge] * (z.shape[1] - 1))
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(z @ w)))
        grad = z.T @ (y - p) - penalty @ w
        hess = (z * (p * (1 - p))[:, None]).T @ z + penalty + 1e-9 * np.eye(len(w))
        step = np.linalg.solve(hess, grad)
        w = w + step
        if np.max(np.abs(step)) < 1e-8:
            break
    slopes = w[1:] / sd  # back to the unstandardised features
    return np.concatenate([[w[0] - slopes @ mu], slopes])


def predict_logistic(weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """P(y | x) for each row of `x` ((N, F) features) under the logistic regression `weights` of `fit_logistic`
    (intercept first, then one slope per feature)."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, len(weights) - 1)
    return 1.0 / (1.0 + np.exp(-(weights[0] + x @ weights[1:])))


def held_out_logistic(x: np.ndarray, y: np.ndarray, folds: int = 10) -> np.ndarray:
    """P(y | x) of every sample, each predicted by a logistic regression (`fit_logistic`) fitted on the samples of
    the other folds (samples dealt to `folds` folds in turn: deterministic), so that no sample is scored by a fit
    it took part in: a sample's own label would pull its prediction towards itself (rev44 D3: the landmarks the
    other map lacks were the negatives of the fit that scored them). 1/2 for a sample with nothing else to fit on."""
    y = np.asarray(y, dtype=bool)
    x = np.asarray(x, dtype=np.float64).reshape(len(y), -1)
    fold = np.arange(len(y)) % max(min(folds, len(y)), 1)
    p = np.full(len(y), 0.5)
    for k in np.unique(fold) if len(y) > 1 else ():
        test = fold == k
        p[test] = predict_logistic(fit_logistic(x[~test], y[~test]), x[test])
    return p
