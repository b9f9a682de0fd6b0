"""`classical`: an open-set region segmenter from well-kept libraries (scikit-image, OpenCV, SciPy); no weights.

Pipeline, at a reduced working resolution (`classical_max_side`):
1. edge-preserving smoothing (bilateral filter) so field texture (crop rows, furrows) does not fragment regions;
2. Felzenszwalb-Huttenlocher graph segmentation (over-segments on purpose: no object is left merged into a
   field at this stage);
3. region merging: adjacent regions whose mean CIELAB colours differ by less than `classical_merge_delta_e`
   are joined (connected components of the region adjacency graph), which rebuilds fields, roads and lawns
   as single large regions while a crown or a roof, distinct from everything around it, stays on its own;
4. filtering: regions larger than `classical_max_area_frac` of the image (background), smaller than
   `classical_min_area_px` (at full resolution), elongated slivers (`classical_max_elongation`: sqrt of the
   covariance eigenvalue ratio; roads, hedgerows, field edges) and regions that differ little from their
   neighbours (`classical_min_contrast`) are dropped;
5. the label image is mapped back to full resolution (nearest neighbour).

The score of a mask is its colour contrast to its neighbours, squashed to [0, 1). Deterministic; CPU only.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..params import SegmentationParams
from .base import Backend, MaskSet

#: Defaults come from `SegmentationParams` (one source of truth: the `classical_*` fields and their comments).
default_conf = {
    f.name[len("classical_"):]: f.default
    for f in dataclasses.fields(SegmentationParams)
    if f.name.startswith("classical_")
}


def conf_from_params(params: SegmentationParams) -> dict:
    """The classical backend's configuration from the `classical_*` fields of the parameters."""
    return {key: getattr(params, f"classical_{key}", value) for key, value in default_conf.items()}


