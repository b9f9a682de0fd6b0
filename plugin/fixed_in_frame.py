"""Features fixed in the image frame: burned-in text (a date or telemetry stamp), a logo or watermark, parts of the
drone (a landing-gear leg), dirt on the lens. They sit at the same pixel in every image whatever the camera does,
so ORB matches them between any two images with zero displacement: to a pose-free matcher they are points at
infinity. In a pair of little ground overlap they are all its matches, and a RANSAC model takes the overlay's
identity mapping (the pose check then says the true poses miss the "matches" by 150-300 px); in tie points they
pull every camera toward one attitude (the nu35 sweep: a date stamp tilted a refined block by 1.8 deg).

A ground feature stays at one pixel only when the camera does not move (a hover) or at the fixed point of a turn,
so the regions are learned from the flight itself (`learn_fixed_in_frame`): over the pairs whose other matches show
the camera moved (`camera_moved`: enough moved matches agreeing on one homography; a hovering camera's pairs are
all static and teach nothing), the grid cells holding a static match in a good share of them are fixed in the
frame. Every pair, overlapping or not, then leaves out the matches with an end in those cells
(`FixedInFrame.keep`). One mechanism for both users of pose-free ORB matches: the pose check
(`plugin.pose_check.check`) and the tie points of the pose refinement (`workflows.pose_refinement.tie_points`).
COLMAP's structure from motion needs none of this: its geometric verification and incremental mapping never let a
static cluster decide the poses.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .image_matching import homography_inliers

# A match is static when it moved less than this, in pixels of the copy the features were detected on: ORB
# localises a keypoint within ~1 px at its finest levels (a stamp's or a logo's matches moved 0-3 px on 640 px
# frames, nu35), while a moving camera's ground matches lie that close to their start only near the fixed point of a
# turn (none within 3 px in 6 pairs of the clean synthetic flight B).
STATIC_PX = 3.0
# A pair shows the camera moved when at least this many of its matches moved beyond MOVED_STATICS x STATIC_PX and
# agree on one homography (the ground is nearly flat); chance matches do not agree, and a hover's drift stays
# within a few static radii.
MIN_MOVED = 12
MOVED_STATICS = 4.0
# cells along the longer side of the image: ~20 px at 640, ~32 px at 1024; an overlay's features are a few cells
GRID_CELLS = 32
# A cell is fixed in the frame when a static match lies in it in at least this share of the moving pairs (and in
# MIN_PAIRS of them), or when it touches such a cell and holds static matches in MIN_PAIRS pairs (hysteresis: an
# overlay is one connected region, and its weaker parts are matched in fewer pairs). An overlay is in every frame,
# but its features are matched only in some pairs (text whose digits change, contrast under auto-exposure: a
# stamp's cells static in 3-28 of 59 pairs, nu35); a ground feature is static in a moving pair only by
# coincidence, at a different cell each time (0-2 pairs per cell on the same flights).
MIN_SHARE = 0.2
MIN_PAIRS = 3


@dataclass(frozen=True)
class FixedInFrame:
    """Cells of the image where features are fixed in the frame. `cells` (rows, cols) bool over an image of
    `width` x `height` pixels (the pixels the matches were given in), `cell_px` the side of a cell; `pairs_taught`:
    the moving pairs it was learned from; `static_pairs`: per cell in how many of them it held a static match."""

    cells: np.ndarray
    cell_px: float
    width: float
    height: float
    pairs_taught: int
    static_pairs: np.ndarray

    def __bool__(self) -> bool:
        return bool(self.cells.any())

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which `points` (N, 2) (x, y pixels as given to `learn_fixed_in_frame`) lie in a fixed cell."""
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        if not self or not len(pts):
            return np.zeros(len(pts), bool)
        rows, cols = self.cells.shape
        c = np.clip(np.floor(pts[:, 0] / self.cell_px), 0, cols - 1).astype(int)
        r = np.clip(np.floor(pts[:, 1] / self.cell_px), 0, rows - 1).astype(int)
        return self.cells[r, c]

    def keep(self, points_a: np.ndarray, points_b: np.ndarray) -> np.ndarray:
        """(N,) bool: the matches (points_a[k] <-> points_b[k]) with neither end in a fixed cell."""
        return ~(self.contains(points_a) | self.contains(points_b))

    def detection_mask(self) -> np.ndarray:
        """uint8 (rows, cols) image of `height` x `width` pixels (those it was learned in): 0 in the fixed cells,
        255 elsewhere (a pixel in the cell `contains` puts its keypoint in); for `image_matching.orb_features`'s
        `mask`, so that the feature budget goes to the ground."""
        rows, cols = int(np.ceil(self.height)), int(np.ceil(self.width))
        r = np.minimum(np.arange(rows) // self.cell_px, self.cells.shape[0] - 1).astype(int)
        c = np.minimum(np.arange(cols) // self.cell_px, self.cells.shape[1] - 1).astype(int)
        return np.where(self.cells[r[:, None], c[None, :]], 0, 255).astype(np.uint8)

    def boxes(self, scale: float = 1.0) -> list[tuple[int, int, int, int]]:
        """The fixed regions as boxes (x0, x1, y0, y1) in pixels of `scale` x the pixels given (full-size pixels:
        1 / the detection scale), one per connected group of fixed cells, largest first."""
        import cv2

        if not self:
            return []
        count, labels = cv2.connectedComponents(self.cells.astype(np.uint8), connectivity=8)
        out = []
        for k in range(1, count):
            r, c = np.nonzero(labels == k)
            x0, x1 = c.min() * self.cell_px, min((c.max() + 1) * self.cell_px, self.width)
            y0, y1 = r.min() * self.cell_px, min((r.max() + 1) * self.cell_px, self.height)
            out.append((len(r), tuple(int(round(v * scale)) for v in (x0, x1, y0, y1))))
        return [box for _, box in sorted(out, key=lambda t: -t[0])]

    def describe(self, scale: float = 1.0) -> str:
        """One line for logs and reports ('' when nothing is fixed)."""
        boxes = self.boxes(scale)
        if not boxes:
            return ""
        where = ", ".join(f"x {x0}-{x1} y {y0}-{y1} px" for x0, x1, y0, y1 in boxes[:4])
        more = f" and {len(boxes) - 4} more" if len(boxes) > 4 else ""
        return (f"matches fixed in the image frame left out ({where}{more}; static in up to "
                f"{int(self.static_pairs.max())} of {self.pairs_taught} pairs of a moving camera): burned-in text, "
                "a logo or parts of the drone?")


def camera_moved(points_a: np.ndarray, points_b: np.ndarray, static_px: float = STATIC_PX) -> bool:
    """Whether a pair's matches show the camera moved: at least MIN_MOVED of them moved beyond MOVED_STATICS
    static radii and agree on one homography (within 2 static radii)."""
    d = np.linalg.norm(np.asarray(points_b, np.float64) - np.asarray(points_a, np.float64), axis=1)
    moved = d > MOVED_STATICS * static_px
    if moved.sum() < MIN_MOVED:
        return False
    inl = homography_inliers(np.asarray(points_a)[moved], np.asarray(points_b)[moved], 2.0 * static_px)
    return inl is not None and int(inl.sum()) >= MIN_MOVED


def learn_fixed_in_frame(pairs: Iterable[tuple[np.ndarray, np.ndarray]], width: float, height: float,
                         static_px: float = STATIC_PX) -> FixedInFrame:
    """The cells of a `width` x `height` image where features stay at one pixel while the camera moves, from the
    matches of image pairs (`pairs`: per pair the matched points (N, 2) in a and in b, pixels of the detection
    copy, before any geometric model: RANSAC may already have kept the overlay). Only the pairs of a moving camera
    teach (`camera_moved`); a cell is fixed when it holds a static match in at least MIN_SHARE of them (and
    MIN_PAIRS), or in MIN_PAIRS of them and is connected to such a cell by others that are. The fixed cells are
    grown by one cell: a keypoint near a cell's edge falls on either side."""
    import cv2

    cell = max(float(width), float(height)) / GRID_CELLS
    shape = (max(1, int(np.ceil(height / cell))), max(1, int(np.ceil(width / cell))))
    counts = np.zeros(shape, np.int64)
    taught = 0
    for points_a, points_b in pairs:
        pa, pb = np.asarray(points_a, np.float64).reshape(-1, 2), np.asarray(points_b, np.float64).reshape(-1, 2)
        if not camera_moved(pa, pb, static_px):
            continue
        taught += 1
        static = np.linalg.norm(pb - pa, axis=1) <= static_px
        if not static.any():
            continue
        mid = 0.5 * (pa[static] + pb[static])
        c = np.clip(np.floor(mid[:, 0] / cell), 0, shape[1] - 1).astype(int)
        r = np.clip(np.floor(mid[:, 1] / cell), 0, shape[0] - 1).astype(int)
        hit = np.zeros(shape, bool)
        hit[r, c] = True
        counts += hit
    fixed = (counts >= max(MIN_PAIRS, MIN_SHARE * taught)) if taught else np.zeros(shape, bool)
    if fixed.any():
        weak = counts >= MIN_PAIRS
        count, labels = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
        fixed = np.isin(labels, np.unique(labels[fixed]))  # the weak regions that hold a strong cell
        fixed = cv2.dilate(fixed.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return FixedInFrame(fixed, cell, float(width), float(height), taught, counts)
