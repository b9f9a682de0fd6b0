"""The compact landmark map: a documented, versioned, checksummed binary format (`.sosmap`).

Layout (little-endian; see docs/ARCHITECTURE.md):
    magic b"SOSMAP\\0\\0" | uint16 version | uint16 flags | uint32 count | 3 x float64 origin | uint32 epsg
    | uint32 reserved | count x (3 x float32 offset from origin, float16 metric size)
    | [version 2 with flag 2: the map's noise figures, 3 x float64 + uint32 + 4 zero bytes] | uint32 CRC-32
14 bytes per landmark plus 52 bytes (84 with the noise figures). Ids are implicit by order. The noise figures
(`plugin.map_noise.MapNoise`: what the map measured about its own scatter) travel with the file, so a map copied
out of its session is matched with the tolerances derived from them, as its session is; a map without them is
written as version 1, byte for byte as before. Flag 4 (`FLAG_SFM_POSES`, no bytes of its own) says the map's poses
came from sosmatch's structure from motion (`sosmatch poses`, `map --images`): such a block may be domed, scaled by
a few % about its centre, so `match` searches it with a similarity (`workflows.match.transform_choice`); maps of
given poses do not set it and stay byte for byte as before (readers before the flag refuse a map that sets it).
The reader validates every field and raises `InputError` naming the file for anything wrong; it never returns a
partial or wrong map.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from ..plugin.map_noise import MapNoise
from .atomic import write_bytes_atomic
from .text_input import MIB, read_user_bytes

MAGIC = b"SOSMAP\0\0"
VERSION = 2  # the newest this reader knows; 1: no noise figures (written so when a map has none)
VERSIONS = (1, 2)
FLAG_SIZES = 1
FLAG_NOISE = 2  # version 2: the noise block follows the records
FLAG_SFM_POSES = 4  # the map's poses came from structure from motion (no bytes of its own; module doc)
KNOWN_FLAGS = FLAG_SIZES | FLAG_NOISE | FLAG_SFM_POSES
# where a map's poses came from, as run.json's `pose_source` says it: sosmatch's structure from motion (`sosmatch
# poses`, `map --images`), or poses taken as given (a pose file or model, a synth session, EXIF/XMP tags)
POSE_SOURCE_SFM = "structure from motion"
POSE_SOURCE_GIVEN = "given"
_HEADER = struct.Struct("<8sHHI3dII")
_RECORD = np.dtype([("xyz", "<f4", (3,)), ("size", "<f2")])
_NOISE = struct.Struct("<3dI4x")  # ground resolution m, residual m, size log std (NaN: unknown), landmarks
assert _HEADER.size == 48 and _RECORD.itemsize == 14 and _NOISE.size == 32
BYTES_PER_LANDMARK = _RECORD.itemsize
# A map of 76 million landmarks (a whole season's flights hold tens of thousands): the largest file read.
LANDMARK_MAP_LIMIT_BYTES = 1024 * MIB
MAX_OFFSET_M = 1.0e6  # float32 offsets beyond this lose centimetres; the writer refuses them


@dataclass
class LandmarkMap:
    """Landmark positions (world frame, float64) and metric sizes (float32, NaN where unknown)."""

    positions: np.ndarray
    sizes: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    epsg: int = 0  # 0: local frame; otherwise the world frame is this projected CRS
    noise: MapNoise | None = None  # what the map measured about its own scatter (`plugin.map_noise`); None: unknown
    # its poses came from structure from motion (flag 4); False: given poses, or unknown (a map of an older version)
    sfm_poses: bool = False

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
        """Whether any landmark has a known size (sizes NaN: unknown)."""
        return bool(len(self.sizes)) and not bool(np.all(np.isnan(self.sizes)))


MAX_WORLD_COORD_M = 1.0e8  # no world frame on Earth (projected CRS, ECEF, local) has coordinates beyond 100,000 km
MAX_ORIGIN_M = MAX_WORLD_COORD_M
MAX_SIZE_M = 65504.0  # the largest float16: a larger size would be stored as infinity
EPSG_RANGE = (1024, 32767)  # the EPSG dataset's codes (0 = local frame)


def landmark_map_problem(origin: np.ndarray, offsets: np.ndarray, stored_sizes: np.ndarray, epsg: int,
                         flags: int, noise: MapNoise | None = None) -> str | None:
    """What makes a map unwritable / unreadable, or None: the one validation of the format, shared by
    `encode_landmark_map` (which refuses to write it) and `decode_landmark_map` (which refuses to read it).

    `offsets` are positions minus origin, `stored_sizes` the sizes as float16 (as the file holds them), `noise`
    the noise figures it carries."""
    if not np.all(np.isfinite(origin)) or not np.all(np.isfinite(offsets)):
        return "landmark map holds non-finite coordinates"
    if np.abs(origin).max() > MAX_ORIGIN_M:
        return f"landmark map origin is beyond {MAX_ORIGIN_M:g} m (not a coordinate on Earth)"
    if len(offsets) and np.abs(offsets).max() > MAX_OFFSET_M:
        return (f"landmark map holds landmarks more than {MAX_OFFSET_M:g} m from its origin (float32 offsets would "
                "lose centimetres; choose a closer origin)")
    if epsg != 0 and not EPSG_RANGE[0] <= epsg <= EPSG_RANGE[1]:
        lo, hi = EPSG_RANGE
        return f"landmark map has EPSG code {epsg}, not an EPSG code (0 = local frame, else {lo}..{hi})"
    known = stored_sizes[np.isfinite(stored_sizes)]
    if np.any(np.isinf(stored_sizes)) or np.any(known <= 0):
        return f"landmark map holds sizes that are not positive metres up to {MAX_SIZE_M:g} (zero, negative, infinite)"
    if unknown := flags & ~KNOWN_FLAGS:
        # a flag this reader does not know is one a newer sosmatch writes (as flag 4 was to readers before it): said
        # so, not as a damaged file (rev51 D5)
        return (f"landmark map has flags {flags:#x}, of which {unknown:#x} this sosmatch does not know: it was "
                "probably written by a newer sosmatch; update sosmatch to read it")
    if bool(flags & FLAG_SIZES) != bool(len(known)):
        return "landmark map's size flag disagrees with its sizes"
    problem = None if noise is None else noise.problem()
    return None if problem is None else f"landmark map's {problem}"


def check_two_maps(path_a: str | Path, path_b: str | Path, map_a: LandmarkMap, map_b: LandmarkMap,
                   what: str = "compare") -> tuple[str, str]:
    """The two maps' fingerprints (`landmark_map_fingerprint`); InputError (naming `path_b`) when B is A, by path
    or by content: comparing a map with itself or with a copy of it answers nothing (`match` would report the
    identity as a success)."""
    from ..plugin.errors import InputError

    if Path(path_a).resolve() == Path(path_b).resolve():
        raise InputError(f"A and B are the same session: nothing to {what} (give the sessions of two flights)",
                         path_b)
    prints = landmark_map_fingerprint(map_a), landmark_map_fingerprint(map_b)
    if prints[0] == prints[1]:
        raise InputError(f"holds the same landmark map as {path_a} (a copy of one session?): nothing to {what}",
                         path_b)
    return prints


# two maps whose landmarks' centres lie closer than this on the ground are of one site, whatever their EPSG codes
ONE_SITE_KM = 50.0


def crs_disagreement(map_a: LandmarkMap, map_b: LandmarkMap) -> str | None:
    """What to say when two maps are georeferenced in different EPSG codes, or None. Their coordinates are then
    unrelated numbers to the search (it needs none). Where each code puts its map on the ground tells the two
    causes apart: far apart, one label is wrong (a UTM zone or hemisphere; the thirteenth sweep: EPSG:32632 against
    32732, matched and merged silently with a near-identity transform); within ONE_SITE_KM, both can be right (a
    site on the boundary of two UTM zones, whose flights took the zone of their first image: told "one label is
    wrong" before)."""
    if not (map_a.epsg and map_b.epsg) or map_a.epsg == map_b.epsg:
        return None
    apart = _ground_distance_km(map_a, map_b)
    head = f"A is georeferenced in EPSG:{map_a.epsg}{_crs_name(map_a.epsg)}, B in EPSG:{map_b.epsg}" \
           f"{_crs_name(map_b.epsg)}"
    if apart is not None and apart <= ONE_SITE_KM:
        return (f"{head}, {apart:.1f} km apart on the ground: one site in two projections"
                f"{_why_two_projections(map_a.epsg, map_b.epsg)}; they are searched as maps in unrelated frames, so "
                "the answer holds the change of "
                "projection and no search near the georeference runs; map both in one CRS to match them in one "
                f"frame (`sosmatch map`, `batch` or `poses-from-exif` with `--epsg {map_a.epsg}`)")
    where = f", {apart:,.0f} km apart on the ground" if apart is not None else ""
    return (f"{head}{where}: they are searched as maps in unrelated frames and B's georeference is not carried "
            "over; if both are surveys of one site, one label is wrong")


def _crs_name(epsg: int) -> str:
    """" (WGS 84 / UTM zone 32N)": the CRS's name for a message, "" when pyproj does not know the code."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return f" ({CRS.from_epsg(epsg).name})"
    except CRSError:
        return ""


def _why_two_projections(epsg_a: int, epsg_b: int) -> str:
    """The likely cause of one site in two CRSs, by what they are: two UTM zones of one hemisphere are a site on
    their boundary whose flights took the zone of their first image; any other pair (a national grid and UTM,
    nu34: EPSG:2056 against 32632, told "the two UTM zones of a zone boundary?") were chosen so."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        zones = [CRS.from_epsg(e).utm_zone for e in (epsg_a, epsg_b)]
    except CRSError:
        return ""
    if all(zones) and zones[0] == zones[1]:  # rev23: WGS 84 / UTM 32N against ETRS89 / UTM 32N
        return f" (UTM zone {zones[0]} in two datums)"
    if all(zones) and zones[0][-1] == zones[1][-1]:
        return f" (UTM zones {zones[0]} and {zones[1]}: a site on a zone boundary?)"
    return " (maps made in different CRSs)"


def _ground_distance_km(map_a: LandmarkMap, map_b: LandmarkMap) -> float | None:
    """The geodesic distance between the centres of two georeferenced maps' landmarks, each placed by its own
    EPSG code (None: a code or a position pyproj cannot place)."""
    from pyproj import CRS, Geod, Transformer
    from pyproj.exceptions import CRSError, ProjError

    lonlat = []
    try:
        for lmap in (map_a, map_b):
            centre = np.median(np.asarray(lmap.positions, np.float64).reshape(-1, 3)[:, :2], axis=0)
            to_geo = Transformer.from_crs(CRS.from_epsg(int(lmap.epsg)), CRS.from_epsg(4326), always_xy=True)
            lonlat.append(to_geo.transform(float(centre[0]), float(centre[1]), errcheck=True))
        _, _, metres = Geod(ellps="WGS84").inv(*lonlat[0], *lonlat[1])
    except (CRSError, ProjError, ValueError):
        return None
    return float(metres) / 1000.0 if np.isfinite(metres) else None


def georeference_offset_m(map_a: LandmarkMap, map_b: LandmarkMap, transform: object,
                          associations: np.ndarray) -> float | None:
    """How far an alignment a_from_b (`transform`, anything with `apply`) puts B's paired landmarks from where B's
    own georeference puts them, horizontally, at the median over `associations` (K, 2): the figure `match` records
    as `search_mode.georeference_off_m` and `plugin.match_answer.georeference_disagreement` judges. Maps in one
    EPSG: the move in grid metres (`chance.median_horizontal_move`, as `match_answer` computes it). Maps in two
    codes (`crs_disagreement`): each place on the ground by its own code, the geodesic distance, so a wrong label
    (the Swiss flight tagged in Fiji: 16,684 km) is measured while one site in two UTM zones, whose answer holds
    only the change of projection, is not (centimetres). None: a map without a georeference, no pairs, or a
    position pyproj cannot place."""
    from ..plugin.chance import median_horizontal_move

    pairs = np.asarray(associations, np.int64).reshape(-1, 2)
    if not (map_a.epsg and map_b.epsg) or not len(pairs):
        return None
    paired_b = np.asarray(map_b.positions, np.float64)[pairs[:, 1]]
    if map_a.epsg == map_b.epsg:
        return median_horizontal_move(transform, paired_b)
    from pyproj import CRS, Geod, Transformer
    from pyproj.exceptions import CRSError, ProjError

    placed = transform.apply(paired_b)  # type: ignore[attr-defined]  # in A's grid
    try:
        lonlat = []
        for epsg, xy in ((map_a.epsg, placed), (map_b.epsg, paired_b)):
            to_geo = Transformer.from_crs(CRS.from_epsg(int(epsg)), CRS.from_epsg(4326), always_xy=True)
            lonlat.append(to_geo.transform(xy[:, 0], xy[:, 1], errcheck=True))
        _, _, metres = Geod(ellps="WGS84").inv(*lonlat[0], *lonlat[1])
    except (CRSError, ProjError, ValueError):
        return None
    metres = np.asarray(metres, np.float64)
    return float(np.median(metres)) if np.all(np.isfinite(metres)) else None


def landmark_map_fingerprint(lmap: LandmarkMap) -> str:
    """A content fingerprint of a map: sha256 of its world positions, sizes and EPSG code ("sha256:...").

    Two maps with this fingerprint have the same landmarks in the same order, whatever file they came from;
    match.json names its maps by it, so a consumer can check that a match is about its maps."""
    import hashlib

    sizes = np.where(np.isnan(lmap.sizes), np.float32(np.nan), lmap.sizes).astype("<f4")  # one NaN pattern
    h = hashlib.sha256(b"sosmatch landmarks v1\0")
    h.update(struct.pack("<QI", len(lmap), int(lmap.epsg) & 0xFFFFFFFF))
    h.update(np.ascontiguousarray(lmap.positions, dtype="<f8").tobytes())
    h.update(sizes.tobytes())
    return "sha256:" + h.hexdigest()


def encode_landmark_map(lmap: LandmarkMap) -> bytes:
    """Serialise a map. Positions are stored as float32 offsets from `origin` (choose it near the data).

    Raises ValueError for a map the format cannot hold (`landmark_map_problem`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        offsets = lmap.positions - lmap.origin
        records = np.zeros(len(lmap), dtype=_RECORD)
        records["xyz"] = offsets
        records["size"] = lmap.sizes
    flags = ((FLAG_SIZES if lmap.has_sizes else 0) | (FLAG_NOISE if lmap.noise is not None else 0)
             | (FLAG_SFM_POSES if lmap.sfm_poses else 0))
    problem = landmark_map_problem(lmap.origin, offsets, records["size"].astype(np.float32), int(lmap.epsg), flags,
                                   lmap.noise)
    if problem is None and not np.all(np.isfinite(records["xyz"])):
        problem = "landmark map holds non-finite coordinates"
    if problem is not None:
        raise ValueError(problem)
    header = _HEADER.pack(MAGIC, VERSION if lmap.noise is not None else 1, flags, len(lmap), *lmap.origin,
                          int(lmap.epsg), 0)
    body = header + records.tobytes()
    if lmap.noise is not None:
        n = lmap.noise
        body += _NOISE.pack(n.ground_resolution_m, n.residual_m, n.size_log_std, n.landmarks)
    return body + struct.pack("<I", zlib.crc32(body))


def decode_landmark_map(data: bytes, source: str | Path = "<bytes>") -> LandmarkMap:
    """Parse and validate a serialised map; any defect raises InputError naming `source`."""
    if len(data) < _HEADER.size + 4:
        raise InputError(f"not a landmark map (only {len(data)} bytes)", source)
    magic, version, flags, count, ox, oy, oz, epsg, reserved = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise InputError("not a landmark map (bad magic bytes)", source)
    if version not in VERSIONS:
        newer = "; probably written by a newer sosmatch: update sosmatch to read it" if version > VERSION else ""
        raise InputError(f"unsupported landmark map version {version} (this reader knows "
                         f"{', '.join(map(str, VERSIONS))}){newer}", source)
    if flags & FLAG_NOISE and version < 2:
        raise InputError(f"landmark map has unknown flags {flags:#x} for version {version}", source)
    if version == 2 and not flags & FLAG_NOISE:
        raise InputError("landmark map of version 2 without its noise figures (flag 2)", source)
    expected = _HEADER.size + count * BYTES_PER_LANDMARK + (_NOISE.size if flags & FLAG_NOISE else 0) + 4
    if len(data) != expected:
        raise InputError(f"landmark map is {len(data)} bytes, header says {expected} (truncated?)", source)
    (crc,) = struct.unpack_from("<I", data, expected - 4)
    if zlib.crc32(data[: expected - 4]) != crc:
        raise InputError("landmark map checksum mismatch (file is corrupt)", source)
    if reserved != 0:
        raise InputError(f"landmark map has a non-zero reserved field ({reserved:#x})", source)
    origin = np.array([ox, oy, oz])
    records = np.frombuffer(data, dtype=_RECORD, count=count, offset=_HEADER.size)
    offsets = records["xyz"].astype(np.float64)
    sizes = records["size"].astype(np.float32)
    noise = None
    if flags & FLAG_NOISE:
        *figures, landmarks = _NOISE.unpack_from(data, _HEADER.size + count * BYTES_PER_LANDMARK)
        noise = MapNoise(*figures, landmarks)
        if data[expected - 8:expected - 4] != bytes(4):
            raise InputError("landmark map's noise block has non-zero padding", source)
    problem = landmark_map_problem(origin, offsets, sizes, int(epsg), flags, noise)
    if problem is not None:
        raise InputError(problem, source)
    if not flags & FLAG_SIZES:
        sizes[:] = np.nan
    return LandmarkMap(positions=offsets + origin, sizes=sizes, origin=origin, epsg=int(epsg), noise=noise,
                       sfm_poses=bool(flags & FLAG_SFM_POSES))


def write_landmark_map(path: str | Path, lmap: LandmarkMap) -> int:
    """Write atomically; returns the number of bytes written."""
    data = encode_landmark_map(lmap)
    write_bytes_atomic(path, data)
    return len(data)


def read_landmark_map(path: str | Path) -> LandmarkMap:
    """Read and validate a .sosmap file (version 1 or 2, see docs/ARCHITECTURE.md "Landmark map format"): world
    positions (origin + float32 offsets), sizes (NaN where the map has none), EPSG code and, in version 2, the
    map's noise figures, and whether its poses came from structure from motion (flag 4).
    A missing, unreadable, oversized (> 1 GiB) or malformed file raises InputError naming `path`. A mapped
    session's folder or a COLMAP model: `database.map_loading.load_map`."""
    return decode_landmark_map(read_user_bytes(path, "landmark map", LANDMARK_MAP_LIMIT_BYTES), path)
