"""`palpate sweep slam`: the mapper's speed-accuracy trade on the Rubik's cube scene of the graph.

The sensor streams come from the graph of ``launch/slam_eval.yaml`` without its mapper nodes (sim and
noise, run in-process with lockstep semantics): per tick the joint reading (true and noisy) and the
contacts (link names and positions in the link frames, as the mapper nodes receive them). The same
stream then feeds mapper cores for every resolution and K (``run_mapper``: wall and CPU ms per
``Mapper.update``, peak memory traced from the mapper's creation to the last update), and the maps
are scored as in ``palpate eval slam`` (palpate/evaluation/slam.py). The cores model the finger of
the FastSLAM node's ``mount`` (``fastslam_chain``). Feeding the cores directly keeps the timing to
the mapper alone; through the graph the same update adds the message codec (about 0.1 ms per
message). Each resolution is one task on Dask (palpate.evaluation.dask_runs: a local cluster or
--scheduler; resumable from runs.jsonl); the stream is recorded here and travels with the tasks.
Concurrent tasks share the machine, so compare the timing columns of one run only.
"""

from __future__ import annotations

import argparse
import gc
import math
import sys
import time
import tracemalloc
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from palpate import jsonio
from palpate.argtypes import path_arg
from palpate.config import load
from palpate.errors import ConfigError
from palpate.evaluation.dask_runs import (
    RunLog,
    RunTask,
    add_arguments,
    config_from_args,
    output_folder,
    read_non_finite,
    report_failures,
    report_progress,
    run_key,
    run_tasks,
)
from palpate.evaluation.slam import (
    MIN_CELLS_ACROSS,
    SLAM_LAUNCH,
    BoxTruth,
    Scorer,
    SlamEvalConfig,
    free_margin_m,
)
from palpate.text_table import Column, fixed_width_table

FloatArray = NDArray[np.float64]

KS = (1, 10, 30, 100, 300)
RESOLUTIONS_MM = (1.0, 2.0, 4.0)
#: (resolution_mm, K) left out by --quick: K=300 at 1 mm alone takes longer than the rest together.
QUICK_SKIP = frozenset({(1.0, 300)})
DEFAULT_OUT = Path("out") / "sweep_slam"  # not eval slam's: each keeps its own runs.jsonl


@dataclass(frozen=True)
class SensorStream:
    """What the mappers receive each tick: names (J,) of the chain's joints, q_true and q_noisy
    (T, J) rad, and per tick the contact link names and positions (n_t, 3) in the link frames; plus
    the true contact points (world, all ticks) and the object's vertices."""

    q_true: FloatArray
    q_noisy: FloatArray
    contact_links: list[list[str]]
    contact_local_m: list[FloatArray]
    contact_world_m: FloatArray
    vertices_m: FloatArray


def record_stream(seed: int, duration_s: float, sigma_deg: float, launch_path: Path = SLAM_LAUNCH) -> SensorStream:
    """Run sim and noise of the evaluation graph for duration_s and keep what the mappers would read."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.runtime.inprocess import InProcessGraph

    launch = load_launch(launch_path, {"seed": seed, "duration_s": duration_s, "sigma_deg": sigma_deg})
    launch.nodes = [n for n in launch.nodes if n.fields.get("type") != "mapper"]
    true_q: dict[int, FloatArray] = {}
    noisy_q: dict[int, FloatArray] = {}
    contacts: dict[int, tuple[list[str], FloatArray, FloatArray]] = {}
    names: list[str] = []
    vertices: list[FloatArray] = []

    def listen(tick: int, node: str, topic: str, message: Any) -> None:
        if topic == "sensors/joint_states":
            names[:] = list(message.names)
            true_q[message.stamp_ns] = np.array(message.positions_rad, dtype=np.float64)
        elif topic == "sensors/joint_states_noisy":
            noisy_q[message.stamp_ns] = np.array(message.positions_rad, dtype=np.float64)
        elif topic == "sensors/contacts":
            contacts[message.stamp_ns] = (
                list(message.links),
                np.array(message.local_positions_m, dtype=np.float64).reshape(-1, 3),
                np.array(message.positions_m, dtype=np.float64).reshape(-1, 3),
            )
        elif topic == "truth/object":
            vertices.append(np.array(message.vertices_m, dtype=np.float64))

    InProcessGraph(resolve(launch).in_process_members(), listener=listen).run()
    stamps = sorted(true_q)
    if not stamps or not names or not vertices or set(stamps) - set(noisy_q):
        raise ConfigError(f"{launch_path}: the sim and noise nodes did not publish joint states and the object")
    empty: tuple[list[str], FloatArray, FloatArray] = ([], np.zeros((0, 3)), np.zeros((0, 3)))
    per_tick = [contacts.get(s, empty) for s in stamps]
    world = [c[2] for c in per_tick if len(c[2])]
    return SensorStream(
        q_true=np.array([true_q[s] for s in stamps]),
        q_noisy=np.array([noisy_q[s] for s in stamps]),
        contact_links=[c[0] for c in per_tick],
        contact_local_m=[c[1] for c in per_tick],
        contact_world_m=np.concatenate(world) if world else np.zeros((0, 3)),
        vertices_m=vertices[0],
    )


@dataclass(frozen=True)
class SweepRow:
    """One configuration's result. K = 0 for the single-map methods (known, dead_reckoning)."""

    method: str
    K: int
    resolution_mm: float
    rmse: float
    accuracy_mm: float
    completeness_mm: float
    ms_per_update: float
    cpu_ms_per_update: float
    peak_memory_mb: float

    def as_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


