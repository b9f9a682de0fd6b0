"""Reading a user's text file: one place that turns a missing or unreadable file into a one-line InputError."""

from __future__ import annotations

from pathlib import Path

from ..plugin.errors import InputError


def read_user_text(path: str | Path, what: str) -> str:
    """The UTF-8 text of `path`; raises InputError("<what> not found" / "cannot read <what>: ...") naming the file.

    `what` is the file's role as a user knows it ("pose file", "telemetry file"), so the one-line error says
    which input is wrong, not just which path.
    """
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {what}: {exc}", path) from None
