"""Memory stays bounded on any file: a user's input is read with a cap, whatever the path names (a device, a pipe,
a huge file), and an image is refused by its declared size before it is decoded; real survey frames (100 MP and
more) are read."""

from __future__ import annotations

import io
import os
import struct
import threading
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.images import MAX_IMAGE_PIXELS, read_gray, read_image
from sosmatch.database.landmark_map import read_landmark_map
from sosmatch.database.match_io import read_match_json
from sosmatch.database.text_input import TEXT_LIMIT_BYTES, bounded_lines, read_user_bytes, read_user_text
from sosmatch.plugin.errors import InputError


def test_a_file_over_the_limit_is_refused_without_being_read(tmp_path: Path) -> None:
    big = tmp_path / "match.json"
    with open(big, "wb") as f:  # sparse: no disk used, but a stat size over the limit
        f.truncate(TEXT_LIMIT_BYTES + 1)
    tracemalloc.start()
    with pytest.raises(InputError, match=r"match\.json: match file is larger than 256 MiB"):
        read_match_json(big)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 4_000_000


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_an_endless_device_is_read_up_to_the_limit_only() -> None:
    tracemalloc.start()
    with pytest.raises(InputError, match=r"/dev/zero: pose file is larger than 3 MiB"):
        read_user_bytes("/dev/zero", "pose file", limit_bytes=3 << 20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 16 << 20


def test_a_pipe_is_read_whole_when_it_ends_within_the_limit(tmp_path: Path) -> None:
    fifo = tmp_path / "poses.fifo"
    os.mkfifo(fifo)
    payload = b"name,x,y,z\n" * 1000

    def feed() -> None:
        with open(fifo, "wb") as f:
            f.write(payload)

    writer = threading.Thread(target=feed)
    writer.start()
    try:
        assert read_user_text(fifo, "pose file") == payload.decode()
    finally:
        writer.join()


def test_a_folder_and_a_missing_file_name_their_role(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="match file is a folder, not a file"):
        read_user_text(tmp_path, "match file")
    with pytest.raises(InputError, match="landmark map not found"):
        read_landmark_map(tmp_path / "nothing.sosmap")


def test_a_line_without_an_end_is_not_read_whole() -> None:
    text = "# images.txt\n1 1 0 0 0 0 0 0 1 a.jpg\n" + "9" * 5000
    lines = bounded_lines(io.StringIO(text), "images.txt", "images file", limit_bytes=1000)
    assert next(lines) == (1, "# images.txt")
    assert next(lines) == (2, "1 1 0 0 0 0 0 0 1 a.jpg")
    with pytest.raises(InputError, match=r"images\.txt:3: images file has a line longer than 1000 bytes"):
        next(lines)


def test_a_survey_frame_of_more_than_89_megapixels_is_read(tmp_path: Path) -> None:
    """PIL's default bomb guard (89 MP, a warning taken as an error) called a 102 MP survey frame corrupt."""
    import cv2

    h, w = 9000, 10000  # 90 MP
    gray = np.zeros((h, w), np.uint8)
    gray[::97] = 200
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), gray)
    assert read_gray(path).shape == (h, w)
    rgb = read_image(path)
    assert rgb.shape == (h, w, 3) and rgb[97, 5, 0] == 200


def _png_declaring(width: int, height: int) -> bytes:
    """A valid 1x1 PNG whose header is rewritten to declare width x height (its pixels never decode)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0\0")) + chunk(b"IEND", b"")


@pytest.mark.parametrize("side", [30_000, 60_000])  # 900 MP (PIL warns) and 3.6 GP (PIL raises)
def test_an_image_declaring_more_pixels_than_the_limit_is_refused_before_decoding(tmp_path: Path,
                                                                                   side: int) -> None:
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_declaring(side, side))
    assert side * side > MAX_IMAGE_PIXELS
    for reader in (read_image, read_gray):
        tracemalloc.start()
        with pytest.raises(InputError, match=r"bomb\.png: image .*megapixels"):
            reader(path)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < 16 << 20


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
def test_a_named_pipe_nobody_writes_to_is_refused_not_waited_on_forever(tmp_path: Path, monkeypatch) -> None:
    """A FIFO given by mistake blocked `open()` until a writer came (forever; nu45): it is now given
    FIFO_WAIT_S for one, and a writer that starts a moment after the reader, or that connects at once and sends
    its first byte only after FIFO_WAIT_S, is still read to its end."""
    import time

    import sosmatch.database.text_input as text_input

    monkeypatch.setattr(text_input, "FIFO_WAIT_S", 0.5)
    pipe = tmp_path / "poses.csv"
    os.mkfifo(pipe)
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"poses\.csv: pose file is a named pipe nobody opened for writing within "
                                          r"0\.5 s"):
        read_user_bytes(pipe, "pose file")
    assert time.monotonic() - t0 < 5.0

    def writer() -> None:
        time.sleep(0.1)
        with open(pipe, "wb") as handle:
            for _ in range(3):
                handle.write(b"name,x,y,z\n")
                handle.flush()
                time.sleep(0.05)

    thread = threading.Thread(target=writer)
    thread.start()
    assert read_user_bytes(pipe, "pose file") == b"name,x,y,z\n" * 3
    thread.join()

    def quiet_writer() -> None:  # connected at once, its first byte long after the wait (rev30: was refused)
        with open(pipe, "wb") as handle:
            time.sleep(1.0)
            handle.write(b"name,x,y,z\n")

    thread = threading.Thread(target=quiet_writer)
    thread.start()
    assert read_user_bytes(pipe, "pose file") == b"name,x,y,z\n"
    thread.join()

    # a writer let in by the reader's first (non-blocking) open that writes and closes at once: its data stays in
    # the pipe for the reader (closing that open first dropped it: the pipe waited 30 s for another writer)
    for k in range(20):
        quick = tmp_path / f"quick{k}.csv"
        os.mkfifo(quick)
        thread = threading.Thread(target=lambda q=quick: q.write_bytes(b"name,x,y,z\n" * 100))
        thread.start()
        assert read_user_bytes(quick, "pose file") == b"name,x,y,z\n" * 100
        thread.join()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
def test_images_txt_read_line_by_line_does_not_wait_forever_on_a_pipe(tmp_path: Path, monkeypatch) -> None:
    """images.txt (read line by line), a binary model's files (memory-mapped) and a COLMAP database are not read
    through `read_user_bytes`: their opens waited on a writer-less FIFO forever; they share
    `open_without_waiting` now."""
    import sosmatch.database.text_input as text_input
    from sosmatch.database.colmap_model import _read_images_txt

    monkeypatch.setattr(text_input, "FIFO_WAIT_S", 0.3)
    pipe = tmp_path / "images.txt"
    os.mkfifo(pipe)
    with pytest.raises(InputError, match=r"images\.txt: cannot read images file: a named pipe nobody opened"):
        _read_images_txt(pipe)
    # and the other user files opened without `read_user_bytes`: a binary model's files, a COLMAP database
    from sosmatch.database.colmap_binary import _read
    from sosmatch.database.colmap_db import open_colmap_database

    with pytest.raises(InputError, match=r"cannot read COLMAP model file: a named pipe nobody opened"):
        _read(pipe)
    with pytest.raises(InputError, match=r"cannot read COLMAP database: a named pipe nobody opened"):
        open_colmap_database(pipe)
