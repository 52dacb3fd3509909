"""Whole-shape figures of the exploration benchmark on hand-made shape series."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from palpate.evaluation.shape_report import (
    first_reaching,
    last_within,
    plot_fscore_vs_travel,
    shape_summary,
    shape_table,
)


def point(contacts: int, travel_cm: float, fscore: float, chamfer: float = 1.0) -> dict[str, Any]:
    return {"contacts": contacts, "travel_cm": travel_cm, "fscore_2mm": fscore, "chamfer_mm": chamfer}


def run(obj: str, index: int, strategy: str, series: list[dict[str, Any]]) -> dict[str, Any]:
    return {"object": obj, "run": index, "strategy": strategy, "shape": series}


def test_first_reaching_and_last_within() -> None:
    series = [point(10, 20.0, 0.5), point(20, 45.0, 0.92), point(30, 70.0, 0.95)]
    assert first_reaching(series) == series[1] and first_reaching(series, 0.99) is None
    assert last_within(series, contacts=25) == series[1] and last_within(series, contacts=5) is None
    assert last_within(series, travel_cm=100.0) == series[2]  # the run ended earlier: its final estimate


def test_the_goal_and_the_budgets_are_inclusive() -> None:
    series = [point(10, 20.0, 0.5), point(50, 100.0, 0.9)]
    assert first_reaching(series) == series[1]  # F = 0.9 reaches F >= 0.9
    assert last_within(series, contacts=50) == series[1]  # 50 contacts are within a budget of 50
    assert last_within(series, travel_cm=100.0) == series[1]  # 1 m of travel is within 1 m


def test_runs_that_errored_are_left_out() -> None:
    results = [
        run("a", 0, "igef", [point(10, 100.0, 0.95)]),
        {**run("a", 0, "area", [point(10, 50.0, 0.95)]), "error": "sim diverged"},
    ]
    summary = shape_summary(results, ["igef", "area"])
    assert summary["igef"]["paired_runs_f2"] == 0 and summary["igef"]["runs_with_shape"] == 1
    assert summary["area"]["runs_with_shape"] == 0 and summary["area"]["runs_reaching_f2"] == 0
    assert math.isnan(summary["area"]["fscore_2mm_at_50_contacts"])


def test_effort_is_paired_and_averaged_per_object_first() -> None:
    results = [
        run("a", 0, "igef", [point(10, 100.0, 0.95)]),
        run("a", 0, "area", [point(10, 50.0, 0.95)]),
        run("a", 1, "igef", [point(10, 300.0, 0.95)]),
        run("a", 1, "area", [point(10, 150.0, 0.95)]),
        run("b", 0, "igef", [point(10, 40.0, 0.91, chamfer=2.0)]),
        run("b", 0, "area", [point(10, 20.0, 0.91, chamfer=4.0)]),
        run("b", 1, "igef", [point(10, 999.0, 0.95)]),
        run("b", 1, "area", [point(10, 5.0, 0.5)]),  # never reaches 0.9: the pair b/1 is left out
    ]
    summary = shape_summary(results, ["igef", "area"])
    assert summary["igef"]["paired_runs_f2"] == 3
    assert summary["igef"]["travel_to_f2_cm"] == pytest.approx(((100 + 300) / 2 + 40) / 2)
    assert summary["area"]["travel_to_f2_cm"] == pytest.approx(((50 + 150) / 2 + 20) / 2)
    assert summary["area"]["runs_reaching_f2"] == 3 and summary["area"]["runs_with_shape"] == 4
    # budgets: every run with an estimate by then, object means first
    assert summary["area"]["chamfer_mm_at_50_contacts"] == pytest.approx((1.0 + (4.0 + 1.0) / 2) / 2)
    assert summary["area"]["fscore_2mm_at_1m"] == pytest.approx((0.95 + (0.91 + 0.5) / 2) / 2)  # a/1 not yet
    table = shape_table(summary)
    assert "| Travel to F-score@2 mm >= 0.9 (paired) | 120.0 cm | 60.0 cm |" in table


def test_the_plot_is_written(tmp_path: Path) -> None:
    results = [run("a", 0, "igef", [point(10, 10.0, 0.3), point(20, 30.0, 0.95)])]
    plot_fscore_vs_travel(tmp_path / "f.png", results, "a")
    assert (tmp_path / "f.png").stat().st_size > 1000


def test_budget_cells_say_how_many_objects_they_average_where_strategies_differ() -> None:
    """A large object whose first estimate lies beyond 1 m of one strategy's travel left that column's
    mean over fewer objects without a word."""
    results = [
        run("small", 0, "igef", [point(10, 50.0, 0.95)]),
        run("small", 0, "area", [point(10, 60.0, 0.9)]),
        run("large", 0, "igef", [point(40, 90.0, 0.3)]),
        run("large", 0, "area", [point(40, 150.0, 0.4)]),  # its first estimate lies beyond 1 m
    ]
    summary = shape_summary(results, ["igef", "area"])
    assert summary["igef"]["objects_at_1m"] == 2 and summary["area"]["objects_at_1m"] == 1
    assert summary["igef"]["objects_at_50_contacts"] == summary["area"]["objects_at_50_contacts"] == 2
    table = shape_table(summary)
    assert "| F-score@2 mm after 1 m of travel | 0.625 [2] | 0.900 [1] |" in table
    assert "| F-score@2 mm after 50 contacts | 0.625 | 0.650 |" in table
    assert "[n]: the number of objects a cell averages" in table
    even = shape_table(shape_summary(results[:2], ["igef", "area"]))
    assert "[" not in even and "over the objects with an estimate by then." in even
