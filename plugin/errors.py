"""The one exception type for problems the user can fix (bad files, bad values, bad paths).

The command line prints such an error as one line and exits with code 2; anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

from pathlib import Path

MAX_PROBLEM_CHARS = 400  # a problem that quotes a user's file is cut here


def one_line(text: str, limit: int = MAX_PROBLEM_CHARS) -> str:
    """`text` on one line: control characters (line breaks from a quoted field, NULs) escaped, at most `limit`
    characters."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return out if len(out) <= limit else out[: limit - 3] + "..."


class InputError(Exception):
    """A user-fixable problem. The message names the file (if any) and the problem in one line (whatever the
    problem quotes from the file is escaped and cut: `one_line`)."""

    def __init__(self, problem: str, path: str | Path | None = None, line: int | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.line = line
        problem = one_line(problem)
        self.problem = problem
        where = ""
        if path is not None:
            where = f"{one_line(str(path), 1000)}:{line}: " if line is not None else f"{one_line(str(path), 1000)}: "
        super().__init__(f"{where}{problem}")
