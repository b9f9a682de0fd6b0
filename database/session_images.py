"""A mapped session's keyframe images: where they are (the directory its run.json records, or one given), whether
the map was made from them (`check_map_of_images`: sha256 of a few keyframes), what grey levels the map read them
between (`levels_record`, `recorded_levels`) and the images themselves, read on demand (`KeyframeImages`). The
surface evidence of change detection looks at them; the rest of a session is `database.session_io`'s.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plugin.errors import InputError
from ..plugin.sampling import evenly_spaced
from .session_io import MapRecord, SessionFiles, map_record_of, read_map_record

if TYPE_CHECKING:
    from .images import Levels


def check_map_of_images(map_dir: str | Path, images_dir: str | Path, samples: int = 6) -> None:
    """Refuse (InputError) a mapped session that was not made from the images in `images_dir`: up to `samples`
    of its keyframes (run.json `keyframe_images`, sha256 per image) must have the same contents there.

    Sessions of one flight path share their image names, so names alone cannot tell a summer map from a
    winter one; a map without the record (an older sosmatch, a merged model) is not checked."""
    from .output_markers import sha256_file

    map_dir, images_dir = Path(map_dir), Path(images_dir)
    try:
        digests = (read_map_record(map_dir) or {}).get("keyframe_images")
    except InputError:
        return
    items = sorted(digests.items()) if isinstance(digests, dict) else []
    if not items:
        return
    picks = [items[i] for i in evenly_spaced(len(items), samples)]
    for name, digest in picks:
        image = images_dir / str(name)
        try:
            actual = sha256_file(image)  # the digest `run.json` recorded, by the same reader
        except OSError:
            raise InputError(f"map was made from images that are not in {images_dir} (no {name}); is it this "
                             "session's map?", map_dir) from None
        if actual != digest:
            raise InputError(f"map was made from other images than {images_dir} ({name} differs); is it this "
                             "session's map (sessions given in the other order)?", map_dir)


class KeyframeImages(Sequence):
    """A session's keyframe images as grey float arrays, read on demand (the surface evidence of change detection
    looks at a few keyframes per landmark) and kept while they fit in `max_bytes` (least recently used out first:
    bounded memory on any survey; the cache changes only the speed, never a value)."""

    def __init__(self, images_dir: Path, names: Sequence[str], sizes: Sequence[tuple[int, int]],
                 max_bytes: int = 512 * 2**20, levels: Levels | int | None = None) -> None:
        self.images_dir, self.names, self.sizes, self.max_bytes = Path(images_dir), list(names), list(sizes), max_bytes
        # what the map read the flight's images beyond 8 bits between (`recorded_levels`): the same grey levels
        # here as there, not each image scaled by itself (a thermal flight read at 12 grey levels: rev24)
        self.levels = levels
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._bytes = 0

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, k: int) -> np.ndarray:  # type: ignore[override]
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        from .images import read_image

        path = self.images_dir / self.names[k]
        rgb = read_image(path, self.levels)
        if (rgb.shape[1], rgb.shape[0]) != tuple(self.sizes[k]):
            raise InputError(f"image is {rgb.shape[1]} x {rgb.shape[0]} px but the map's camera of this keyframe is "
                             f"{self.sizes[k][0]} x {self.sizes[k][1]}: images of another session?", path)
        grey = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
        self._cache[k] = grey
        self._bytes += grey.nbytes
        while self._bytes > self.max_bytes and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes
        return grey


def levels_record(levels: Levels | int | None) -> list[float] | None:
    """run.json's "image_levels" for what a flight's images beyond 8 bits are read between
    (`flight_levels.flight_white_level`): [black, white], [0, white] for a bare white level, None for 8-bit images; what
    `recorded_levels` reads back."""
    from .images import Levels

    if levels is None:
        return None
    return [levels.black, levels.white] if isinstance(levels, Levels) else [0, int(levels)]


def recorded_levels(session: str | Path, run: MapRecord | None = None) -> Levels | int | None:
    """What `sosmatch map` read the session's images beyond 8 bits between (run.json "image_levels", the one
    measurement of `flight_levels.flight_white_level`): `Levels` for data offset from zero, the white level for others,
    None for 8-bit images or a record without it (an earlier map: each image read by its own white level). `run`:
    the session's run.json when read already (`session_io.map_record_of`)."""
    from .images import Levels

    run = map_record_of(session) if run is None else run
    if run.error is not None:
        return None
    record = run.record
    levels = record.get("image_levels") if isinstance(record, dict) else None
    if not (isinstance(levels, list) and len(levels) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels)):
        return None
    black, white = levels
    if not black < white:
        return None
    # a bare white level only for unsigned integer data read from 0; signed data below zero and float data
    # (degC) were read between their own levels
    return white if black == 0 and isinstance(white, int) else Levels(black, white)


