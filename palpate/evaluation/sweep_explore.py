"""`palpate sweep explore`: the speed-accuracy trade of the exploration graph, one knob at a time.

Each setting changes one knob of launch/explore.yaml from its default (the first row, "default") and
runs the same episodes (objects, start positions, strategies) as the default, each a task on Dask
(palpate.evaluation.dask_runs; resumable from runs.jsonl). Reported per setting and strategy, over
its runs: surface RMSE (the headline, confident estimate -> truth, and the whole estimate's symmetric
RMSE; see docs/exploration.md), the whole estimate's F-score@2 mm and travel at 80 % coverage
(completed runs), and over every run, completed or not, the coverage, F-score@2 mm and travel at its
end, contacts, milliseconds of CPU per planning step (GPIS update + local surface + planner, per
contact), CPU seconds per run, and how many runs completed. The contact noise knobs (the noise
node's position and normal noise) show what noisy sensing costs in contacts and travel: a setting
that keeps runs from 80 % shows it in the end figures.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from palpate import jsonio
from palpate.argtypes import path_arg
from palpate.errors import ConfigError
from palpate.evaluation.dask_runs import RunLog, output_folder, report_failures
from palpate.evaluation.dask_runs import add_arguments as add_cluster_arguments
from palpate.evaluation.dask_runs import config_from_args as cluster_config
from palpate.evaluation.explore import (
    QUIET_RUNS,
    Episode,
    add_objects_arguments,
    check_episodes,
    episodes,
    parse_sets,
    parse_strategies,
    report_errors,
    report_stopped,
    run_episodes,
    runs_of,
    select_cases,
)


@dataclass(frozen=True)
class Setting:
    """One point of the sweep: a name, the knob it turns, and the node parameter overrides."""

    name: str
    knob: str
    params: tuple[tuple[str, Any], ...]


def _s(name: str, knob: str, **params: Any) -> Setting:
    return Setting(name, knob, tuple((k.replace("__", "."), v) for k, v in params.items()))


#: The sweep: the default first, then one knob changed at a time (keys: node.param, "__" for ".").
SETTINGS: tuple[Setting, ...] = (
    _s("default", "-"),
    _s("kernel gaussian (sigma 3 cm)", "kernel", gpis__gp__kernel="gaussian"),
    _s("value noise 1 mm", "GP noise", gpis__gp__value_noise_m=1e-3),
    _s("gradient noise 0.3", "GP noise", gpis__gp__gradient_noise=0.3),
    _s("gradient noise 0.03", "GP noise", gpis__gp__gradient_noise=0.03),
    _s("local mesh 3.5 mm", "marching-cubes resolution", gpis__local_resolution_m=0.0035),
    _s("local mesh 7.5 mm", "marching-cubes resolution", gpis__local_resolution_m=0.0075),
    # the GPIS node gives GP-V's variance at the same spacing (palpate.launch checks that they agree)
    _s("candidate step 2.5 mm", "candidate step", planner__candidate_step_m=0.0025, gpis__variance_step_m=0.0025),
    _s("candidate step 10 mm", "candidate step", planner__candidate_step_m=0.01, gpis__variance_step_m=0.01),
    _s("v0 2.5 cm/s", "speed v0", controller__controller__v0_m_s=0.025),
    _s("v0 10 cm/s", "speed v0", controller__controller__v0_m_s=0.1),
    _s("sim step 1 ms", "simulation time step", sim__scene__timestep_s=0.001),
    _s("sim step 5 ms", "simulation time step", sim__scene__timestep_s=0.005),
    _s("tick 20 ms", "simulation time step", sim__tick_period_s=0.02),
    _s("contact position noise 0.5 mm", "contact noise", noise__position_sigma_m=0.0005),
    _s("contact position noise 2 mm", "contact noise", noise__position_sigma_m=0.002),
    _s("contact normal noise 5 deg", "contact noise", noise__normal_sigma_deg=5.0),
    _s("contact normal noise 15 deg", "contact noise", noise__normal_sigma_deg=15.0),
)
#: Objects of --quick: the smallest meshes by area.
QUICK_OBJECTS = 2
#: Objects without --quick.
FULL_OBJECTS = 5


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of `palpate sweep explore`."""
    add_objects_arguments(parser)
    parser.add_argument("--quick", action="store_true", help=f"the {QUICK_OBJECTS} smallest objects, IGEF, 1 run")
    parser.add_argument("--runs", type=int, help="start positions per object (default 1)")
    parser.add_argument("--strategies", default="igef", help="comma-separated strategies (default igef)")
    parser.add_argument("--only", default="", help="comma-separated setting names or knobs to run (default all)")
    parser.add_argument("--out", type=path_arg, default=Path("out/sweep_explore"), help="output folder")
    parser.add_argument("--json", action="store_true", help="print the rows as one JSON list, last line")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.KEY=VALUE", help="applies to all")
    add_cluster_arguments(parser)
    parser.set_defaults(func=main)


