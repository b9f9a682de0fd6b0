"""Property-based fuzzing of every reader of a user file: `.sosmap`, pose CSV, cameras.txt, match.json, COLMAP
binary models, config TOML.

Every outcome must be the project's own one-line error (InputError) or a valid object that the format's writer
would also write (and that reads back the same), never another exception, a hang (each example has a
deadline), or Python memory beyond a bound proportional to the file size (tracemalloc).
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import tracemalloc
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sosmatch.database.cameras import format_cameras_txt, read_cameras_txt
from sosmatch.database.config_io import dump_params, load_params
from sosmatch.database.landmark_map import LandmarkMap, decode_landmark_map, encode_landmark_map
from sosmatch.database.match_io import parse_match, read_match
from sosmatch.database.poses import format_poses_csv, read_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Poses

# SOSMATCH_FUZZ_EXAMPLES=2000 for a longer hunt (the suite runs 150 per reader)
FUZZ = settings(max_examples=int(os.environ.get("SOSMATCH_FUZZ_EXAMPLES", "150")), deadline=2000,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _bounded(fn, size: int):
    """fn() under tracemalloc: its result (or InputError), checking the peak is proportional to `size`."""
    tracemalloc.start()
    try:
        return fn()
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc)
        return exc
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < 64 * size + 4_000_000, f"{peak} bytes for a {size}-byte file"


def _mutate(data: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    out = bytearray(data)
    for pos, value in edits:
        if out:
            out[pos % len(out)] = value
    return bytes(out[:cut] if cut is not None else out)


def _insert(text: str, inserts: list[tuple[int, str]], token: str) -> str:
    for pos, piece in inserts:
        k = pos % (len(text) + 1)
        text = text[:k] + piece + token + text[k:]
    return text


edits = st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=6)
cuts = st.none() | st.integers(0, 4000)


# --- .sosmap ---------------------------------------------------------------------------------------------------

def _sosmap() -> bytes:
    rng = np.random.default_rng(0)
    pos = rng.uniform(-500, 500, (40, 3)) + [480000.0, 5200000.0, 100.0]
    return encode_landmark_map(LandmarkMap(pos, rng.uniform(0.5, 20, 40), pos.mean(0).round(), 32617))


SOSMAP = _sosmap()


def _refresh_crc(data: bytes) -> bytes:
    """Make the CRC right again, so the checks behind it are reached (checksum-valid corrupt files)."""
    return data[:-4] + struct.pack("<I", zlib.crc32(data[:-4])) if len(data) >= 4 else data


@FUZZ
@given(edits, cuts, st.booleans(), st.binary(max_size=64))
def test_sosmap_reader(edits, cut, fix_crc, header):
    data = _mutate(SOSMAP, edits, cut)
    if header and len(data) > len(header):
        data = header + data[len(header):]  # arbitrary header fields: counts, origin, EPSG, flags
    if fix_crc:
        data = _refresh_crc(data)
    out = _bounded(lambda: decode_landmark_map(data, "fuzz.sosmap"), len(data))
    if isinstance(out, LandmarkMap):
        _writer_writes(out, data)


def _writer_writes(lmap: LandmarkMap, data: bytes) -> None:
    """The writer accepts what the reader returned and writes the same map (bytes equal, except where a float32
    offset below the origin's float64 resolution reads back as a slightly different world position)."""
    again = encode_landmark_map(lmap)
    if again != data:
        back = decode_landmark_map(again)
        scale = 1e-9 * (1.0 + np.abs(lmap.origin).max())
        assert np.allclose(back.positions, lmap.positions, rtol=0, atol=scale)
        assert np.array_equal(back.sizes, lmap.sizes, equal_nan=True) and back.epsg == lmap.epsg


@FUZZ
@given(st.floats(allow_nan=True, allow_infinity=True), st.integers(0, 2**32 - 1), st.floats(width=16))
def test_sosmap_fields_the_writer_refuses_are_refused(origin, epsg, size):
    header = struct.pack("<8sHHI3dII", b"SOSMAP\0\0", 1, 1, 1, origin, 0.0, 0.0, epsg, 0)
    body = header + np.array([(0.0, 0.0, 0.0, size)], dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                                              ("s", "<f2")]).tobytes()
    data = body + struct.pack("<I", zlib.crc32(body))
    out = _bounded(lambda: decode_landmark_map(data, "f.sosmap"), len(data))
    if isinstance(out, LandmarkMap):
        _writer_writes(out, data)


