"""Which sosmatch made an output (`database.code_version`): map's run.json records the package version and a digest
of its sources, and a batch that keeps a session another version made says so, and maps it again with
--overwrite (its pairs too)."""

from __future__ import annotations

import ast
import json
import logging
from pathlib import Path

import pytest

from sosmatch.database.code_version import (
    PACKAGE_DIR,
    PACKAGE_FOLDERS,
    code_versions,
    describe,
    other_version,
    source_digest,
)
from sosmatch.tools.cli import main
from sosmatch.workflows import batch
from sosmatch.workflows.executors import LocalExecutor


def test_the_source_digest_follows_the_code_not_the_tests(tmp_path):
    (tmp_path / "plugin").mkdir()
    (tmp_path / "tests").mkdir()
    (tmp_path / "plugin" / "a.py").write_text("x = 1\n")
    (tmp_path / "tests" / "test_a.py").write_text("y = 1\n")
    first = source_digest(tmp_path)
    assert source_digest.__wrapped__(tmp_path) == first  # deterministic
    (tmp_path / "tests" / "test_a.py").write_text("y = 2\n")
    assert source_digest.__wrapped__(tmp_path) == first
    (tmp_path / "plugin" / "a.py").write_text("x = 2\n")
    assert source_digest.__wrapped__(tmp_path) != first


def _package(root: Path) -> None:
    for folder in PACKAGE_FOLDERS:
        (root / folder / "sub").mkdir(parents=True)
        (root / folder / "__init__.py").write_text("")
        (root / folder / "sub" / "m.py").write_text(f"NAME = {folder!r}\nVALUE = 1\n")
    (root / "tools" / "benchmarks").mkdir()
    (root / "tools" / "benchmarks" / "bench.py").write_text("print(1)\n")


def test_the_source_digest_is_the_same_checked_out_and_installed(tmp_path):
    """The digest hashed every .py below the repository root: a checkout (setup.py, build/, a venv/ inside, a stray
    script) and the installed package of the same code had different digests, as had CRLF and LF checkouts, so a
    batch resumed from the installed layout warned "kept as made by ..." and --overwrite re-mapped everything."""
    installed, checkout = tmp_path / "site" / "sosmatch", tmp_path / "repo"
    _package(installed)
    _package(checkout)
    first = source_digest.__wrapped__(installed)
    (checkout / "setup.py").write_text("from setuptools import setup\nsetup()\n")
    (checkout / "stray.py").write_text("print('a script beside the package')\n")
    (checkout / "build" / "lib" / "sosmatch" / "plugin").mkdir(parents=True)
    (checkout / "build" / "lib" / "sosmatch" / "plugin" / "m.py").write_text("OLD = 1\n")
    (checkout / "venv" / "lib" / "site-packages" / "foo").mkdir(parents=True)
    (checkout / "venv" / "lib" / "site-packages" / "foo" / "__init__.py").write_text("FOO = 1\n")
    (checkout / "tests").mkdir()
    (checkout / "tests" / "test_m.py").write_text("def test(): pass\n")
    for path in (checkout / "plugin").rglob("*.py"):  # a Windows checkout (core.autocrlf)
        path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    (checkout / "tools" / "benchmarks" / "bench.py").write_text("print(2)\n")
    assert source_digest.__wrapped__(checkout) == first
    (checkout / "plugin" / "sub" / "m.py").write_text("NAME = 'plugin'\nVALUE = 2\n")
    assert source_digest.__wrapped__(checkout) != first
    (installed / "__main__.py").write_text("print('run')\n")  # the package's own top-level module counts
    assert source_digest.__wrapped__(installed) != first


def test_the_digested_folders_are_the_installed_ones():
    """PACKAGE_FOLDERS is setup.py's TOP_LEVEL (what an installation holds): a folder added to one only would make
    the checkout's and the installed package's digests differ again."""
    setup = PACKAGE_DIR / "setup.py"
    if not setup.is_file():
        pytest.skip("an installed package: no setup.py beside it")
    tree = ast.parse(setup.read_text())
    top = next(node.value for node in ast.walk(tree) if isinstance(node, ast.Assign)
               and any(isinstance(t, ast.Name) and t.id == "TOP_LEVEL" for t in node.targets))
    assert tuple(ast.literal_eval(top)) == PACKAGE_FOLDERS


def test_other_version_names_the_maker():
    today = code_versions()
    assert other_version({"versions": dict(today)}) is None
    assert other_version({"versions": {**today, "sosmatch_source": "0123456789abcdef"}}) == (
        f"sosmatch {today['sosmatch']} (source 0123456789abcdef)")
    assert "its source was not recorded" in other_version({"versions": {"sosmatch": today["sosmatch"]}})
    assert other_version(None) is None  # no record: nothing to say
    assert describe(today).endswith(f"(source {today['sosmatch_source']})")