def sweep_episodes(
    base: Sequence[Episode], settings: Sequence[Setting], common: Mapping[str, Any]
) -> list[tuple[Setting, Episode]]:
    """Every base episode under every setting (common overrides first, the setting's on top)."""
    out = []
    for setting in settings:
        for ep in base:
            params = {**common, **dict(setting.params)}
            out.append((setting, Episode(**{**ep.__dict__, "params": tuple(sorted(params.items()))})))
    return out


def summarise(setting: Setting, strategy: str, rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One table row: the means over the setting's runs of one strategy (the 80 % figures over completed
    runs, the end figures over all)."""
    ok = [r for r in rows if "error" not in r]
    done = [r for r in ok if r["milestones"]["80"]["reached"]]

    def mean(values: Sequence[float]) -> float:
        finite = [v for v in values if v is not None and math.isfinite(v)]
        return float(np.mean(finite)) if finite else math.nan

    return {
        "setting": setting.name,
        "knob": setting.knob,
        "strategy": strategy,
        "params": dict(setting.params),
        "runs": len(rows),
        "completed": len(done),
        "rmse_mm": mean([r["milestones"]["80"]["rmse_mm"] for r in done]),
        "rmse_symmetric_mm": mean([r["milestones"]["80"].get("rmse_symmetric_mm", math.nan) for r in done]),
        "fscore_2mm": mean([r["milestones"]["80"].get("fscore_2mm", math.nan) for r in done]),
        "travel_cm": mean([r["milestones"]["80"]["travel_cm"] for r in done]),
        "contacts": mean([float(r["contacts"]) for r in ok]),
        "coverage": mean([float(r["coverage"]) for r in ok]),
        "fscore_2mm_end": mean([r["shape"][-1]["fscore_2mm"] for r in ok if r.get("shape")]),
        "travel_cm_end": mean([r["touches"][-1]["travel_cm"] for r in ok if r.get("touches")]),
        "miss_mm": mean([r["milestones"]["80"]["prediction_miss_mm"] for r in done]),
        "plan_ms": mean([float(r["plan_ms"]) for r in ok]),
        "cpu_s": mean([float(r["cpu_s"]) for r in ok]),
    }


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown table of the summary rows."""

    def f(v: float, digits: int = 1) -> str:
        return "-" if not math.isfinite(v) else f"{v:.{digits}f}"

    lines = [
        "| Setting | Knob | Strategy | Completed | RMSE 80 % (mm) | Whole, symmetric (mm) | F-score@2 mm 80 % "
        "| Travel 80 % (cm) | Coverage at end (%) | F-score@2 mm at end | Travel at end (cm) | Contacts | Miss (mm) "
        "| Plan step (ms CPU) | Run (s CPU) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['setting']} | {r['knob']} | {r['strategy']} | {r['completed']}/{r['runs']} | {f(r['rmse_mm'], 2)} | "
            f"{f(r['rmse_symmetric_mm'], 2)} | {f(r['fscore_2mm'], 3)} | {f(r['travel_cm'])} | "
            f"{f(100.0 * r['coverage'])} | {f(r['fscore_2mm_end'], 3)} | {f(r['travel_cm_end'])} | "
            f"{f(r['contacts'], 0)} | {f(r['miss_mm'])} | {f(r['plan_ms'])} | {f(r['cpu_s'])} |"
        )
    return "\n".join(lines)


