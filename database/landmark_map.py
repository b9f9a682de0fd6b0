"""The compact landmark map: a documented, versioned, checksummed binary format (`.sosmap`).

Layout (little-endian; see docs/ARCHITECTURE.md):
    magic b"SOSMAP\\0\\0" | uint16 version | uint16 flags | uint32 count | 3 x float64 origin | uint32 epsg
    | uint32 reserved | count x (3 x float32 offset from origin, float16 metric size) | uint32 CRC-32
14 bytes per landmark plus 52 bytes. Ids are implicit by order. The reader validates every field and raises
`InputError` naming the file for anything wrong; it never returns a partial or wrong map.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from .atomic import write_bytes_atomic

MAGIC = b"SOSMAP\0\0"
VERSION = 1
FLAG_SIZES = 1
_HEADER = struct.Struct("<8sHHI3dII")
_RECORD = np.dtype([("xyz", "<f4", (3,)), ("size", "<f2")])
assert _HEADER.size == 48 and _RECORD.itemsize == 14
BYTES_PER_LANDMARK = _RECORD.itemsize
MAX_OFFSET_M = 1.0e6  # float32 offsets beyond this lose centimetres; the writer refuses them


@dataclass
class LandmarkMap:
    """Landmark positions (world frame, float64) and metric sizes (float32, NaN where unknown)."""

    positions: np.ndarray
    sizes: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    epsg: int = 0  # 0: local frame; otherwise the world frame is this projected CRS

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        self.sizes = np.asarray(self.sizes, dtype=np.float32).reshape(-1)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if len(self.sizes) != len(self.positions):
            raise ValueError(f"{len(self.positions)} positions but {len(self.sizes)} sizes")

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def has_sizes(self) -> bool:
        return bool(len(self.sizes)) and not bool(np.all(np.isnan(self.sizes)))


def encode_landmark_map(lmap: LandmarkMap) -> bytes:
    """Serialise a map. Positions are stored as float32 offsets from `origin` (choose it near the data)."""
    if not np.all(np.isfinite(lmap.positions)) or not np.all(np.isfinite(lmap.origin)):
        raise ValueError("landmark positions and origin must be finite")
    offsets = lmap.positions - lmap.origin
    if len(offsets) and np.abs(offsets).max() > MAX_OFFSET_M:
        raise ValueError("landmarks are too far from the map origin for float32 offsets; choose a closer origin")
    records = np.zeros(len(lmap), dtype=_RECORD)
    records["xyz"] = offsets
    records["size"] = lmap.sizes
    flags = FLAG_SIZES if lmap.has_sizes else 0
    header = _HEADER.pack(MAGIC, VERSION, flags, len(lmap), *lmap.origin, int(lmap.epsg), 0)
    body = header + records.tobytes()
    return body + struct.pack("<I", zlib.crc32(body))


def decode_landmark_map(data: bytes, source: str | Path = "<bytes>") -> LandmarkMap:
    """Parse and validate a serialised map; any defect raises InputError naming `source`."""
    if len(data) < _HEADER.size + 4:
        raise InputError(f"not a landmark map (only {len(data)} bytes)", source)
    magic, version, flags, count, ox, oy, oz, epsg, reserved = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise InputError("not a landmark map (bad magic bytes)", source)
    if version != VERSION:
        raise InputError(f"unsupported landmark map version {version} (this reader knows {VERSION})", source)
    expected = _HEADER.size + count * BYTES_PER_LANDMARK + 4
    if len(data) != expected:
        raise InputError(f"landmark map is {len(data)} bytes, header says {expected} (truncated?)", source)
    (crc,) = struct.unpack_from("<I", data, expected - 4)
    if zlib.crc32(data[: expected - 4]) != crc:
        raise InputError("landmark map checksum mismatch (file is corrupt)", source)
    if flags & ~FLAG_SIZES or reserved != 0:
        raise InputError(f"landmark map has unknown flags {flags:#x}", source)
    origin = np.array([ox, oy, oz])
    records = np.frombuffer(data, dtype=_RECORD, count=count, offset=_HEADER.size)
    if not np.all(np.isfinite(origin)) or not np.all(np.isfinite(records["xyz"])):
        raise InputError("landmark map holds non-finite coordinates", source)
    sizes = records["size"].astype(np.float32)
    if not flags & FLAG_SIZES:
        sizes[:] = np.nan
    elif np.any(sizes[np.isfinite(sizes)] < 0) or np.any(np.isinf(sizes)):
        raise InputError("landmark map holds negative or infinite sizes", source)
    positions = records["xyz"].astype(np.float64) + origin
    return LandmarkMap(positions=positions, sizes=sizes, origin=origin, epsg=int(epsg))


def write_landmark_map(path: str | Path, lmap: LandmarkMap) -> int:
    """Write atomically; returns the number of bytes written."""
    data = encode_landmark_map(lmap)
    write_bytes_atomic(path, data)
    return len(data)


def read_landmark_map(path: str | Path) -> LandmarkMap:
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError("landmark map not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read landmark map: {exc.strerror}", path) from None
    return decode_landmark_map(data, path)
