"""Aggregation and tables of the exploration benchmark (synthetic run rows, no simulation)."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.evaluation import explore_report as report


def run(
    obj: str, strategy: str, idx: int, travel: float | None, contacts: int = 10, rmse: float = 1.0
) -> dict[str, Any]:
    """A result row; travel None means the run never reached 80 % (it reached 50 % at half)."""
    reached = travel is not None
    t = travel if travel is not None else 999.0

    def milestone(scale: float, ok: bool) -> dict[str, Any]:
        return {
            "reached": ok,
            "contacts": contacts * scale,
            "travel_cm": t * scale,
            "rotation_deg": 10.0 * t * scale,
            "rmse_mm": rmse,
            "rmse_estimate_to_truth_mm": rmse,
            "rmse_truth_to_estimate_mm": rmse,
            "prediction_miss_mm": 2.0,
            "angle_deg": 5.0,
            "coverage": 0.5 * scale,
            "vertex_coverage": 0.5 * scale,
        }

    return {
        "object": obj,
        "strategy": strategy,
        "run": idx,
        "complete": reached,
        "finished": "goal" if reached else "contact budget",
        "coverage": 0.8 if reached else 0.6,
        "vertex_coverage": 0.8,
        "contacts": contacts,
        "area_m2": 0.01,
        "covering_bound_contacts": 86.0,
        "milestones": {"50": milestone(0.5, True), "80": milestone(1.0, reached)},
    }


RESULTS = [
    run("a", "gpv", 0, 100.0),
    run("a", "igef", 0, 60.0),
    run("a", "gpv", 1, 200.0),
    run("a", "igef", 1, 100.0),
    run("b", "gpv", 0, 50.0),
    run("b", "igef", 0, None),  # incomplete: pair b/0 drops out at 80 %
    run("c", "gpv", 0, None),
    run("c", "igef", 0, 30.0),  # its own completion counts, but it is not paired
]


def test_paired_means_average_per_object_then_over_objects() -> None:
    means = report.paired_means(RESULTS, ("gpv", "igef"), "80")
    # only object a is paired at 80 %: (100 + 200) / 2 and (60 + 100) / 2
    assert means["gpv"]["travel_cm"] == pytest.approx(150.0)
    assert means["igef"]["travel_cm"] == pytest.approx(80.0)
    assert means["gpv"]["paired_runs"] == 2 and means["gpv"]["objects"] == 1
    assert means["gpv"]["runs"] == 4 and means["gpv"]["runs_completed"] == 3
    assert means["igef"]["runs_completed"] == 3
    # at 50 % everything is paired; objects weigh equally: a (75, 40), b (25, 499.5), c (499.5, 15)
    half = report.paired_means(RESULTS, ("gpv", "igef"), "50")
    assert half["gpv"]["objects"] == 3
    assert half["gpv"]["travel_cm"] == pytest.approx((75.0 + 25.0 + 499.5) / 3)


def test_a_run_that_errored_is_neither_paired_nor_completed_even_with_its_milestones() -> None:
    rows = [run("a", "gpv", 0, 100.0), {**run("a", "igef", 0, 60.0), "error": "planner crashed"}]
    means = report.paired_means(rows, ("gpv", "igef"), "80")
    assert means["gpv"]["paired_runs"] == 0 and math.isnan(means["gpv"]["travel_cm"])
    assert means["igef"]["runs"] == 1 and means["igef"]["runs_completed"] == 0
    assert means["gpv"]["runs_completed"] == 1


def test_a_figure_missing_in_some_runs_is_averaged_over_the_runs_that_have_it() -> None:
    rows = [
        run("a", "tour", 0, 10.0, rmse=2.0),
        run("a", "tour", 1, 10.0),  # no RMSE (null): object a's mean is its other run's 2.0
        run("b", "tour", 0, 10.0, rmse=4.0),
        run("c", "tour", 0, 10.0),  # no RMSE at all: object c drops out of this figure only
    ]
    for row in (rows[1], rows[3]):
        row["milestones"]["80"]["rmse_mm"] = None
    means = report.paired_means(rows, ("tour",), "80")
    assert means["tour"]["rmse_mm"] == pytest.approx((2.0 + 4.0) / 2)  # objects a and b
    assert means["tour"]["travel_cm"] == pytest.approx(10.0) and means["tour"]["objects"] == 3


def test_contacts_per_covering_bound_is_averaged_like_the_milestone_figures() -> None:
    rows = [
        run("a", "tour", 0, 10.0, contacts=43),
        run("a", "tour", 1, 10.0, contacts=129),  # object a: (0.5 + 1.5) / 2 = 1.0 of its 86-contact bound
        run("b", "tour", 0, 10.0, contacts=172),  # object b: 2.0
        run("c", "tour", 0, None, contacts=86),  # not at 80 %: left out
    ]
    means = report.paired_means(rows, ("tour",), "80")
    assert means["tour"]["contacts_over_bound"] == pytest.approx((1.0 + 2.0) / 2)
    assert report.summary_json(rows, ("tour",))["tour"]["contacts_over_bound"] == pytest.approx(1.5)
    del rows[2]["covering_bound_contacts"]  # a row of an older runs.jsonl: its object drops out of this figure
    assert report.paired_means(rows, ("tour",), "80")["tour"]["contacts_over_bound"] == pytest.approx(1.0)
    assert "| 80 % | Avg. contacts / covering bound | 1.00 |" in report.table2(rows, "tour", "tour")


def test_improvement_is_relative_to_the_baseline() -> None:
    assert report.improvement_pct(159.0, 117.0) == pytest.approx(26.4, abs=0.1)
    assert math.isnan(report.improvement_pct(0.0, 1.0))
    # more of the confident fraction is better: 0.8 -> 1.0 is an improvement (an outside audit found it signed
    # as a loss in the tables)
    assert report.improvement_pct(0.8, 1.0, higher_is_better=True) == pytest.approx(25.0)
    assert math.isnan(report.improvement_pct(math.nan, 1.0))


def test_summary_json_has_the_issue_keys_and_ratios() -> None:
    summary = report.summary_json(RESULTS, ("igef", "gpv"))
    for s in ("igef", "gpv"):
        for key in ("travel_cm", "rotation_deg", "rmse_mm", "prediction_miss_mm", "contacts", "runs_completed", "runs"):
            assert key in summary[s]
    assert summary["igef"]["runs"] == 4 and summary["igef"]["runs_completed"] == 3
    assert summary["ratios"]["travel_cm_igef_over_gpv"] == pytest.approx(80.0 / 150.0, abs=1e-4)
    assert summary["ratios"]["travel_improvement_pct"] == pytest.approx(100 * 70 / 150, abs=1e-3)


def test_the_shape_figures_join_the_summary_without_replacing_its_own() -> None:
    shape = {"igef": {"runs_with_shape": 1, "travel_to_f2_cm": 12.5}}  # one run scored: runs stays 4
    summary = report.summary_json(RESULTS, ("igef", "gpv"), extra=shape)
    assert summary["igef"]["runs"] == 4 and summary["igef"]["runs_with_shape"] == 1
    with pytest.raises(ValueError, match="'runs' would replace"):
        report.summary_json(RESULTS, ("igef", "gpv"), extra={"igef": {"runs": 1}})


def test_a_larger_confident_fraction_counts_as_an_improvement_in_the_table() -> None:
    rows = [run("a", "gpv", 0, 100.0), run("a", "igef", 0, 60.0)]
    for row, fraction in zip(rows, (0.8, 1.0), strict=True):
        row["milestones"]["80"]["confident_fraction"] = fraction
    assert "| 80 % | Avg. confident fraction of the estimate | 0.80 | 1.00 | 25 % |" in report.table2(rows)


def test_tables_state_counts_and_mark_incomplete_objects() -> None:
    t2 = report.table2(RESULTS)
    assert "| 80 % | Avg. traveled distance | 150.0 cm | 80.0 cm | 47 % |" in t2
    assert "80 %: 2 paired runs on 1 objects; completed GPV 3/4, IGEF 3/4" in t2
    t4 = report.table4(RESULTS)
    row_b = next(line for line in t4.splitlines() if line.startswith("| b |"))
    assert "50.0 cm (1/1)" in row_b and "- (0/1)" in row_b
    assert "| 86 |" in row_b  # the covering bound beside the travel


def test_tables_of_a_single_strategy_show_it_once_without_an_improvement(tmp_path: Path) -> None:
    igef = [r for r in RESULTS if r["strategy"] == "igef"]
    t2 = report.table2(igef, "igef", "igef")
    assert "| Coverage | Metric | IGEF |" in t2 and "improvement" not in t2.lower()
    assert "| 80 % | Avg. traveled distance | 55.0 cm |" in t2  # objects a (80) and c (30), b incomplete
    assert "80 %: 3 runs on 2 objects; completed IGEF 3/4." in t2
    t4 = report.table4(igef, "igef", "igef")
    header, rule, *rows = t4.splitlines()
    assert header.count("IGEF") == 3 and rule.count("|") == header.count("|")
    assert all(row.count("|") == header.count("|") for row in rows if row.startswith("|"))
    assert "| a | 80.0 cm (2/2) | 10 | 86 | 80 % |" in t4
    summary = report.summary_json(igef, ("igef",), "igef", "igef")
    assert "ratios" not in summary and summary["igef"]["runs_completed"] == 3
    report.plot_travel_per_object(tmp_path / "t.png", igef, "igef", "igef")
    assert (tmp_path / "t.png").stat().st_size > 1000


def test_tables_of_more_strategies_show_each_against_the_baseline_over_runs_all_complete() -> None:
    tour = [run("a", "tour", 0, 40.0), run("a", "tour", 1, None), run("b", "tour", 0, 20.0), run("c", "tour", 0, 15.0)]
    rows = RESULTS + tour
    t2 = report.table2(rows, "gpv", "igef", ["tour", "igef"])  # a repeated strategy is one column
    assert "| Coverage | Metric | GPV | IGEF | TOUR | IGEF vs GPV | TOUR vs GPV |" in t2
    # at 80 % only a/0 has all three: GP-V 100, IGEF 60 (40 %), tour 40 (60 %)
    assert "| 80 % | Avg. traveled distance | 100.0 cm | 60.0 cm | 40.0 cm | 40 % | 60 % |" in t2
    assert "80 %: 1 paired runs on 1 objects; completed GPV 3/4, IGEF 3/4, TOUR 3/4" in t2
    t4 = report.table4(rows, "gpv", "igef", ["tour"])
    header, rule, *lines = t4.splitlines()
    assert "| IGEF vs GPV (paired) | TOUR vs GPV (paired) |" in header
    columns = header.count("|")
    assert rule.count("|") == columns and all(x.count("|") == columns for x in lines if x.startswith("|"))
    row_a = next(line for line in lines if line.startswith("| a |"))
    assert "| 150.0 cm (2/2) | 80.0 cm (2/2) | 40.0 cm (1/2) | 40.0 % | 60.0 % |" in row_a
    assert row_a.endswith("| 80 % / 80 % / 70 % |")  # the mean coverage of each strategy's runs


def test_csv_has_one_row_per_run_with_milestone_columns(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    report.write_csv(path, RESULTS)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == len(RESULTS)
    assert rows[5]["object"] == "b" and rows[5]["reached_80"] == "False" and rows[5]["coverage"] == "0.6"
    for column in ("travel_cm_80", "rmse_mm_50", "rmse_estimate_to_truth_mm_80", "covering_bound_contacts"):
        assert column in rows[0]


def test_plots_are_written(tmp_path: Path) -> None:
    rows = [dict(r, touches=[{"travel_cm": 1.0 * i, "coverage": 0.01 * i} for i in range(5)]) for r in RESULTS]
    report.plot_coverage_vs_travel(tmp_path / "c.png", rows, "a")
    report.plot_travel_per_object(tmp_path / "t.png", rows, others=["tour"])  # a strategy without runs: no bars
    assert (tmp_path / "c.png").stat().st_size > 1000 and (tmp_path / "t.png").stat().st_size > 1000


def test_a_run_of_one_point_is_drawn(tmp_path: Path) -> None:
    """An outside walkthrough: a run of one touch (a 3 mm sphere covered at once) left its plot empty."""
    import matplotlib.colors
    import matplotlib.image

    colour = 255 * np.array(matplotlib.colors.to_rgb(report.strategy_colour(RESULTS[0]["strategy"])))

    def coloured_pixels(points: int) -> int:
        row = dict(RESULTS[0], touches=[{"travel_cm": 5.0, "coverage": 0.5}] * points)
        report.plot_coverage_vs_travel(tmp_path / "c.png", [row], "a")
        rgb = matplotlib.image.imread(tmp_path / "c.png")[..., :3] * 255
        return int((abs(rgb - colour).max(axis=-1) < 40).sum())

    assert coloured_pixels(1) > coloured_pixels(2) + 20  # a marker, where two points at one place draw no line


def test_every_strategy_has_a_colour_of_its_own_in_the_plots() -> None:
    from palpate.evaluation.explore_report import SPARE_COLOURS, STRATEGY_COLOURS, strategy_colour

    assert strategy_colour("igef") == "tab:blue" and strategy_colour("gpv") == "tab:orange"
    new = strategy_colour("nearest")  # a strategy the table does not list: a spare colour, not black
    assert new in SPARE_COLOURS and new not in STRATEGY_COLOURS.values() and new == strategy_colour("nearest")
