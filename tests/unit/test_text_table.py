"""The fixed-width text table: alignment, widths, rule length, custom cells."""

from __future__ import annotations

from palpate.text_table import Column, fixed_width_table


def _columns() -> list[Column]:
    return [
        Column("name", 8, "name", align="<"),
        Column("n", 4, "n"),
        Column("mm", 7, lambda r: 1e3 * r["m"], ".2f"),
    ]


def test_header_rule_and_rows_are_aligned_to_the_widths() -> None:
    text = fixed_width_table(_columns(), [{"name": "cube", "n": 3, "m": 0.0125}, {"name": "torus", "n": 12, "m": 0.5}])
    assert text.split("\n") == [
        "name       n     mm",
        "-------------------",
        "cube       3  12.50",
        "torus     12 500.00",
    ]


def test_rule_is_as_long_as_the_header_and_every_padded_line() -> None:
    columns = _columns()
    lines = fixed_width_table(columns, [{"name": "a", "n": 1, "m": 0.001}]).splitlines()
    width = sum(c.width for c in columns)
    assert len(lines[0]) == len(lines[1]) == len(lines[2]) == width == 19
    assert set(lines[1]) == {"-"}


def test_no_rows_gives_header_and_rule_only_and_wide_cells_are_not_cut() -> None:
    assert fixed_width_table(_columns(), []) == "name       n     mm\n-------------------"
    text = fixed_width_table([Column("x", 3, "x", align="<"), Column("y", 3, "y")], [{"x": "long text", "y": 12345}])
    assert text.splitlines()[2] == "long text12345"


def test_callable_cell_matches_the_equivalent_f_string() -> None:
    row = {"v": 0.5, "v_std": 0.125}
    column = Column("pm", 16, lambda r: f"{r['v']:.3f} +- {r['v_std']:.3f}")
    assert column.cell(row) == f"{'0.500 +- 0.125':>16}"
    assert Column("g", 6, "v", "g").cell(row) == f"{0.5:>6g}"