def _region_stats(labels: np.ndarray, n: int, lab: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(area (n,), mean colour (n, 3), covariance terms (n, 3) = sxx, sxy, syy) of every label, via bincount."""
    flat = labels.ravel()
    area = np.bincount(flat, minlength=n).astype(np.float64)
    safe = np.maximum(area, 1)
    color = np.stack([np.bincount(flat, lab[..., c].ravel(), n) for c in range(3)], 1) / safe[:, None]
    h, w = labels.shape
    ys, xs = np.divmod(np.arange(h * w), w)
    mx = np.bincount(flat, xs, n) / safe
    my = np.bincount(flat, ys, n) / safe
    dx = xs - mx[flat]
    dy = ys - my[flat]
    cov = np.stack([np.bincount(flat, dx * dx, n), np.bincount(flat, dx * dy, n), np.bincount(flat, dy * dy, n)], 1)
    return area, color, cov / safe[:, None]


def _adjacency(labels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Adjacent label pairs (a < b) and their shared boundary length in pixel edges (4-neighbourhood)."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    diff = a != b
    a, b = a[diff], b[diff]
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    code, count = np.unique(lo * n + hi, return_counts=True)
    return code // n, code % n, count


def _relabel(labels: np.ndarray, mapping: np.ndarray) -> tuple[np.ndarray, int]:
    uniq, inv = np.unique(mapping, return_inverse=True)
    return inv[labels].astype(np.int32), len(uniq)


def _watershed_regions(smooth: np.ndarray, lab: np.ndarray, flat_percentile: float) -> tuple[np.ndarray, int]:
    """Over-segmentation by marker-controlled watershed: every flat zone (colour gradient below the
    `flat_percentile` percentile) seeds a region, OpenCV floods the rest. Boundary pixels (-1) join the
    neighbouring region with the highest label (a deterministic choice; they are 1 px wide)."""
    gx = cv2.Sobel(lab, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lab, cv2.CV_32F, 0, 1, ksize=3)
    grad = np.sqrt((gx * gx + gy * gy).sum(axis=2))
    flat = (grad <= np.percentile(grad, flat_percentile)).astype(np.uint8)
    _, markers = cv2.connectedComponents(flat, connectivity=4)
    markers = markers.astype(np.int32)
    if markers.max() == 0:  # a uniform image: one region
        return np.zeros(grad.shape, np.int32), 1
    ws = cv2.watershed(np.ascontiguousarray(smooth), markers)
    ws[0, :] = ws[1, :]  # cv2.watershed marks the image border as boundary
    ws[-1, :] = ws[-2, :]
    ws[:, 0] = ws[:, 1]
    ws[:, -1] = ws[:, -2]
    for _ in range(2):
        edge = ws < 1
        if not edge.any():
            break
        grown = cv2.dilate(ws.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
        ws[edge] = grown[edge]
    ws[ws < 1] = 1
    return _relabel(ws, np.arange(ws.max() + 1))


def segment_classical(image: np.ndarray, conf: dict | None = None) -> MaskSet:
    """Segment an (H, W, 3) uint8 RGB image into non-overlapping object-like regions (see module doc)."""
    c = {**default_conf, **(conf or {})}
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    h, w = image.shape[:2]
    scale = min(1.0, c["max_side"] / max(h, w)) if c["max_side"] > 0 else 1.0
    small = image
    if scale < 1.0:
        small = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    sh, sw = small.shape[:2]
    px_area = (h * w) / (sh * sw)  # full-resolution pixels per working pixel
    smooth = np.ascontiguousarray(small)
    if c["median_ksize"] > 1:  # removes leaf / furrow texture finer than the kernel before any edge is seen
        smooth = cv2.medianBlur(smooth, int(c["median_ksize"]) | 1)
    smooth = cv2.bilateralFilter(smooth, 5, c["smooth_sigma_color"], 3)
    lab = cv2.cvtColor(smooth.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)

    labels, n = _watershed_regions(smooth, lab, c["flat_percentile"])

    # Merge adjacent regions of nearly the same mean colour (single linkage over the adjacency graph).
    area, color, _ = _region_stats(labels, n, lab)
    a, b, _ = _adjacency(labels, n)
    de = np.linalg.norm(color[a] - color[b], axis=1)
    join = de < c["merge_delta_e"]
    graph = coo_matrix((np.ones(int(join.sum())), (a[join], b[join])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    labels, n = _relabel(labels, comp)

    area, color, cov = _region_stats(labels, n, lab)
    a, b, length = _adjacency(labels, n)
    de = np.linalg.norm(color[a] - color[b], axis=1)
    # Contrast of a region: boundary-length-weighted mean colour difference to its neighbours.
    wsum = np.bincount(a, length, n) + np.bincount(b, length, n)
    contrast = (np.bincount(a, length * de, n) + np.bincount(b, length * de, n)) / np.maximum(wsum, 1)
    tr = cov[:, 0] + cov[:, 2]
    disc = np.sqrt(np.maximum(0.25 * (cov[:, 0] - cov[:, 2]) ** 2 + cov[:, 1] ** 2, 0))
    lam_max, lam_min = 0.5 * tr + disc, np.maximum(0.5 * tr - disc, 1e-3)
    elongation = np.sqrt(lam_max / lam_min)

    full_area = area * px_area
    keep = (
        (full_area >= c["min_area_px"])
        & (area <= c["max_area_frac"] * sh * sw)
        & (elongation <= c["max_elongation"])
        & (contrast >= c["min_contrast"])
    )
    mapping = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int32)
    small_labels = mapping[labels]
    scores = (1.0 - np.exp(-contrast[keep] / 20.0)).astype(np.float32)
    if scale < 1.0:
        full = cv2.resize(small_labels.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int32)
    else:
        full = small_labels
    masks = MaskSet.from_labels(full, scores)  # labels lost in resizing (tiny) drop their score
    return masks


def make(params: SegmentationParams) -> Backend:
    """Backend factory for the registry."""
    conf = conf_from_params(params)

    def backend(image: np.ndarray) -> MaskSet:
        return segment_classical(image, conf)

    return backend