def _feed(mapper: Any, q_stream: FloatArray, links: Sequence[NDArray[np.intp]], local: Sequence[FloatArray]) -> None:
    for t in range(len(q_stream)):
        mapper.update(q_stream[t], links[t], local[t])


def run_mapper(
    config: Any,
    chain: Any,
    q_stream: FloatArray,
    links: Sequence[NDArray[np.intp]],
    local: Sequence[FloatArray],
    seed: int,
    measure_memory: bool,
) -> tuple[Any, float, float, float]:
    """Feed a mapper core (MapperConfig, KinematicChain) the stream q (T, J) with per tick the
    contact links (n_t,) and link-frame points (n_t, 3); returns (mapper, wall ms per update, CPU ms
    per update, peak MB or nan).

    Timing comes from a first pass without tracemalloc (which would slow numpy's many small
    allocations by half); the peak memory from a second, identical pass under tracemalloc.
    """
    from palpate.nodes.mapper.core import Mapper

    gc.collect()
    mapper = Mapper(config, chain, np.random.default_rng(seed))
    t0, c0 = time.perf_counter(), time.process_time()
    _feed(mapper, q_stream, links, local)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = np.nan
    if measure_memory:
        gc.collect()
        tracemalloc.start()
        _feed(Mapper(config, chain, np.random.default_rng(seed)), q_stream, links, local)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    n = max(1, len(q_stream))
    return mapper, 1e3 * wall / n, 1e3 * cpu / n, peak


def mapper_config(params: Mapping[str, Any], resolution_m: float, **changes: Any) -> Any:
    """The MapperConfig of the evaluation graph's FastSLAM mapper node, at another resolution."""
    from palpate.nodes.mapper.core import MapperConfig

    base = load(MapperConfig, dict(params), "mapper_fastslam.mapper")
    return replace(base, resolution_m=resolution_m, **changes)


def _fastslam_node_params(launch_path: Path, args: Mapping[str, Any]) -> dict[str, Any]:
    from palpate.launch.loader import load_launch

    launch = load_launch(launch_path, dict(args))
    node = next(n for n in launch.nodes if n.fields.get("name") == "mapper_fastslam")
    return dict(node.fields["params"])


def fastslam_params(launch_path: Path = SLAM_LAUNCH, **args: Any) -> dict[str, Any]:
    """The ``mapper`` params of the FastSLAM node of the launch file (arguments substituted)."""
    return dict(_fastslam_node_params(launch_path, args)["mapper"])


def fastslam_chain(launch_path: Path = SLAM_LAUNCH) -> Any:
    """The KinematicChain of the launch file's FastSLAM node: the hand description at its ``mount``."""
    from palpate.config import load
    from palpate.description import load_hand
    from palpate.nodes.mapper.kinematics import FingerMount, KinematicChain

    mount = load(FingerMount, _fastslam_node_params(launch_path, {}).get("mount", {}), "mapper_fastslam.mount")
    return KinematicChain.from_description(load_hand(), mount)