# --- pose CSV ----------------------------------------------------------------------------------------------------

POSES_TEXT = format_poses_csv(Poses([f"frame_{i:05d}.jpg" for i in range(6)], np.tile(np.eye(3), (6, 1, 1)),
                                    np.arange(18, dtype=float).reshape(6, 3)), 0)
csv_noise = st.text(st.characters(codec="utf-8", exclude_categories=["Cs"]), max_size=40)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10**6), csv_noise), max_size=5), st.booleans(),
       st.sampled_from(["", ",yaw_deg,pitch_deg,roll_deg", "1e300", "nan", "x" * 140_000, "-0", "1e-320", '"']))
def test_pose_csv_reader(tmp_path_factory, inserts, ypr, token):
    text = POSES_TEXT
    if ypr:
        text = text.replace("qw,qx,qy,qz", "yaw_deg,pitch_deg,roll_deg").replace(",1.0,0.0,0.0,0.0", ",0,-90,0")
    text = _insert(text, inserts, token)
    path = tmp_path_factory.mktemp("p") / "poses.csv"
    path.write_text(text, encoding="utf-8")
    out = _bounded(lambda: read_poses_csv(path), len(text.encode()))
    if not isinstance(out, InputError):
        poses, epsg = out
        again = tmp_path_factory.mktemp("q") / "poses.csv"
        again.write_text(format_poses_csv(poses, epsg), encoding="utf-8")  # the writer accepts it ...
        back, epsg2 = read_poses_csv(again)  # ... and it reads back the same
        assert back.names == poses.names and epsg2 == epsg
        assert np.allclose(back.centers, poses.centers, rtol=0, atol=1e-9 * (1 + np.abs(poses.centers)))


# --- cameras.txt ---------------------------------------------------------------------------------------------------

CAMERAS_TEXT = "1 PINHOLE 640 480 500 500 320 240\n2 OPENCV 4000 3000 2900 2900 2000 1500 -0.1 0.01 0.001 0\n"


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10**6), csv_noise), max_size=5),
       st.sampled_from(["", " 1e300", " nan", "9" * 5000, " -1", " SIMPLE_RADIAL", " EQUIRECTANGULAR", "\n"]))
def test_cameras_reader(tmp_path_factory, inserts, token):
    text = _insert(CAMERAS_TEXT, inserts, token)
    path = tmp_path_factory.mktemp("c") / "cameras.txt"
    path.write_text(text, encoding="utf-8")
    out = _bounded(lambda: read_cameras_txt(path), len(text.encode()))
    if not isinstance(out, InputError):
        again = path.with_name("again.txt")
        again.write_text(format_cameras_txt(out), encoding="utf-8")
        assert read_cameras_txt(again) == out


# --- match.json ----------------------------------------------------------------------------------------------------

TRANSFORM = {"rotation": np.eye(3).tolist(), "translation": [1.0, 2.0, 0.0], "scale": 1.0}
MATCH_DOC = {
    "format": "sosmatch match v1",
    "map_a": {"path": "a", "landmarks": 20, "fingerprint": "sha256:aa"},
    "map_b": {"path": "b", "landmarks": 20, "fingerprint": "sha256:bb"},
    "params": {"association": {"min_associations": 6}},
    "transform_kind": "rigid", "best": 0,
    "consensus": {"transform": TRANSFORM, "associations": [[0, 1], [2, 3], [4, 5]]},
    "hypotheses": [{"associations": [[0, 1], [2, 3], [4, 5]], "transform": TRANSFORM, "accepted": True,
                    "tilt_deg": 0.5, "roll_deg": 0.1, "pitch_deg": 0.2}],
    "search_seconds": 0.5,
}
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12)


