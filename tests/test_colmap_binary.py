"""Corrupt COLMAP binary models are refused before pycolmap reads them: no allocation driven by a bad count,
no `unordered_map::at`, one line naming the file."""

from __future__ import annotations

import shutil
import struct
import tracemalloc

import numpy as np
import pycolmap
import pytest

from sosmatch.database.colmap_binary import check_binary_model
from sosmatch.database.colmap_model import load_reconstruction
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main


@pytest.fixture
def toy(toy_sessions):
    return toy_sessions.root, toy_sessions.a.path, toy_sessions.b.path, toy_sessions.match


def test_a_valid_model_passes_with_pycolmaps_counts(toy):
    _, a, _, _ = toy
    summary = check_binary_model(a / "sparse")
    rec = pycolmap.Reconstruction(str(a / "sparse"))
    assert (summary.cameras, summary.images, summary.points3D) == (rec.num_cameras(), rec.num_images(),
                                                                    rec.num_points3D())
    assert load_reconstruction(a / "sparse").num_points3D() == rec.num_points3D()


def test_random_points3d_is_refused_without_allocating(toy, tmp_path):
    _, a, _, _ = toy
    model = tmp_path / "sparse"
    shutil.copytree(a / "sparse", model)
    size = (model / "points3D.bin").stat().st_size
    (model / "points3D.bin").write_bytes(np.random.default_rng(0).bytes(size))
    tracemalloc.start()
    with pytest.raises(InputError, match="points3D.bin.*(claims|truncated)"):
        load_reconstruction(model)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 20 * size + 1_000_000


def test_huge_count_in_a_header_is_refused(toy, tmp_path):
    _, a, _, _ = toy
    model = tmp_path / "sparse"
    shutil.copytree(a / "sparse", model)
    data = bytearray((model / "images.bin").read_bytes())
    data[:8] = struct.pack("<Q", 2**62)
    (model / "images.bin").write_bytes(bytes(data))
    with pytest.raises(InputError, match="claims 4611686018427387904 images"):
        check_binary_model(model)


def test_dangling_ids_are_explained(toy, tmp_path):
    _, a, _, _ = toy
    model = tmp_path / "sparse"
    shutil.copytree(a / "sparse", model)
    data = bytearray((model / "images.bin").read_bytes())
    struct.pack_into("<I", data, 8 + 4 + 56, 99)  # the first image's camera id
    (model / "images.bin").write_bytes(bytes(data))
    with pytest.raises(InputError, match="refers to camera 99, which cameras.bin does not hold"):
        load_reconstruction(model)


def test_corrupt_images_bin_in_merge_is_one_line(toy, tmp_path, capsys):
    _, a, b, match = toy
    broken = tmp_path / "A"
    shutil.copytree(a, broken)
    data = bytearray((broken / "sparse" / "images.bin").read_bytes())
    rng = np.random.default_rng(1)
    for i in rng.integers(8, len(data), 50):
        data[i] = int(rng.integers(0, 256))
    (broken / "sparse" / "images.bin").write_bytes(bytes(data))
    assert main(["merge", str(broken), str(b), "--match", str(match), "--out", str(tmp_path / "M")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "sparse" in err and "unordered_map" not in err
    assert not (tmp_path / "M").exists()
