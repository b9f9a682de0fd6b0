"""Progress off a terminal: periodic log lines instead of bars (workflows.progress, every command's one helper)."""

import logging
import operator

import pytest

from sosmatch.workflows import progress
from sosmatch.workflows.executors import LocalExecutor


@pytest.fixture
def fast_clock(monkeypatch):
    """Every reading of the progress clock is 31 s after the last: each update is a log line's worth."""
    ticks = iter(range(0, 10**6, 31))
    monkeypatch.setattr(progress, "_clock", lambda: float(next(ticks)))


def _lines(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "sosmatch.progress"]


def test_off_a_terminal_a_long_stage_logs_where_it_is_and_that_it_ended(fast_clock, caplog):
    with caplog.at_level(logging.INFO, logger="sosmatch.progress"):
        with progress.progress_bar(4, "keyframes", "kf", initial=1) as bar:  # pytest's stderr is no terminal
            assert isinstance(bar, progress.LoggedProgress)
            bar.update()
            bar.update(2)
    lines = _lines(caplog)
    assert lines[0].startswith("keyframes: 2/4 kf (50 %), 31 s elapsed, about 1 min 02 s left"), lines
    assert lines[-1].startswith("keyframes: 4/4 kf (100 %), done in"), lines


def test_a_short_stage_and_disabled_progress_say_nothing(caplog):
    with caplog.at_level(logging.INFO, logger="sosmatch.progress"):
        with progress.progress_bar(3, "stage", "x") as bar:  # well under 30 s
            bar.update(3)
        with progress.progress_bar(3, "stage", "x", enabled=False) as bar:
            bar.update(3)
        assert list(progress.progress_iter(range(3), 3, "it", "x")) == [0, 1, 2]
    assert _lines(caplog) == []


def test_executor_tasks_log_their_progress_off_a_terminal(fast_clock, caplog):
    """A batch logged to a file showed tqdm's carriage-return bars in it, or nothing with them off."""
    with caplog.at_level(logging.INFO, logger="sosmatch.progress"):
        results = LocalExecutor(0).run(operator.mul, {k: (k, 2) for k in range(3)}, desc="maps", progress=True)
    assert [r.value for r in results.values()] == [0, 2, 4]
    assert any(line.startswith("maps: 1/3 task") for line in _lines(caplog)), _lines(caplog)
