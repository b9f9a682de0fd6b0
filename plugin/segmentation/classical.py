"""`classical`: an open-set region segmenter from well-kept libraries (OpenCV, NumPy, SciPy); no weights.

Pipeline, at a reduced working resolution (`classical_max_side`, 400 px; `sosmatch map` raises it from the flying
height it measures where a working pixel would cover more than `classical_ground_resolution_m` of ground, and lowers
it where one would cover less than `classical_min_ground_resolution_m`: merge costs and kernels count working
pixels, `plugin.params.for_ground_resolution`):
1. smoothing: median filter (removes leaf / furrow texture finer than the kernel) then a bilateral filter;
2. over-segmentation: marker-controlled watershed (OpenCV) seeded by the flat zones of the CIELAB gradient and
   by its minima deeper than the flat level (`classical_minima_depth`: a textured crown, bush or boulder on snow);
3. a merge hierarchy: greedy Ward linkage on the region adjacency graph over colour (CIELAB and the
   shading-invariant normalised r, g chromaticity, `classical_chroma_weight`), texture (local lightness std) and
   the mean gradient along the shared boundary (`classical_edge_weight`); the partitions at
   `classical_merge_levels` (7) cost levels are kept. Size-aware merging rebuilds crowns from their lit and
   shaded fragments and fields from their patches before a crown joins the lawn around it;
4. object-like regions of every level: not larger than `classical_max_area_frac` of the image (background),
   not smaller than `classical_min_area_px`, not elongated (`classical_max_elongation`: roads, hedgerows,
   field edges), contrasted to their neighbours (`classical_min_contrast`); nested near-duplicates across
   levels (IoU > `classical_dedup_iou`) keep the more contrasted one, and parts of an elliptic whole
   (`classical_fragment_ratio`) are dropped. Like SAM's multimask output the masks
   may overlap (a crown and the pair of crowns it belongs to), so they are returned as bbox crops;
5. masks are mapped back to full resolution window by window (nearest neighbour).

The score of a mask is its contrast to its neighbours squashed to [0, 1). Deterministic; CPU only.
Tuned on synthetic summer / winter sessions (tools/benchmarks/bench_segment.py) and checked on Seneca frames.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ..errors import InputError
from ..params import SegmentationParams
from .base import Backend, MaskSet, check_image_u8

#: Defaults come from `SegmentationParams` (one source of truth: the `classical_*` fields and their comments).
default_conf = {
    f.name[len("classical_"):]: f.default
    for f in dataclasses.fields(SegmentationParams)
    if f.name.startswith("classical_")
}


def conf_from_params(params: SegmentationParams) -> dict:
    """The classical backend's configuration from the `classical_*` fields of the parameters."""
    return {key: getattr(params, f"classical_{key}", value) for key, value in default_conf.items()}


def _region_moments(labels: np.ndarray, n: int, feats: np.ndarray) -> np.ndarray:
    """(n, 6 + F) raw moments of every label: area, sum x, sum y, sum xx, sum xy, sum yy, sum of each feature.

    Raw sums add up under merging, so every coarser level's statistics come from these without a pixel pass."""
    flat = labels.ravel()
    h, w = labels.shape
    xs = np.tile(np.arange(w, dtype=np.float64), h)
    ys = np.repeat(np.arange(h, dtype=np.float64), w)
    cols = [np.ones(h * w), xs, ys, xs * xs, xs * ys, ys * ys]
    cols += [feats[..., c].ravel().astype(np.float64) for c in range(feats.shape[2])]
    return np.stack([np.bincount(flat, col, n) for col in cols], 1)


