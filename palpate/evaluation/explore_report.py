"""Tables and plots of the exploration benchmark, in the form of paper 002's Tables 2 and 4.

Input: the rows :func:`palpate.evaluation.explore.run_episode` returns (one per run). How averages
treat incomplete runs (a run whose budget ended before the milestone): a figure at a milestone
(50 % or 80 % coverage) is averaged only over PAIRED runs, the (object, run) pairs in which every
strategy reached that milestone, so that both strategies are measured on the same objects from the
same starts. Runs are first averaged per object, then objects are averaged (each object counts once,
as in the paper). Every run still appears in the CSV with its coverage, and the tables give the
counts of runs, completed runs and paired runs.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Milestones of Table 2 (percent coverage).
MILESTONES = ("50", "80")
#: Table 2's metrics: (key in a milestone, label, unit).
METRICS = (
    ("travel_cm", "Avg. traveled distance", "cm"),
    ("rotation_deg", "Avg. overall rotation", "deg"),
    ("rmse_mm", "Avg. surface RMSE (confident estimate -> truth)", "mm"),
    ("confident_fraction", "Avg. confident fraction of the estimate", ""),
    ("rmse_symmetric_mm", "Avg. RMSE whole estimate, symmetric", "mm"),
    ("rmse_estimate_to_truth_mm", "Avg. RMSE whole estimate -> truth", "mm"),
    ("rmse_truth_to_estimate_mm", "Avg. RMSE truth -> whole estimate", "mm"),
    ("prediction_miss_mm", "Avg. prediction miss", "mm"),
    ("contacts", "Avg. number of contacts", ""),
    ("angle_deg", "Avg. fingertip-normal angle", "deg"),
)
#: A figure derived per run (not a milestone value): contacts at the milestone over the object's covering
#: bound (issue 13 asks for at most 1.2 on average).
BOUND_METRIC = ("contacts_over_bound", "Avg. contacts / covering bound", "")
#: Columns of the per-run CSV (milestone figures get a _50 / _80 suffix).
RUN_COLUMNS = (
    "object",
    "strategy",
    "run",
    "complete",
    "finished",
    "stop_reason",
    "coverage",
    "vertex_coverage",
    "contacts",
    "area_m2",
    "covering_bound_contacts",
    "ticks",
    "cpu_s",
    "wall_s",
    "error",
)
MILESTONE_COLUMNS = (
    "reached",
    "contacts",
    "travel_cm",
    "rotation_deg",
    "rmse_mm",
    "confident_fraction",
    "rmse_symmetric_mm",
    "rmse_estimate_to_truth_mm",
    "rmse_truth_to_estimate_mm",
    "prediction_miss_mm",
    "angle_deg",
    "coverage",
    "vertex_coverage",
)


def flat_row(result: Mapping[str, Any]) -> dict[str, Any]:
    """One CSV row of a run result (milestone figures as ``<name>_<percent>``)."""
    row: dict[str, Any] = {key: result.get(key, "") for key in RUN_COLUMNS}
    milestones = result.get("milestones", {})
    for percent in MILESTONES:
        m = milestones.get(percent, {})
        for key in MILESTONE_COLUMNS:
            row[f"{key}_{percent}"] = m.get(key, "")
    return row


def write_csv(path: Path, results: Iterable[Mapping[str, Any]]) -> None:
    """Every run, one row each (see RUN_COLUMNS and MILESTONE_COLUMNS)."""
    rows = [flat_row(r) for r in results]
    columns = list(RUN_COLUMNS) + [f"{k}_{p}" for p in MILESTONES for k in MILESTONE_COLUMNS]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(v) for k, v in row.items()})


def _csv_value(value: Any) -> Any:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"
    return value


def _reached(result: Mapping[str, Any], percent: str) -> bool:
    m = result.get("milestones", {}).get(percent)
    return bool(m and m.get("reached"))


def _value(result: Mapping[str, Any], percent: str, key: str) -> float:
    """A run's figure at milestone ``percent``: a milestone value, or BOUND_METRIC (NaN without a bound)."""
    if key == BOUND_METRIC[0]:
        bound = float(result.get("covering_bound_contacts") or 0.0)
        return _value(result, percent, "contacts") / bound if bound > 0.0 else math.nan
    v = result["milestones"][percent].get(key)
    return math.nan if v is None else float(v)


