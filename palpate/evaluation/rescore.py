"""`palpate eval rescore`: an evaluation's whole estimate at a milestone, rebuilt from its recorded
touches under other GPIS settings, without simulating again.

Each run of a runs.jsonl (``palpate eval explore``) holds its touches with their measured positions and
normals. The GPIS node's estimate at the milestone depends only on them and on the node's settings, so
a rebuild with the run's own settings gives the recorded surface scores to the bit, and a rebuild with
``--set gpis.KEY=VALUE`` shows what another estimator would have made of the same contacts. The
planner saw the recorded estimator's local meshes: a setting that changes those would also change the
path, which only a new evaluation measures (docs/exploration.md, "The estimator's settings").
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from palpate import jsonio
from palpate.argtypes import path_arg
from palpate.errors import ConfigError, EstimationError, InputError, PalpateError
from palpate.evaluation.dask_runs import (
    RunLog,
    RunTask,
    SharedFile,
    file_digest,
    local_copy,
    output_folder,
    report_failures,
    run_key,
    run_tasks,
)
from palpate.evaluation.dask_runs import add_arguments as add_cluster_arguments
from palpate.evaluation.dask_runs import config_from_args as cluster_config
from palpate.evaluation.explore import (
    EXPLORE_LAUNCH,
    ObjectCase,
    add_objects_arguments,
    overrides_under,
    parse_sets,
    report_errors,
    runs_from,
    select_cases,
)

if TYPE_CHECKING:
    from palpate.nodes.explore_eval.core import EvalConfig
    from palpate.nodes.gpis.session import GPISNodeConfig

#: --out default.
DEFAULT_OUT = Path("out/eval_rescore")
#: The milestone figures a rebuild replaces (``explore_eval.core.surface_fields``).
REBUILT = (
    "rmse_mm",
    "confident_fraction",
    "rmse_symmetric_mm",
    "rmse_estimate_to_truth_mm",
    "rmse_truth_to_estimate_mm",
)


def node_configs(
    strategy: str, params: Mapping[str, Any], launch_path: Path = EXPLORE_LAUNCH
) -> tuple[GPISNodeConfig, EvalConfig]:
    """The GPIS node's config and the evaluator's settings in an evaluated run of ``strategy`` with
    node overrides ``params`` (all of the run's, as ``episode_launch`` applies them), as the launch
    file resolves them. ConfigError for settings a rebuild cannot follow."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import apply_params, load_launch

    launch = load_launch(launch_path, {"strategy": strategy})
    apply_params(launch, params.items())
    with tempfile.TemporaryDirectory() as bus_dir:
        nodes = {node.name: node.config for node in resolve(launch, bus_dir=Path(bus_dir)).nodes}
    if nodes["gpis"].free_space:
        raise ConfigError(
            "gpis.free_space: the free space comes from the fingertip's path, which runs.jsonl does not hold; "
            "a rebuild cannot follow it (run the evaluation with the setting instead)"
        )
    return nodes["gpis"], nodes["eval"].eval


def rebuilt_scores(
    truth: tuple[np.ndarray, np.ndarray],
    positions_m: np.ndarray,
    normals: np.ndarray,
    config: GPISNodeConfig,
    eval_config: EvalConfig | None = None,
) -> dict[str, float]:
    """The milestone's surface figures (REBUILT) of the whole estimate that a GPIS node with ``config``
    makes from these contacts (positions (n, 3) m, unit normals (n, 3)), scored against the true mesh
    as the evaluator with ``eval_config`` scores it. A touch the estimator refuses is left out, as the
    node leaves it out (an input error there); EstimationError when it refuses every one."""
    from palpate.nodes.explore_eval.core import EvalConfig, ExplorationEvaluator, surface_fields
    from palpate.nodes.gpis.session import GPISSession

    session = GPISSession(config)
    refused: list[InputError] = []
    for position, normal in zip(positions_m, normals, strict=True):
        try:
            session.touch(position, normal)
        except InputError as exc:
            refused.append(exc)
    if refused and session.gp.n_contacts == 0:
        raise EstimationError(f"the estimator took none of the {len(refused)} touches: {refused[0]}")
    mesh = session.whole(variance=True)
    evaluator = ExplorationEvaluator(*truth, eval_config or EvalConfig())
    return surface_fields(evaluator.rmse(mesh.vertices, mesh.faces, mesh.vertex_variance))


def rescore_on_worker(
    case: ObjectCase,
    positions_m: list[list[float]],
    normals: list[list[float]],
    configs: tuple[GPISNodeConfig, EvalConfig],
    identity: dict[str, Any],
    *mesh: SharedFile,
) -> dict[str, Any]:
    """On a Dask worker: ``identity`` (the run's object, strategy, run and milestone) with the rebuilt
    figures, on the worker's copy of the mesh; with ``error`` instead when the estimator cannot make
    the surface (it would fail the same way on any worker)."""
    if mesh:
        case = replace(case, mesh=str(local_copy(mesh[0])))
    try:
        scores = rebuilt_scores(case.true_mesh(), np.array(positions_m), np.array(normals), *configs)
    except PalpateError as exc:
        return {**identity, "error": f"{type(exc).__name__}: {exc}"}
    return {**identity, "rebuilt": scores}


def touches_at(run: Mapping[str, Any], percent: str, source: Path) -> tuple[list[list[float]], list[list[float]]]:
    """Positions and normals of the touches up to the run's milestone ``percent``."""
    count = int(run["milestones"][percent]["contacts"])
    touches = run.get("touches", [])[:count]
    if len(touches) < count or any(t.get("normal") is None for t in touches):
        raise ConfigError(
            f"{source}: {run['object']} {run['strategy']} run {run['run']} has no touch normals (a runs.jsonl "
            "written before touches recorded them); run the evaluation again to rescore it"
        )
    return [t["position_m"] for t in touches], [t["normal"] for t in touches]


def tasks_of(
    runs: Sequence[Mapping[str, Any]],
    cases: Mapping[str, ObjectCase],
    sets: Mapping[str, Any],
    percent: str,
    source: Path,
) -> list[RunTask]:
    """One task per run that reached ``percent``, rebuilt with its own settings and ``sets`` on top."""
    configs: dict[str, tuple[GPISNodeConfig, EvalConfig]] = {}
    areas: dict[str, float] = {}
    tasks = []
    for run in runs:
        milestone = run.get("milestones", {}).get(percent)
        if "error" in run or not (milestone and milestone.get("reached")):
            continue
        if run["object"] not in cases:
            raise ConfigError(f"{source}: object {run['object']!r} is not among --objects; give its mesh's folder")
        case = cases[run["object"]]
        _check_size(run, case, areas, source)
        params = dict(run.get("params", {})) | dict(sets)
        signature = jsonio.dumps([run["strategy"], params], sort_keys=True)
        if signature not in configs:
            configs[signature] = node_configs(run["strategy"], params)
        positions, normals = touches_at(run, percent, source)
        identity = {"object": run["object"], "strategy": run["strategy"], "run": run["run"], "milestone": percent}
        mesh = file_digest(Path(case.mesh)) if case.mesh else ""
        spec = [identity, signature, asdict(replace(case, mesh=mesh)), positions, normals]
        tasks.append(
            RunTask(
                key=run_key(f"rescore-{run['object']}-{run['strategy']}-{run['run']}", spec),
                function=rescore_on_worker,
                args=(case, positions, normals, configs[signature], identity),
                files=(Path(case.mesh),) if case.mesh else (),
                label=f"{run['object']} {run['strategy']} run {run['run']}",
            )
        )
    return tasks


def _check_size(run: Mapping[str, Any], case: ObjectCase, areas: dict[str, float], source: Path) -> None:
    """ConfigError when the mesh found for the run's object has another area than the one it ran on
    (another file of that name, or another --scale)."""
    recorded = run.get("area_m2")
    if recorded is None:
        return
    if case.name not in areas:
        from palpate.metrics.exploration import mesh_area

        areas[case.name] = mesh_area(case.true_mesh())
    if not math.isclose(areas[case.name], float(recorded), rel_tol=1e-6):
        raise ConfigError(
            f"{source}: {case.name} ran on a surface of {recorded:.6g} m^2, but {case.mesh or case.kind} is "
            f"{areas[case.name]:.6g} m^2 here; give the same mesh with the --scale the evaluation had"
        )


def with_rebuilt(
    runs: Sequence[Mapping[str, Any]], rows: Sequence[Mapping[str, Any]], percent: str
) -> list[dict[str, Any]]:
    """The runs with their milestone's REBUILT figures replaced by the rebuilt ones (runs not rebuilt,
    or rebuilt with an error, are left out)."""
    rebuilt = {(r["object"], r["strategy"], r["run"]): r["rebuilt"] for r in rows if "rebuilt" in r}
    out = []
    for run in runs:
        scores = rebuilt.get((run["object"], run["strategy"], run["run"]))
        if scores is not None:
            milestones = dict(run["milestones"])
            milestones[percent] = {**milestones[percent], **scores}
            out.append({**run, "milestones": milestones})
    return out


def comparison(
    recorded: Sequence[Mapping[str, Any]], rebuilt: Sequence[Mapping[str, Any]], strategies: Sequence[str], percent: str
) -> dict[str, dict[str, float]]:
    """Per strategy, the recorded and the rebuilt figures over the runs every strategy rebuilt (object
    means, then over objects, as ``eval explore`` pairs them)."""
    from palpate.evaluation.explore_report import paired_means

    kept = {(r["object"], r["strategy"], r["run"]) for r in rebuilt}
    before = paired_means([r for r in recorded if (r["object"], r["strategy"], r["run"]) in kept], strategies, percent)
    after = paired_means(rebuilt, strategies, percent)
    out: dict[str, dict[str, float]] = {}
    for s in strategies:
        out[s] = {"paired_runs": after[s]["paired_runs"]}
        for key in REBUILT:
            out[s][f"recorded_{key}"] = before[s][key]
            out[s][key] = after[s][key]
    return out


def table(summary: Mapping[str, Mapping[str, float]], percent: str) -> str:
    """The comparison as a Markdown table."""
    lines = [
        f"| strategy | paired runs | symmetric RMSE at {percent} %, mm: recorded | rebuilt | estimate -> truth | "
        "truth -> estimate | confident RMSE |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for s, f in summary.items():
        cells = [f["recorded_rmse_symmetric_mm"], f["rmse_symmetric_mm"], f["rmse_estimate_to_truth_mm"]]
        cells += [f["rmse_truth_to_estimate_mm"], f["rmse_mm"]]
        text = " | ".join("-" if math.isnan(v) else f"{v:.3f}" for v in cells)
        lines.append(f"| {s} | {int(f['paired_runs'])} | {text} |")
    return "\n".join(lines)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of `palpate eval rescore` (registered by palpate.commands.evaluate)."""
    parser.add_argument("runs", type=path_arg, metavar="RUNS.jsonl", help="the runs.jsonl of a palpate eval explore")
    add_objects_arguments(parser)
    parser.add_argument("--milestone", type=float, default=80, help="coverage milestone, percent (default 80)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="gpis.KEY=VALUE",
        help="a GPIS node setting for the rebuild, on top of the run's own (YAML value), e.g. gpis.gp.R_m=2.0",
    )
    parser.add_argument("--json", action="store_true", help="print the comparison as one JSON object, last line")
    parser.add_argument("--out", type=path_arg, default=DEFAULT_OUT, help="output folder (rescored.jsonl, tables.md)")
    add_cluster_arguments(parser, runs_file="rescored.jsonl")
    parser.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    """`palpate eval rescore`: rebuild, write OUT/rescored.jsonl and OUT/tables.md, print the comparison."""
    sets = parse_sets(args.set)
    others = sorted(key for key in sets if not key.startswith("gpis."))
    if others:
        raise ConfigError(
            f"--set {others[0]}: a rescore rebuilds the GPIS estimate only; other nodes' settings change the "
            "path, which needs a new evaluation"
        )
    from palpate.nodes.explore_eval.core import milestone_key

    percent = milestone_key(args.milestone / 100)
    runs = runs_from(args.runs, given_as="RUNS.jsonl")
    strategies = list(dict.fromkeys(r["strategy"] for r in runs))
    cases = {c.name: c for c in select_cases(args.objects, scale=args.scale)}
    tasks = tasks_of(runs, cases, sets, percent, args.runs)
    if not tasks:
        held = sorted({key for r in runs for key in r.get("milestones", {})}, key=float)
        raise ConfigError(
            f"{args.runs}: no run reached the {percent} % milestone (its milestones: {', '.join(held) or 'none'}); "
            "nothing to rescore"
        )
    start = time.perf_counter()
    output_folder(args.out)
    with RunLog(args.out / "rescored.jsonl", resume=args.resume) as log:
        outcome = run_tasks(tasks, log, cluster_config(args), foreign_rows="")
    report_failures(outcome)
    rows = outcome.ordered(tasks)
    report_errors([r for r in rows if "error" in r])
    summary = comparison(runs, with_rebuilt(runs, rows, percent), strategies, percent)
    settings = overrides_under(sets.items(), "gpis.") or "their own settings"
    text = f"{len(outcome.rows)} runs of {args.runs} rebuilt at {percent} % with {settings}.\n\n"
    text += table(summary, percent) + "\n"
    (args.out / "tables.md").write_text(text)
    print(text)
    print(outcome.summary())
    print(f"wrote {args.out}: rescored.jsonl, tables.md ({time.perf_counter() - start:.0f} s)")
    if args.json:
        milestone = int(args.milestone) if float(args.milestone).is_integer() else args.milestone
        print(jsonio.dumps({"milestone": milestone, "set": sets, **summary}))
    return 1 if outcome.failed or any("error" in r for r in rows) else 0
