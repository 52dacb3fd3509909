"""Argument types for the command line: argparse refuses a negative, zero or non-finite value by name."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _int(text, 1, "a positive integer")


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _int(text, 0, "an integer >= 0")


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _float(text, positive=True, refusal=f"{text!r} is not a finite number > 0")


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    return _float(text, positive=False, refusal=f"{text!r} is not a finite number >= 0")


def bounded_positive_int(highest: int) -> Any:
    """An argument type: an integer from 1 to `highest` (a larger one would overflow a buffer's length)."""

    def parse(text: str) -> int:
        value = positive_int(text)
        if value > highest:
            raise argparse.ArgumentTypeError(f"{_shown(text)} is more than {highest:,}")
        return value

    parse.__name__ = "positive_int"  # argparse names the type in its message for a ValueError
    return parse


def json_object(text: str) -> dict[str, Any]:
    """A JSON object, ``{"key": value, ...}``."""
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        raise argparse.ArgumentTypeError(f"{_shown(text)} is not JSON; give an object {{...}}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{_shown(text)} is not a JSON object {{...}}")
    return value


def json_string_map(text: str) -> dict[str, str]:
    """A JSON object whose values are strings, ``{"key": "text", ...}``."""
    value = json_object(text)
    if not all(isinstance(v, str) for v in value.values()):
        raise argparse.ArgumentTypeError(f"{_shown(text)}: every value must be a string")
    return value


def _shown(text: str, limit: int = 200) -> str:
    """`text` quoted, its middle left out when it is long (an error message echoes it)."""
    return repr(text) if len(text) <= limit else f"{text[: limit // 2]!r}...{text[-limit // 2 :]!r}"


def path_arg(text: str) -> Path:
    """A path that is not empty ('' would be the working directory, which nobody means)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is no path")
    return Path(text)


def add_scale_argument(parser: argparse.ArgumentParser) -> None:
    """``--scale``: metres per unit of the --objects files."""
    parser.add_argument(
        "--scale",
        type=positive_scale,
        default=1.0,
        help="metres per unit of the --objects mesh files (default 1; 0.001 for files in millimetres)",
    )


def positive_scale(text: str) -> float:
    """``--scale``: a finite number > 0."""
    return _float(text, positive=True, refusal=f"expected a finite number > 0 (0.001: millimetres), got {text!r}")


def _float(text: str, *, positive: bool, refusal: str) -> float:
    """`text` as a finite float, > 0 if `positive` else >= 0; ArgumentTypeError(refusal) otherwise."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
        raise argparse.ArgumentTypeError(refusal)
    return value


def _int(text: str, lowest: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if value < lowest:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return value