def paired_means(
    results: Sequence[Mapping[str, Any]], strategies: Sequence[str], percent: str
) -> dict[str, dict[str, float]]:
    """Per strategy, each metric at milestone ``percent`` averaged over the paired runs (see the
    module doc: object means, then the mean over objects), plus counts.

    Returns {strategy: {metric: mean, "contacts_over_bound": mean, "runs": n, "runs_completed": n,
    "paired_runs": n, "objects": n}}; contacts_over_bound is each run's contacts at the milestone over
    its object's covering bound, averaged the same way (runs whose rows lack the bound left out).
    """
    by_key: dict[tuple[str, int], dict[str, Mapping[str, Any]]] = {}
    for r in results:
        by_key.setdefault((r["object"], int(r["run"])), {})[r["strategy"]] = r
    paired = [
        runs
        for runs in by_key.values()
        if all(s in runs and "error" not in runs[s] and _reached(runs[s], percent) for s in strategies)
    ]
    out: dict[str, dict[str, float]] = {}
    for s in strategies:
        mine = [r for r in results if r["strategy"] == s]
        per_object: dict[str, list[Mapping[str, Any]]] = {}
        for runs in paired:
            per_object.setdefault(runs[s]["object"], []).append(runs[s])
        stats: dict[str, float] = {
            "runs": float(len(mine)),
            "runs_completed": float(sum(1 for r in mine if "error" not in r and _reached(r, percent))),
            "paired_runs": float(len(paired)),
            "objects": float(len(per_object)),
        }
        for key, _, _ in (*METRICS, BOUND_METRIC):
            object_means = [
                float(np.nanmean([_value(r, percent, key) for r in rs]))
                for rs in per_object.values()
                if not all(math.isnan(_value(r, percent, key)) for r in rs)
            ]
            stats[key] = float(np.mean(object_means)) if object_means else math.nan
        out[s] = stats
    return out


#: Milestone figures where more is better (the others are costs and errors: less is better).
HIGHER_IS_BETTER = frozenset({"confident_fraction"})


def improvement_pct(baseline: float, method: float, higher_is_better: bool = False) -> float:
    """(baseline - method) / baseline in percent: how much smaller the method's figure is; for a figure
    where more is better, (method - baseline) / baseline. Positive: the method does better."""
    if not (math.isfinite(baseline) and math.isfinite(method)) or baseline == 0.0:
        return math.nan
    gain = method - baseline if higher_is_better else baseline - method
    return 100.0 * gain / baseline


def _fmt(value: float, unit: str = "", digits: int = 1) -> str:
    if not math.isfinite(value):
        return "-"
    return f"{value:.{digits}f}" + (f" {unit}" if unit else "")


def _compared(baseline: str, method: str, others: Sequence[str] = ()) -> tuple[str, ...]:
    """The strategies a table compares: the baseline, the method, then the others in their order,
    each once (one column when an evaluation ran a single strategy)."""
    return tuple(dict.fromkeys((baseline, method, *others)))


def _improvement_headers(shown: Sequence[str]) -> list[str]:
    """The improvement columns: the paper's one for two strategies, else one per strategy against the baseline."""
    if len(shown) == 2:
        return ["Avg. improvement"]
    return [f"{s.upper()} vs {shown[0].upper()}" for s in shown[1:]]


def table2(
    results: Sequence[Mapping[str, Any]], baseline: str = "gpv", method: str = "igef", others: Sequence[str] = ()
) -> str:
    """Markdown table in the form of the paper's Table 2 (averages at 50 % and 80 % coverage).

    Columns: baseline, method, then ``others``; the improvement of each against the baseline (one
    column, the paper's, for two strategies; none for a single strategy, baseline == method).
    """
    shown = _compared(baseline, method, others)
    improvements = _improvement_headers(shown) if len(shown) > 1 else []
    header = ["Coverage", "Metric", *(s.upper() for s in shown), *improvements]
    lines = ["| " + " | ".join(header) + " |", "|---|---|" + "---:|" * (len(header) - 2)]
    notes = []
    for percent in MILESTONES:
        means = paired_means(results, shown, percent)
        for key, label, unit in (*METRICS, BOUND_METRIC):
            digits = 2 if (unit == "mm" and "miss" not in key) or key in ("confident_fraction", BOUND_METRIC[0]) else 1
            cells = [_fmt(means[s][key], unit, digits) for s in shown]
            if improvements:
                better = key in HIGHER_IS_BETTER
                cells += [_fmt(improvement_pct(means[baseline][key], means[s][key], better), "%", 0) for s in shown[1:]]
            lines.append(f"| {percent} % | {label} | " + " | ".join(cells) + " |")
        first = means[shown[0]]
        completed = ", ".join(f"{s.upper()} {int(means[s]['runs_completed'])}/{int(means[s]['runs'])}" for s in shown)
        counted = "paired runs" if improvements else "runs"
        notes.append(
            f"{percent} %: {int(first['paired_runs'])} {counted} on {int(first['objects'])} objects; "
            f"completed {completed}"
        )
    lines.append("")
    lines.append(
        "Averages over paired runs only (every strategy reached the coverage in that (object, run)): "
        "per object, then over objects."
        + (
            " Improvement = (baseline - method) / baseline; for the confident fraction, where more is better, "
            "(method - baseline) / baseline. "
            if improvements
            else " "
        )
        + "; ".join(notes)
        + "."
    )
    return "\n".join(lines)


