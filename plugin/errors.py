"""The one exception type for problems the user can fix (bad files, bad values, bad paths).

The command line prints such an error as one line and exits with code 2; anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """A user-fixable problem. The message names the file (if any) and the problem in one line."""

    def __init__(self, problem: str, path: str | Path | None = None, line: int | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.line = line
        self.problem = problem
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        super().__init__(f"{where}{problem}")
