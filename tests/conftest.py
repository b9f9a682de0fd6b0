"""Test-wide settings (the synthetic world cache out of the user's home directory) and shared fixtures."""

import logging
import os
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pytest

# Shared by all test workers and runs (entries are keyed by code version and written atomically), so a
# repeated `make test` reuses rendered worlds instead of filling ~/.cache.
os.environ.setdefault("SOSMATCH_CACHE_DIR", str(Path(tempfile.gettempdir()) / "sosmatch-test-cache"))


@pytest.fixture(autouse=True)
def _sosmatch_log_level():
    """Each test starts with the "sosmatch" logger at its library default (NOTSET: the root's level decides). The
    CLI sets it for the whole process (-q: WARNING), so a test that captures INFO records
    (`caplog.at_level(logging.INFO)`) saw them or not by which CLI call ran before it in its worker, a module
    fixture's `synth -q` included (test_image_rigs failed by test order under xdist, s51)."""
    logger = logging.getLogger("sosmatch")
    logger.setLevel(logging.NOTSET)
    yield
    logger.setLevel(logging.NOTSET)


@pytest.fixture(scope="module")
def toy_sessions(tmp_path_factory):
    """Three small mapped toy sessions (A and B overlap in one world, C flies over another world) and A-B's
    match.json: cheap inputs for the multi-session commands (no rendering)."""
    from sosmatch.plugin.multisession import Sim3
    from sosmatch.tools.toy_sessions import lawnmower, make_world, toy_match_json, write_toy_session, yaw_transform

    root = tmp_path_factory.mktemp("toy")
    world = make_world(200, seed=5)
    a = write_toy_session(root / "A", world, lawnmower(20, 120, 20, 120, 60, 40, 10), Sim3.identity(), seed=1)
    b = write_toy_session(root / "B", world, lawnmower(70, 180, 70, 180, 60, 40, 10), yaw_transform(30, (5, 2, 0)),
                          seed=2)
    c = write_toy_session(root / "C", make_world(200, seed=9), lawnmower(20, 120, 20, 120, 60, 40, 10),
                          Sim3.identity(), seed=3)
    return SimpleNamespace(root=root, a=a, b=b, c=c, match=toy_match_json(a, b, root / "AB" / "match.json"))


@pytest.fixture
def cli_error(capsys):
    """cli_error(*argv) runs the command line, asserts the one-line user error (exit 2, no traceback) and returns
    it."""
    from sosmatch.tools.cli import main

    def run(*argv: object) -> str:
        code = main([str(a) for a in argv])
        err = capsys.readouterr().err
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        return err

    return run


@pytest.fixture
def run_moved(capsys, monkeypatch):
    """run_moved(project, moved, argv): runs the command line inside `project`, moves the project to `moved`
    (`shutil.move`, as `mv`) and runs the same command line inside it; both must succeed (a project moved whole is
    the same project: its finished outputs are this run's, not "made from other inputs")."""
    import shutil

    from sosmatch.tools.cli import main

    def run(project: Path, moved: Path, argv: list[str]) -> None:
        monkeypatch.chdir(project)
        assert main(argv) == 0, capsys.readouterr().err
        shutil.move(project, moved)
        monkeypatch.chdir(moved)
        assert main(argv) == 0, capsys.readouterr().err

    return run


@pytest.fixture
def match_doc():
    """match_doc(pairs, min_associations, tolerance_m, verification=None): the smallest match.json (a dict) that
    `match_io.parse_match` reads: one accepted hypothesis and the consensus holding `pairs` at the identity, and
    `verification` (a dict) when given, for the tests of what the notes say of a match."""
    identity = {"rotation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "translation": [0.0, 0.0, 0.0],
                "scale": 1.0}

    def build(pairs: list, min_associations: int, tolerance_m: float, verification: dict | None = None) -> dict:
        doc = {"format": "sosmatch match v1", "map_a": {"path": "a"}, "map_b": {"path": "b"},
               "params": {"association": {"min_associations": min_associations,
                                          "distance_tolerance_m": tolerance_m}},
               "transform_kind": "rigid", "best": 0, "consensus": {"transform": identity, "associations": pairs},
               "hypotheses": [{"associations": pairs, "transform": identity, "accepted": True}]}
        if verification is not None:
            doc["verification"] = {"associations": pairs, **verification}
        return doc

    return build


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs (a disk that fills at once, for full-disk tests; it is the real file system's ENOSPC, nothing
    faked): its folder. Needs root to mount: the test is skipped elsewhere. Unmounted after the test."""
    import subprocess

    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    disk = tmp_path / "small_disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], capture_output=True)