def table4(
    results: Sequence[Mapping[str, Any]], baseline: str = "gpv", method: str = "igef", others: Sequence[str] = ()
) -> str:
    """Markdown table in the form of the paper's Table 4: per object, travel at 80 % coverage.

    Each strategy's travel is its mean over its own completed runs (the count beside it); the
    improvement of each strategy against the baseline compares the paired runs only; the covering
    bound (contacts) is beside it. Columns as in :func:`table2`.
    """
    shown = _compared(baseline, method, others)
    improvements = _improvement_headers(shown) if len(shown) > 1 else []
    objects = sorted({r["object"] for r in results})
    header = (
        ["Object"]
        + [f"{s.upper()} travel" for s in shown]
        + ["Improvement (paired)" if h == "Avg. improvement" else f"{h} (paired)" for h in improvements]
        + [f"{s.upper()} contacts" for s in shown]
        + ["Covering bound (contacts)", "Coverage reached " + " / ".join(s.upper() for s in shown)]
    )
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 2) + "---|"]
    for name in objects:
        mine = [r for r in results if r["object"] == name]
        cells = []
        contact_cells = []
        for s in shown:
            done = [r for r in mine if r["strategy"] == s and "error" not in r and _reached(r, "80")]
            runs = [r for r in mine if r["strategy"] == s]
            travel = float(np.mean([_value(r, "80", "travel_cm") for r in done])) if done else math.nan
            contacts = float(np.mean([_value(r, "80", "contacts") for r in done])) if done else math.nan
            cells.append(f"{_fmt(travel, 'cm')} ({len(done)}/{len(runs)})")
            contact_cells.append(_fmt(contacts, "", 0))
        if improvements:
            paired = paired_means(mine, shown, "80")
            cells += [
                _fmt(improvement_pct(paired[baseline]["travel_cm"], paired[s]["travel_cm"]), "%", 1) for s in shown[1:]
            ]
        bound = next((float(r["covering_bound_contacts"]) for r in mine if "covering_bound_contacts" in r), math.nan)
        coverage = " / ".join(
            _fmt(100.0 * _mean([float(r.get("coverage", 0.0)) for r in mine if r["strategy"] == s]), "%", 0)
            for s in shown
        )
        lines.append("| " + " | ".join([name, *cells, *contact_cells, _fmt(bound, "", 0), coverage]) + " |")
    avg = paired_means(results, shown, "80")
    cells = [_fmt(avg[s]["travel_cm"], "cm") for s in shown]
    if improvements:
        cells += [_fmt(improvement_pct(avg[baseline]["travel_cm"], avg[s]["travel_cm"]), "%", 1) for s in shown[1:]]
    cells += [_fmt(avg[s]["contacts"], "", 0) for s in shown]
    lines.append("| " + " | ".join(["**average (paired)**", *cells, "", ""]) + " |")
    lines.append("")
    lines.append(
        "Travel at 80 % coverage, mean over each strategy's completed runs (completed/runs in brackets)"
        + ("; the improvement compares the paired runs only" if improvements else "")
        + ". Covering bound: 1.21 x 0.8 x area / (pi (6 mm)^2), "
        "the fewest 6 mm discs that cover 80 % of a flat surface of that area."
    )
    return "\n".join(lines)


def summary_json(
    results: Sequence[Mapping[str, Any]],
    strategies: Sequence[str],
    baseline: str = "gpv",
    method: str = "igef",
    extra: Mapping[str, Mapping[str, float | int]] | None = None,
) -> dict[str, Any]:
    """The --json summary: per strategy the figures at 80 % (paired averages) and counts, plus ratios;
    ``extra`` adds more figures per strategy (the whole-shape summary), floats rounded as the others."""
    keys = ("travel_cm", "rotation_deg", "rmse_mm", "prediction_miss_mm", "contacts")
    means = paired_means(results, strategies, "80")
    out: dict[str, Any] = {}
    for s in strategies:
        m = means[s]
        out[s] = {k: _json_number(m[k]) for k in keys}
        out[s].update(
            runs_completed=int(m["runs_completed"]),
            runs=int(m["runs"]),
            paired_runs=int(m["paired_runs"]),
            confident_fraction=_json_number(m["confident_fraction"]),
            rmse_symmetric_mm=_json_number(m["rmse_symmetric_mm"]),
            rmse_estimate_to_truth_mm=_json_number(m["rmse_estimate_to_truth_mm"]),
            rmse_truth_to_estimate_mm=_json_number(m["rmse_truth_to_estimate_mm"]),
            contacts_over_bound=_json_number(m[BOUND_METRIC[0]]),
        )
        for k, v in (extra or {}).get(s, {}).items():
            if k in out[s]:
                raise ValueError(f"summary_json: the extra figure {k!r} would replace the summary's own")
            out[s][k] = _json_number(v) if isinstance(v, float) else v
    if baseline != method and baseline in means and method in means:
        out["ratios"] = {
            f"{k}_{method}_over_{baseline}": _json_number(_ratio(means[method][k], means[baseline][k])) for k in keys
        }
        out["ratios"]["travel_improvement_pct"] = _json_number(
            improvement_pct(means[baseline]["travel_cm"], means[method]["travel_cm"])
        )
    out["coverage"] = 80
    out["averaging"] = "paired runs (every strategy reached 80 %), mean per object, then over objects"
    return out


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else math.nan


