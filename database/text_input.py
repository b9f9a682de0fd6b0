"""Reading a user's file: one place that turns a missing, unreadable or implausibly large file into a one-line
InputError, and that reads no more than a bound, whatever the path is.

Every whole-file input (pose and telemetry tables, cameras files, match.json, run.json, config TOML, landmark
maps) is read here, every JSON document through `read_user_json`. A file is read with a cap instead of after a
`stat`, because the size of what a path names is not always known in advance: `--match /dev/zero` (or a pipe
that never ends) filled memory until Python raised MemoryError with a traceback. The caps are far above what the
format holds for any real survey (a pose table of a million frames is about 100 MB), so they only ever stop a
wrong path.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..plugin.errors import InputError

MIB = 1 << 20
# The largest text input read whole: a pose or telemetry table of a million rows is ~100 MB, a match.json of two
# whole-season maps a few MB. Parsing holds a few times the text, so memory stays within a few GB.
TEXT_LIMIT_BYTES = 256 * MIB
# The longest line of a text file read line by line (a COLMAP images.txt POINTS2D line of 100 k observations is
# ~4 MB).
LINE_LIMIT_BYTES = 64 * MIB
# The largest NumPy archive read (terrain.npz: a synthetic world's height raster is ~64 MB; a user's DEM a few
# hundred MB at most).
NPZ_LIMIT_BYTES = 1024 * MIB


def _size_words(limit_bytes: int) -> str:
    return f"{limit_bytes / MIB:.0f} MiB" if limit_bytes >= MIB else f"{limit_bytes} bytes"


def _read_capped(handle: IO[bytes], limit_bytes: int, chunk_bytes: int = MIB) -> bytes:
    """At most limit_bytes + 1 bytes of a stream, in chunks (one `read(n)` allocates n bytes at once)."""
    out = bytearray()
    while len(out) <= limit_bytes:
        chunk = handle.read(min(chunk_bytes, limit_bytes + 1 - len(out)))
        if not chunk:
            break
        out += chunk
    return bytes(out)


FIFO_WAIT_S = 30.0  # how long a named pipe given as an input may take to get a writer


def open_without_waiting(path: str | Path) -> IO[bytes]:
    """`open(path, "rb")` that does not wait forever for a writer: a named pipe (FIFO) gets FIFO_WAIT_S for one
    to connect (a plain `open` blocked until one did: forever, for a pipe given by mistake), then it is read as
    `open` reads it, however slowly the writer sends (`slow-command | sosmatch ... --poses /dev/stdin`,
    `<(ssh host cat poses.csv)`). Raises TimeoutError when no writer came. Anything else opens as with `open`.

    The wait is for the writer, not for data (rev30: waiting for the first byte refused a connected writer quiet
    for 30 s). The pipe is read through the non-blocking descriptor opened first, kept open throughout: a writer
    that connects to it, writes and closes before anything else happens leaves its data there (a pipe whose
    every end closed drops it). A writer is known to have come when a blocking open in a thread returns (it does
    once one connects) or the pipe shows data or a hang-up; the thread is then released by opening the FIFO for
    writing from here."""
    import select
    import threading
    import time

    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # never blocks
    try:
        is_fifo = stat.S_ISFIFO(os.fstat(fd).st_mode)
    except BaseException:
        os.close(fd)
        raise
    if not is_fifo:
        os.close(fd)
        return open(path, "rb")
    got: dict[str, Any] = {}

    def wait_for_writer() -> None:
        try:
            got["fd"] = os.open(path, os.O_RDONLY)
        except OSError as exc:
            got["error"] = exc

    waiter = threading.Thread(target=wait_for_writer, daemon=True)
    waiter.start()
    poller = select.poll()
    poller.register(fd, select.POLLIN | select.POLLHUP)
    deadline = time.monotonic() + FIFO_WAIT_S
    came = False
    while not came and time.monotonic() < deadline:
        # Linux shows no event on a FIFO no writer ever opened; POLLIN / POLLHUP once one did
        came = not waiter.is_alive() or bool(poller.poll(50))
    came = came or not waiter.is_alive()
    while waiter.is_alive():
        # be the writer that lets the waiting open return; again until it has (the thread may not have reached its
        # open yet when the first of these came and went)
        with contextlib.suppress(OSError):
            os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        waiter.join(0.05)
    if "fd" in got:
        os.close(got["fd"])
    if not came:
        os.close(fd)
        raise TimeoutError(f"a named pipe nobody opened for writing within {FIFO_WAIT_S:g} s")
    import fcntl

    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return os.fdopen(fd, "rb")


def read_user_bytes(path: str | Path, what: str, limit_bytes: int = TEXT_LIMIT_BYTES) -> bytes:
    """The bytes of `path`, at most `limit_bytes`; raises InputError naming the file when it is missing, a
    folder, unreadable or larger than the limit (read with a cap, so a device or a pipe cannot fill memory).

    `what` is the file's role as a user knows it ("pose file", "match file"), so the one-line error says which
    input is wrong, not just which path.
    """
    path = Path(path)
    try:
        with open_without_waiting(path) as handle:
            info = os.fstat(handle.fileno())
            if stat.S_ISREG(info.st_mode):  # its size is known: a file over the limit is not read at all
                data = b"" if info.st_size > limit_bytes else handle.read()
                too_large = info.st_size > limit_bytes or len(data) > limit_bytes
            else:  # a pipe or a device: its size is unknown, so read in chunks up to the limit
                data = _read_capped(handle, limit_bytes)
                too_large = len(data) > limit_bytes
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except IsADirectoryError:
        raise InputError(f"{what} is a folder, not a file", path) from None
    except TimeoutError as exc:
        raise InputError(f"{what} is {exc}", path) from None
    except OSError as exc:
        raise InputError(f"cannot read {what}: {exc.strerror or exc}", path) from None
    if too_large:
        raise InputError(f"{what} is larger than {_size_words(limit_bytes)}, more than any {what} holds: is it "
                         "the right file?", path)
    return data


def read_user_text(path: str | Path, what: str, limit_bytes: int = TEXT_LIMIT_BYTES) -> str:
    """The UTF-8 text of `path` (`read_user_bytes`' checks and bound); InputError naming the file when it is not
    UTF-8 text. A leading byte order mark is not text: Excel's "CSV UTF-8" and Windows editors write one, and
    it made a valid pose table's header read as '\ufeff# sosmatch poses v1' (refused)."""
    data = read_user_bytes(path, what, limit_bytes)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read {what}: not UTF-8 text (byte {exc.start})", path) from None


# How a one-line error names what a JSON document holds (Python's type of the parsed value).
_JSON_KINDS = {dict: "a JSON object", list: "a JSON array", str: "a string", int: "a number", float: "a number",
               bool: "true or false", type(None): "null"}


def read_user_json(path: str | Path, what: str, expect: type | tuple[type, ...] | None = dict, *, redo: str = "",
                   limit_bytes: int = TEXT_LIMIT_BYTES) -> Any:
    """The parsed JSON document of `path` (`read_user_text`' checks and bound); InputError naming the file when it
    is empty, not JSON (the line, in the error's place, and the column of the first syntax error), nested too
    deeply, or not of the type `expect` (None: any). The format's own validation is the caller's.

    `redo` is what to do about an empty or unparsable file when another command wrote it ("re-run `sosmatch
    match`"): such a file is a truncated copy or an interrupted write."""
    path = Path(path)
    text = read_user_text(path, what, limit_bytes)
    hint = f"; {redo}" if redo else ""
    if not text.strip():
        raise InputError(f"{what} is empty (an interrupted copy?){hint}", path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"cannot read {what}: not valid JSON, truncated or another kind of file ({exc.msg}, "
                         f"column {exc.colno}){hint}", path, exc.lineno) from None
    except RecursionError:
        raise InputError(f"cannot read {what}: nested too deeply", path) from None
    except ValueError as exc:  # integers of more than 4300 digits
        raise InputError(f"cannot read {what}: {str(exc).splitlines()[0]}", path) from None
    if expect is not None and not isinstance(data, expect):
        wanted = " or ".join(_JSON_KINDS.get(t, t.__name__) for t in (expect if isinstance(expect, tuple)
                                                                        else (expect,)))
        raise InputError(f"{what} must hold {wanted}, not {_JSON_KINDS.get(type(data), type(data).__name__)}", path)
    return data


def read_user_npz(path: str | Path, what: str, limit_bytes: int = NPZ_LIMIT_BYTES) -> dict[str, np.ndarray]:
    """Every array of the NumPy archive at `path` (`read_user_bytes`' checks and bound; no pickled objects),
    decompressed here, so that a truncated, empty or foreign file is an InputError naming it: NumPy raises
    EOFError, zipfile.BadZipFile, zlib.error or ValueError for those, at load or at a member's first access."""
    import io
    import zipfile
    import zlib

    data = read_user_bytes(path, what, limit_bytes)
    if not data:
        raise InputError(f"{what} is empty (an interrupted copy?)", path)
    try:
        archive = np.load(io.BytesIO(data), allow_pickle=False)
        if not hasattr(archive, "files"):  # a .npy file: one array without names
            raise InputError(f"{what} is a single array, not a .npz archive of named arrays", path)
        with archive:
            return {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(f"cannot read {what}: not a NumPy .npz archive, or a truncated one ({exc})", path) from None


def bounded_lines(handle: IO[str], path: str | Path, what: str,
                  limit_bytes: int = LINE_LIMIT_BYTES) -> Iterator[tuple[int, str]]:
    """(line number from 1, line without its end) of an open text file, one line in memory at a time; a line
    longer than `limit_bytes` characters is an InputError naming the file and the line (a file without line
    ends would otherwise be read whole as one line)."""
    lineno = 0
    while True:
        try:
            line = handle.readline(limit_bytes + 1)
        except UnicodeDecodeError as exc:
            raise InputError(f"cannot read {what}: not UTF-8 text (byte {exc.start})", Path(path),
                             lineno + 1) from None
        if not line:
            return
        lineno += 1
        if len(line) > limit_bytes:
            raise InputError(f"{what} has a line longer than {_size_words(limit_bytes)}: is it the right file?",
                             Path(path), lineno)
        yield lineno, line.rstrip("\r\n")
