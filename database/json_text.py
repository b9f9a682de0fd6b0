"""JSON text that strict parsers read: RFC 8259 has no NaN or Infinity (Python's json writes them; JavaScript's
JSON.parse, Go and Rust reject the document), so non-finite numbers become null."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def finite(obj: Any) -> Any:
    """`obj` with every non-finite float (NaN, +-inf) in its dicts, lists and tuples replaced by None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    return obj


def json_default(obj: Any) -> Any:
    """`json.dumps`' `default` for the values our records hold besides Python's own: numpy scalars and arrays
    (as Python numbers and lists) and paths (as text); anything else is an error, as without a `default`."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def json_text(obj: Any, **kwargs: Any) -> str:
    """`json.dumps` of `obj` with non-finite numbers as null (`finite`; numpy float64 is a float, other numpy
    scalars and arrays need a `default`, as `json.dumps` itself does)."""
    return json.dumps(finite(obj), allow_nan=False, **kwargs)