def _ratio(a: float, b: float) -> float:
    return a / b if math.isfinite(a) and math.isfinite(b) and b != 0.0 else math.nan


def _json_number(value: float) -> float | None:
    return None if not math.isfinite(value) else round(float(value), 4)


#: Line colour of each strategy in the plots; a strategy not listed takes one of SPARE_COLOURS.
STRATEGY_COLOURS = {
    "igef": "tab:blue",
    "gpv": "tab:orange",
    "random": "tab:gray",
    "area": "tab:green",
    "tour": "tab:red",
}
SPARE_COLOURS = ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")


def strategy_colour(strategy: str) -> str:
    """The plots' colour of a strategy (a new one gets a spare colour, the same in every plot)."""
    if strategy in STRATEGY_COLOURS:
        return STRATEGY_COLOURS[strategy]
    return SPARE_COLOURS[sum(map(ord, strategy)) % len(SPARE_COLOURS)]


def plot_against_travel(
    path: Path,
    results: Sequence[Mapping[str, Any]],
    object_name: str,
    series: tuple[str, str],
    ylabel: str,
    levels: Sequence[float],
    title: str,
    scale: float = 1.0,
) -> None:
    """One line per run of ``object_name``: ``series`` = (list field of a result, value field of its
    items) times ``scale``, against the items' ``travel_cm``; dashed lines at ``levels``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    field, value = series
    labelled: set[str] = set()
    for r in results:
        if r["object"] != object_name or not r.get(field):
            continue
        s = r["strategy"]
        travel = [t["travel_cm"] for t in r[field]]
        ys = [scale * t[value] for t in r[field]]
        colour = strategy_colour(s)
        marker = "o" if len(travel) == 1 else None  # a line of one point draws nothing (a run of one touch)
        ax.plot(travel, ys, color=colour, alpha=0.8, marker=marker, label=None if s in labelled else s.upper())
        labelled.add(s)
    for level in levels:
        ax.axhline(level, color="0.6", linewidth=0.8, linestyle="--")
    ax.set_xlabel("travelled distance (cm)")
    ax.set_ylabel(ylabel)
    ax.set_title(f"{object_name}: {title}")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_coverage_vs_travel(path: Path, results: Sequence[Mapping[str, Any]], object_name: str) -> None:
    """Coverage against travelled distance for every strategy (and run) on one object (paper Fig. 7a)."""
    ylabel = "coverage (% of the true surface within 6 mm of a contact)"
    title = "exploration progress"
    plot_against_travel(path, results, object_name, ("touches", "coverage"), ylabel, (50, 80), title, scale=100.0)


def plot_travel_per_object(
    path: Path,
    results: Sequence[Mapping[str, Any]],
    baseline: str = "gpv",
    method: str = "igef",
    others: Sequence[str] = (),
) -> None:
    """Per-object travel at 80 % coverage for every strategy compared (bars; completed runs only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    objects = sorted({r["object"] for r in results})
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(objects) + 2.0), 4.5))
    x = np.arange(len(objects))
    compared = _compared(baseline, method, others)
    bars = tuple(zip(compared, map(strategy_colour, compared), strict=False))
    width = 0.8 / len(bars)
    for k, (s, colour) in enumerate(bars):
        values = []
        for name in objects:
            done = [
                _value(r, "80", "travel_cm")
                for r in results
                if r["object"] == name and r["strategy"] == s and "error" not in r and _reached(r, "80")
            ]
            values.append(float(np.mean(done)) if done else 0.0)
        ax.bar(x + (k - (len(bars) - 1) / 2) * width, values, width=width, color=colour, label=s.upper())
    ax.set_xticks(x)
    ax.set_xticklabels(objects, rotation=70, ha="right", fontsize=7)
    ax.set_ylabel("travelled distance to 80 % coverage (cm)")
    ax.set_title("Travel per object (completed runs; no bar: none completed)")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
