"""The mask container every segmentation backend returns, and the backend interface.

Memory: a 1200x900 image with a few hundred full-size boolean masks would take hundreds of MB, so a `MaskSet`
stores either one label image (backends whose masks do not overlap, e.g. `classical`) or one boolean crop per
mask inside its bounding box (overlapping backends, e.g. SAM). Both forms answer the same questions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

#: A backend: image (H, W, 3) uint8 RGB -> MaskSet. Backends are plain callables (closures or objects).
Backend = Callable[[np.ndarray], "MaskSet"]


def check_image_u8(image: np.ndarray) -> None:
    """ValueError unless `image` is an (H, W, 3) RGB or (H, W) gray uint8 array, the image every backend and the
    mask description take. Other dtypes are not cast here: a cast keeps a 16-bit value's low byte and zeroes a
    0..1 float (describe_masks then found no SIFT without an error, rev50 D6), and the right 8-bit image needs the
    flight's white level, which `sosmatch.database.images.to_rgb_u8` applies (as `read_image` does)."""
    if image.dtype != np.uint8:
        raise ValueError(f"image dtype {image.dtype}: expected uint8 (8-bit RGB or gray; convert others with "
                         "sosmatch.database.images.to_rgb_u8 and the flight's white level)")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"image shape {image.shape}: expected (H, W, 3) RGB or (H, W) gray")