def sweep(
    stream: SensorStream,
    Ks: Sequence[int] = KS,
    resolutions_mm: Sequence[float] = RESOLUTIONS_MM,
    *,
    seed: int = 0,
    config: SlamEvalConfig | None = None,
    measure_memory: bool = True,
    progress: bool = True,
    skip: frozenset[tuple[float, int]] = frozenset(),
) -> list[Any]:
    """SweepRows for known pose and dead reckoning, then FastSLAM at every K,
    per resolution, scored as in palpate eval slam: ``SweepRow.rmse`` is its ``rmse`` (surface band
    intersect the cells the known-pose mapper observed), paired with its ``rmse_explored``: a list of
    (SweepRow, rmse_explored) (``rows_as_dicts`` flattens them). ``skip`` leaves out (resolution_mm, K)
    pairs."""
    config = config or SlamEvalConfig()
    chain = fastslam_chain()
    index = {name: i for i, name in enumerate(chain.link_names)}
    links = [np.array([index[n] for n in names if n in index], dtype=np.intp) for names in stream.contact_links]
    local = [
        loc[[i for i, n in enumerate(names) if n in index]].reshape(-1, 3)
        for names, loc in zip(stream.contact_links, stream.contact_local_m, strict=True)
    ]
    truth = BoxTruth.from_vertices(stream.vertices_m)
    params = fastslam_params(sigma_deg=config.sigma_deg)
    rows: list[Any] = []
    for res_mm in resolutions_mm:
        params["free_margin_m"] = free_margin_m(res_mm * 1e-3)
        known = mapper_config(params, res_mm * 1e-3, mode="known")
        runs = [("known", 0, known, stream.q_true), ("dead_reckoning", 0, known, stream.q_noisy)]
        runs += [
            ("fastslam", int(K), mapper_config(params, res_mm * 1e-3, n_particles=int(K)), stream.q_noisy)
            for K in Ks
            if (float(res_mm), int(K)) not in skip
        ]
        scorer: Scorer | None = None
        for done, (method, K, cfg, q) in enumerate(runs):
            report_progress(f"{method} K={K} ({done + 1} of {len(runs)})")  # the bar moves per resolution only
            t0 = time.perf_counter()
            mapper, ms, cpu_ms, peak = run_mapper(cfg, chain, q, links, local, seed + 1, measure_memory)
            m = mapper.best_map()
            if scorer is None:  # the known-pose run comes first: its map defines the observed cells
                scorer = Scorer(m.spec, truth, stream.contact_world_m, m.flat, config)
            score = scorer.score(m)
            row = SweepRow(
                method=method,
                K=K,
                resolution_mm=float(res_mm),
                rmse=score.rmse,
                accuracy_mm=score.accuracy_mm,
                completeness_mm=score.completeness_mm,
                ms_per_update=ms,
                cpu_ms_per_update=cpu_ms,
                peak_memory_mb=float(peak),
            )
            rows.append((row, score.rmse_explored))
            if progress:
                print(
                    f"  {res_mm:g} mm {method:<15} K={K:<4} rmse {score.rmse:.3f} explored {score.rmse_explored:.3f} "
                    f"{ms:.2f} ms/update ({time.perf_counter() - t0:.0f} s)",
                    file=sys.stderr,
                    flush=True,
                )
    return rows


def rows_as_dicts(rows: Sequence[Any]) -> list[dict[str, Any]]:
    """(SweepRow, rmse_explored) pairs as flat dicts."""
    return [{**row.as_dict(), "rmse_explored": explored} for row, explored in rows]