def _stats_from_moments(mom: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(area, mean features (n, F), elongation sqrt(lambda_max / lambda_min), fill) from raw moments."""
    area = mom[:, 0]
    safe = np.maximum(area, 1)
    mx, my = mom[:, 1] / safe, mom[:, 2] / safe
    sxx = mom[:, 3] / safe - mx * mx
    sxy = mom[:, 4] / safe - mx * my
    syy = mom[:, 5] / safe - my * my
    tr = sxx + syy
    disc = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy**2, 0))
    lam_max, lam_min = 0.5 * tr + disc, np.maximum(0.5 * tr - disc, 1.0 / 12.0)  # 1/12: one pixel's own spread
    lam_max = np.maximum(lam_max, 1.0 / 12.0)
    # fill: area over the area of the ellipse with the same second moments (1 for a solid ellipse; branchy or
    # ring-shaped regions such as field margins and hedgerow networks score low)
    fill = area / (4.0 * np.pi * np.sqrt(lam_max * lam_min))
    return area, mom[:, 6:] / safe[:, None], np.sqrt(lam_max / lam_min), fill


def _adjacency(
    labels: np.ndarray, n: int, strength: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Adjacent label pairs (a < b), their shared boundary length in pixel edges (4-neighbourhood) and the sum
    of `strength` (e.g. gradient magnitude; the larger of the two pixels) along that boundary."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    diff = a != b
    a, b = a[diff], b[diff]
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    code, inv, count = np.unique(lo * n + hi, return_inverse=True, return_counts=True)
    if strength is None:
        sums = np.zeros(len(code))
    else:
        sa = np.concatenate([strength[:, :-1].ravel(), strength[:-1, :].ravel()])[diff]
        sb = np.concatenate([strength[:, 1:].ravel(), strength[1:, :].ravel()])[diff]
        sums = np.bincount(inv, np.maximum(sa, sb), len(code))
    return code // n, code % n, count, sums


def _relabel(labels: np.ndarray, mapping: np.ndarray) -> tuple[np.ndarray, int]:
    uniq, inv = np.unique(mapping, return_inverse=True)
    return inv[labels].astype(np.int32), len(uniq)


def _watershed_regions(
    smooth: np.ndarray, lab: np.ndarray, flat_percentile: float, minima_depth: float = 0.0
) -> tuple[np.ndarray, int, np.ndarray]:
    """Over-segmentation by marker-controlled watershed: every flat zone (colour gradient below the
    `flat_percentile` percentile) seeds a region, and so does every basin of the gradient at least
    `minima_depth` x that flat level deep (h-minima); OpenCV floods the rest. Boundary pixels (-1) join the
    neighbouring region with the highest label (a deterministic choice; they are 1 px wide).

    Why the minima: the flat level is a percentile of this image's gradient, so on a frame that is mostly smooth
    (snow) it falls to the snow's own noise, and a small textured object (a bush, a boulder, a conifer: no pixel
    that flat) had no seed and was flooded into the snow around it. Its basin, bounded by its rim, is deep
    against that same level: winter bushes found 8/27 -> 24/27 (held-out world 97) and 5/21 -> 14/21 (world 64),
    summer unchanged (BENCHMARKS, issue 16)."""
    gx = cv2.Sobel(lab, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lab, cv2.CV_32F, 0, 1, ksize=3)
    grad = np.sqrt((gx * gx + gy * gy).sum(axis=2))
    level = float(np.percentile(grad, flat_percentile))
    flat = grad <= level
    if minima_depth > 0 and level > 0:
        from skimage.morphology import h_minima

        flat |= h_minima(grad, minima_depth * level).astype(bool)
    flat = flat.astype(np.uint8)
    _, markers = cv2.connectedComponents(flat, connectivity=4)
    markers = markers.astype(np.int32)
    if markers.max() == 0:  # a uniform image: one region
        return np.zeros(grad.shape, np.int32), 1, grad
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
    return (*_relabel(ws, np.arange(ws.max() + 1)), grad)


# Heap pushes per watershed region after which `_ward_merge` stops re-costing every neighbour of a region too large
# to be a mask each time it grows. Seneca frames at 800 working px take 8-70 per region, synthetic sessions' 6-15,
# the test's blobs on a noisy field 101 (BENCHMARKS, "The Ward merge's cost cliff"); near-uniform noisy frames
# (snow, calm water, fog) at 600-800 px took up to 736 (n^2 / 5: one region grows over the whole frame, and every
# merge re-costed all of its neighbours).
_FULL_REFRESH_PUSHES_PER_REGION = 200


def _ward_merge(
    area: np.ndarray, mean: np.ndarray, a: np.ndarray, b: np.ndarray, thresholds: list[float],
    length: np.ndarray | None = None, edge: np.ndarray | None = None, edge_weight: float = 0.0,
    frozen_area: float = float("inf"),
) -> list[np.ndarray]:
    """Greedy Ward merging of adjacent regions: repeatedly join the adjacent pair with the smallest increase of
    the within-region sum of squares, n_a n_b / (n_a + n_b) * |mean_a - mean_b|^2, until it exceeds `threshold`.

    Size-aware where single linkage is not: the lit and shaded fragments of one crown (small, different) join
    each other before a crown (small) joins the lawn around it (large, different), and big field patches of
    nearly the same colour join at once. Ward costs never decrease along the merge sequence, so one pass gives
    every level: returns, per threshold (ascending), the root region of every input region. Deterministic
    (ties are broken by region index). Plain Python on a heap: a few thousand regions take a few tens of ms.

    The cost is bounded: once the heap has taken `_FULL_REFRESH_PUSHES_PER_REGION` pushes per region, a region
    larger than `frozen_area` (no mask can be that large) that grows costs only the pairs the absorbed region
    brought; its other pairs keep the costs they had (its mean barely moves as it takes in small ones). Below the
    budget the merge is exact, so ordinary frames keep their masks (rev50 D3: flat noisy frames took 7-45 s).
    """
    import heapq
    from math import dist

    n = len(area)
    cnt = area.astype(float).tolist()
    sums = (mean * area[:, None]).tolist()
    mu = [tuple(m) for m in mean.tolist()]  # current means, kept up to date (the cost is evaluated ~100k times)
    nbrs: list[set[int]] = [set() for _ in range(n)]
    for i, j in zip(a.tolist(), b.tolist()):
        nbrs[i].add(j)
        nbrs[j].add(i)
    version = [0] * n
    alive = [True] * n
    parent = list(range(n))

    # boundary (length, strength sum) per pair, kept up to date under merging (both add up)
    bnd: dict[tuple[int, int], list[float]] = {}
    if edge_weight > 0 and length is not None and edge is not None:
        for i, j, ln, e in zip(a.tolist(), b.tolist(), length.tolist(), edge.tolist()):
            bnd[(i, j)] = [ln, e]

    def cost(i: int, j: int) -> float:
        ci, cj = cnt[i], cnt[j]
        if ci <= 0 or cj <= 0:
            return 0.0
        d2 = dist(mu[i], mu[j]) ** 2  # math.dist: one C call instead of a Python loop over the features
        if bnd:
            ln, e = bnd[(i, j) if i < j else (j, i)]
            g = edge_weight * e / ln  # mean edge strength along the shared boundary
            d2 += g * g
        return ci * cj / (ci + cj) * d2

    heap = [(cost(i, j), i, j, 0, 0) for i, j in zip(a.tolist(), b.tolist())]
    heapq.heapify(heap)
    levels = sorted(thresholds)
    snapshots: list[list[int]] = []
    # The loop below runs ~100k times per frame: locals instead of attribute look-ups, the next threshold in a
    # variable, and the cost inlined (same arithmetic, in the same order, as `cost`).
    heappop, heappush = heapq.heappop, heapq.heappush
    next_level = levels[0] if levels else float("inf")
    budget = _FULL_REFRESH_PUSHES_PER_REGION * n
    pushes = 0
    while heap:
        c, i, j, vi, vj = heappop(heap)
        if c > next_level:
            while len(snapshots) < len(levels) and c > levels[len(snapshots)]:
                snapshots.append(list(parent))
            if len(snapshots) == len(levels):
                break
            next_level = levels[len(snapshots)]
        if version[i] != vi or version[j] != vj or not (alive[i] and alive[j]):
            continue
        ci = cnt[i] + cnt[j]
        cnt[i] = ci
        si = [x + y for x, y in zip(sums[i], sums[j])]
        sums[i] = si
        mu_i = tuple(x / ci for x in si) if ci > 0 else mu[i]
        mu[i] = mu_i
        alive[j] = False
        parent[j] = i
        nb_i = nbrs[i]
        nb_j = nbrs[j]
        for k in nb_j:
            if k != i:
                nbrs[k].discard(j)
                nbrs[k].add(i)
                nb_i.add(k)
                if bnd:
                    jk = bnd.pop((j, k) if j < k else (k, j))
                    ik = bnd.setdefault((i, k) if i < k else (k, i), [0.0, 0.0])
                    ik[0] += jk[0]
                    ik[1] += jk[1]
        nb_i.discard(j)
        nbrs[j] = set()
        if ci > frozen_area and pushes > budget:
            # past the budget a region too large to be a mask keeps its version, so its pairs' entries stay
            # valid at their costs; only the pairs j brought (new neighbours, longer boundaries) are costed
            vi = version[i]
            targets = nb_j - {i}
        else:
            vi = version[i] + 1
            version[i] = vi
            targets = nb_i
        pushes += len(targets)
        for k in targets:
            ck = cnt[k]
            if ci <= 0 or ck <= 0:
                ckost = 0.0
            else:
                d2 = dist(mu_i, mu[k]) ** 2
                if bnd:
                    ln, e = bnd[(i, k) if i < k else (k, i)]
                    g = edge_weight * e / ln
                    d2 += g * g
                ckost = ci * ck / (ci + ck) * d2
            heappush(heap, (ckost, i, k, vi, version[k]))
    while len(snapshots) < len(levels):
        snapshots.append(list(parent))
    roots = []
    for snap in snapshots:
        root = np.asarray(snap)
        while True:  # path compression, vectorised (chains are short)
            nxt = root[root]
            if np.array_equal(nxt, root):
                break
            root = nxt
        roots.append(root)
    return roots


# The fewest pixels on a side the pipeline works with: the watershed's border rows and columns are copied from
# their inner neighbours and the filters (median, Sobel) are 3 px wide. A narrower image holds no region a mask
# could describe (its covariance is flat along that side) and is no aerial frame: it is refused, one line.
MIN_SIDE_PX = 3


def segment_classical(image: np.ndarray, conf: dict | None = None) -> MaskSet:
    """Segment an (H, W, 3) uint8 RGB image into non-overlapping object-like regions (see module doc).

    Raises InputError for an image with fewer than MIN_SIDE_PX rows or columns, ValueError for one that is not
    uint8 RGB or gray (`check_image_u8`)."""
    check_image_u8(image)
    c = {**default_conf, **(conf or {})}
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    h, w = image.shape[:2]
    if min(h, w) < MIN_SIDE_PX:
        raise InputError(f"image of {w}x{h} px is too small to segment (at least {MIN_SIDE_PX} px on each side)")
    scale = min(1.0, c["max_side"] / max(h, w)) if c["max_side"] > 0 else 1.0
    small = image
    if scale < 1.0:
        # a long, narrow image keeps MIN_SIDE_PX across (an 8000x29 image at 400 px was 1 px high and crashed
        # the watershed, rev50 D1); the two scales may then differ, which the mapping back below allows
        size = (max(MIN_SIDE_PX, round(w * scale)), max(MIN_SIDE_PX, round(h * scale)))
        small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    sh, sw = small.shape[:2]
    px_area = (h * w) / (sh * sw)  # full-resolution pixels per working pixel
    smooth = np.ascontiguousarray(small)
    if c["median_ksize"] > 1:  # removes leaf / furrow texture finer than the kernel before any edge is seen
        smooth = cv2.medianBlur(smooth, int(c["median_ksize"]) | 1)
    smooth = cv2.bilateralFilter(smooth, 5, c["smooth_sigma_color"], 3)
    lab = cv2.cvtColor(smooth.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    if c["texture_weight"] > 0:
        # Texture as a fourth feature: local standard deviation of the (unsmoothed) lightness. Crowns and bare
        # winter trees are rough, their cast shadows, snow, water and lawns smooth: colour alone merges them.
        light = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY).astype(np.float32) * (100.0 / 255.0)
        k = (int(c["texture_window"]) | 1,) * 2
        mean = cv2.blur(light, k)
        tex = np.sqrt(np.maximum(cv2.blur(light * light, k) - mean * mean, 0.0))
        feats = np.concatenate([lab, (c["texture_weight"] * tex)[..., None]], axis=2)
    else:
        feats = lab
    if c["chroma_weight"] > 0:
        # Illumination-invariant chromaticity (normalised r, g): a cast shadow on the lawn keeps the lawn's
        # chromaticity and a crown's shaded half its lit half's, while CIELAB a, b shrink with the light.
        s3 = smooth.astype(np.float32)
        tot = s3.sum(axis=2, keepdims=True) + 3.0
        chroma = (c["chroma_weight"] * 300.0) * s3[..., :2] / tot
        feats = np.concatenate([feats, chroma], axis=2)
    if c["lightness_weight"] != 1.0:
        # Lit and shaded halves of one crown differ mostly in lightness, a crown and the lawn in chroma and
        # texture: a lighter weight on L lets the halves join first.
        feats = feats.copy()
        feats[..., 0] *= c["lightness_weight"]

    labels, n, grad = _watershed_regions(smooth, lab, c["flat_percentile"], c["minima_depth"])
    mom = _region_moments(labels, n, feats)
    a0, b0, len0, edge0 = _adjacency(labels, n, grad)
    area0, mean0, _, _ = _stats_from_moments(mom)
    costs = [c["merge_cost"] * c["merge_level_factor"] ** k for k in range(max(1, c["merge_levels"]))]
    roots = _ward_merge(area0, mean0, a0, b0, costs, len0, edge0, c["edge_weight"], c["max_area_frac"] * sh * sw)

    # Object-like regions at every level of the merge hierarchy (a crown may be complete at one level and
    # split, or fused with its neighbour, at another: SAM's multimask output has the same nesting).
    cand: list[tuple[float, int, int, float]] = []  # (contrast, level, root id, area)
    parent_of: list[np.ndarray] = []
    area_at: list[np.ndarray] = []
    keep_at: list[np.ndarray] = []
    contrast_at: list[np.ndarray] = []
    for lvl, root in enumerate(roots):
        # rows of non-root regions stay zero (a root's id is one of its own members)
        lm = np.stack([np.bincount(root, mom[:, k], n) for k in range(mom.shape[1])], 1)
        area, mean, elong, fill = _stats_from_moments(lm)
        ra, rb = root[a0], root[b0]
        cross = ra != rb
        ra, rb, ln = ra[cross], rb[cross], len0[cross]
        de = np.linalg.norm(mean[ra] - mean[rb], axis=1)
        wsum = np.bincount(ra, ln, n) + np.bincount(rb, ln, n)
        # contrast: boundary-length-weighted mean feature difference to the neighbours
        contrast = (np.bincount(ra, ln * de, n) + np.bincount(rb, ln * de, n)) / np.maximum(wsum, 1)
        keep = (
            (area * px_area >= c["min_area_px"])
            & (area <= c["max_area_frac"] * sh * sw)
            & (elong <= c["max_elongation"])
            & (fill >= c["min_fill"])
            & (contrast >= c["min_contrast"])
        )
        for r in np.flatnonzero(keep):
            cand.append((float(contrast[r]), lvl, int(r), float(area[r])))
        parent_of.append(root)
        area_at.append(area)
        contrast_at.append(contrast)
        keep_at.append(keep & (fill >= c["fragment_parent_fill"]))

    if c["fragment_ratio"] > 0:
        # Parts of a whole: a candidate that is at least `fragment_ratio` of a coarser candidate containing it,
        # when that one is elliptic (fill >= `fragment_parent_fill`: one crown, not a clump of two) and at least
        # as contrasted. Such parts (a third of a crown, its lit side) are tracked like objects but their
        # centroids sit a metre or two off the object's: on the 100-frame summer session they made 45 % of the
        # landmarks on objects and doubled the median landmark error (BENCHMARKS, Mapping).
        def is_fragment(con: float, lvl: int, r: int, ar: float) -> bool:
            for L in range(lvl + 1, len(parent_of)):
                anc = parent_of[L][r]
                if ar < c["fragment_ratio"] * area_at[L][anc]:
                    return False
                if area_at[L][anc] > ar and keep_at[L][anc] and contrast_at[L][anc] >= con:
                    return True
            return False

        cand = [t for t in cand if not is_fragment(*t)]

    # Near-duplicates across levels (a region that only gained a sliver): the nested pair with IoU above
    # `dedup_iou` keeps the member with the higher contrast. Nested masks: IoU = small area / large area.
    cand.sort(key=lambda t: (-t[0], t[1], t[2]))
    levels = len(parent_of)
    chosen: list[tuple[float, int, int, float]] = []
    chosen_at: set[tuple[int, int]] = set()
    areas_of: dict[tuple[int, int], float] = {}
    finer_areas: dict[tuple[int, int], list[float]] = {}  # (level, root) -> areas of chosen masks nested inside
    for con, lvl, r, ar in cand:
        # a root id is one of its own member regions, so parent_of[L][r] is r's ancestor at level L
        dup = any(
            (L, int(parent_of[L][r])) in chosen_at and ar / areas_of[(L, int(parent_of[L][r]))] > c["dedup_iou"]
            for L in range(lvl + 1, levels)
        ) or any(a2 / ar > c["dedup_iou"] for a2 in finer_areas.get((lvl, r), ()))
        if dup:
            continue
        chosen.append((con, lvl, r, ar))
        chosen_at.add((lvl, r))
        areas_of[(lvl, r)] = ar
        for L in range(lvl + 1, levels):
            finer_areas.setdefault((L, int(parent_of[L][r])), []).append(ar)
    if not chosen:
        return MaskSet.empty((h, w))
    chosen.sort(key=lambda t: (t[1], t[2]))

    from scipy.ndimage import find_objects

    # Working-resolution crops of the chosen regions: (y0, x0, bool crop, contrast). The box of a merged region
    # is the union of its watershed regions' boxes: one find_objects pass instead of one per level.
    big = np.iinfo(np.int64).max
    base = np.tile(np.array([big, -1, big, -1], dtype=np.int64), (n, 1))  # empty labels: an empty box
    for k, sl in enumerate(find_objects(labels + 1)):
        if sl is not None:
            base[k] = (sl[0].start, sl[0].stop, sl[1].start, sl[1].stop)
    small_masks: list[tuple[int, int, np.ndarray, float]] = []
    by_level: dict[int, np.ndarray] = {}
    for con, lvl, r, _ in chosen:
        if lvl not in by_level:
            root = parent_of[lvl]
            box = np.empty((n, 4), dtype=np.int64)
            box[:, 0::2] = big
            box[:, 1::2] = -1
            for col, red in ((0, np.minimum), (2, np.minimum), (1, np.maximum), (3, np.maximum)):
                red.at(box[:, col], root, base[:, col])
            by_level[lvl] = box
        y0, y1, x0, x1 = by_level[lvl][r]
        small_masks.append((int(y0), int(x0), parent_of[lvl][labels[y0:y1, x0:x1]] == r, con))
    if c["split_solidity"] > 0:
        min_small = c["min_area_px"] / px_area
        small_masks += [
            part for m in small_masks for part in _split_touching(m, c["split_solidity"], min_small, c["min_fill"])
        ]

    boxes, crops, scores = [], [], []
    fy, fx = h / sh, w / sw
    # working-resolution row / column of every full-resolution row / column (nearest neighbour), computed once
    all_src_y = ((np.arange(h) + 0.5) / fy).astype(np.int64)
    all_src_x = ((np.arange(w) + 0.5) / fx).astype(np.int64)
    for sy0, sx0, sm, con in small_masks:
        if scale < 1.0:
            # map only the region's window back to full size (nearest neighbour, as for the whole image): the
            # full-resolution rows and columns whose working row / column lies in the window. The window's box
            # scaled outward took up to one more row and column a side, filled with the window's edge (masks
            # +0.7 % in size at median, rev50 D4)
            y0, y1 = np.searchsorted(all_src_y, (sy0, sy0 + sm.shape[0])).tolist()
            x0, x1 = np.searchsorted(all_src_x, (sx0, sx0 + sm.shape[1])).tolist()
            m = sm[(all_src_y[y0:y1] - sy0)[:, None], (all_src_x[x0:x1] - sx0)[None, :]]
        else:
            y0, x0, m = sy0, sx0, sm
        rows = np.flatnonzero(m.any(axis=1))
        if len(rows) == 0:
            continue
        cols = np.flatnonzero(m.any(axis=0))
        boxes.append((x0 + int(cols[0]), y0 + int(rows[0]), x0 + int(cols[-1]) + 1, y0 + int(rows[-1]) + 1))
        crops.append(np.ascontiguousarray(m[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]))
        scores.append(1.0 - np.exp(-con / 20.0))
    return MaskSet((h, w), np.asarray(scores, np.float32), boxes=np.asarray(boxes, np.int32), crops=crops)


def _split_touching(
    region: tuple[int, int, np.ndarray, float], max_solidity: float, min_area: float, min_fill: float
) -> list[tuple[int, int, np.ndarray, float]]:
    """Parts of a non-convex region (solidity = area / convex hull area below `max_solidity`): touching crowns
    or a crown fused with its shadow. Classic separation of touching blobs: a watershed of the distance
    transform from its well-separated maxima. The parts are extra masks (the region itself stays)."""
    y0, x0, crop, con = region
    area = int(crop.sum())
    if area < 2 * min_area:
        return []
    mask8 = np.pad(crop, 1).astype(np.uint8)
    contours, _ = cv2.findContours(mask8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return []
    hull = cv2.contourArea(cv2.convexHull(np.concatenate(contours)))
    if hull <= 0 or area / hull >= max_solidity:
        return []
    dist = cv2.distanceTransform(mask8, cv2.DIST_L2, 3)
    # maxima: pixels equal to the max of their neighbourhood (size ~ the typical part radius), clearly inside
    k = max(3, int(0.5 * dist.max()) | 1)
    peaks = (dist >= cv2.dilate(dist, np.ones((k, k), np.uint8))) & (dist >= 0.5 * dist.max()) & (mask8 > 0)
    n, markers = cv2.connectedComponents(peaks.astype(np.uint8), connectivity=8)
    if n <= 2:  # one maximum (plus background): nothing to split
        return []
    from skimage.segmentation import watershed

    parts = watershed(-dist, markers, mask=mask8 > 0)[1:-1, 1:-1]
    out = []
    for p in range(1, n):
        part = parts == p
        pa = int(part.sum())
        if pa < min_area:
            continue
        ys, xs = np.nonzero(part)
        cov = np.cov(np.stack([xs, ys]).astype(np.float64), bias=True) + np.eye(2) / 12.0
        fill = pa / (4.0 * np.pi * np.sqrt(max(np.linalg.det(cov), 1e-9)))
        if fill < min_fill:
            continue
        ry0, ry1, rx0, rx1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        out.append((y0 + int(ry0), x0 + int(rx0), part[ry0:ry1, rx0:rx1], con * 0.9))
    return out if len(out) >= 2 else []


def make(params: SegmentationParams) -> Backend:
    """Backend factory for the registry."""
    conf = conf_from_params(params)

    def backend(image: np.ndarray) -> MaskSet:
        return segment_classical(image, conf)

    return backend
