"""The exploration benchmark of paper 002 (Sec. 3.2): episodes, one run in-process, many runs in workers.

An episode is one object, one strategy and one run index. The run index seeds everything random: the
first approach direction (uniform on the upper hemisphere, the same for every strategy, so IGEF and
GP-V are compared from the same start) and the launch seed of the graph. The probe starts at

    start = c + d (R_b + clearance),

c the centre of the object's bounding box, R_b the radius of the smallest ball about c holding the
object, d the drawn direction. The initial target (Algorithm 1 line 2, "known from the operator") is
the first hit of the ray start -> c on the true mesh, pushed ``inside_m`` further along the ray; a
ray that misses (through a hole: the torus, a cup seen from above) is drawn again. The probe starts
facing along the ray (fingertip axis = -d), as an operator would point it. Where no ray through c meets
the object (separate bodies around an empty centre: a dumbbell), the rays aim at points drawn on its
surface instead.

Every run builds the graph of ``launch/explore.yaml`` with the episode as launch arguments and runs
it with :class:`palpate.runtime.inprocess.InProcessGraph` (exactly the lockstep semantics of the
process graph; ``tests/integration/test_explore_graph.py`` checks both give the same contacts).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import suppress
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

import numpy as np
from numpy.typing import NDArray

from palpate import jsonio
from palpate.argtypes import add_scale_argument, path_arg, positive_float, positive_int
from palpate.config import load
from palpate.errors import ConfigError, LaunchError, MeshError
from palpate.evaluation.dask_runs import (
    KEY_FIELD,
    ClusterConfig,
    Outcome,
    RunLog,
    RunTask,
    SharedFile,
    file_digest,
    local_copy,
    output_folder,
    read_rows,
    report_failures,
    report_progress,
    run_key,
    run_tasks,
)
from palpate.evaluation.dask_runs import add_arguments as add_cluster_arguments
from palpate.evaluation.dask_runs import config_from_args as cluster_config
from palpate.paths import LAUNCH_DIR, MESH_SUFFIXES

if TYPE_CHECKING:
    from palpate.nodes.explore_eval.core import EvalConfig

FloatArray = NDArray[np.float64]

#: The launch file every episode runs.
EXPLORE_LAUNCH = LAUNCH_DIR / "explore.yaml"
#: Other 3-D formats: an --objects folder's files of these are named as skipped (others, a README, quietly).
OTHER_3D_SUFFIXES = (".3ds", ".3mf", ".blend", ".dae", ".dxf", ".fbx", ".igs", ".step", ".stp", ".xyz")
#: Archives and compressed files that may hold meshes; said when skipped.
ARCHIVE_SUFFIXES = (".zip", ".gz", ".bz2", ".xz", ".7z", ".tar", ".tgz", ".zst")
#: Strategies compared by default (the paper's Table 2).
DEFAULT_STRATEGIES = ("igef", "gpv")
DEFAULT_RUNS = 3  # start positions per object
#: Strategies of --quick: the paper's two and ours.
QUICK_STRATEGIES = ("igef", "gpv", "tour")


@dataclass(frozen=True, kw_only=True)
class ObjectCase:
    """An object to explore: a mesh file (``kind="mesh"``) or a built-in primitive of the sim."""

    name: str
    kind: str = "mesh"
    mesh: str = ""
    size_m: tuple[float, ...] | None = None
    #: Metres per unit of the mesh file (0.001: a file in millimetres).
    scale: float = 1.0

    def launch_args(self) -> dict[str, Any]:
        """The launch arguments of explore.yaml that select this object."""
        size_m = list(self.size_m) if self.size_m else None
        return {"object": self.kind, "mesh": self.mesh, "size_m": size_m, "scale": self.scale}

    def true_mesh(self) -> tuple[FloatArray, NDArray[np.int64]]:
        """The object's true surface as the simulation builds it: vertices (V, 3) m, faces (F, 3)."""
        from palpate.nodes.sim.objects import ObjectSpec, load_object

        spec = {"kind": self.kind, "path": self.mesh or None, "size_m": self.size_m, "scale": self.scale}
        model = load_object(load(ObjectSpec, spec, f"object {self.name!r}"))
        return np.asarray(model.mesh.vertices, dtype=np.float64), np.asarray(model.mesh.faces, dtype=np.int64)


def _subfolders_with_meshes(entries: Sequence[Path]) -> list[str]:
    """The names of the subfolders among a folder's ``entries`` that hold mesh files themselves (sorted;
    one that cannot be read is left out)."""
    found = []
    for d in entries:
        try:
            if d.is_dir() and any(p.suffix.lower() in MESH_SUFFIXES for p in d.iterdir()):
                found.append(d.name)
        except OSError:  # lost+found, another user's folder
            continue
    return sorted(found)


def _check_self_contained(path: Path) -> None:
    """ConfigError for a .gltf whose buffers or images lie in files beside it: an evaluation ships each
    mesh to its workers as one file (a .glb holds everything)."""
    if path.suffix.lower() != ".gltf":
        return
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return  # the mesh check names what is wrong with it
    parts = [*document.get("buffers", []), *document.get("images", [])] if isinstance(document, dict) else []
    beside = sorted(
        {str(p["uri"]) for p in parts if isinstance(p, dict) and "uri" in p and not str(p["uri"]).startswith("data:")}
    )
    if beside:
        raise ConfigError(
            f"{path}: a .gltf that keeps its data in files beside it ({', '.join(beside)}); an evaluation sends "
            "each mesh to its workers as one file: export it as .glb (or with embedded buffers)"
        )