def _paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


PATHS = list(_paths(MATCH_DOC))[1:]


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(PATHS), json_values), min_size=1, max_size=4))
def test_match_json_values(tmp_path_factory, replacements):
    doc = json.loads(json.dumps(MATCH_DOC))
    for path, value in replacements:
        node = doc
        try:
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue
    text = json.dumps(doc)  # NaN / Infinity tokens as Python writes them
    file = tmp_path_factory.mktemp("m") / "match.json"
    file.write_text(text, encoding="utf-8")
    out = _bounded(lambda: read_match(file), len(text))
    if not isinstance(out, InputError):
        assert out.associations.dtype == np.int64 and np.all(out.associations >= 0)
        assert out.transform is None or np.isfinite(out.transform.matrix()).all()


@FUZZ
@given(edits, cuts, st.sampled_from(["", "[" * 100_000, "1" * 5000, "Infinity", '{"a":' * 3000]))
def test_match_json_text(tmp_path_factory, edits, cut, token):
    raw = _mutate(json.dumps(MATCH_DOC).encode(), edits, cut)
    raw = raw[: len(raw) // 2] + token.encode() + raw[len(raw) // 2:]
    file = tmp_path_factory.mktemp("t") / "match.json"
    file.write_bytes(raw)
    _bounded(lambda: read_match(file), len(raw))


def test_match_writer_output_is_accepted():
    assert parse_match(MATCH_DOC).accepted


# --- COLMAP binary models ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def model(tmp_path_factory):
    from sosmatch.plugin.multisession import Sim3
    from sosmatch.tools.toy_sessions import lawnmower, make_world, write_toy_session

    root = tmp_path_factory.mktemp("model")
    s = write_toy_session(root / "S", make_world(40, 120, seed=4), lawnmower(20, 60, 20, 60, 50, 40, 20),
                          Sim3.identity(), seed=1)
    return s.path / "sparse"


@FUZZ
@given(st.sampled_from(["cameras.bin", "images.bin", "points3D.bin", "rigs.bin", "frames.bin"]), edits, cuts)
def test_colmap_binary_model(tmp_path_factory, model, name, edits, cut):
    from sosmatch.database.colmap_model import load_reconstruction

    d = tmp_path_factory.mktemp("sp") / "sparse"
    shutil.copytree(model, d)
    data = _mutate((d / name).read_bytes(), edits, cut)
    (d / name).write_bytes(data)
    size = sum(p.stat().st_size for p in d.iterdir())
    _bounded(lambda: load_reconstruction(d), size)  # pycolmap runs only on files the walk accepted


# --- config TOML ---------------------------------------------------------------------------------------------------

toml_scalars = (st.integers(-(2**63), 2**63 - 1) | st.floats(allow_nan=True) | st.booleans() | st.text(max_size=10))
SECTIONS = {"keyframes": ["interval_m"], "tracking": ["epipolar_margin_px", "min_score", "max_track_age_keyframes"],
            "triangulation": ["min_observations", "pixel_sigma_px"],
            "association": ["affinity_sigma_m", "transform", "window_length", "min_associations"],
            "segmentation": ["backend", "classical_median_ksize"], "bogus": ["x"]}


@FUZZ
@given(st.dictionaries(st.sampled_from(sorted(SECTIONS)), st.dictionaries(
    st.sampled_from(sorted({k for v in SECTIONS.values() for k in v})), toml_scalars, max_size=3), max_size=3),
    st.text(max_size=30))
def test_config_toml(tmp_path_factory, tables, junk):
    import tomli_w

    try:
        text = tomli_w.dumps(tables)
    except (TypeError, ValueError):
        return
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    for content in (text, text + junk):
        path.write_text(content, encoding="utf-8")
        out = _bounded(lambda: load_params(path), len(content.encode()))
        if not isinstance(out, InputError):
            path.write_text(dump_params(out), encoding="utf-8")
            assert load_params(path) == out
