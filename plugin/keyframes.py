"""Keyframe selection by camera travel (SOS-Match step 1, `theta_T`)."""

from __future__ import annotations

import numpy as np


def select_keyframes(centers: np.ndarray, interval_m: float) -> np.ndarray:
    """Indices of the keyframes of a sequence of camera centres.

    The first frame is always a keyframe; after that a frame becomes a keyframe as soon as its straight-line
    distance from the position of the last keyframe reaches `interval_m` (`theta_T`, 2.0 m in the paper).
    Distance from the last keyframe, not path length, so hovering or jitter in place never adds keyframes.

    Args:
        centers: (N, 3) camera centres in metres, in acquisition order.
        interval_m: travel between keyframes; <= 0 makes every frame a keyframe.

    Returns:
        (K,) int64 sorted indices into `centers`.
    """
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"centers must be (N, 3), got {centers.shape}")
    n = len(centers)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.all(np.isfinite(centers)):
        raise ValueError("centers contain NaN or inf")
    if interval_m <= 0:
        return np.arange(n, dtype=np.int64)
    keys = [0]
    last = 0
    # One vectorised distance scan per keyframe: the selection is sequential by nature (each keyframe depends
    # on the previous one), but the search for the next one is not.
    while last < n - 1:
        dist = np.linalg.norm(centers[last + 1 :] - centers[last], axis=1)
        far = np.flatnonzero(dist >= interval_m)
        if len(far) == 0:
            break
        last = last + 1 + int(far[0])
        keys.append(last)
    return np.asarray(keys, dtype=np.int64)
