"""On-disk cache of synthetic worlds, so that each `sosmatch synth` call does not rebuild its world.

Building a world (terrain, ground cover, object placement) and a season's ground albedo takes ~9 s of CPU;
loading them takes a fraction of a second. An entry is a directory `<cache>/worlds/<key>/` holding the world's
rasters as .npy files and `world.json` (objects, roads, per-file CRC-32); each season's albedo is added beside
it the first time that season is rendered (`albedo_<season>.npy` + `albedo_<season>.json`).

- key: SHA-256 of `WORLD_CODE_VERSION`, a digest of the world-building source files and every `WorldConfig`
  field, so a change of settings or code never reuses a stale world. Bump `WORLD_CODE_VERSION` when world
  generation changes in a way the source digest would not see (e.g. a dependency's behaviour).
- location: `$SOSMATCH_CACHE_DIR` if set (empty, `0` or `off` disables the cache), else
  `$XDG_CACHE_HOME/sosmatch`, else `~/.cache/sosmatch`. ~110 MB per world at the default 600 m / 0.15 m,
  plus 48 MB per season. At most `MAX_WORLDS` entries are kept (the least recently used are removed when a new
  one is written), so code edits and setting changes do not fill the disk. Delete the directory at any time.
- safety: entries are written atomically (temporary sibling + rename); an entry that fails to load or whose
  CRC does not match is rebuilt and rewritten; a cache that cannot be written only logs a warning. A cached
  world is bit-identical to a freshly built one, so sessions do not depend on the cache. Two runs of one new
  world at once both build it; the second finds the first's entry complete and equal and uses it (DEBUG only).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import logging
import os
import shutil
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...database.atomic import atomic_path, write_bytes_atomic

if TYPE_CHECKING:
    from .world import World, WorldConfig

log = logging.getLogger(__name__)

WORLD_CODE_VERSION = 1
MAX_WORLDS = 6
_SOURCES = ("world.py", "objects.py", "appearance.py", "noise.py")  # what a cached world is built by
_CORE_ARRAYS = ("terrain_coarse", "terrain", "cover", "cell", "cp_cls", "cp_crop", "cp_theta", "cp_period",
                "cp_phase", "cp_bright")


def cache_root() -> Path | None:
    """The cache directory (None: caching disabled by SOSMATCH_CACHE_DIR = '', '0' or 'off')."""
    env = os.environ.get("SOSMATCH_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in ("", "0", "off") else Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "sosmatch"


@functools.lru_cache(maxsize=1)
def _source_digest() -> str:
    h = hashlib.sha256()
    for name in _SOURCES:
        h.update((Path(__file__).parent / name).read_bytes())
    return h.hexdigest()


def world_key(config: WorldConfig) -> str:
    """Cache key of a world: code version, source digest and every world setting."""
    text = json.dumps({"code": WORLD_CODE_VERSION, "source": _source_digest(), "config": dataclasses.asdict(config)},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def entry_dir(config: WorldConfig) -> Path | None:
    """The cache entry directory of a world (None when caching is disabled)."""
    root = cache_root()
    return None if root is None else root / "worlds" / world_key(config)


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _load_npy(path: Path, crc: int) -> np.ndarray:
    data = path.read_bytes()
    if zlib.crc32(data) != crc:
        raise ValueError(f"{path.name}: checksum mismatch")
    return np.load(io.BytesIO(data), allow_pickle=False)


def load_world(config: WorldConfig) -> World | None:
    """The cached world of `config`, or None (no cache, no entry, or a corrupt one: logged)."""
    from .world import CellParams, World, WorldObject

    entry = entry_dir(config)
    if entry is None or not (entry / "world.json").exists():
        return None
    try:
        meta = json.loads((entry / "world.json").read_text(encoding="utf-8"))
        if meta.get("key") != entry.name:
            raise ValueError("key mismatch")
        arr = {name: _load_npy(entry / f"{name}.npy", int(meta["crc"][name])) for name in _CORE_ARRAYS}
        n = config.cells
        if arr["terrain"].shape != (n, n) or arr["cover"].shape != (n, n) or arr["cell"].shape != (n, n):
            raise ValueError("raster shape mismatch")
        from ...database.synth_session import TerrainSampler

        parts = {
            "terrain_sampler": TerrainSampler(arr["terrain_coarse"], 0.0, 0.0, config.terrain_resolution_m),
            "terrain": arr["terrain"], "cover": arr["cover"], "cell": arr["cell"],
            "cell_params": CellParams(arr["cp_cls"], arr["cp_crop"], arr["cp_theta"], arr["cp_period"],
                                      arr["cp_phase"], arr["cp_bright"]),
            "roads": [(k, float(w), np.asarray(p, np.float64)) for k, w, p in meta["roads"]],
            "objects": [WorldObject(**o) for o in meta["objects"]],
        }
        world = World(config, parts=parts)
    except (OSError, ValueError, KeyError, TypeError, json.JSONDecodeError) as exc:
        log.warning("world cache entry %s is unusable (%s): rebuilding it", entry, exc)
        return None
    world.cache_entry = entry
    try:
        os.utime(entry / "world.json")  # mark as recently used for `prune`
    except OSError:
        pass
    return world


def prune(worlds_dir: Path, keep: int = MAX_WORLDS) -> list[Path]:
    """Remove all but the `keep` most recently used entries of `worlds_dir` (by world.json's mtime; entries
    without one count as oldest). Returns the removed directories."""

    def used(d: Path) -> float:
        try:
            return (d / "world.json").stat().st_mtime
        except OSError:
            return float("-inf")

    entries = sorted((d for d in worlds_dir.iterdir() if d.is_dir() and not d.name.startswith(".")), key=used,
                     reverse=True)
    for d in entries[keep:]:
        shutil.rmtree(d, ignore_errors=True)
    return entries[keep:]


def save_world(world: World) -> None:
    """Write the world's cache entry (atomically; failures are logged, not raised)."""
    entry = entry_dir(world.config)
    if entry is None:
        return
    p = world.cell_params
    arrays = {"terrain_coarse": world.terrain_sampler.heights, "terrain": world.terrain, "cover": world.cover,
              "cell": world.cell, "cp_cls": p.cls, "cp_crop": p.crop, "cp_theta": p.theta, "cp_period": p.period,
              "cp_phase": p.phase, "cp_bright": p.bright}
    crc = {name: zlib.crc32(_npy_bytes(a)) for name, a in arrays.items()}
    try:
        if _complete_and_equal(entry, crc):  # another run wrote it since this one looked (`_complete_and_equal`)
            log.debug("another run wrote the world cache %s first; using it", entry)
        else:
            if entry.exists():  # an entry `load_world` found unusable: the cache's own, so it removes it
                shutil.rmtree(entry, ignore_errors=True)
            with atomic_path(entry) as tmp:
                tmp.mkdir()
                for name, a in arrays.items():
                    (tmp / f"{name}.npy").write_bytes(_npy_bytes(a))
                meta = {"key": entry.name, "config": dataclasses.asdict(world.config), "crc": crc,
                        "roads": [[k, float(w), np.asarray(pts, np.float64).tolist()] for k, w, pts in world.roads],
                        "objects": [_object_dict(o) for o in world.objects]}
                (tmp / "world.json").write_text(json.dumps(meta), encoding="utf-8")
        prune(entry.parent)
    except OSError as exc:
        # two `synth` runs of one new world at once: both build it, the first renames its entry into place and
        # the second's rename finds a directory there (the nu51 sweep: "cannot write the world cache X: X: exists
        # and is a directory; not replaced", harmless yet read as a failure). The same key builds the same bytes,
        # so an entry that is complete and equal to this world's is the cache working; anything else is a failure
        if _complete_and_equal(entry, crc):
            log.debug("another run wrote the world cache %s first; using it", entry)
        else:
            log.warning("cannot write the world cache %s: %s", entry, getattr(exc, "problem", None) or exc.strerror
                        or exc)
            return
    world.cache_entry = entry


