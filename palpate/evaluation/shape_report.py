"""Whole-shape figures of the exploration benchmark: F-score and Chamfer distance against effort.

Input: the rows of :func:`palpate.evaluation.explore.run_episode`, each with its ``shape`` series
(the whole estimate's scores every few contacts, at each milestone and at the end; see
``EvalConfig.shape_interval``). Per strategy:

- the travel and the contacts to the first estimate with F-score@2 mm >= 0.9, averaged over the
  PAIRED runs (every strategy got there from the same start), per object first, then over objects;
- the F-score@2 mm and the Chamfer distance at fixed budgets (50, 100, 200 contacts; 1, 2, 5 m of
  travel): the last estimate within the budget (a run that ended earlier counts with its final
  estimate), averaged per object, then over the objects with an estimate by then (``objects_at_...``
  counts them; a large object's first checkpoint may lie beyond a small budget, for one strategy's
  travel and not another's, and the table says so where a row's strategies average different counts).

The series is sampled every ``EvalConfig.shape_interval`` contacts (10; more on an object whose
covering bound exceeds 600 contacts), so "travel to F >= 0.9" is that of the first sampled estimate
that reaches it: an upper bound, coarse by at most that many contacts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: The F-score@2 mm the "effort to a good shape" figures ask for.
FSCORE_GOAL = 0.9
CONTACT_BUDGETS = (50, 100, 200)
TRAVEL_BUDGETS_M = (1.0, 2.0, 5.0)

Row = Mapping[str, Any]


def first_reaching(series: Sequence[Row], goal: float = FSCORE_GOAL) -> Row | None:
    """The first point of a shape series with F-score@2 mm >= goal, or None."""
    return next((p for p in series if (p.get("fscore_2mm") or 0.0) >= goal), None)


def last_within(series: Sequence[Row], *, contacts: int | None = None, travel_cm: float | None = None) -> Row | None:
    """The last point of a series within a budget of contacts or of travel (None: no point yet)."""
    inside = [
        p
        for p in series
        if (contacts is None or p["contacts"] <= contacts) and (travel_cm is None or p["travel_cm"] <= travel_cm)
    ]
    return inside[-1] if inside else None


def _per_object_mean(values: Mapping[str, list[float]]) -> float:
    means = [float(np.mean(v)) for v in values.values() if v]
    return float(np.mean(means)) if means else math.nan


def shape_summary(results: Sequence[Row], strategies: Sequence[str]) -> dict[str, dict[str, float | int]]:
    """Per strategy the figures of the module docstring; keys: ``travel_to_f2_cm``,
    ``contacts_to_f2``, ``runs_reaching_f2``, ``runs_with_shape`` (runs scored at least once),
    ``paired_runs_f2``, ``fscore_2mm_at_<n>_contacts``, ``chamfer_mm_at_<n>_contacts``,
    ``fscore_2mm_at_<x>m``, ``chamfer_mm_at_<x>m``, and ``objects_at_<n>_contacts``,
    ``objects_at_<x>m`` (the objects those budget figures average)."""
    ok = [r for r in results if "error" not in r and r.get("shape")]
    by_start: dict[tuple[str, int], dict[str, Row]] = {}
    for r in ok:
        by_start.setdefault((r["object"], int(r["run"])), {})[r["strategy"]] = r
    paired = [
        runs for runs in by_start.values() if all(s in runs and first_reaching(runs[s]["shape"]) for s in strategies)
    ]
    out: dict[str, dict[str, float | int]] = {}
    for s in strategies:
        mine = [r for r in ok if r["strategy"] == s]
        travel: dict[str, list[float]] = {}
        contacts: dict[str, list[float]] = {}
        for runs in paired:
            point = first_reaching(runs[s]["shape"])
            assert point is not None
            travel.setdefault(runs[s]["object"], []).append(float(point["travel_cm"]))
            contacts.setdefault(runs[s]["object"], []).append(float(point["contacts"]))
        stats: dict[str, float | int] = {
            "runs_reaching_f2": sum(1 for r in mine if first_reaching(r["shape"])),
            "runs_with_shape": len(mine),
            "paired_runs_f2": len(paired),
            "travel_to_f2_cm": _per_object_mean(travel),
            "contacts_to_f2": _per_object_mean(contacts),
        }
        budgets: list[tuple[str, dict[str, Any]]] = [(f"{n}_contacts", {"contacts": n}) for n in CONTACT_BUDGETS]
        budgets += [(f"{x:g}m", {"travel_cm": 100.0 * x}) for x in TRAVEL_BUDGETS_M]
        for label, budget in budgets:
            fscore: dict[str, list[float]] = {}
            chamfer: dict[str, list[float]] = {}
            for r in mine:
                point = last_within(r["shape"], **budget)
                if point is not None:
                    fscore.setdefault(r["object"], []).append(float(point["fscore_2mm"]))
                    chamfer.setdefault(r["object"], []).append(float(point["chamfer_mm"]))
            stats[f"fscore_2mm_at_{label}"] = _per_object_mean(fscore)
            stats[f"chamfer_mm_at_{label}"] = _per_object_mean(chamfer)
            stats[f"objects_at_{label}"] = len(fscore)
        out[s] = stats
    return out


def shape_table(summary: Mapping[str, Mapping[str, float | int]]) -> str:
    """Markdown table of :func:`shape_summary`: one column per strategy."""
    strategies = list(summary)
    rows = [
        ("Travel to F-score@2 mm >= 0.9 (paired)", "travel_to_f2_cm", "cm", 1, ""),
        ("Contacts to F-score@2 mm >= 0.9 (paired)", "contacts_to_f2", "", 1, ""),
        ("Runs reaching F-score@2 mm >= 0.9", "runs_reaching_f2", "", 0, ""),
    ]
    for n in CONTACT_BUDGETS:
        rows.append((f"F-score@2 mm after {n} contacts", f"fscore_2mm_at_{n}_contacts", "", 3, f"{n}_contacts"))
        rows.append((f"Chamfer after {n} contacts", f"chamfer_mm_at_{n}_contacts", "mm", 2, f"{n}_contacts"))
    for x in TRAVEL_BUDGETS_M:
        rows.append((f"F-score@2 mm after {x:g} m of travel", f"fscore_2mm_at_{x:g}m", "", 3, f"{x:g}m"))
        rows.append((f"Chamfer after {x:g} m of travel", f"chamfer_mm_at_{x:g}m", "mm", 2, f"{x:g}m"))
    lines = ["| Figure | " + " | ".join(s.upper() for s in strategies) + " |", "|---|" + "---:|" * len(strategies)]
    uneven = False
    for label, key, unit, digits, budget in rows:
        counts = [int(summary[s].get(f"objects_at_{budget}", 0)) for s in strategies] if budget else []
        show_counts = len(set(counts)) > 1
        uneven |= show_counts
        cells = []
        for i, s in enumerate(strategies):
            v = float(summary[s][key])
            cell = "-" if not math.isfinite(v) else f"{v:.{digits}f}{' ' + unit if unit else ''}"
            cells.append(f"{cell} [{counts[i]}]" if show_counts else cell)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    paired = next(iter(summary.values()))["paired_runs_f2"] if summary else 0
    lines.append("")
    lines.append(
        f"Paired runs for the effort to F-score@2 mm >= 0.9: {paired}. Budget figures: the last estimate within "
        "the budget, per object, then over the objects with an estimate by then"
        + (
            "; [n]: the number of objects a cell averages, where a row's strategies average different ones "
            "(an object whose first estimate lies beyond the budget is left out)."
            if uneven
            else "."
        )
    )
    return "\n".join(lines)


def plot_fscore_vs_travel(path: Path, results: Sequence[Row], object_name: str) -> None:
    """F-score@2 mm of the whole estimate against travelled distance, every strategy, one object."""
    from palpate.evaluation.explore_report import plot_against_travel

    ylabel = "F-score@2 mm of the whole estimate"
    title = "shape quality against effort"
    plot_against_travel(path, results, object_name, ("shape", "fscore_2mm"), ylabel, (FSCORE_GOAL,), title)
