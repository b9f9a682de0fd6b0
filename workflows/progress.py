"""Progress of a long stage: a tqdm bar on a terminal, a periodic log line otherwise.

Every workflow that shows progress takes it from `progress_bar`, so the choice is made in one place. A bar needs a
terminal; written to a file (`> log 2>&1`, nohup, a batch system) it is carriage-return noise, and before this
module the map command turned it off there: a 1500-frame map logged two lines and nothing during its 5.6-minute
keyframe stage (new-user sweep 22). Off a terminal the stage now logs where it is every LOG_INTERVAL_S seconds
(a stage shorter than that says nothing) and, if it said anything, when it ends.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

log = logging.getLogger("sosmatch.progress")

# Often enough that a log shows a run is alive and how far it is, rare enough that a long run's log stays short
# (a 6-minute stage: 12 lines).
LOG_INTERVAL_S = 30.0

# The clock the log lines are timed by (tests replace it).
_clock = time.monotonic


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


class LoggedProgress:
    """The tqdm calls the workflows use (update, set_description, close, context manager), as log lines."""

    def __init__(self, total: int | None, desc: str, unit: str, initial: int = 0,
                 interval_s: float = LOG_INTERVAL_S) -> None:
        self.total, self.desc, self.unit, self.n = total, desc, unit, initial
        self._initial = initial
        self._interval = interval_s
        self._start = self._last = _clock()
        self._logged = False
        self._closed = False

    def _where(self) -> str:
        if not self.total:
            return f"{self.n} {self.unit}"
        return f"{self.n}/{self.total} {self.unit} ({100.0 * self.n / self.total:.0f} %)"

    def _maybe_log(self) -> None:
        now = _clock()
        if now - self._last < self._interval:
            return
        self._last = now
        self._logged = True
        elapsed = now - self._start
        text = f"{self.desc}: {self._where()}, {_duration(elapsed)} elapsed"
        done = self.n - self._initial
        if self.total and 0 < done and self.n < self.total:  # the rate of this run (cached items cost nothing)
            text += f", about {_duration(elapsed / done * (self.total - self.n))} left"
        log.info("%s", text)

    def update(self, n: int = 1) -> None:
        """Count `n` more items done; log if LOG_INTERVAL_S passed since the last line."""
        self.n += n
        self._maybe_log()

    def set_description(self, desc: str) -> None:
        """Name the part now running (a stage bar's next stage)."""
        self.desc = desc
        self._maybe_log()

    def close(self) -> None:
        """End the stage: a last line when it logged any (a log that showed 60 % shows it finished)."""
        if self._closed:
            return
        self._closed = True
        if self._logged:
            log.info("%s: %s, done in %s", self.desc, self._where(), _duration(_clock() - self._start))

    def __enter__(self) -> LoggedProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress_bar(total: int | None, desc: str, unit: str, enabled: bool = True, initial: int = 0,
                 leave: bool = False) -> Any:
    """A progress display for a stage of `total` items (tqdm's update / set_description / close interface).

    Args:
        total: number of items (None: unknown).
        desc: the stage's name, shown before the count.
        unit: what an item is ("kf", "task", "frame").
        enabled: False (--no-progress, --quiet): nothing is shown.
        initial: items already done (resumed from a cache).
        leave: keep the bar on the terminal when it closes.

    Returns:
        A tqdm bar when stderr is a terminal, else a LoggedProgress (a log line every LOG_INTERVAL_S seconds);
        a disabled tqdm when not `enabled`.
    """
    from tqdm import tqdm

    if enabled and not _stderr_is_terminal():
        return LoggedProgress(total, desc, unit, initial)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled, leave=leave)


def progress_iter(items: Any, total: int | None, desc: str, unit: str, enabled: bool = True,
                  leave: bool = True) -> Any:
    """Iterate over `items` while showing progress as `progress_bar` does (a generator: the bar closes at the end)."""
    bar = progress_bar(total, desc, unit, enabled, leave=leave)
    try:
        for item in items:
            yield item
            bar.update()
    finally:
        bar.close()


def _stderr_is_terminal() -> bool:
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # replaced by an object without isatty, or closed
        return False