def _complete_and_equal(entry: Path, crc: dict[str, int]) -> bool:
    """Whether `entry` holds a complete cache entry of this key whose rasters are the ones with checksums `crc`
    (each file read and checked, as `load_world` does): what another run of the same world writes."""
    try:
        meta = json.loads((entry / "world.json").read_text(encoding="utf-8"))
        if meta.get("key") != entry.name or meta.get("crc") != crc:
            return False
        for name, value in crc.items():
            _load_npy(entry / f"{name}.npy", value)
    except (OSError, ValueError, KeyError, TypeError, AttributeError, json.JSONDecodeError):
        return False
    return True


def _object_dict(o: Any) -> dict:
    # Plain Python values by declared field type; floats round-trip exactly through JSON (repr), so a loaded
    # world is bit-identical to the built one.
    conv = {"int": int, "float": float, "bool": bool, "str": str}
    return {f.name: conv[str(f.type)](getattr(o, f.name)) for f in dataclasses.fields(o)}


def load_albedo(entry: Path, season: str, shape: tuple[int, int]) -> np.ndarray | None:
    """A season's cached ground albedo, or None (missing or corrupt)."""
    meta_path = entry / f"albedo_{season}.json"
    if not meta_path.exists():
        return None
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        a = _load_npy(entry / f"albedo_{season}.npy", int(meta["crc"]))
        if a.shape != shape + (3,) or a.dtype != np.uint8:
            raise ValueError("albedo shape mismatch")
    except (OSError, ValueError, KeyError, TypeError, json.JSONDecodeError) as exc:
        log.warning("cached %s albedo in %s is unusable (%s): recomputing it", season, entry, exc)
        return None
    return a


def save_albedo(entry: Path, season: str, albedo: np.ndarray) -> None:
    """Add a season's ground albedo to a cache entry (the .npy first, then the .json that validates it)."""
    data = _npy_bytes(albedo)
    try:
        write_bytes_atomic(entry / f"albedo_{season}.npy", data)
        write_bytes_atomic(entry / f"albedo_{season}.json", json.dumps({"crc": zlib.crc32(data)}).encode())
    except OSError as exc:
        log.warning("cannot write the %s albedo to the world cache %s: %s", season, entry, exc)
