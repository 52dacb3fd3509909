"""Argument types for the command line: argparse refuses a negative, zero or non-finite value by name."""

from __future__ import annotations

import argparse
import math
from pathlib import Path


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
