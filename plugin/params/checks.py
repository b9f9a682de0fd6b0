"""Valid values of the parameters: every field declares its range or choices, and a value outside it is
refused however the params are made (a config file, --set, `config check`, direct construction)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError


# ---------------------------------------------------------------------------------------------------------------
# Valid values: every field declares its range or choices (metadata "valid"); `params_from_dict` (and so every
# config file, --set and `config check`) refuses a value outside it. tests/test_params.py fails for a field
# without a declaration, so a field added later must declare one.
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Valid:
    """The values a parameter may take: a closed or open numeric range, odd integers, a set of choices, text."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    odd: bool = False
    choices: tuple[Any, ...] | None = None
    off: float | None = None  # one value outside the range that is also accepted: "off" (e.g. 0)

    def describe(self) -> str:
        if self.off is not None:
            return f"{self.off:g} (off) or " + Valid(self.lo, self.hi, self.lo_open, self.hi_open, self.odd).describe()
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.lo is None and self.hi is None:
            return "any value"
        lo = "-inf" if self.lo is None else (f"{self.lo:g}" if isinstance(self.lo, float) else str(self.lo))
        hi = "inf" if self.hi is None else (f"{self.hi:g}" if isinstance(self.hi, float) else str(self.hi))
        text = f"within {'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open or self.hi is None else ']'}"
        return text + (", odd" if self.odd else "")

    def accepts(self, value: Any) -> bool:
        if self.choices is not None:
            return value in self.choices
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return True  # text and flags: the type check is all
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.off is not None and value == self.off:
            return True
        if self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)):
            return False
        if self.hi is not None and (value > self.hi or (self.hi_open and value == self.hi)):
            return False
        return not self.odd or value % 2 == 1


def _valid(default: Any, valid: Valid) -> Any:
    return field(default=default, metadata={"valid": valid})


def within(default: float, lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False,
           off: float | None = None) -> Any:
    """A number within [lo, hi] (None: unbounded; *_open: that end excluded), or exactly `off` (a value that
    switches the feature off, e.g. 0, when the range itself excludes it); never NaN or infinite."""
    return _valid(default, Valid(lo, hi, lo_open, hi_open, off=off))


def positive(default: float) -> Any:
    return within(default, 0.0, None, lo_open=True)


def non_negative(default: float) -> Any:
    return within(default, 0.0, None)


def fraction(default: float) -> Any:
    return within(default, 0.0, 1.0)


MAX_COUNT = 2**31 - 1  # counts reach COLMAP's options and compiled kernels as C ints: a larger one overflows there


def count(default: int, lo: int = 0, hi: int | None = None, odd: bool = False) -> Any:
    """An integer of at least `lo` and at most `hi` (None: MAX_COUNT)."""
    return _valid(default, Valid(lo, MAX_COUNT if hi is None else hi, odd=odd))


def one_of(default: Any, *choices: Any) -> Any:
    return _valid(default, Valid(choices=tuple(choices)))


def flag(default: bool) -> Any:
    return _valid(default, Valid())


def text(default: str) -> Any:
    """Free text (a path; "" = unset)."""
    return _valid(default, Valid())


class Checked:
    """Base of the params dataclasses: a value outside its declaration is refused however the params are made
    (`params_from_dict` names the dotted key; `dataclasses.replace` and direct construction land here)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            valid = f.metadata.get("valid")
            value = getattr(self, f.name)
            if valid is not None and not valid.accepts(value):
                raise InputError(f"{type(self).__name__}.{f.name} must be {valid.describe()}, got {value!r}")


def valid_values(cls: type, name: str) -> Valid | None:
    """The declaration of field `name` of params dataclass `cls` (None if it has none)."""
    f = next((f for f in dataclasses.fields(cls) if f.name == name), None)
    return None if f is None else f.metadata.get("valid")