def recorded_images_dir(session: str | Path) -> Path | None:
    """The images directory a mapped session's run.json records (None when it records none or is unreadable);
    it may no longer exist. The place relative to the session (its record's `inputs_from_session`) is taken first
    when it exists: it moves with a project folder moved or copied whole (a copy whose absolute path still names
    the original's images read those, and edits there changed the copy's results). The absolute path otherwise:
    a session folder moved alone. Which images a map was made from is checked by the caller
    (`check_map_of_images`).

    The relative place is tried from the session as given (`map` computed it from the path it wrote to) and from
    the folder it really is (a session reached through a symlink, `flights/M1 -> ../M1`: the OS reads
    `flights/M1/../S1` as `M1/../S1`); the path returned is the one found to be a directory (rev44 D1: the
    existence was tested on one and the other returned, so a batch over a folder of linked sessions compared
    them without their images)."""
    try:
        record = read_map_record(Path(session)) or {}
        recorded = (record.get("inputs") or {}).get("images")
        relative = (record.get("inputs_from_session") or {}).get("images")
    except (InputError, AttributeError):  # unreadable, or "inputs" not an object: no images known
        return None
    if not (isinstance(recorded, str) and recorded):
        return None
    if isinstance(relative, str) and relative:
        given = Path(session).absolute()
        for base in (given, given.resolve()):
            candidate = Path(os.path.normpath(base / relative))
            if candidate.is_dir():
                return candidate
    return Path(recorded)


def session_images_dir(session: str | Path | SessionFiles, images_dir: str | Path | None = None) -> Path | None:
    """The directory of a mapped session's keyframe images: `images_dir` if given, else the one its run.json
    records, when it still exists (None otherwise: no surface evidence). The map must have been made from those
    images (`check_map_of_images`: InputError otherwise)."""
    path = session.path if isinstance(session, SessionFiles) else Path(session)
    if images_dir is None:
        images_dir = recorded_images_dir(path)
        if images_dir is None or not images_dir.is_dir():
            return None
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise InputError("is a file, not an images directory" if images_dir.exists() else
                         "images directory not found", images_dir)
    check_map_of_images(path, images_dir)
    return images_dir


def compared_images_dirs(sessions: Sequence[str | Path | SessionFiles], given: Sequence[str | Path | None],
                         wanted: bool = True) -> tuple[list[Path | None], list[int]]:
    """The images directories change detection reads for each compared session (`session_images_dir`: the one
    given, else the one its run.json records) and the positions of the sessions whose images are not available.
    The surface evidence compares the sessions' images with each other, so with one session's missing none is
    used (all None); none either when not `wanted` (`changes.surface_evidence` off). InputError as
    `session_images_dir` (a given directory that is missing, or images the map was not made from)."""
    if not wanted:
        return [None] * len(sessions), []
    dirs = [session_images_dir(s, g) for s, g in zip(sessions, given, strict=True)]
    missing = [k for k, d in enumerate(dirs) if d is None]
    return ([None] * len(dirs) if missing else dirs), missing