def objects_in(folder: Path, scale: float = 1.0) -> list[ObjectCase]:
    """Every mesh file in ``folder`` (sorted by name) as an ObjectCase, in metres after ``scale``; a mesh
    file itself is one."""
    if folder.is_file() and folder.suffix.lower() in MESH_SUFFIXES:
        _check_self_contained(folder)
        return [ObjectCase(name=folder.stem, kind="mesh", mesh=_resolved(folder), scale=scale)]
    if not folder.exists():
        raise ConfigError(f"--objects {str(folder)!r} does not exist")
    if not folder.is_dir():
        raise ConfigError(
            f"--objects {str(folder)!r} is neither a folder nor a mesh file ({', '.join(MESH_SUFFIXES)}; see --scale)"
        )
    entries = list(folder.iterdir())
    files = sorted(p for p in entries if p.suffix.lower() in MESH_SUFFIXES)
    meshes = ", ".join(MESH_SUFFIXES)
    for suffixes, kind, advice in (
        (OTHER_3D_SUFFIXES, "file(s) of formats palpate does not read", f"convert them to one of {meshes}"),
        (
            ARCHIVE_SUFFIXES,
            "archive(s) or compressed file(s)",
            f"an evaluation reads mesh files ({meshes}): unpack them",
        ),
    ):
        if skipped := sorted(p.name for p in entries if p.suffix.lower() in suffixes):
            print(
                f"--objects {str(folder)!r}: skipped {len(skipped)} {kind}: {', '.join(skipped)}; {advice}",
                file=sys.stderr,
            )
    below = _subfolders_with_meshes(entries)
    if below and files:
        print(
            f"--objects {str(folder)!r}: its subfolders are not searched; {', '.join(below)} hold mesh files "
            "(give them as --objects too)",
            file=sys.stderr,
        )
    if not files:
        inside = f" (its subfolders {', '.join(below)} hold some: give them as --objects)" if below else ""
        raise ConfigError(f"no mesh files ({', '.join(MESH_SUFFIXES)}) in {str(folder)!r}{inside}")
    by_name: dict[str, Path] = {}
    for p in files:
        if p.stem in by_name:  # runs, tables and resumed logs know an object by its name
            raise ConfigError(
                f"{str(folder)!r} holds two meshes named {p.stem!r} ({by_name[p.stem].name} and {p.name}); "
                "rename one: an object's file name without its extension names it in the runs and tables"
            )
        by_name[p.stem] = p
        _check_self_contained(p)
    return [ObjectCase(name=p.stem, kind="mesh", mesh=_resolved(p), scale=scale) for p in files]


def _resolved(path: Path) -> str:
    """The absolute path of a mesh file; MeshError for a link that leads nowhere (a loop)."""
    try:
        return str(path.resolve(strict=True))
    except (OSError, RuntimeError) as exc:  # a symlink loop, a dangling link
        raise MeshError(f"{path}: cannot follow it to a mesh file ({exc}); point it at a file or remove it") from None


@dataclass(frozen=True)
class Approach:
    """Where a run starts: probe start (3,) m, initial target (3,) m inside the object, the unit
    direction d (3,) from the target to the start (the probe faces along -d), and how many directions
    were drawn."""

    start_m: FloatArray
    target_m: FloatArray
    direction: FloatArray
    draws: int


def approach(
    vertices: FloatArray,
    faces: NDArray[np.int64],
    run: int,
    *,
    clearance_m: float = 0.03,
    inside_m: float = 0.003,
    max_draws: int = 256,
) -> Approach:
    """The seeded start and initial target of run ``run`` on a mesh (see the module docstring)."""
    from palpate.geometry.mesh_query import MeshScene  # imported here: it loads Open3D
    from palpate.metrics.exploration import sample_surface

    V = np.asarray(vertices, dtype=np.float64)
    scene = MeshScene(V, faces)  # shifted to the bounding-box centre
    centre = scene.origin_m
    radius = float(np.linalg.norm(V - centre, axis=1).max())
    rng = np.random.default_rng(run)
    for draw in range(1, 2 * max_draws + 1):
        d = rng.standard_normal(3)
        d /= np.linalg.norm(d)
        d[2] = abs(d[2])  # upper hemisphere
        start_local = d * (radius + clearance_m)
        ray = -d
        if draw > max_draws:  # no ray through the centre met it: aim at a point of its surface
            aim = sample_surface((V - centre, faces), 1, rng)[0]
            ray = (aim - start_local) / np.linalg.norm(aim - start_local)
        t = float(scene.ray_hit_distance(start_local, ray)[0])
        if math.isfinite(t):
            target = start_local + ray * (t + inside_m)
            return Approach(start_local + centre, target + centre, -ray, draw)
    raise MeshError(f"no ray from the upper hemisphere meets the mesh in {2 * max_draws} draws (has it any face?)")


