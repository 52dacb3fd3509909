"""Strict JSON: every `--json` line and results file palpate writes goes through `dumps`.

JSON has no NaN or infinity. Python's json module writes them as bare ``NaN`` and ``Infinity``, which
other parsers (jq, JavaScript, serde) reject. `dumps` writes ``null`` for every non-finite float,
including numpy scalars and array elements, writes numpy values as plain numbers and paths as text,
and refuses (TypeError) anything else JSON cannot hold. A metric that was not measured (a coverage
milestone never reached) reads ``null``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import numpy as np


def strict(value: Any) -> Any:
    """`value` with non-finite floats as None, numpy values as Python values, tuples as lists, paths as text."""
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict(v) for v in value]
    if isinstance(value, np.ndarray):
        return strict(value.tolist())
    if isinstance(value, np.generic):
        return strict(value.item())
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable: {value!r}")


def dumps(value: Any, **kwargs: Any) -> str:
    """JSON text of `value` (see `strict`); keyword arguments go to json.dumps (indent, sort_keys, ...)."""
    return json.dumps(strict(value), allow_nan=False, **kwargs)


def write(path: str | Path, value: Any, **kwargs: Any) -> None:
    """Write `value` as strict JSON to `path` (creating its folder), ending with a newline."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps(value, **kwargs) + "\n")