def format_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Fixed-width table of the sweep rows (dicts of ``rows_as_dicts``)."""
    columns = [
        Column("method", 15, "method", align="<"),
        Column("K", 5, "K"),
        Column("res_mm", 8, "resolution_mm", ".1f"),
        Column("rmse", 8, "rmse", ".3f"),
        Column("rmse_expl", 10, "rmse_explored", ".3f"),
        Column("acc_mm", 8, "accuracy_mm", ".2f"),
        Column("comp_mm", 9, "completeness_mm", ".2f"),
        Column("ms/upd", 9, "ms_per_update", ".2f"),
        Column("cpu_ms", 9, "cpu_ms_per_update", ".2f"),
        Column("peak_MB", 9, "peak_memory_mb", ".1f"),
    ]
    return fixed_width_table(columns, rows)


def plot(path: Path, rows: Sequence[Mapping[str, Any]], title: str) -> None:
    """RMSE against ms per update: one line per resolution through K, baselines as markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    colours = {1.0: "tab:blue", 2.0: "tab:orange", 4.0: "tab:green"}
    for res in sorted({float(r["resolution_mm"]) for r in rows}):
        c = colours.get(res)
        fs = sorted(
            (r for r in rows if r["method"] == "fastslam" and float(r["resolution_mm"]) == res), key=lambda r: r["K"]
        )
        if fs:
            ax.plot(
                [r["ms_per_update"] for r in fs], [r["rmse"] for r in fs], "o-", color=c, label=f"FastSLAM {res:g} mm"
            )
            for r in fs:
                ax.annotate(
                    f"K={r['K']}",
                    (r["ms_per_update"], r["rmse"]),
                    fontsize=7,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
        for method, marker in (("known", "*"), ("dead_reckoning", "x")):
            b = [r for r in rows if r["method"] == method and float(r["resolution_mm"]) == res]
            if b:
                label = f"{method.replace('_', ' ')} {res:g} mm"
                ax.plot([b[0]["ms_per_update"]], [b[0]["rmse"]], marker, color=c, markersize=10, label=label)
    ax.axvline(10.0, color="0.5", linestyle="--", linewidth=1)
    ax.text(10.0, ax.get_ylim()[1], " 100 updates/s", va="top", fontsize=8, color="0.4")
    ax.set_xscale("log")
    ax.set_xlabel("wall-clock ms per update (one core)")
    ax.set_ylabel("map RMSE (surface band, observed cells)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: Resolutions with more cells than this per map (0.2 mm over the 90 mm region) get a note on stderr.
MANY_CELLS = 50_000_000


def check_settings(Ks: Sequence[int], resolutions_mm: Sequence[float]) -> None:
    """ConfigError, before anything is recorded, for a K and resolution whose maps would not fit in this
    machine's memory (``mapper.core.check_fits``) or a value given twice."""
    from palpate.nodes.mapper.core import check_fits
    from palpate.nodes.mapper.grid import GridSpec

    for name, values in (("--particles", Ks), ("--resolutions-mm", resolutions_mm)):
        if len(set(values)) < len(values):
            raise ConfigError(f"{name} repeats a value: {list(values)}")
    params, chain = fastslam_params(), fastslam_chain()
    for r in resolutions_mm:
        config = mapper_config(params, r / 1000.0, n_particles=max(Ks))
        extent_mm = 1000.0 * min(hi - lo for lo, hi in zip(config.region_min_m, config.region_max_m, strict=True))
        if extent_mm / r < MIN_CELLS_ACROSS:
            raise ConfigError(
                f"--resolutions-mm {r:g}: cells of {r:g} mm leave fewer than {MIN_CELLS_ACROSS} across the "
                f"{extent_mm:g} mm region the maps cover; their maps cannot be scored (give at most "
                f"{extent_mm / MIN_CELLS_ACROSS:g} mm)"
            )
        check_fits(config, chain)
        cells = GridSpec.from_bounds(config.region_min_m, config.region_max_m, config.resolution_m).n_cells
        if cells > MANY_CELLS:
            print(
                f"note: --resolutions-mm {r:g} gives about {cells:,.0f} cells per map ({(1.0 / r) ** 3:,.0f} times "
                "those of 1 mm): its rows may take long, and the progress bar moves only when a resolution is "
                "done",
                file=sys.stderr,
            )


def sweep_resolution_on_worker(
    stream: SensorStream,
    Ks: Sequence[int],
    resolution_mm: float,
    seed: int,
    measure_memory: bool,
    skip: frozenset[tuple[float, int]],
) -> dict[str, Any]:
    """On a Dask worker: every method and K at one resolution (the known-pose map comes first: it
    defines the scored cells), as a runs.jsonl row; non-finite figures spelled out."""
    from palpate.evaluation.dask_runs import spell_non_finite

    rows = sweep(stream, Ks, [resolution_mm], seed=seed, measure_memory=measure_memory, progress=False, skip=skip)
    return {"resolution_mm": resolution_mm, "rows": [spell_non_finite(r) for r in rows_as_dicts(rows)]}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of `palpate sweep slam` (registered by palpate.commands.evaluate)."""
    parser.add_argument("--quick", action="store_true", help="5 s of exploration instead of 20 s, no K=300 at 1 mm")
    parser.add_argument("--json", action="store_true", help="end with one line of JSON (every row)")
    parser.add_argument(
        "--duration-s", type=float, help="simulated exploration mapped per setting (default 20, --quick 5)"
    )
    parser.add_argument("--seed", type=int, default=0, help="launch seed of the recorded run")
    parser.add_argument("--particles", default=",".join(map(str, KS)), help="comma-separated K values")
    parser.add_argument("--resolutions-mm", default=",".join(f"{r:g}" for r in RESOLUTIONS_MM), help="comma-separated")
    parser.add_argument("--no-memory", action="store_true", help="skip tracemalloc (peak memory column nan)")
    parser.add_argument(
        "--out", type=path_arg, default=DEFAULT_OUT, help="output folder (runs.jsonl, slam_sweep.json, slam_sweep.png)"
    )
    add_arguments(parser)
    parser.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from palpate.runtime import memory

    memory.keep_freed_buffers()  # as node processes do: the mappers' big temporaries reuse freed pages
    duration = args.duration_s if args.duration_s is not None else (5.0 if args.quick else 20.0)
    try:
        Ks = [int(k) for k in str(args.particles).split(",") if k]
        resolutions = [float(r) for r in str(args.resolutions_mm).split(",") if r]
    except ValueError as exc:
        raise ConfigError(f"--particles and --resolutions-mm take comma-separated numbers: {exc}") from None
    if not (duration > 0 and math.isfinite(duration)) or not Ks or not resolutions:
        raise ConfigError("need a positive --duration-s, at least one K and one resolution")
    if min(Ks) < 1 or not all(r > 0 and math.isfinite(r) for r in resolutions):
        raise ConfigError(f"--particles must be >= 1 and --resolutions-mm finite and > 0, got {Ks} and {resolutions}")
    t0 = time.perf_counter()
    check_settings(Ks, resolutions)
    print(f"palpate sweep slam: recording {duration:g} s of exploration (seed {args.seed})", file=sys.stderr)
    stream = record_stream(args.seed, duration, 1.5)
    if len(stream.contact_world_m) == 0:  # every map empty: rows of NaN
        raise ConfigError(
            f"the finger made no contact in the {duration:g} s recorded (seed {args.seed}): every map would be "
            "empty and every score undefined; give a longer --duration-s (the default is 20 s, --quick 5 s)"
        )
    skip = QUICK_SKIP if args.quick else frozenset()
    memory_too = not args.no_memory
    spec = {"duration_s": duration, "seed": args.seed, "Ks": Ks, "memory": memory_too}
    tasks = [
        RunTask(
            key=run_key(f"sweep-slam-{r:g}mm", spec),
            function=sweep_resolution_on_worker,
            args=(stream, Ks, r, args.seed, memory_too, frozenset(p for p in skip if p[0] == r)),
            label=f"{r:g} mm",
        )
        for r in resolutions
    ]
    output_folder(args.out)
    with RunLog(args.out / "runs.jsonl", resume=args.resume) as log:
        outcome = run_tasks(tasks, log, config_from_args(args), foreign_rows="")
    report_failures(outcome)
    rows = [read_non_finite(row) for done in outcome.ordered(tasks) for row in done["rows"]]
    png = args.out / "slam_sweep.png"
    plot(png, rows, f"Rubik's cube, {duration:g} s of exploration, sigma 1.5 deg (seed {args.seed})")
    jsonio.write(args.out / "slam_sweep.json", rows, indent=1)
    print(format_table(rows))
    print(outcome.summary())
    print(f"wrote {args.out / 'slam_sweep.json'} and {png} ({time.perf_counter() - t0:.0f} s)")
    if args.json:
        print(jsonio.dumps({"duration_s": duration, "seed": args.seed, "rows": rows}))
    return 1 if outcome.failed else 0
