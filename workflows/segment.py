"""`sosmatch segment`: segment images, describe the masks, write overlay PNGs and a per-image summary.

Python use:
```python
from sosmatch.workflows import segment
report = segment.run(["frames/"], "out/", backend="classical")
```
Writes, per image `NAME.EXT`: `OUT/NAME.EXT.png` (overlay: masks coloured, boundaries, centroids, 2-sigma
covariance ellipses) and `OUT/NAME.EXT.json` (per-mask centroid, covariance, size, area, score, SIFT count),
plus `OUT/summary.csv` (one line per image). Every file is written atomically; a re-run of the same images and
settings replaces them (other ones need `overwrite`). A backend's model files count as settings by their contents
(`database.segmentation_models`): another model, named by the environment or replaced at its path, needs
`overwrite` too, and NAME.EXT.json names the files ("models"). Outputs an earlier sosmatch named by the stem
(`NAME.json`, `NAME.png`) are replaced by the re-run too.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..database.atomic import write_bytes_atomic, write_text_atomic
from ..database.images import list_images, no_images_message, read_image, shared_file_name
from ..database.output_markers import versioned_identity
from ..database.outputs import OutputDir, open_output_dir
from ..database.segmentation_models import keyed_by_models, segmentation_models
from ..plugin.errors import InputError
from ..plugin.mask_features import MaskFeatures, describe_masks, segment_and_describe
from ..plugin.params import Params
from ..plugin.segmentation import MaskSet, get_backend

log = logging.getLogger(__name__)


def mask_colors(n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) uint8 distinct-ish RGB colours (golden-ratio hues, deterministic)."""
    hues = (np.arange(n) * 0.618033988749895 + 0.1 * seed) % 1.0
    hsv = np.stack([hues * 179, np.full(n, 220), np.full(n, 255)], 1).astype(np.uint8)[None]
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0] if n else np.zeros((0, 3), np.uint8)


def render_overlay(image: np.ndarray, masks: MaskSet, feats: MaskFeatures, alpha: float = 0.45) -> np.ndarray:
    """(H, W, 3) uint8 RGB overlay: masks in colour, mask boundaries, centroids and 2-sigma covariance ellipses."""
    out = image.copy()
    if len(masks) == 0:
        return out
    labels = masks.rasterise()
    colors = mask_colors(len(masks))
    inside = labels >= 0
    blend = out[inside].astype(np.float32) * (1 - alpha) + colors[labels[inside]].astype(np.float32) * alpha
    out[inside] = np.clip(blend, 0, 255).astype(np.uint8)
    # boundaries: pixels whose right or lower neighbour has another label
    edge = np.zeros(labels.shape, bool)
    edge[:, :-1] |= labels[:, :-1] != labels[:, 1:]
    edge[:-1, :] |= labels[:-1, :] != labels[1:, :]
    edge &= inside | np.roll(inside, 1, 0) | np.roll(inside, 1, 1)
    out[edge] = (255, 255, 255)
    thick = max(1, round(max(image.shape[:2]) / 600))
    for k in range(len(feats)):
        color = tuple(int(v) for v in colors[feats.mask_ids[k]])
        cx, cy = feats.centroids[k] - 0.5  # COLMAP -> OpenCV drawing convention
        evals, evecs = np.linalg.eigh(feats.covariances[k])
        axes = 2.0 * np.sqrt(np.maximum(evals, 0))  # 2 sigma
        angle = float(np.degrees(np.arctan2(evecs[1, 1], evecs[0, 1])))
        center = (int(round(cx * 16)), int(round(cy * 16)))
        size = (int(round(axes[1] * 16)), int(round(axes[0] * 16)))
        cv2.ellipse(out, center, size, angle, 0, 360, (0, 0, 0), thick + 1, cv2.LINE_AA, 4)
        cv2.ellipse(out, center, size, angle, 0, 360, color, thick, cv2.LINE_AA, 4)
        cv2.circle(out, center, (thick + 1) * 16, (0, 0, 0), -1, cv2.LINE_AA, 4)
        cv2.circle(out, center, thick * 16, (255, 255, 0), -1, cv2.LINE_AA, 4)
    return out


@dataclass
class ImageResult:
    """What `run` records for one input image."""

    path: Path
    width: int = 0
    height: int = 0
    num_masks: int = 0
    num_sift: int = 0
    median_size_px: float = float("nan")
    seconds_segment: float = 0.0
    seconds_describe: float = 0.0
    error: str | None = None


@dataclass
class SegmentReport:
    """Result of `run`: one entry per input image (failed ones carry `error`)."""

    images: list[ImageResult] = field(default_factory=list)

    @property
    def failed(self) -> list[ImageResult]:
        return [r for r in self.images if r.error is not None]


