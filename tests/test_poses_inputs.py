"""What a `poses` output depends on (its identity), how its database is published and what it says, without a
structure from motion run where none is needed."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from sosmatch.plugin.params import Params
from sosmatch.workflows import poses as poses_wf


def _folder(tmp_path: Path) -> Path:
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        Image.fromarray(np.full((8, 8, 3), 40 * k, np.uint8)).save(images / f"f{k}.jpg")
    return images


def test_an_edited_telemetry_changes_the_poses_identity_and_its_place_does_not(tmp_path):
    """rev49 D4: the identity keyed the telemetry's path, so `poses` (and `map --images`, and the stages of an
    interrupted run) gave back the result of the file as it was before an edit. Its content keys it now."""
    images = _folder(tmp_path)
    tele = tmp_path / "tele.csv"
    tele.write_text("FileName,Heading\nf0.jpg,090\n")
    st = tele.stat()
    before = poses_wf.identity_of(images, Params(), tele)
    source = poses_wf.PosesFromImages(images, Params(), telemetry=tele)  # `map --images --telemetry`
    source_before = source.identity()
    tele.write_text("FileName,Heading\nf0.jpg,270\n")  # the same size, and the same time below
    os.utime(tele, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert poses_wf.identity_of(images, Params(), tele) != before
    assert source.identity() != source_before
    moved = tmp_path / "moved.csv"
    moved.write_text("FileName,Heading\nf0.jpg,090\n")
    assert poses_wf.identity_of(images, Params(), moved) == before  # the same content elsewhere: the same input
    assert poses_wf.identity_of(images, Params()) != before
