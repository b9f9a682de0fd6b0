"""The package installs under one namespace and the command line behaves."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import sosmatch.database
import sosmatch.plugin
import sosmatch.tools
import sosmatch.workflows
from sosmatch.tools.cli import build_parser, main

SOSMATCH = str(Path(sys.executable).parent / "sosmatch")


def test_subpackages_live_under_one_namespace(tmp_path):
    # From a neutral directory (not the checkout), only the namespaced names may import.
    code = (
        "import importlib.util, sosmatch.plugin, sosmatch.database, sosmatch.workflows, sosmatch.tools\n"
        "bare = [n for n in ('plugin', 'database', 'workflows', 'tools') if importlib.util.find_spec(n)]\n"
        "assert not bare, bare\n"
    )
    subprocess.run([sys.executable, "-c", code], cwd=tmp_path, check=True)
    assert sosmatch.plugin.__version__
    for mod in (sosmatch.plugin, sosmatch.database, sosmatch.workflows, sosmatch.tools):
        assert mod.__name__.startswith("sosmatch.")


def test_console_script_version_and_help():
    out = subprocess.run([SOSMATCH, "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"sosmatch {sosmatch.plugin.__version__}"
    out = subprocess.run([SOSMATCH, "--help"], capture_output=True, text=True, check=True)
    assert "config" in out.stdout


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    names = [a for a in parser._subparsers._group_actions[0].choices]
    assert "config" in names
    for name in names:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        assert "usage: sosmatch" in capsys.readouterr().out


@pytest.mark.parametrize("name, outputs", [
    ("map", ["database.db", "sparse/", "landmarks.sosmap", "quality.png", "pose_check.json", "run.json"]),
    ("batch", ["sessions/", "pairs/", "merged/", "report.md", "session_graph.png"])])
def test_the_help_of_map_and_batch_says_what_they_write(name, outputs, capsys):
    """nu54 M5: `map --help` said "session directory to write", `batch --help` "output directory", and no more;
    the other commands' help names their files."""
    with pytest.raises(SystemExit):
        main([name, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(item in text for item in outputs), text


def test_user_error_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[tracking]\nno_such_key = 1\n")
    out = subprocess.run(
        [sys.executable, "-m", "sosmatch.tools.cli", "config", "check", "--config", str(bad)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert str(bad) in lines[0] and "no_such_key" in lines[0]
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("argv, help_of", [(["map", "--no-such-flag"], "sosmatch map"), (["match"], "sosmatch match"),
                                           (["nosuchcommand"], "sosmatch"), (["match", "--set"], "sosmatch match"),
                                           (["match", "A", "B", "--out", "M", "--bogus"], "sosmatch match"),
                                           (["--bogus"], "sosmatch")])
def test_a_command_line_mistake_is_one_line_exit_2(argv, help_of, capsys):
    """The line points to the help that lists the flags: the command's (`sosmatch map --help`), not the top-level
    one. Before, an unknown flag after a command (argparse reports those from the top-level parser) said "see
    'sosmatch --help'", which lists only the commands."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert len(err.strip().splitlines()) == 1 and "error:" in err, err
    assert f"(see '{help_of} --help')" in err, err


@pytest.mark.parametrize("user_level, verbose, expected", [(None, 0, 2), (None, 2, 0), ("1", 0, 1)])
def test_colmap_log_is_quiet_for_commands_that_load_pycolmap_later(user_level, verbose, expected):
    # Commands import pycolmap inside `run`, after the CLI set up logging: glog must be told through its environment
    # (on stderr, not a file per run in /tmp), and a user's own GLOG_minloglevel wins.
    code = (
        f"from sosmatch.tools.cli import _setup_logging; _setup_logging({verbose}, False)\n"
        "import pycolmap\n"
        "print(int(pycolmap.logging.minloglevel), bool(pycolmap.logging.logtostderr))\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("GLOG_")}
    if user_level is not None:
        env["GLOG_minloglevel"] = user_level
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.split() == [str(expected), "True"]


def test_no_file_of_the_package_holds_a_merge_conflict_marker():
    """A merge committed its conflict markers inside a module docstring, where neither ruff nor an import sees them
    (rev52 D1): every text file of the package is free of them."""
    import re

    root = Path(sosmatch.plugin.__file__).resolve().parents[1]
    marker = re.compile(r"^(<{7} |>{7} |={7}$)", re.MULTILINE)
    texts = [p for ext in ("py", "md", "toml", "cfg") for p in root.rglob(f"*.{ext}")
             if not {".venv", ".git", "build", "node_modules"} & set(p.relative_to(root).parts)]
    assert len(texts) > 50
    held = [str(p.relative_to(root)) for p in texts if marker.search(p.read_text(encoding="utf-8", errors="replace"))]
    assert not held, held
