"""A run stopped from outside ends in one line: Ctrl-C at any moment, start-up included (nu56 D4), a Ctrl-C that
pycolmap's import wrapper turned into "Cannot import the C++ backend" (D3), and SIGTERM after pycolmap loaded,
whose glog handler printed a 30-line stack dump (D5)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from sosmatch.tools.commands import export


def _run_script(body: str, cwd) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(body)], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=300)


@pytest.mark.parametrize("module", ["sosmatch.tools.commands._common", "sosmatch.tools.synth.config"])
def test_ctrl_c_during_start_up_is_the_one_line(module, tmp_path):
    """A real SIGINT while the CLI imports its modules (start-up takes seconds on a loaded machine): before, the
    import of cli.py or the parser's build (which imports every command's module) ran outside the handler and
    printed a traceback."""
    result = _run_script(f"""
        import os, signal, sys
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a background job of a shell inherits it ignored
        def hook(event, args):
            if event == "import" and args[0] == {module!r}:
                os.kill(os.getpid(), signal.SIGINT)
        sys.addaudithook(hook)
        from sosmatch.tools.cli import main
        sys.exit(main(["synth", "--out", "S"]))
    """, tmp_path)
    assert result.returncode == 130, result.stderr
    assert result.stderr == "sosmatch synth: interrupted (re-run the same command to resume)\n"


def test_ctrl_c_turned_into_pycolmap_s_import_error_is_the_interrupt(monkeypatch, tmp_path, capsys):
    """pycolmap's __init__ raises "Cannot import the C++ backend ... pip install pycolmap" from the ImportError its
    core raised while a KeyboardInterrupt was being handled: the chain pycolmap makes, built here as it does."""
    from sosmatch.tools.cli import main

    def run(args):
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt:
                raise ImportError("initialization failed")  # noqa: B904 - as the C++ core does
        except ImportError as exc:
            raise RuntimeError("Cannot import the C++ backend pycolmap._core.") from exc

    monkeypatch.setattr(export, "run", run, raising=False)
    assert main(["export", str(tmp_path / "M"), "--csv", "--out", str(tmp_path / "l.csv")]) == 130
    assert capsys.readouterr().err == "sosmatch export: interrupted (re-run the same command to resume)\n"


def test_a_runtime_error_that_is_no_interrupt_is_not_taken_for_one(monkeypatch, tmp_path):
    from sosmatch.tools.cli import main

    def run(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(export, "run", run, raising=False)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["export", str(tmp_path / "M"), "--csv", "--out", str(tmp_path / "l.csv")])


def test_sigterm_after_pycolmap_loaded_is_one_line_not_glog_s_dump(tmp_path):
    result = _run_script(f"""
        import os, signal, sys, time
        import sosmatch.tools.commands.export as export
        from sosmatch.tools.cli import main
        def run(args):
            import pycolmap  # its core installs glog's SIGTERM handler
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(60)
        export.run = run
        sys.exit(main(["export", {str(tmp_path / "M")!r}, "--csv", "--out", {str(tmp_path / "l.csv")!r}]))
    """, tmp_path)
    assert result.returncode == 128 + signal.SIGTERM, result.stderr
    assert result.stderr == "sosmatch export: terminated (re-run the same command to resume)\n"