def _features_json(name: str, feats: MaskFeatures, width: int, height: int, backend: str,
                   models: dict[str, Any] | None = None) -> str:
    masks = []
    counts = np.bincount(feats.sift_mask, minlength=len(feats)) if len(feats) else np.zeros(0, int)
    for k in range(len(feats)):
        masks.append({
            "centroid": [round(float(v), 3) for v in feats.centroids[k]],
            "covariance": [round(float(v), 3) for v in feats.covariances[k].ravel()[[0, 1, 3]]],
            "size_px": round(float(feats.sizes[k]), 3),
            "area_px": int(feats.areas[k]),
            "score": round(float(feats.scores[k]), 4),
            "num_sift": int(counts[k]),
        })
    head = {"image": name, "width": width, "height": height, "backend": backend, "num_masks": len(masks),
            "pixel_convention": "COLMAP (centre of the top-left pixel is (0.5, 0.5)); covariance as xx, xy, yy"}
    if models:  # which model files made the masks (path, bytes, sha256); none for classical
        head["models"] = models
    # one mask per line: readable and diff-friendly
    body = ",\n".join("  " + json.dumps(m) for m in masks)
    return json.dumps(head)[:-1] + ', "masks": [\n' + body + ("\n" if masks else "") + "]}\n"


def segment_image(image: np.ndarray, params: Params, backend: object = None) -> tuple[MaskSet, MaskFeatures]:
    """Segment and describe one (H, W, 3) uint8 RGB image (the backend is built from `params` if not given)."""
    seg = params.segmentation
    backend = backend or get_backend(seg.backend, seg)
    return segment_and_describe(image, backend, seg)  # SIFT detection runs beside the backend


def run(
    inputs: list[str | Path],
    out_dir: str | Path,
    params: Params | None = None,
    backend: str | None = None,
    write_overlays: bool = True,
    overwrite: bool = False,
) -> SegmentReport:
    """Segment every image of `inputs` (files and/or directories) and write overlays and summaries to `out_dir`.

    A bad image (unreadable, corrupt, or refused by the backend: too small) is logged and recorded in the report;
    the others continue. The caller decides the exit code from `report.failed`. Raises InputError if `inputs`
    names nothing that exists or contains no image at all. `out_dir` is taken through `sosmatch.database.outputs`
    (`overwrite`: replace a complete segmentation of other images or settings there).
    """
    params = params or Params()
    if backend is not None:
        params = replace(params, segmentation=replace(params.segmentation, backend=backend))
    paths = list_images(inputs)
    if not paths:
        folders = [Path(p) for p in inputs if Path(p).is_dir()]
        if len(folders) == 1:
            raise InputError(no_images_message(folders[0]), folders[0])
        raise InputError(f"no images found in {', '.join(str(p) for p in inputs)}")
    _refuse_shared_names(paths)
    out_dir = Path(out_dir)
    images = [[str(p.resolve()), *_stat(p)] for p in paths]  # once: the identity is built for every version
    # the backend's model files (settings, else environment), fingerprinted once: the settings may not name them
    models = segmentation_models(params.segmentation)
    identity = keyed_by_models(lambda extra: versioned_identity(lambda as_dict: {
        "images": images, "overlays": write_overlays, "segmentation": as_dict(params.segmentation), **extra}), models)
    seg_backend = get_backend(params.segmentation.backend, models.params(params.segmentation))
    # every file it writes, checked when the folder is taken: a user's file at one of their names is refused before
    # the first image is segmented, not after
    files = [*(f"{p.name}.{ext}" for p in paths for ext in ("json", "png")[:1 + write_overlays]), "summary.csv"]
    with open_output_dir(out_dir, "segment", identity, inputs=inputs, overwrite=overwrite, files=files) as taken:
        report = _segment_into(taken, paths, params, seg_backend, write_overlays, models.record())
        taken.finish()
    return report


def _refuse_shared_names(paths: list[Path]) -> None:
    """InputError naming both when two images share a file name, before anything is written: their outputs
    NAME.json / NAME.png would be one file, the first image's silently replaced by the second's (exit 0, and
    summary.csv listing both). The file name is the image's name as COLMAP keeps it, and as `sosmatch map`
    refuses two of them (`database.images.shared_file_name`)."""
    shared = shared_file_name(paths)
    if shared is None:
        return
    first, second = shared
    if first.resolve() == second.resolve():
        raise InputError(f"image {second} is given twice (as {first} and {second}): give each image once", second)
    raise InputError(f"images {first} and {second} share the file name {second.name!r}, under which segment writes "
                     "each image's outputs: segment each folder into its own --out, or rename the images apart",
                     second.parent)


def _stat(path: Path) -> list[int]:
    st = path.stat()
    return [st.st_size, st.st_mtime_ns]


# images whose outputs one `publish` moves into the folder (see `_segment_into`)
PUBLISH_GROUP_IMAGES = 64


