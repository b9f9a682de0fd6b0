"""A full disk (or a kill) at any step of writing a single output file (export, poses-from-exif, check-poses)
leaves a state the same command's re-run takes as its own (nu56 D1: the file was renamed into place before its
registry entry was written, and the re-run refused it as "not written by sosmatch")."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from sosmatch.database import atomic
from sosmatch.database.output_files import OutputFiles
from sosmatch.plugin.errors import InputError


def _full_disk_at(monkeypatch, folder: Path, step: int) -> None:
    """The disk fills at the `step`-th rename into `folder` (1: the registry's pending record, 2: the output file,
    3: the registry's final record). The fault is the disk's (ENOSPC from the rename), nothing else is faked."""
    calls = {"n": 0}
    real = os.replace

    def replace(src, dst, *args, **kwargs):
        if Path(dst).parent == folder:
            calls["n"] += 1
            if calls["n"] == step:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))
        return real(src, dst, *args, **kwargs)
    monkeypatch.setattr(atomic.os, "replace", replace)


@pytest.mark.parametrize("step", [1, 2, 3])
@pytest.mark.parametrize("earlier", [None, b"old,bytes\n"])
def test_a_full_disk_at_any_step_of_a_file_write_is_resumed_by_the_re_run(tmp_path, monkeypatch, step, earlier):
    out = tmp_path / "l.csv"
    if earlier is not None:  # an earlier export of the same command is replaced
        OutputFiles([out], "export", "old").write(out, earlier)
    with monkeypatch.context() as m:
        _full_disk_at(m, tmp_path, step)
        with pytest.raises((InputError, OSError)):
            OutputFiles([out], "export", "new", overwrite=True).write(out, b"new,bytes\n")
    left = out.read_bytes() if out.exists() else None
    assert left == (earlier if step < 3 else b"new,bytes\n")  # the old file until the rename, then the new
    OutputFiles([out], "export", "new", overwrite=True).write(out, b"new,bytes\n")  # the re-run, with room
    assert out.read_bytes() == b"new,bytes\n"
    # and what the re-run left is an ordinary registry: a later run of the same settings takes the file as its own
    OutputFiles([out], "export", "new").write(out, b"new,bytes\n")
    assert not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


def test_a_file_stopped_before_its_rename_still_belongs_to_its_earlier_run(tmp_path, monkeypatch):
    """The pending record names the new bytes beside the old: the old file, still in place, keeps its identity
    (a run of the old settings needs no --overwrite)."""
    out = tmp_path / "l.csv"
    OutputFiles([out], "export", "old").write(out, b"old\n")
    with monkeypatch.context() as m:
        _full_disk_at(m, tmp_path, 2)
        with pytest.raises((InputError, OSError)):
            OutputFiles([out], "export", "new", overwrite=True).write(out, b"new\n")
    OutputFiles([out], "export", "old").write(out, b"old\n")
    with pytest.raises(InputError, match="overwrite"):
        OutputFiles([out], "export", "new")
    out.write_bytes(b"a user's edit\n")
    with pytest.raises(InputError, match="not written by"):
        OutputFiles([out], "export", "old")