def probe_quaternion(direction: FloatArray) -> tuple[float, float, float, float]:
    """wxyz quaternion of the probe facing along -direction (its z axis pokes towards the object)."""
    from palpate.geometry.rotations import get_rotation, matrix_to_quat, quat_to_matrix

    R0 = quat_to_matrix([0.0, 1.0, 0.0, 0.0])  # the sim's default: facing -z
    q = matrix_to_quat(get_rotation(R0, direction))
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@dataclass(frozen=True, kw_only=True)
class Episode:
    """One run: object, strategy, run index (the seed), start geometry and parameter overrides.

    ``params`` are dotted overrides of node parameters, ``"node.key.subkey" -> value`` (the sweep's
    knobs), applied to the launch file after its arguments are substituted.
    """

    case: ObjectCase
    strategy: str
    run: int
    start_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]
    duration_s: float = 3600.0
    params: tuple[tuple[str, Any], ...] = ()
    results_path: str = ""
    plot_path: str = ""

    def launch_args(self) -> dict[str, Any]:
        """Launch arguments of explore.yaml for this episode."""
        return {
            **self.case.launch_args(),
            "strategy": self.strategy,
            "seed": self.run,
            "start": list(self.start_m),
            "start_quaternion": list(self.quaternion_wxyz),
            "target": list(self.target_m),
            "duration_s": self.duration_s,
            "variance": "auto",  # the GP variance at the candidates only for a planner that rates by it
            "results": self.results_path,
            "plot": self.plot_path,
        }


def overrides_under(params: Iterable[tuple[str, Any]], prefix: str) -> dict[str, Any]:
    """The dotted overrides ``"node.key" = value`` under ``prefix`` (e.g. "planner."), keyed without it."""
    return {key.removeprefix(prefix): value for key, value in params if key.startswith(prefix)}


def episodes(
    cases: Sequence[ObjectCase],
    runs: int,
    strategies: Sequence[str] = DEFAULT_STRATEGIES,
    *,
    duration_s: float = 3600.0,
    params: Mapping[str, Any] | None = None,
) -> list[Episode]:
    """Every (object, run, strategy) episode; the start geometry depends on the object and run only.

    Each run's simulated clock is at least ``duration_s`` and lets it use its travel budget (the
    evaluator's, after ``params``) at the controller's speed v0, CLOCK_PER_TRAVEL_BUDGET times over:
    the budgets, not the launch file's clock, end a run on a large object."""
    from palpate.metrics.exploration import triangle_areas
    from palpate.nodes.controller.trajectory import ControllerConfig
    from palpate.nodes.explore_eval.core import EvalConfig

    params = params or {}
    config = load(EvalConfig, overrides_under(params.items(), "eval.eval."), "eval params")
    controller = load(ControllerConfig, overrides_under(params.items(), "controller.controller."), "controller params")
    out = []
    frozen = tuple(sorted(params.items()))
    refused = []  # every bad mesh at once (one per attempt was a slow way to find them)
    for case in cases:
        try:
            vertices, faces = case.true_mesh()
        except MeshError as exc:
            refused.append(str(exc))
            continue
        area = float(triangle_areas(vertices, faces).sum())
        bound = config.covering_bound(area)
        _note_size(case.name, area, bound, config)
        clock_s = max(duration_s, CLOCK_PER_TRAVEL_BUDGET * config.travel_budget_m(bound) / controller.v0_m_s)
        try:
            starts = [approach(vertices, faces, run) for run in range(runs)]
        except MeshError as exc:
            refused.append(f"{case.mesh or case.name}: {exc}")
            continue
        for run, a in enumerate(starts):
            q = probe_quaternion(a.direction)
            for strategy in strategies:
                out.append(
                    Episode(
                        case=case,
                        strategy=strategy,
                        run=run,
                        start_m=_triple(a.start_m),
                        target_m=_triple(a.target_m),
                        quaternion_wxyz=q,
                        duration_s=clock_s,
                        params=frozen,
                    )
                )
    if len(refused) == 1:
        raise MeshError(refused[0])
    if refused:
        raise MeshError(f"{len(refused)} meshes refused:\n  " + "\n  ".join(refused))
    return out


#: A running evaluation run says how far it is at most this often (wall seconds; ``run_episode``).
PROGRESS_EVERY_S = 10.0
#: Simulated time a run may take per second of travelling its whole travel budget at the controller's
#: speed v0 (touches, turns and the controller's slower steps near a target take the rest).
CLOCK_PER_TRAVEL_BUDGET = 2.0


def _note_size(name: str, area: float, bound: float, config: EvalConfig) -> None:
    """Say on stderr when an object is so small or so large that its runs behave unlike others
    (``size_note``)."""
    from palpate.nodes.explore_eval.core import size_note

    if note := size_note(name, area, bound, config, "cap them with --max-contacts and --max-travel-m; give --scale"):
        print(f"note: {note}", file=sys.stderr)


