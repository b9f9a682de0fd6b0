"""Several images per capture (one trigger, one time and one position): a multispectral camera writes one file
per band (MicaSense: IMG_0001_1.tif .. _5.tif), a multi-camera rig one per camera. Their images of a capture
share a position but not a viewpoint (the lenses sit centimetres apart, each band its own lens), so neither
structure from motion nor the tags' poses make one camera of them: the nu30 sweep's MicaSense folder was refused
with "orientations could not be solved from tie points", which misses the cause. Repeated frames at one
time and fix (bracketed exposures, a GPS slower than the shutter, one gray camera shooting faster than its clock
ticks) are no rig: a rig is told by its images being different sensors'."""

from __future__ import annotations

import logging
import re
from collections import Counter, defaultdict
from pathlib import Path

from ..database.exif import ImageMetadata
from ..plugin.errors import InputError

log = logging.getLogger(__name__)

# a folder is a rig's when the captures holding several images hold at least this share of its images (every or
# most triggers; a hover's few repeated fixes, or two frames of one clock second at one fix, are not)
RIG_SHARE = 0.5
# and at least this many such captures: one position repeated (a burst within one clock second at a frozen fix,
# or a few test frames written with one set of tags) is no rig's trigger series, and no survey either
MIN_RIG_CAPTURES = 3


def one_image_per_capture(metas: list[ImageMetadata], folder: str | Path) -> list[int]:
    """The indices of `metas` to use, one image per capture: all of them when the captures hold one image each;
    when most hold several (same capture time and same GPS position), the one image of each capture whose file
    type differs from the others' when every capture has exactly one such image of one type (DJI P4
    Multispectral: one RGB JPEG beside five TIFF bands; said in an info line naming the bands left out), else an
    InputError naming `folder` and the cause."""
    groups: dict[tuple[float, float, float], list[int]] = defaultdict(list)
    for i, m in enumerate(metas):
        if m.has_gps and m.capture_time_s is not None:
            groups[(float(m.capture_time_s), float(m.latitude), float(m.longitude))].append(i)  # type: ignore[arg-type]
    # a rig's capture holds different sensors' images; repeated frames of one camera at one fix (bracketed
    # exposures, a GPS or a clock slower than the shutter, a gray NIR camera at 2 fps) are mapped as they are
    shared = [g for g in groups.values() if len(g) > 1 and _sensors_differ(g, metas)]
    if sum(map(len, shared)) < RIG_SHARE * len(metas) or len(shared) < MIN_RIG_CAPTURES:
        return list(range(len(metas)))
    per_capture = Counter(len(g) for g in shared).most_common(1)[0][0]
    chosen = [_odd_one(g, metas) for g in shared]
    kinds = {metas[i].path.suffix.lower() for i in chosen if i is not None}
    if None in chosen or len(kinds) != 1:
        raise InputError(f"{per_capture} images per capture (same time and position): a multispectral or "
                         "multi-camera rig? map one band's images", folder)
    in_shared = {i for g in shared for i in g}
    keep = sorted(set(chosen) | (set(range(len(metas))) - in_shared))  # type: ignore[arg-type]
    skipped = sorted({metas[i].path.suffix for g in shared for i in g if i not in keep})
    log.info("%d images per capture (same time and position, a multispectral camera?): the %d %s images (one per "
             "capture, of their own file type) are used; the %d band images (%s) are left out", per_capture,
             len(chosen), metas[chosen[0]].path.suffix, sum(map(len, shared)) - len(chosen), ", ".join(skipped))
    return keep


# MicaSense / Altum names a capture's bands IMG_0001_1.tif .. IMG_0001_6.tif: one stem, a band index of 1-2 digits
_BAND_SUFFIX = re.compile(r"^(?P<stem>.+)_(?P<band>\d{1,2})$")


def _sensors_differ(group: list[int], metas: list[ImageMetadata]) -> bool:
    """Whether the images of one capture come from different sensors (bands or cameras) rather than being repeated
    frames of one camera: different XMP band names (MicaSense, DJI multispectral write `BandName`), different
    file types (DJI P4 Multispectral: an RGB JPEG beside TIFF bands), or one name stem with band indices."""
    bands = {metas[i].xmp.get("BandName") for i in group}
    if len(bands - {None}) > 1:
        return True
    if len({metas[i].path.suffix.lower() for i in group}) > 1:
        return True
    names = [_BAND_SUFFIX.match(metas[i].path.stem) for i in group]
    return all(names) and len({m["stem"] for m in names if m}) == 1 and len({m["band"] for m in names if m}) > 1


