"""Fixed-width plain-text tables: a header line, a dashed rule and one line per row."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

Row = Mapping[str, Any]


@dataclass(frozen=True)
class Column:
    """One column: ``header`` and each cell padded to ``width`` characters, aligned by ``align``.

    ``value`` is a row key or a callable ``row -> value``; the cell is ``format(value, f"{align}{width}{spec}")``,
    i.e. ``spec`` is the rest of a format spec (".2f", "g", ".0f" ...). Text wider than ``width`` is not cut.
    """

    header: str
    width: int
    value: str | Callable[[Row], Any]
    spec: str = ""
    align: Literal["<", ">"] = ">"

    def cell(self, row: Row) -> str:
        """The formatted cell of ``row``."""
        value = row[self.value] if isinstance(self.value, str) else self.value(row)
        return format(value, f"{self.align}{self.width}{self.spec}")


def fixed_width_table(columns: Sequence[Column], rows: Iterable[Row]) -> str:
    """Header line, ``"-" * len(header)`` and one line per row, joined with newlines (no trailing one)."""
    head = "".join(format(c.header, f"{c.align}{c.width}") for c in columns)
    lines = [head, "-" * len(head)]
    lines += ["".join(c.cell(row) for c in columns) for row in rows]
    return "\n".join(lines)