@dataclass
class MaskSet:
    """K binary masks over an image of `shape` (H, W), with a confidence score per mask.

    Exactly one representation is set:
    - `labels`: (H, W) int32, mask k is `labels == k`, -1 = no mask (non-overlapping masks);
    - `boxes` + `crops`: boxes (K, 4) int32 `x0, y0, x1, y1` (x1, y1 exclusive) and crops[k] a bool array of
      shape (y1 - y0, x1 - x0) (masks may overlap).
    """

    shape: tuple[int, int]
    scores: np.ndarray
    labels: np.ndarray | None = None
    boxes: np.ndarray | None = None
    crops: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.shape = (int(self.shape[0]), int(self.shape[1]))
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        if self.labels is not None:
            if self.labels.shape != self.shape:
                raise ValueError(f"labels shape {self.labels.shape} != image shape {self.shape}")
            self.labels = self.labels.astype(np.int32, copy=False)
            self._bbox_from_labels()
        else:
            if self.boxes is None:
                self.boxes = np.zeros((0, 4), np.int32)
            self.boxes = np.asarray(self.boxes, dtype=np.int32).reshape(-1, 4)
            if len(self.crops) != len(self.boxes):
                raise ValueError("need one crop per box")
            for box, crop in zip(self.boxes, self.crops):
                if crop.shape != (box[3] - box[1], box[2] - box[0]):
                    raise ValueError(f"crop shape {crop.shape} does not match box {box.tolist()}")
        if len(self.scores) != len(self):
            raise ValueError(f"{len(self.scores)} scores for {len(self)} masks")

    # -- construction --------------------------------------------------------------------------------------
    @classmethod
    def from_labels(cls, labels: np.ndarray, scores: np.ndarray | None = None) -> MaskSet:
        """From a label image of integers (or integral floats; negative = background, so an unsigned image has
        none: its 0 is a label too). Labels need not be consecutive: present labels are renumbered 0..K-1 in
        increasing order of their value; `scores`, if given, is indexed by the ORIGINAL label value (length > max
        label) or already has one entry per present label. ValueError for NaN, infinite or non-numeric labels."""
        labels = np.asarray(labels)
        if labels.dtype.kind not in "biuf":
            raise ValueError(f"labels dtype {labels.dtype}: expected integers (negative = background)")
        if labels.dtype.kind == "f" and not np.isfinite(labels).all():
            raise ValueError("labels hold NaN or infinite values: mark the background with a negative label")
        # max() with no initial: `initial=-1` does not fit an unsigned dtype (uint8 labels raised OverflowError)
        top = int(labels.max()) if labels.size else -1
        if top < 0:
            return cls(labels.shape, np.zeros(0, np.float32), labels=np.full(labels.shape, -1, np.int32))
        if top > np.iinfo(np.int64).max - 2:
            raise ValueError(f"label {top} is too large (at most {np.iinfo(np.int64).max - 2})")
        shifted = labels.astype(np.int64, copy=False).ravel() + 1
        shifted[shifted < 0] = 0
        if top < 2 * shifted.size + 1024:
            # bincount + lookup table instead of np.unique: no sort over millions of pixels
            present = np.flatnonzero(np.bincount(shifted, minlength=top + 2)[1:])
            lut = np.full(top + 2, -1, np.int32)
            lut[present + 1] = np.arange(len(present), dtype=np.int32)
            out = lut[shifted].reshape(labels.shape)
        else:
            # sparse labels far beyond the pixel count (2^33 asked bincount for 64 GiB): sorted instead
            uniq, inv = np.unique(shifted, return_inverse=True)
            background = int(uniq[0] == 0)
            present = uniq[background:] - 1
            out = (inv.reshape(-1) - background).astype(np.int32).reshape(labels.shape)
        if scores is None:
            scores = np.ones(len(present), np.float32)
        else:
            scores = np.asarray(scores, np.float32)
            if len(scores) != len(present):
                scores = scores[present]
        return cls(labels.shape, scores, labels=out)

    @classmethod
    def from_masks(
        cls, masks: np.ndarray | list[np.ndarray], scores: np.ndarray | None = None,
        shape: tuple[int, int] | None = None,
    ) -> MaskSet:
        """From full-size boolean masks (K, H, W) (or a list of them): cropped to their bounding boxes.
        Empty masks are dropped (with their scores). `shape`: the image's (H, W), needed when there is no mask
        (an empty list gave shape (0, 0), which no image matches); ValueError if the masks' shapes differ from
        it or from each other."""
        if shape is None and isinstance(masks, np.ndarray) and masks.ndim == 3:
            shape = masks.shape[1:]
        masks = [np.asarray(m, dtype=bool) for m in masks]
        if scores is None:
            scores = np.ones(len(masks), np.float32)
        if shape is None:
            if not masks:
                raise ValueError("no masks: give the image's shape (from_masks([], shape=(H, W)))")
            shape = masks[0].shape
        shape = (int(shape[0]), int(shape[1]))
        for k, m in enumerate(masks):
            if m.shape != shape:
                raise ValueError(f"mask {k} has shape {m.shape}, the image {shape}")
        boxes, crops, keep = [], [], []
        for k, m in enumerate(masks):
            rows = np.flatnonzero(m.any(axis=1))
            if len(rows) == 0:
                continue
            cols = np.flatnonzero(m.any(axis=0))
            x0, x1, y0, y1 = cols[0], cols[-1] + 1, rows[0], rows[-1] + 1
            boxes.append((x0, y0, x1, y1))
            crops.append(m[y0:y1, x0:x1].copy())
            keep.append(k)
        return cls(shape, np.asarray(scores, np.float32)[keep], boxes=np.asarray(boxes, np.int32).reshape(-1, 4),
                   crops=crops)

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> MaskSet:
        return cls(shape, np.zeros(0, np.float32), boxes=np.zeros((0, 4), np.int32), crops=[])

    # -- queries -------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        if self.labels is not None:
            return int(self._label_boxes.shape[0])
        return len(self.crops)

    @property
    def overlapping(self) -> bool:
        """True for the crop representation (masks may overlap)."""
        return self.labels is None

    def _bbox_from_labels(self) -> None:
        from scipy.ndimage import find_objects

        # find_objects: one C pass over the image, slices per label 1..K (background -1 -> 0 is ignored)
        slices = find_objects(self.labels + 1)
        boxes = np.zeros((len(slices), 4), np.int32)
        for k, sl in enumerate(slices):
            if sl is not None:
                boxes[k] = (sl[1].start, sl[0].start, sl[1].stop, sl[0].stop)
        self._label_boxes = boxes

    @property
    def bboxes(self) -> np.ndarray:
        """(K, 4) int32 bounding boxes x0, y0, x1, y1 (exclusive)."""
        return self._label_boxes if self.labels is not None else self.boxes

    def areas(self) -> np.ndarray:
        """(K,) int64 pixel counts."""
        if self.labels is not None:
            lab = self.labels[self.labels >= 0]
            return np.bincount(lab, minlength=len(self)).astype(np.int64)
        return np.asarray([int(c.sum()) for c in self.crops], np.int64)

    def crop(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(box (4,), bool crop) of mask k."""
        box = self.bboxes[k]
        if self.labels is not None:
            return box, self.labels[box[1] : box[3], box[0] : box[2]] == k
        return box, self.crops[k]

    def mask(self, k: int) -> np.ndarray:
        """Full-size (H, W) bool mask k (allocates H*W bytes: use `crop` in loops)."""
        out = np.zeros(self.shape, bool)
        box, crop = self.crop(k)
        out[box[1] : box[3], box[0] : box[2]] = crop
        return out

    def rasterise(self, order: str = "area") -> np.ndarray:
        """(H, W) int32 label image, -1 where no mask. Overlaps are resolved by painting the largest masks
        first (`order="area"`, so small masks stay visible on top) or in index order (`order="index"`)."""
        if self.labels is not None:
            return self.labels.copy()
        out = np.full(self.shape, -1, np.int32)
        idx = np.argsort(-self.areas(), kind="stable") if order == "area" else np.arange(len(self))
        for k in idx:
            box, crop = self.crop(int(k))
            view = out[box[1] : box[3], box[0] : box[2]]
            view[crop] = k
        return out

    def union(self) -> np.ndarray:
        """(H, W) bool: pixels covered by any mask."""
        if self.labels is not None:
            return self.labels >= 0
        out = np.zeros(self.shape, bool)
        for box, crop in zip(self.boxes, self.crops):
            out[box[1] : box[3], box[0] : box[2]] |= crop
        return out

    def subset(self, indices: np.ndarray) -> MaskSet:
        """The masks `indices` (in that order) as a new MaskSet (label images are renumbered)."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        if self.labels is not None:
            lut = np.full(len(self) + 1, -1, np.int32)
            lut[indices] = np.arange(len(indices), dtype=np.int32)
            # index -1 (background) maps to lut[-1] == -1
            return MaskSet(self.shape, self.scores[indices], labels=lut[self.labels])
        return MaskSet(self.shape, self.scores[indices], boxes=self.boxes[indices],
                       crops=[self.crops[int(k)] for k in indices])


def mask_iou_matrix(masks: MaskSet, targets: MaskSet) -> np.ndarray:
    """(K, T) IoU between every mask of `masks` and every mask of `targets` (same image shape).

    Computed from a pairwise intersection count: for label-image targets one bincount per mask crop, so the
    cost is the total mask area, not K * T * H * W.
    """
    if masks.shape != targets.shape:
        raise ValueError(f"shapes differ: {masks.shape} vs {targets.shape}")
    k, t = len(masks), len(targets)
    inter = np.zeros((k, t), np.int64)
    if k and t:
        if targets.labels is not None:
            tl = targets.labels
            for i in range(k):
                box, crop = masks.crop(i)
                vals = tl[box[1] : box[3], box[0] : box[2]][crop]
                vals = vals[vals >= 0]
                inter[i] = np.bincount(vals, minlength=t)
        else:
            tb = targets.bboxes
            for i in range(k):
                box, crop = masks.crop(i)
                # only targets whose box overlaps this mask's box
                hit = np.flatnonzero(
                    (tb[:, 0] < box[2]) & (tb[:, 2] > box[0]) & (tb[:, 1] < box[3]) & (tb[:, 3] > box[1])
                )
                for j in hit:
                    bj, cj = targets.crop(int(j))
                    x0, y0 = max(box[0], bj[0]), max(box[1], bj[1])
                    x1, y1 = min(box[2], bj[2]), min(box[3], bj[3])
                    a = crop[y0 - box[1] : y1 - box[1], x0 - box[0] : x1 - box[0]]
                    b = cj[y0 - bj[1] : y1 - bj[1], x0 - bj[0] : x1 - bj[0]]
                    inter[i, j] = int(np.count_nonzero(a & b))
    union = masks.areas()[:, None] + targets.areas()[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)