def _odd_one(group: list[int], metas: list[ImageMetadata]) -> int | None:
    """The one image of a capture whose file type (extension) no other of its images has (None: not one)."""
    kinds = Counter(metas[i].path.suffix.lower() for i in group)
    odd = [i for i in group if kinds[metas[i].path.suffix.lower()] == 1]
    return odd[0] if len(odd) == 1 and len(kinds) == 2 else None


def one_image_per_exposure(metas: list[ImageMetadata]) -> tuple[list[int], list[str]]:
    """(the indices of `metas` to use, the warning said) for one image per exposure: two images of one camera
    with the same capture time (to the fraction of a second where recorded), the same GPS position and the same
    exposure time, which show the same view (`same_view`: no image motion between them), are one exposure under
    two names, whatever their bytes (an edited copy, "frame-Edit.jpg", auto-contrast: nu42, its three copies
    replaced their originals as keyframes without a word). Said in one warning naming both files; the one kept
    is `original_name`. Frames of one clock second at one fix that show the camera moved (a GPS slower than the
    shutter), bracketed exposures (their exposure times differ) and a rig's bands (other sensors,
    `one_image_per_capture`) are kept."""
    groups: dict[tuple, list[int]] = defaultdict(list)
    for i, m in enumerate(metas):
        if m.has_gps and m.capture_time_s is not None:
            groups[(float(m.capture_time_s), float(m.latitude), float(m.longitude),  # type: ignore[arg-type]
                    m.altitude, m.exposure_s, m.make, m.model)].append(i)
    drop: set[int] = set()
    said = []
    for group in groups.values():
        if len(group) < 2 or _sensors_differ(group, metas):
            continue
        keep = original_name([metas[i].path.name for i in group])
        kept = group[keep]
        copies = [i for i in group if i != kept and same_view(metas[kept].path, metas[i].path)]
        drop.update(copies)
        said += [f"{metas[i].path.name} (= {metas[kept].path.name})" for i in copies]
    warnings = []
    if said:
        warnings.append(f"{len(said)} image(s) repeat another's exposure (same capture time, GPS position and "
                        "exposure, the same view) under another name (a copy, edited or not?): "
                        + "; ".join(said[:5]) + (f" ... ({len(said)} in all)" if len(said) > 5 else "")
                        + "; each is left out, its original kept (the name the others derive from); remove the copies")
        log.warning("%s", warnings[0])
    return [i for i in range(len(metas)) if i not in drop], warnings


def original_name(names: list[str]) -> int:
    """Which of one exposure's file names is the original, by a rule no editor's naming decides: a copy's name is
    made from its original's (an editor appends "-Edit", "_edited", " (1)", prepends "copy of "), so the original
    is the name whose stem every other name contains; failing that (renamed copies), the shortest name, then the
    first in name order. (File times say nothing: a copy made by `cp` is newer, one restored from a backup older.)"""
    stems = [Path(n).stem for n in names]
    derived_from = [k for k, s in enumerate(stems) if all(s in n for j, n in enumerate(names) if j != k)]
    candidates = derived_from or list(range(len(names)))
    return min(candidates, key=lambda k: (len(names[k]), names[k]))


# the image motion (working pixels) below which two images show the same view: the measurement's own precision
SAME_VIEW_PX = 1.0
SAME_VIEW_WIDTH = 512  # the working width the two are compared at (pixels)


def same_view(a: Path, b: Path) -> bool:
    """Whether two images show the same view: the same size, and phase correlation of their gray levels (blind to
    a change of tone or contrast) finds no motion between them; an image that does not read is not judged the
    same (it is named where its pixels are read)."""
    import cv2

    from ..database.images import read_gray

    try:
        ga, gb = read_gray(a), read_gray(b)
    except InputError:
        return False
    if ga.shape != gb.shape:
        return False
    scale = min(1.0, SAME_VIEW_WIDTH / ga.shape[1])
    size = (max(1, round(ga.shape[1] * scale)), max(1, round(ga.shape[0] * scale)))
    wa, wb = (cv2.resize(g.astype("float64"), size, interpolation=cv2.INTER_AREA) for g in (ga, gb))
    window = cv2.createHanningWindow(size, cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(wa, wb, window)
    return bool((dx * dx + dy * dy) ** 0.5 < SAME_VIEW_PX)