def _segment_into(taken: OutputDir, paths: list[Path], params: Params, seg_backend: Any,
                  write_overlays: bool, models: dict[str, Any] | None = None) -> SegmentReport:
    """`run` inside its taken output directory (`models`: the backend's model files as NAME.EXT.json records them)."""
    report = SegmentReport()
    from ..database.flight_levels import flight_white_level
    from ..plugin.flight_contrast import flight_contrast
    from .progress import progress_iter

    # one scale per folder: a folder holds one camera's flight, and folders given together may be of cameras of
    # other bit depths (one 16-bit scale read a 12-bit camera's images 16 times too dark)
    folders: dict[Path, list[Path]] = {}
    for path in paths:
        folders.setdefault(path.parent, []).append(path)
    white = {folder: flight_white_level(members) for folder, members in folders.items()}
    # and one contrast gain per folder (`plugin.flight_contrast`), as `sosmatch map` gives a flight: a hazy
    # folder is segmented as the map would segment it, and every image of it alike
    contrast = {folder: flight_contrast(members, params.segmentation.contrast_reference, white[folder])
                for folder, members in folders.items()}
    for folder, c in contrast.items():
        if c.stretched:
            log.warning("%s", c.message(f"{folder}: the images'"))
    # an image's outputs are staged and published in groups: each `publish` rewrites the marker, which records every
    # file written so far, so publishing image by image cost time quadratic in the images (4 ms an image at 1000);
    # a killed run loses at most a group's staged outputs, which a re-run segments anew as it does every image
    pending: list[str] = []
    pending_images: list[str] = []

    def publish_pending() -> None:
        if pending:
            taken.publish(pending)
            for image_name in pending_images:  # only once the outputs under the whole file name are published
                _remove_stem_named_outputs(taken, image_name)
        pending.clear()
        pending_images.clear()

    for path in progress_iter(paths, len(paths), "segment", "img", len(paths) >= 3):
        res = ImageResult(path)
        report.images.append(res)
        try:
            image = read_image(path, white[path.parent])
        except InputError as exc:  # recorded in the report; the caller says it (the CLI: once, on one line)
            res.error = str(exc)
            log.debug("%s", exc)
            continue
        res.height, res.width = image.shape[:2]
        t0 = time.perf_counter()
        try:
            masks = seg_backend(contrast[path.parent].apply(image))  # described and drawn on the image as read
        except InputError as exc:  # an image the backend refuses (too small): recorded like an unreadable one
            res.error = str(InputError(exc.problem, path))
            log.debug("%s", res.error)
            continue
        t1 = time.perf_counter()
        feats = describe_masks(image, masks, params.segmentation)
        t2 = time.perf_counter()
        res.seconds_segment, res.seconds_describe = t1 - t0, t2 - t1
        res.num_masks, res.num_sift = len(feats), len(feats.sift_mask)
        if len(feats):
            res.median_size_px = float(np.median(feats.sizes))
        # named by the whole file name, as COLMAP names an image's outputs (stereo/depth_maps/x.jpg.geometric.bin):
        # by the stem, x.jpg's and x.png's were one file holding the second image's
        written = [f"{path.name}.json"]
        write_text_atomic(taken.staged(written[0]),
                          _features_json(path.name, feats, res.width, res.height, params.segmentation.backend,
                                         models))
        if write_overlays:
            overlay = render_overlay(image, masks, feats)
            written.append(f"{path.name}.png")
            ok, buf = cv2.imencode(".png", cv2.cvtColor(overlay, cv2.COLOR_RGB2BGR))
            write_bytes_atomic(taken.staged(written[-1]), buf.tobytes())
        pending.extend(written)
        pending_images.append(path.name)
        if len(pending_images) >= PUBLISH_GROUP_IMAGES:
            publish_pending()
        log.info("%s: %d masks, %d SIFT, %.2f s", path.name, res.num_masks, res.num_sift, t2 - t0)
    publish_pending()
    taken.write_file("summary.csv", _summary_csv(report))
    return report


def _remove_stem_named_outputs(taken: OutputDir, image_name: str) -> None:
    """Remove this image's outputs as an earlier sosmatch named them (`STEM.json`, `STEM.png`) once its outputs
    under the whole file name are written: a re-run replaces an image's outputs, and the older ones would stay
    beside the new (rev36). Only a `STEM.json` that segment wrote for this very image goes (its "image" field
    names it, and the marker records it as segment's, unchanged: a user's file is left as it is), with the overlay
    beside it."""
    out_dir = taken.path
    stem = Path(image_name).stem
    old = out_dir / f"{stem}.json"
    if stem == image_name or not old.is_file():
        return
    try:
        made_for = json.loads(old.read_text()).get("image")
    except (OSError, ValueError, AttributeError):
        return  # not a segment output this run can recognise: left as it is
    if made_for != image_name:
        return
    overlay = f"{stem}.png"  # never the new overlay, NAME.EXT.png: the stem differs from the name
    for name in (old.name, overlay):
        with contextlib.suppress(InputError):  # not segment's (the user's, or changed since): left as it is
            taken.remove_file(name)


def _summary_csv(report: SegmentReport) -> str:
    """summary.csv: one row per image, written by the csv module (a file name or error holding a comma or a
    quote is one quoted field; joined by hand, `a,b.jpg` made a row of 10 fields under a header of 9)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["image", "width", "height", "num_masks", "num_sift", "median_size_px", "seconds_segment",
                     "seconds_describe", "error"])
    for r in report.images:
        writer.writerow([r.path.name, r.width, r.height, r.num_masks, r.num_sift, f"{r.median_size_px:.2f}",
                         f"{r.seconds_segment:.3f}", f"{r.seconds_describe:.3f}", r.error or ""])
    return buf.getvalue()
