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