def test_a_batch_says_which_sessions_an_earlier_version_made_and_maps_them_again_with_overwrite(tmp_path, caplog):
    """Identities key the settings, not the code: after an upgrade a batch resumed every map an earlier sosmatch made
    without a word, and --overwrite did not map them again (the state matched). Now each such session is named once,
    with both versions and the remedy; with --overwrite it is mapped again, and its pair matched again."""
    for k in (1, 2):
        assert main(["synth", "-q", "--world-seed", "7", "--session-seed", str(k), "--frames", "24", "--width", "320",
                     "--height", "240", "--out", str(tmp_path / "fl" / f"F{k}")]) == 0
    options = batch.BatchOptions(progress=False, merge=False, changes=False, verify=False)

    def run(**changes: object) -> batch.BatchReport:
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            report = batch.run(tmp_path / "fl", tmp_path / "out", executor=LocalExecutor(0),
                               options=batch.BatchOptions(**{**options.__dict__, **changes}))
        assert not report.failures, report.failures
        return report

    run()
    record = tmp_path / "out" / "sessions" / "F1" / "run.json"
    made = json.loads(record.read_text())
    assert made["versions"]["sosmatch_source"] == source_digest()
    # F1 as a map of sosmatch before this record held the source: the same settings, made by other code
    del made["versions"]["sosmatch_source"]
    record.write_text(json.dumps(made))
    marker = json.loads((record.parent / ".sosmatch-output.json").read_text())
    del marker["files"]  # nor did its marker record the files (else the edit above is a change of run.json)
    (record.parent / ".sosmatch-output.json").write_text(json.dumps(marker))
    kept = run()
    said = [r.getMessage() for r in caplog.records if "kept as made by" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("sessions/F1: kept as made by sosmatch"), said
    assert "its source was not recorded" in said[0] and "--overwrite" in said[0]
    assert describe(code_versions()) in said[0]
    assert all(s.get("resumed") for s in kept.sessions) and all(p.get("resumed") for p in kept.pairs)
    again = run(overwrite=True)
    assert {s["name"]: bool(s.get("resumed")) for s in again.sessions} == {"F1": False, "F2": True}
    assert again.pairs and not any(p.get("resumed") for p in again.pairs)  # matched again from the new map
    assert json.loads(record.read_text())["versions"]["sosmatch_source"] == source_digest()
    assert not [r for r in caplog.records if "kept as made by" in r.getMessage()]
    run()
    assert not [r for r in caplog.records if "kept as made by" in r.getMessage()]


def test_a_resumed_map_names_cache_entries_an_earlier_version_made(tmp_path, caplog):
    """The per-keyframe cache key holds the settings, not the code: a map resumed after an upgrade (or kept with
    --keep-cache) reused the earlier code's segmentation without a word. Now it says so once, naming the cache,
    both versions and --overwrite, which computes them again."""
    import numpy as np

    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows import map as map_workflow

    assert main(["synth", "-q", "--frames", "12", "--width", "320", "--height", "240", "--out",
                 str(tmp_path / "s")]) == 0
    inputs = map_workflow.load_inputs(None, tmp_path / "s")
    params = with_overrides(Params(), {"quality.refuse": False, "pose_check.enabled": False})
    out = tmp_path / "m"
    first = map_workflow.run(params, inputs, out, progress=False, keep_cache=True)
    entry = sorted((out / ".partial" / "cache").glob("*.npz"))[1]
    with np.load(entry, allow_pickle=False) as data:  # as an entry of sosmatch before entries recorded their maker
        arrays = {k: data[k] for k in data.files if k != "made_by"}
    np.savez(entry, **arrays)
    with caplog.at_level(logging.WARNING):
        again = map_workflow.run(params, inputs, out, progress=False, keep_cache=True)
    said = [r.getMessage() for r in caplog.records if "resumed from cache entries made by" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{out / '.partial' / 'cache'}: 1 of {first.num_keyframes} ")
    assert "an earlier sosmatch (its version was not recorded)" in said[0] and "--overwrite" in said[0]
    assert again.keyframes_from_cache == first.num_keyframes
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        renewed = map_workflow.run(params, inputs, out, progress=False, keep_cache=True, overwrite=True)
    assert renewed.keyframes_from_cache == first.num_keyframes - 1
    assert not [r for r in caplog.records if "resumed from cache entries" in r.getMessage()]
    with np.load(entry, allow_pickle=False) as data:
        assert json.loads(str(data["made_by"])) == code_versions()
