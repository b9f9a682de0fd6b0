"""pycolmap's database on a full disk: its RuntimeError ("No registered database factory succeeded.") became a
traceback and exit 1 (nu56 D2); it is the full disk's error (OSError ENOSPC: the CLI's one line, exit 2) only
when the folder really has no room."""

from __future__ import annotations

import errno
from types import SimpleNamespace

import pytest

from sosmatch.plugin.params import SfmParams
from sosmatch.workflows import sfm

NO_IMAGES = SimpleNamespace(cameras=[], names=[], camera_index=[])


def test_a_colmap_database_on_a_full_disk_is_the_full_disk_error(small_disk):
    with pytest.raises(OSError) as filled, open(small_disk / "filler", "wb") as filler:
        while True:
            filler.write(b"\0" * 4096)
            filler.flush()
    assert filled.value.errno == errno.ENOSPC
    with pytest.raises(OSError) as raised:
        sfm.create_database(small_disk / "database.db", NO_IMAGES, SfmParams())
    assert raised.value.errno == errno.ENOSPC
    assert isinstance(raised.value.__cause__, RuntimeError)  # pycolmap's own error stays in the chain (-v)


def test_a_library_error_with_room_on_the_disk_stays_what_it_is(tmp_path):
    from sosmatch.database.full_disk import full_disk_reported

    @full_disk_reported
    def write(path):
        raise RuntimeError("a bug, not the disk")

    with pytest.raises(RuntimeError, match="a bug"):
        write(tmp_path / "database.db")