def plot(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """Accuracy (RMSE at 80 %) against time (CPU per run), one labelled point per setting."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    several = len({r["strategy"] for r in rows}) > 1
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, key, label in (
        (axes[0], "cpu_s", "CPU seconds per run"),
        (axes[1], "plan_ms", "CPU ms per planning step (GPIS + planner)"),
    ):
        for r in rows:
            if not (math.isfinite(r["rmse_mm"]) and math.isfinite(r[key])):
                continue
            colour = "tab:red" if r["setting"] == "default" else "tab:blue"
            ax.scatter(r[key], r["rmse_mm"], color=colour)
            name = f"{r['setting']} ({r['strategy']})" if several else r["setting"]
            ax.annotate(name, (r[key], r["rmse_mm"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(label)
        ax.set_ylabel("surface RMSE at 80 % coverage (mm)")
        ax.grid(alpha=0.3)
    fig.suptitle("Exploration speed-accuracy trade (one knob changed from the default per point)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def chosen_settings(only: str) -> list[Setting]:
    """The default and the settings --only names (by setting name or knob; all when empty); ConfigError
    naming a word that matches none."""
    wanted = {w.strip() for w in only.split(",") if w.strip()}
    unknown = sorted(w for w in wanted if not any(w in (s.name, s.knob) for s in SETTINGS))
    if unknown:
        knobs = sorted({s.knob for s in SETTINGS} - {"-"})
        raise ConfigError(
            f"--only {', '.join(map(repr, unknown))} matches no setting; settings: {[s.name for s in SETTINGS]}; "
            f"knobs: {knobs}"
        )
    return [s for s in SETTINGS if not wanted or s.name in wanted or s.knob in wanted or s.name == "default"]


def check_sets(settings: Sequence[Setting], common: Mapping[str, Any]) -> None:
    """ConfigError when --set gives a knob one of the settings turns: that setting's value would replace it
    in those runs (and a setting equal to the default would repeat the default's runs)."""
    for setting in settings:
        clash = sorted(set(dict(setting.params)) & set(common))
        if clash:
            raise ConfigError(
                f"--set {clash[0]} sets the knob that setting {setting.name!r} turns, whose value would replace "
                "it in those runs; leave it out of --set, or --only other settings"
            )


def main(args: argparse.Namespace) -> int:
    """Run the sweep; write sweep.md, sweep.png and runs.jsonl into --out."""
    strategies = parse_strategies(args.strategies)
    settings = chosen_settings(args.only)
    runs = runs_of(args, default=1)
    cases = select_cases(args.objects, QUICK_OBJECTS if args.quick else FULL_OBJECTS, args.scale)
    if args.objects and len(cases) < len(select_cases(args.objects, None, args.scale)):
        print(f"sweep explore takes the {len(cases)} smallest of the objects given (by area)", file=sys.stderr)
    common = {**QUIET_RUNS, **parse_sets(args.set)}
    check_sets(settings, common)
    base = episodes(cases, runs, strategies, params=common)  # budgets and clocks after --set
    pairs = sweep_episodes(base, settings, common)
    for setting in settings:  # each setting's overrides, before any worker starts
        check_episodes([ep for s, ep in pairs if s is setting])
    out: Path = args.out
    output_folder(out)
    start = time.perf_counter()
    with RunLog(out / "runs.jsonl", resume=args.resume) as log:
        chosen = [ep for _, ep in pairs]  # its file holds every setting's rows by design: no advice on others
        results, outcome = run_episodes(chosen, log, cluster_config(args), prefix="sweep-explore", foreign_rows="")
    report_failures(outcome)
    report_stopped([row for row in results if row is not None])
    errors = [row for row in results if row is not None and "error" in row]
    report_errors(errors)  # counted as not completed in the table; said here, and the exit status says so
    elapsed = time.perf_counter() - start
    by_row: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for (setting, episode), row in zip(pairs, results, strict=True):
        if row is not None:
            by_row.setdefault((setting.name, episode.strategy), []).append(row)
    rows = [summarise(s, strategy, by_row.get((s.name, strategy), [])) for s in settings for strategy in strategies]
    given = f"; for every setting {', '.join(args.set)}" if args.set else ""
    text = (
        f"# Exploration sweep\n\nObjects: {', '.join(c.name for c in cases)}; strategies {', '.join(strategies)}; "
        f"{runs} run(s) each{given}; {elapsed / 60:.1f} min wall; {outcome.summary()}.\n\n" + table(rows) + "\n"
    )
    (out / "sweep.md").write_text(text)
    plot(out / "sweep.png", rows)
    print(text)
    print(f"wrote {out}/sweep.md, sweep.png, runs.jsonl")
    if args.json:
        print(jsonio.dumps(rows))
    return 1 if outcome.failed or errors else 0