def _triple(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def run_episode(
    episode: Episode,
    launch_path: Path = EXPLORE_LAUNCH,
    *,
    profile: bool = False,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run one episode in this process; returns the evaluator's summary plus timing and identity, and
    with ``profile`` the wall seconds of each part of the graph's ticks (``InProcessGraph(profile=True)``:
    each node's input handling and on_tick, the clock's step, message transfer) as ``node_s``.
    ``progress`` is told the contacts, coverage and travel so far, at most every PROGRESS_EVERY_S of wall time."""
    from palpate.launch.graph import resolve
    from palpate.runtime.inprocess import InProcessGraph

    t0, c0 = time.perf_counter(), time.process_time()
    graph = InProcessGraph(resolve(episode_launch(episode, launch_path)).in_process_members(), profile=profile)
    plan_s = _time_planning(graph)
    if progress is not None:
        _report_touches(graph.node("eval"), progress)
    t1 = time.perf_counter()
    ticks = graph.run()
    t2, c2 = time.perf_counter(), time.process_time()
    result: dict[str, Any] = dict(graph.node("eval").result)
    result.update(
        object=episode.case.name,
        strategy=episode.strategy,
        run=episode.run,
        ticks=ticks,
        stop_reason=graph.stop_reason,
        setup_s=t1 - t0,
        wall_s=t2 - t1,
        cpu_s=c2 - c0,
        plan_ms=1000.0 * plan_s[0] / max(1, int(result.get("contacts", 0))),
        params=dict(episode.params),
    )
    if graph.timing is not None:
        result["node_s"] = dict(sorted(graph.timing.items()))
    return result


def stopped_early(stop_reason: str) -> bool:
    """Whether a node other than the evaluator ended the run (a planner or controller that cannot go on)."""
    from palpate.nodes.explore_eval.core import FINISHED_PREFIX

    return bool(stop_reason) and not stop_reason.startswith(FINISHED_PREFIX)


def report_errors(rows: Sequence[Mapping[str, Any]]) -> None:
    """Print on stderr each run that ended with palpate's own error (its row's ``error``)."""
    for r in rows:
        print(f"run failed: {r['object']} {r['strategy']} run {r['run']}: {r['error']}", file=sys.stderr)


def report_stopped(results: Sequence[Mapping[str, Any]]) -> None:
    """Print on stderr, once per reason, the runs a node ended before the evaluator did."""
    by_reason: dict[str, list[Mapping[str, Any]]] = {}
    for r in results:
        if stopped_early(str(r.get("stop_reason") or "")):
            by_reason.setdefault(str(r["stop_reason"]), []).append(r)
    for reason, runs in by_reason.items():
        first = runs[0]
        print(
            f"{len(runs)} run(s) stopped early (first: {first['object']} {first['strategy']} run {first['run']}): "
            f"{reason}",
            file=sys.stderr,
        )


def report_short(results: Sequence[Mapping[str, Any]]) -> None:
    """Print on stderr, once per way of ending (budget, no progress, ...), the runs that ended short of
    the goal, with the coverage of the first (runs another node stopped: ``report_stopped``)."""
    by_end: dict[str, list[Mapping[str, Any]]] = {}
    for r in results:
        end = str(r.get("finished") or "")
        if "error" not in r and end not in ("", "goal", "stopped"):
            by_end.setdefault(end, []).append(r)
    for end, runs in by_end.items():
        first = runs[0]
        print(
            f"{len(runs)} run(s) ended short of the coverage goal by {end} (first: {first['object']} "
            f"{first['strategy']} run {first['run']}, {100.0 * float(first.get('coverage', 0.0)):.0f} % with "
            f"{first.get('contacts', 0)} contacts); runs.csv holds each run's end",
            file=sys.stderr,
        )


def _report_touches(evaluator: Any, progress: Callable[[str], None]) -> None:
    """Wrap the evaluator node's touch handler: after a touch, at most every PROGRESS_EVERY_S seconds,
    tell ``progress`` the contacts, the coverage and the travel so far."""
    inner = evaluator.on_touches
    last = [time.perf_counter()]

    def reported(message: Any) -> None:
        inner(message)
        now = time.perf_counter()
        touches = evaluator.run.evaluator.touches if evaluator.run is not None else []
        if touches and now - last[0] >= PROGRESS_EVERY_S:
            last[0] = now
            t = touches[-1]
            contacts = f"{len(touches)} contact" + ("s" if len(touches) != 1 else "")
            progress(f"{contacts}, {100.0 * t.coverage:.1f} % covered, {t.travel_cm / 100.0:.1f} m")

    evaluator.on_touches = reported


def _time_planning(graph: Any) -> list[float]:
    """Accumulate the CPU seconds of the per-contact work (GPIS update + local surface, planner) into
    the returned one-element list while the graph runs."""
    total = [0.0]
    for name, method in (("gpis", "on_touches"), ("planner", "on_surface")):
        node = graph.node(name)
        inner = getattr(node, method)

        def timed(message: Any, inner: Callable[[Any], None] = inner) -> None:
            start = time.process_time()
            try:
                inner(message)
            finally:
                total[0] += time.process_time() - start

        setattr(node, method, timed)
    return total


def episode_task(episode: Episode, prefix: str = "explore", profile: bool = False) -> RunTask:
    """The Dask task of one episode: its run key names object, strategy and run and digests the whole
    episode (the mesh by its SHA-256, not its path); the mesh file travels with it. ``profile`` (each
    part's wall seconds in the row, see :func:`run_episode`) leaves the key as it is."""
    mesh = episode.case.mesh
    spec = asdict(replace(episode, case=replace(episode.case, mesh=file_digest(Path(mesh)) if mesh else "")))
    if episode.case.scale == 1.0:  # the runs recorded before objects had a scale keep their keys
        del spec["case"]["scale"]
    return RunTask(
        key=run_key(f"{prefix}-{episode.case.name}-{episode.strategy}-{episode.run}", spec),
        function=run_episode_on_worker,
        args=(episode, profile),
        files=(Path(mesh),) if mesh else (),
        label=f"{episode.case.name} {episode.strategy} run {episode.run}",
    )


#: Simulated seconds of the untimed run a worker process makes before its first run (``warm_up``).
WARM_UP_S = 2.0
_warmed_up = False


def warm_up(episode: Episode) -> None:
    """Once per process: run ``episode`` for WARM_UP_S untimed, so that the imports, numba's kernels (compiled
    or loaded from their cache) and the first simulator model do not fall on the first timed run (a sweep's
    default row, run first, had 8 times the others' CPU seconds on a fresh clone)."""
    global _warmed_up
    if _warmed_up:
        return
    _warmed_up = True
    with suppress(Exception):  # the run itself says what is wrong with the episode
        run_episode(replace(episode, duration_s=WARM_UP_S, results_path="", plot_path=""))


def run_episode_on_worker(episode: Episode, profile: bool, *mesh: SharedFile) -> dict[str, Any]:
    """On a Dask worker: run the episode on the worker's copy of its mesh (``profile``: as
    :func:`run_episode`). A run that raises a PalpateError (a bad mesh, a diverged simulation) is a row
    with ``error`` set and coverage 0: it would fail the same way on any worker. So is a run that ran
    out of memory (Dask would retry it, repeating its hours on a large object)."""
    import warnings

    from palpate.errors import MeshWarning, PalpateError

    original = episode.case.mesh
    if mesh:
        episode = replace(episode, case=replace(episode.case, mesh=str(local_copy(mesh[0]))))
    try:
        with warnings.catch_warnings():
            # the main process read this file to draw the starts (episodes) and said what is odd about it
            warnings.simplefilter("ignore", MeshWarning)
            warm_up(episode)
            return run_episode(episode, profile=profile, progress=report_progress)
    except MemoryError as exc:
        return error_row(
            episode,
            f"MemoryError: the run ran out of memory ({str(exc) or 'no detail'}); cap it with --max-contacts "
            "(--set eval.eval.max_contacts=N --set eval.eval.contacts_per_bound=0 in a sweep: the budget is the "
            "larger of the two), or give each worker more memory (fewer --workers)",
        )
    except PalpateError as exc:
        message = str(exc).replace(episode.case.mesh, original) if mesh else str(exc)  # the user's file
        return error_row(episode, f"{type(exc).__name__}: {message}")


def error_row(episode: Episode, error: str) -> dict[str, Any]:
    """The row of a run that could not finish: ``error`` set, no coverage, no contacts."""
    return {
        "object": episode.case.name,
        "strategy": episode.strategy,
        "run": episode.run,
        "error": error,
        "complete": False,
        "coverage": 0.0,
        "contacts": 0,
    }


def run_episodes(
    items: Sequence[Episode],
    log: RunLog,
    cluster: ClusterConfig,
    prefix: str = "explore",
    profile: bool = False,
    **run_options: Any,
) -> tuple[list[dict[str, Any] | None], Outcome]:
    """Run the episodes not yet in ``log`` on Dask (big objects first, for the load balance). The rows
    come back in the order of ``items``, None for a run that failed for good (not in ``log``);
    ``profile``: as :func:`run_episode`; ``run_options``: :func:`run_tasks`' (``foreign_rows``)."""
    tasks = [episode_task(ep, prefix, profile) for ep in items]
    order = sorted(range(len(items)), key=lambda i: -_size_key(items[i]))
    outcome = run_tasks([tasks[i] for i in order], log, cluster, **run_options)
    return [outcome.rows.get(t.key) for t in tasks], outcome


def _size_key(ep: Episode) -> float:
    return float(np.linalg.norm(np.subtract(ep.start_m, ep.target_m)))


# --- `palpate eval explore` ---------------------------------------------------------------------------

#: Objects of --quick: the smallest meshes (by area) of the folder.
QUICK_OBJECTS = 3
#: Default output folder.
DEFAULT_OUT = Path("out/eval_explore")
#: Object of the coverage-against-travel plot when present (the paper's Fig. 7 uses the banana).
PLOT_OBJECT = "011_banana"


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of `palpate eval explore` (registered by palpate.commands.evaluate)."""
    from palpate.nodes.planner.config import Strategy

    add_objects_arguments(parser)
    parser.add_argument(
        "--runs", type=int, help=f"start positions per object (seed = run index; default {DEFAULT_RUNS}; --quick: 1)"
    )
    parser.add_argument(
        "--strategies",
        help=f"comma-separated: {', '.join(get_args(Strategy))} (default: igef,gpv; with --quick igef,gpv,tour; "
        "with --from-runs every strategy the file holds)",
    )
    parser.add_argument("--quick", action="store_true", help=f"the {QUICK_OBJECTS} smallest objects, 1 run each")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object, last line")
    parser.add_argument("--out", type=path_arg, default=DEFAULT_OUT, help="output folder (CSV, tables, plots)")
    parser.add_argument(
        "--from-runs",
        type=path_arg,
        metavar="RUNS.jsonl",
        help="no runs: remake the CSV, tables and plots from a runs.jsonl",
    )
    parser.add_argument(
        "--max-contacts",
        type=positive_int,
        help="contact budget per run (default: max(800, 2.5 x the object's covering bound))",
    )
    parser.add_argument(
        "--max-travel-m",
        type=positive_float,
        help="travel budget per run, metres (default: max(20, 0.05 x covering bound))",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NODE.KEY=VALUE",
        help="override a node parameter of launch/explore.yaml (YAML value), e.g. controller.controller.v0_m_s=0.1",
    )
    parser.add_argument(
        "--profile",
        action="store_true",
        help="time each node's part of every tick (node_s in runs.jsonl) and print their sums over the runs",
    )
    add_cluster_arguments(parser)
    parser.set_defaults(func=main)


def profile_summary(results: Sequence[Mapping[str, Any]], strategy: str | None = None) -> dict[str, float]:
    """Wall seconds of each part summed over the runs (of ``strategy``; None: all) that carry ``node_s``
    (``--profile``), largest first."""
    total: dict[str, float] = {}
    for r in results:
        if strategy is None or r.get("strategy") == strategy:
            for part, seconds in r.get("node_s", {}).items():
                total[part] = total.get(part, 0.0) + float(seconds)
    return dict(sorted(total.items(), key=lambda kv: -kv[1]))


def profile_table(results: Sequence[Mapping[str, Any]], strategies: Sequence[str]) -> str:
    """Markdown table of :func:`profile_summary`: each part's seconds over all runs, its share of their
    sum, and its seconds per strategy."""
    total = profile_summary(results)
    by = {s: profile_summary(results, s) for s in strategies}
    whole = sum(total.values()) or 1.0
    rows = [
        f"| {part} | {seconds:.1f} | {100.0 * seconds / whole:.1f} % | "
        + " | ".join(f"{by[s].get(part, 0.0):.1f}" for s in strategies)
        + " |"
        for part, seconds in total.items()
    ]
    head = "## Where the runs' time went (--profile: wall seconds per part, summed over the runs)\n\n"
    columns = "| part | s | share | " + " | ".join(f"{s} s" for s in strategies) + " |\n"
    rule = "|---|---:|---:|" + "---:|" * len(strategies) + "\n"
    return head + columns + rule + "\n".join(rows) + "\n"


def _rounded(seconds: Mapping[str, float]) -> dict[str, float]:
    return {part: round(value, 3) for part, value in seconds.items()}


def parse_sets(items: Sequence[str]) -> dict[str, Any]:
    """``["node.key=value", ...]`` -> {"node.key": value}, values parsed as YAML scalars."""
    from palpate.launch.loader import parse_node_params

    out = parse_node_params(items)
    for key in out:
        if key == "planner.strategy":
            raise ConfigError(
                "--set planner.strategy: choose the strategies with --strategies (each run's is a launch argument)"
            )
    return out


#: The evaluations' own override of every run (no per-run printing), not a user's: errors leave it out.
QUIET_RUNS: dict[str, Any] = {"eval.report": False}


def eval_params(args: argparse.Namespace) -> dict[str, Any]:
    """Node parameter overrides of an evaluation: budgets, no per-run printing, and --set."""
    params: dict[str, Any] = dict(QUIET_RUNS)
    if args.max_contacts is not None:  # a budget given is the budget, whatever the object's size
        params["eval.eval.max_contacts"] = args.max_contacts
        params["eval.eval.contacts_per_bound"] = 0.0
    if args.max_travel_m is not None:
        params["eval.eval.max_travel_m"] = args.max_travel_m
        params["eval.eval.travel_per_bound_m"] = 0.0
    params.update(parse_sets(args.set))
    return params


def runs_from(path: Path, given_as: str = "--from-runs") -> list[dict[str, Any]]:
    """The runs of a runs.jsonl file (``--from-runs``; `given_as` names the argument in errors): ConfigError
    for a line that is not a run or that repeats the object, strategy and run of an earlier line (runs made
    with other settings, left in a file that --resume went on with); a last line cut off by a kill is left
    out with a warning."""
    if not path.is_file():
        raise ConfigError(f"{given_as} {str(path)!r} is not a file; give a runs.jsonl")
    if path.suffix.lower() == ".csv":
        raise ConfigError(f"{given_as} {str(path)!r} is the runs' table; give the runs.jsonl beside it")
    seen: dict[tuple[Any, Any, Any], int] = {}
    results = []
    for number, row in read_rows(path, hint="remove the line"):
        row.pop(KEY_FIELD, None)
        if not {"object", "strategy", "run"} <= row.keys():
            raise ConfigError(f"{path}:{number} has no object, strategy and run; not a run of palpate eval explore")
        which = (row["object"], row["strategy"], row["run"])
        if which in seen:
            raise ConfigError(
                f"{path}:{number} repeats {which[0]} {which[1]} run {which[2]} of line {seen[which]} (runs of "
                "other settings?); keep one of them"
            )
        seen[which] = number
        results.append(row)
    return results


def add_objects_arguments(parser: argparse.ArgumentParser) -> None:
    """``--objects`` (what ``select_cases`` takes) and ``--scale``."""
    parser.add_argument(
        "--objects",
        type=path_arg,
        nargs="+",
        metavar="PATH",
        help="folders of mesh files, or mesh files; metres or see --scale (default: the YCB folder)",
    )
    add_scale_argument(parser)


def select_cases(paths: Sequence[Path] | None, smallest: int | None = None, scale: float = 1.0) -> list[ObjectCase]:
    """The objects of an evaluation: every mesh of the folders and every mesh file in ``paths`` (default:
    the YCB folder), in metres after ``scale``, or only the ``smallest`` ones by surface area."""
    from palpate.paths import YCB_DIR_ENV, ycb_dir, ycb_dir_looked_at

    if not paths:
        ycb = ycb_dir()
        if ycb is None:
            raise ConfigError(
                f"no --objects given and the YCB meshes are not found: {ycb_dir_looked_at()} is no folder "
                f"(give --objects DIR, or set {YCB_DIR_ENV} to the YCB folder)"
            )
        paths = [ycb]
    cases: list[ObjectCase] = []
    for path in paths:
        for case in objects_in(Path(path), scale):
            if any(case.mesh == other.mesh for other in cases):  # a file given twice, or in a folder given
                continue
            if any(case.name == other.name for other in cases):  # runs and tables know an object by its name
                raise ConfigError(f"--objects names two meshes {case.name!r} ({case.mesh}); rename one")
            cases.append(case)
    if smallest is not None:
        from palpate.nodes.sim.objects import read_mesh_file

        areas = {c.name: float(read_mesh_file(Path(c.mesh), c.scale).area) for c in cases}
        cases = sorted(cases, key=lambda c: areas[c.name])[:smallest]
    return cases


def strategies_of(args: argparse.Namespace) -> list[str]:
    """The strategies an evaluation runs: --strategies, else igef and gpv, with --quick ours too."""
    if args.strategies is not None:  # given, even empty ("--strategies $S" with S unset): it must name some
        return parse_strategies(args.strategies)
    return parse_strategies(",".join(QUICK_STRATEGIES if args.quick else DEFAULT_STRATEGIES))


def runs_of(args: argparse.Namespace, default: int = DEFAULT_RUNS) -> int:
    """--runs (else `default`), at least 1; --quick runs one start per object and takes no --runs."""
    if args.quick:
        if args.runs is not None:
            raise ConfigError(f"--quick runs one start per object; leave out --runs {args.runs}")
        return 1
    runs = default if args.runs is None else args.runs
    if runs < 1:
        raise ConfigError(f"--runs must be >= 1, got {runs}")
    return runs


def strategies_in(results: Sequence[Mapping[str, Any]], asked: str | None, path: Path) -> list[str]:
    """The strategies the tables of --from-runs hold: those asked for (each must be in the file), else
    every strategy the file holds, in the order of the planner's list."""
    from palpate.nodes.planner.config import Strategy

    held = [s for s in get_args(Strategy) if any(r["strategy"] == s for r in results)]
    if asked is None:
        if not held:
            raise ConfigError(f"--from-runs {str(path)!r} holds no run")
        return held
    strategies = parse_strategies(asked)
    if missing := [s for s in strategies if s not in held]:
        raise ConfigError(
            f"--from-runs {str(path)!r} holds no run of {', '.join(missing)}; "
            f"its strategies: {', '.join(held) or 'none'}"
        )
    return strategies


def parse_strategies(text: str) -> list[str]:
    """The comma-separated strategies of ``--strategies``; ConfigError for none, an unknown one or a
    repeat, before any run starts."""
    from palpate.nodes.planner.config import Strategy

    known = get_args(Strategy)
    strategies = [s.strip() for s in text.split(",") if s.strip()]
    if not strategies:
        raise ConfigError(f"--strategies {text!r} names no strategy; choose from {', '.join(known)}")
    for s in strategies:
        if s not in known:
            raise ConfigError(f"--strategies: unknown strategy {s!r}; choose from {', '.join(known)}")
    if len(set(strategies)) < len(strategies):
        raise ConfigError(f"--strategies {text!r} names a strategy twice")
    return strategies


def check_episodes(items: Sequence[Episode], launch_path: Path = EXPLORE_LAUNCH) -> None:
    """Validate the launch file with the parameter overrides (``--set``) of each strategy's first episode
    here, before any worker starts: a misspelt key or a bad value then fails once, naming it, instead
    of in every run. (Only the object and start differ between a strategy's episodes.)"""
    from palpate.launch.graph import resolve

    first: dict[str, Episode] = {}
    for episode in items:
        first.setdefault(episode.strategy, episode)
    with tempfile.TemporaryDirectory() as bus_dir:
        for episode in first.values():
            try:
                resolve(episode_launch(episode, launch_path), bus_dir=Path(bus_dir))
            except LaunchError as exc:
                sets = ", ".join(f"{key}={value}" for key, value in episode.params if key not in QUIET_RUNS)
                raise LaunchError(f"{exc} (strategy {episode.strategy}; parameters {sets or 'none'})") from exc


def episode_launch(episode: Episode, launch_path: Path = EXPLORE_LAUNCH) -> Any:
    """The episode's launch file, loaded with its arguments and parameter overrides (not yet resolved)."""
    from palpate.launch.loader import apply_params, load_launch

    launch = load_launch(launch_path, episode.launch_args())
    apply_params(launch, episode.params)
    return launch


def _note_from_runs(args: argparse.Namespace, out: Path) -> None:
    """Say on stderr what --from-runs leaves aside: the options of a run (it tables the file's runs as they
    are), and a runs.jsonl in --out that is not the file tabled (the tables would no longer describe it)."""
    ignored = [
        option
        for option, given in (
            ("--runs", args.runs is not None),
            ("--quick", args.quick),
            ("--objects", bool(args.objects)),
            ("--set", bool(args.set)),
            ("--max-contacts", args.max_contacts is not None),
            ("--max-travel-m", args.max_travel_m is not None),
            ("--resume", args.resume),
            ("--profile", args.profile),
        )
        if given
    ]
    if ignored:
        print(f"--from-runs tables the file's runs as they are; ignored: {', '.join(ignored)}", file=sys.stderr)
    kept = out / "runs.jsonl"
    if kept.is_file() and kept.resolve() != Path(args.from_runs).resolve():
        print(
            f"note: {kept} is not {args.from_runs}, whose runs the tables and runs.csv in {out} now describe",
            file=sys.stderr,
        )


def main(args: argparse.Namespace) -> int:
    """`palpate eval explore`: run, write CSV/JSONL/tables/plots into --out, print the tables."""
    from palpate.evaluation import explore_report as report
    from palpate.evaluation import shape_report

    strategies = strategies_of(args)
    runs = runs_of(args)
    out: Path = args.out
    start = time.perf_counter()
    outcome = None
    if args.from_runs is not None:
        results = runs_from(args.from_runs)
        cases = sorted({r["object"] for r in results})
        runs = 1 + max((int(r["run"]) for r in results), default=0)
        strategies = strategies_in(results, args.strategies, args.from_runs)
        _note_from_runs(args, out)
        output_folder(out)
    else:
        chosen = select_cases(args.objects, QUICK_OBJECTS if args.quick else None, args.scale)
        cases = [c.name for c in chosen]
        items = episodes(chosen, runs, strategies, params=eval_params(args))
        check_episodes(items)
        output_folder(out)  # once the command line holds: a refused one leaves no empty folder
        with RunLog(out / "runs.jsonl", resume=args.resume) as log:
            rows, outcome = run_episodes(items, log, cluster_config(args), profile=args.profile)
        results = [r for r in rows if r is not None]
        report_failures(outcome)
    elapsed = time.perf_counter() - start
    if not results:  # an earlier evaluation's tables and plots in the folder stay as they match its runs.jsonl
        print(f"no run finished: nothing written to {out}", file=sys.stderr)
        return 1
    report.write_csv(out / "runs.csv", results)
    baseline, method = ("gpv", "igef") if {"gpv", "igef"} <= set(strategies) else (strategies[0], strategies[-1])
    others = [s for s in strategies if s not in (baseline, method)]
    shape = shape_report.shape_summary(results, strategies)
    text = (
        f"# Exploration evaluation\n\n{len(cases)} objects x {runs} runs x {len(strategies)} strategies"
        + ("" if outcome is None else f", {elapsed / 60:.1f} min wall; {outcome.summary()}")
        + ".\n\n## Averages (Table 2)\n\n"
        + report.table2(results, baseline, method, others)
        + "\n\n## Per object (Table 4)\n\n"
        + report.table4(results, baseline, method, others)
        + "\n\n## Whole shape (F-score and Chamfer distance of the whole estimate)\n\n"
        + shape_report.shape_table(shape)
        + "\n"
    )
    (out / "tables.md").write_text(text)
    names = sorted({r["object"] for r in results})
    if names:
        report.plot_coverage_vs_travel(
            out / "coverage_vs_travel.png", results, PLOT_OBJECT if PLOT_OBJECT in names else names[0]
        )
        report.plot_travel_per_object(out / "travel_per_object.png", results, baseline, method, others)
        shape_report.plot_fscore_vs_travel(
            out / "fscore_vs_travel.png", results, PLOT_OBJECT if PLOT_OBJECT in names else names[0]
        )
    errors = [r for r in results if "error" in r]
    print(text)
    report_errors(errors)
    report_stopped(results)
    report_short(results)
    plots = "coverage_vs_travel.png, travel_per_object.png, fscore_vs_travel.png"
    made = "runs.csv" if args.from_runs is not None else "runs.csv, runs.jsonl"
    print(f"wrote {out}: {made}, tables.md, {plots}")
    profiled = profile_summary(results) if args.profile else {}
    if profiled:
        print(profile_table(results, strategies))
    if args.json:
        summary = report.summary_json(results, strategies, baseline, method, extra=shape)
        if args.profile:
            summary["node_s"] = _rounded(profiled)
            summary["node_s_by_strategy"] = {s: _rounded(profile_summary(results, s)) for s in strategies}
        print(jsonio.dumps(summary))
    return 1 if errors or (outcome is not None and outcome.failed) else 0
