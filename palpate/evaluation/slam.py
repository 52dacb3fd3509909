"""The Haptic SLAM experiment of paper 000 (Fig. 2): maps of a Rubik's cube after 10 s and 100 s.

Every seed runs the graph of ``launch/slam_eval.yaml`` with
:class:`palpate.runtime.inprocess.InProcessGraph` (the same nodes and messages as the process graph,
in lockstep order): the simulated finger explores the cube, the noise node adds 1.5 deg Gaussian
noise to each joint reading, and three mapper nodes build maps side by side from the same run:

- ``known``: occupancy-grid mapping at the true joint angles (the simulator's joint sensor);
- ``dead_reckoning``: the same mapping fed the noisy angles, no filter;
- ``fastslam``: FastSLAM with K particles on the noisy angles (its best particle's map).

The maps are taken from the OccupancyGrid messages the mappers publish (``map/known``,
``map/dead_reckoning``, ``map/fastslam``; every ``publish_period_s`` of simulated time), through the
graph's listener, at each snapshot time. Scores (docs/slam.md has the exact definitions):

- ``rmse``: ``metrics.map_rmse`` over the surface band of the cube (``metrics.surface_band``)
  restricted to the cells the finger observed at its true pose (the cells whose log-odds the
  known-pose mapper changed during the whole run of that seed): how wrong each map is where the
  finger looked, whatever it covered elsewhere (the same cells for the three maps and both times);
- ``rmse_explored``: the same RMSE over the band cells within ``explored_radius_m`` of a contact
  point the simulator reported during the run: it also charges 0.5^2 for every cell of the
  explored surface that no observation reached, so it mixes coverage with accuracy;
- ``accuracy_mm`` / ``completeness_mm``: ``metrics.surface_distances_mm``, the mean distance from
  occupied cells (belief > 0.5) to the true surface, and from the explored true surface to the
  nearest occupied cell.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray

from palpate import jsonio
from palpate.argtypes import path_arg
from palpate.config import NonEmpty, NonNegativeFloat, PositiveFloat, PositiveInt, Validated
from palpate.errors import ConfigError, PalpateError
from palpate.evaluation.dask_runs import (
    ClusterConfig,
    Outcome,
    RunLog,
    output_folder,
    read_non_finite,
    report_failures,
    spell_non_finite,
)
from palpate.evaluation.dask_runs import add_arguments as add_cluster_arguments
from palpate.evaluation.dask_runs import config_from_args as cluster_config
from palpate.evaluation.dask_runs import describe as describe_cluster
from palpate.paths import LAUNCH_DIR
from palpate.text_table import Column, fixed_width_table

FloatArray = NDArray[np.float64]

#: The launch file every seed runs.
SLAM_LAUNCH = LAUNCH_DIR / "slam_eval.yaml"
#: Methods in table order, with the topic their map arrives on and the mapper node that makes it.
METHODS = ("known", "fastslam", "dead_reckoning")
MAP_TOPICS = {"map/known": "known", "map/fastslam": "fastslam", "map/dead_reckoning": "dead_reckoning"}
MAPPER_NODES = {"known": "mapper_known", "fastslam": "mapper_fastslam", "dead_reckoning": "mapper_dead_reckoning"}
DEFAULT_OUT = Path("out") / "slam"
#: A map needs at least this many cells across its region to have a surface to score.
MIN_CELLS_ACROSS = 4


def free_margin_m(resolution_m: float) -> float | None:
    """The free margin measured on this grid for cells of ``resolution_m``, metres (the mapper's
    MEASURED_FREE_MARGIN_MM: the cube's faces lie 0.5 mm inside their cells at 1 and 2 mm, 2.5 mm at
    4 mm, and at 1 mm the finger's press needs 1.5 mm; docs/slam.md); None (the mapper's one cell) for a
    resolution not measured."""
    from palpate.nodes.mapper.core import measured_free_margin_m

    return measured_free_margin_m(resolution_m)


#: How to set each launch argument of slam_eval.yaml that the evaluation sets itself
#: (SlamEvalConfig.own_arguments; a test checks that the keys agree) instead of with --arg.
OWN_ARGUMENT_HINTS = {
    "seed": "each run's seed (--seeds N runs seeds 0 to N-1)",
    "duration_s": "the last snapshot time (--snapshots-s)",
    "sigma_deg": "--sigma-deg",
    "particles": "--particles",
    "resolution_m": "--resolution-mm",
    "publish_period_s": "derived from the snapshot times",
}


@dataclass(frozen=True, kw_only=True)
class SlamEvalConfig(Validated):
    """One evaluation: seeds, snapshot times and the mapper settings (launch arguments)."""

    seeds: Annotated[tuple[int, ...], NonEmpty] = (0, 1, 2, 3, 4)
    #: Simulated exploration times at which the maps are scored (the paper's 10 s and 100 s).
    snapshot_s: Annotated[tuple[PositiveFloat, ...], NonEmpty] = (10.0, 100.0)
    sigma_deg: NonNegativeFloat = 1.5
    n_particles: PositiveInt = 100
    resolution_m: PositiveFloat = 0.002
    #: Free band outside the surface that the RMSE scores (metrics.surface_band).
    band_m: PositiveFloat = 0.004
    #: A band cell counts as explored when a true contact lies within this distance of its centre.
    explored_radius_m: PositiveFloat = 0.010
    #: Spacing of the true-surface samples of the completeness figure.
    surface_spacing_m: PositiveFloat = 0.001
    #: Extra launch arguments of launch/slam_eval.yaml (name -> value).
    launch_args: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        super().__post_init__()
        own = sorted(set(self.launch_args) & set(self.own_arguments(0)))
        if own:
            raise ConfigError(
                f"launch_args (--arg) {', '.join(own)}: the evaluation sets these launch arguments itself; "
                + "; ".join(f"{k} is {OWN_ARGUMENT_HINTS.get(k, 'set by the evaluation')}" for k in own)
            )

    @property
    def duration_s(self) -> float:
        return max(self.snapshot_s)

    def publish_period_s(self) -> float:
        """A publish period of the mappers that lands on every snapshot time (their GCD, 10 ms steps)."""
        ticks = [round(t * 100) for t in self.snapshot_s]
        return math.gcd(*ticks) / 100.0

    def own_arguments(self, seed: int) -> dict[str, Any]:
        """The launch arguments of slam_eval.yaml that the evaluation sets itself, for one seed."""
        return {
            "seed": seed,
            "duration_s": self.duration_s,
            "sigma_deg": self.sigma_deg,
            "particles": self.n_particles,
            "resolution_m": self.resolution_m,
            "publish_period_s": self.publish_period_s(),
        }

    def arguments(self, seed: int) -> dict[str, Any]:
        """Launch arguments of slam_eval.yaml for one seed: the evaluation's own, the free margin measured
        for its resolution (``free_margin_m``; --arg free_margin_m=... sets another), and ``launch_args``."""
        margin = {"free_margin_m": free_margin_m(self.resolution_m)}
        return {**self.own_arguments(seed), **margin, **self.launch_args}


# --- ground truth ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BoxTruth:
    """An axis-aligned box object: centre (3,) and half extents (3,), metres (world frame)."""

    center_m: FloatArray
    half_m: FloatArray

    @classmethod
    def from_vertices(cls, vertices_m: FloatArray, tolerance_m: float = 1e-6) -> BoxTruth:
        """The box whose mesh vertices (V, 3) are given; ConfigError if they are not an axis-aligned box."""
        v = np.asarray(vertices_m, dtype=np.float64).reshape(-1, 3)
        lo, hi = v.min(axis=0), v.max(axis=0)
        on_bounds = (np.abs(v - lo) <= tolerance_m) | (np.abs(v - hi) <= tolerance_m)
        if len(v) < 8 or not on_bounds.all():
            raise ConfigError(
                "the SLAM evaluation scores axis-aligned boxes (cube, rubiks_cube, box) only; "
                f"the object's {len(v)} vertices are not the corners of one"
            )
        return cls(center_m=(lo + hi) / 2, half_m=(hi - lo) / 2)

    def sdf(self, points_m: FloatArray) -> FloatArray:
        from palpate.nodes.mapper.metrics import box_sdf

        return box_sdf(points_m, self.center_m, self.half_m)

    def surface_points(self, spacing_m: float) -> FloatArray:
        from palpate.nodes.mapper.metrics import box_surface_points

        return box_surface_points(self.center_m, self.half_m, spacing_m)


# --- one seed through the graph -------------------------------------------------------------------
class Capture:
    """Graph listener: the maps at the snapshot stamps, every true contact point, the object."""

    def __init__(self, snapshot_ns: Iterable[int]) -> None:
        self.snapshot_ns = set(snapshot_ns)
        self.maps: dict[tuple[str, int], Any] = {}  # (method, stamp_ns) -> OccupancyGrid
        self.contacts: list[FloatArray] = []
        self.vertices_m: FloatArray | None = None
        self.n_messages = 0

    def __call__(self, tick: int, node: str, topic: str, message: Any) -> None:
        self.n_messages += 1
        method = MAP_TOPICS.get(topic)
        if method is not None:
            if message.stamp_ns in self.snapshot_ns:
                self.maps[(method, int(message.stamp_ns))] = message
        elif topic == "sensors/contacts":
            if len(message.positions_m):
                self.contacts.append(np.array(message.positions_m, dtype=np.float64))
        elif topic == "truth/object":
            self.vertices_m = np.array(message.vertices_m, dtype=np.float64)

    def contact_points(self) -> FloatArray:
        return np.concatenate(self.contacts) if self.contacts else np.zeros((0, 3))


def sparse_map(message: Any) -> Any:
    """The SparseMap carried by an OccupancyGrid message."""
    from palpate.nodes.mapper.grid import GridSpec, SparseMap

    shape = tuple(int(n) for n in message.shape)
    origin = tuple(float(x) for x in message.origin_m)
    spec = GridSpec(origin_m=origin, resolution_m=float(message.resolution_m), shape=shape)  # type: ignore[arg-type]
    return SparseMap(
        spec=spec,
        flat=np.asarray(message.cell_indices, dtype=np.int64),
        log_odds=np.asarray(message.log_odds, dtype=np.float32),
    )


@dataclass(frozen=True)
class MapScore:
    """Scores of one map (see the module docstring)."""

    rmse: float
    rmse_explored: float
    accuracy_mm: float
    completeness_mm: float
    occupied_cells: int


def explored_mask(contacts_m: FloatArray, radius_m: float) -> Callable[[FloatArray], NDArray[np.bool_]]:
    """Centres (n, 3) -> (n,) True within radius_m of a contact point (m, 3)."""
    from scipy.spatial import cKDTree

    if len(contacts_m) == 0:
        return lambda p: np.zeros(len(p), dtype=np.bool_)
    tree = cKDTree(contacts_m)

    def mask(p: FloatArray) -> NDArray[np.bool_]:
        d, _ = tree.query(p, distance_upper_bound=radius_m)
        return np.asarray(np.isfinite(d))

    return mask


class Scorer:
    """Scores maps of one seed: the explored band, the observed band and the surface samples."""

    def __init__(
        self,
        spec: Any,
        truth: BoxTruth,
        contacts_m: FloatArray,
        observed_flat: NDArray[np.int64],
        config: SlamEvalConfig,
    ):
        from palpate.nodes.mapper.metrics import surface_band

        self.truth = truth
        mask = explored_mask(contacts_m, config.explored_radius_m)
        self.region, self.region_truth = surface_band(spec, truth.sdf, config.band_m, mask=mask)
        band, band_truth = surface_band(spec, truth.sdf, config.band_m)
        seen = np.isin(band, observed_flat)
        self.observed, self.observed_truth = band[seen], band_truth[seen]
        surface = truth.surface_points(config.surface_spacing_m)
        self.surface = surface[mask(surface)]

    def score(self, m: Any) -> MapScore:
        from palpate.nodes.mapper.metrics import map_rmse, surface_distances_mm

        accuracy, completeness = surface_distances_mm(m, self.truth.sdf, self.surface)
        return MapScore(
            rmse=map_rmse(m, self.observed, self.observed_truth),
            rmse_explored=map_rmse(m, self.region, self.region_truth),
            accuracy_mm=accuracy,
            completeness_mm=completeness,
            occupied_cells=int(np.count_nonzero(m.log_odds > 0)),
        )


def run_seed(
    seed: int, config: SlamEvalConfig, launch_path: Path = SLAM_LAUNCH, keep_maps: bool = False
) -> dict[str, Any]:
    """Run one seed through the graph; returns rows (one per method and snapshot), timing and,
    with ``keep_maps``, the last snapshot's maps and the truth for plotting."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.runtime import memory
    from palpate.runtime.inprocess import InProcessGraph

    memory.keep_freed_buffers()  # as node processes do: the mappers' big temporaries reuse freed pages
    stamps = {round(t * 1e9): t for t in config.snapshot_s}
    capture = Capture(stamps)
    t0, c0 = time.perf_counter(), time.process_time()
    graph = InProcessGraph(
        resolve(load_launch(launch_path, config.arguments(seed))).in_process_members(), listener=capture
    )
    t1 = time.perf_counter()
    ticks = graph.run()
    t2, c2 = time.perf_counter(), time.process_time()
    if capture.vertices_m is None:
        raise ConfigError(f"{launch_path}: the sim published no truth/object; the evaluation needs the object")
    truth = BoxTruth.from_vertices(capture.vertices_m)
    last_ns = round(config.duration_s * 1e9)
    missing = [(m, stamps[s]) for m in METHODS for s in stamps if (m, s) not in capture.maps]
    if missing:
        raise ConfigError(
            f"no map from {missing} (ran {ticks} ticks): the mappers' publish_period_s must land on every "
            "snapshot time and the run must last until the last one"
        )
    maps = {key: sparse_map(msg) for key, msg in capture.maps.items()}
    known_final = maps[("known", last_ns)]
    if any(m.spec != known_final.spec for m in maps.values()):
        raise ConfigError(f"{launch_path}: the three mappers must map the same grid (region and resolution)")
    scorer = Scorer(known_final.spec, truth, capture.contact_points(), known_final.flat, config)
    rows = []
    for (method, stamp), m in sorted(maps.items(), key=lambda kv: (METHODS.index(kv[0][0]), kv[0][1])):
        rows.append({"seed": seed, "method": method, "time_s": stamps[stamp], **asdict(scorer.score(m))})
    timing: dict[str, Any] = {
        "seed": seed,
        "ticks": ticks,
        "setup_s": t1 - t0,
        "wall_s": t2 - t1,
        "cpu_s": c2 - c0,
        "ms_per_tick": 1e3 * (t2 - t1) / max(1, ticks),
        "contacts": len(capture.contact_points()),
    }
    for method, node in MAPPER_NODES.items():
        counters = graph.node(node).core.counters
        timing[f"ms_per_update_{method}"] = counters.mean_update_ms
        timing[f"updates_{method}"] = counters.updates
    timing["resamples_fastslam"] = graph.node(MAPPER_NODES["fastslam"]).core.counters.resamples
    result: dict[str, Any] = {"rows": rows, "timing": timing}
    if keep_maps:
        result["maps"] = {method: maps[(method, last_ns)] for method in METHODS}
        result["truth"] = truth
        result["surface"] = scorer.surface
    return result


# --- aggregation (pure) -----------------------------------------------------------------------------
SCORE_KEYS = ("rmse", "rmse_explored", "accuracy_mm", "completeness_mm", "occupied_cells")


def aggregate(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Mean and standard deviation over seeds of every score, per (method, time_s).

    Rows come out in METHODS order (unknown methods after, by name), then by time. ``n`` counts the
    seeds; the standard deviation is the sample one (ddof 1; 0 for one seed). Non-finite scores (an
    empty map's distances are inf) propagate to the mean.
    """
    groups: dict[tuple[str, float], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault((str(row["method"]), float(row["time_s"])), []).append(row)

    def order(key: tuple[str, float]) -> tuple[int, str, float]:
        method, t = key
        return (METHODS.index(method) if method in METHODS else len(METHODS), method, t)

    out = []
    for key in sorted(groups, key=order):
        members = groups[key]
        summary: dict[str, Any] = {"method": key[0], "time_s": key[1], "n": len(members)}
        for k in SCORE_KEYS:
            values = np.array([float(r[k]) for r in members], dtype=np.float64)
            summary[k] = float(np.mean(values))
            with np.errstate(invalid="ignore"):  # inf - inf: the std of an infinite score is nan
                summary[f"{k}_std"] = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
        out.append(summary)
    return out


def summary_json(summary: Sequence[Mapping[str, Any]], timing: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The --json object: ``rmse_<method>`` at the last snapshot time (mean over seeds), the other
    scores as ``<score>_<method>_<t>s``, the ordering checks and the timing means."""
    if not summary:
        raise ConfigError("no results to summarise")
    last = max(float(s["time_s"]) for s in summary)
    out: dict[str, Any] = {}
    for s in summary:
        t = f"{float(s['time_s']):g}s"
        for k in ("rmse", "rmse_explored", "accuracy_mm", "completeness_mm"):
            out[f"{k}_{s['method']}_{t}"] = round(float(s[k]), 4)
        if float(s["time_s"]) == last:
            out[f"rmse_{s['method']}"] = round(float(s["rmse"]), 4)
    if all(f"rmse_{m}" in out for m in METHODS):
        out["fastslam_beats_dead_reckoning"] = bool(out["rmse_fastslam"] < out["rmse_dead_reckoning"])
        out["known_best"] = bool(out["rmse_known"] <= min(out["rmse_fastslam"], out["rmse_dead_reckoning"]))
    out["seeds"] = sorted({int(t["seed"]) for t in timing})
    out["time_s"] = last
    for key in (
        "ms_per_tick",
        "ms_per_update_known",
        "ms_per_update_dead_reckoning",
        "ms_per_update_fastslam",
        "wall_s",
    ):
        values = [float(t[key]) for t in timing if key in t]
        if values:
            out[key] = round(float(np.mean(values)), 3)
    return out


def format_table(summary: Sequence[Mapping[str, Any]]) -> str:
    """Fixed-width table: one line per method and snapshot time, mean +- std over seeds."""
    columns = [
        Column("method", 16, "method", align="<"),
        Column("t_s", 6, lambda s: float(s["time_s"]), "g"),
        Column("seeds", 6, lambda s: int(s["n"])),
        Column("rmse", 16, lambda s: _pm(s, "rmse", 3)),
        Column("rmse_explored", 16, lambda s: _pm(s, "rmse_explored", 3)),
        Column("accuracy_mm", 16, lambda s: _pm(s, "accuracy_mm", 2)),
        Column("completeness_mm", 18, lambda s: _pm(s, "completeness_mm", 2)),
        Column("occupied", 10, lambda s: float(s["occupied_cells"]), ".0f"),
    ]
    return fixed_width_table(columns, summary)


def _pm(s: Mapping[str, Any], key: str, digits: int) -> str:
    return f"{float(s[key]):.{digits}f} +- {float(s[key + '_std']):.{digits}f}"


# --- figure -------------------------------------------------------------------------------------------
def plot_maps(path: Path, maps: Mapping[str, Any], truth: BoxTruth, surface_m: FloatArray, title: str) -> None:
    """Four 3D panels: the true cube (explored surface highlighted) and the occupied cell centres of
    each map (belief > 0.5), coloured by belief, zoomed onto the explored surface (m, 3)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(16, 4.6))
    cube_lo, cube_hi = truth.center_m - truth.half_m, truth.center_m + truth.half_m
    # the map panels zoom onto the explored surface (the finger reaches a few faces only)
    zoom_lo = surface_m.min(axis=0) if len(surface_m) else cube_lo
    zoom_hi = surface_m.max(axis=0) if len(surface_m) else cube_hi
    margin = 0.004
    panels: list[tuple[str, FloatArray, FloatArray | None]] = []
    cube = truth.surface_points(0.004)
    panels.append(("true cube (explored surface in red)", cube, None))
    for method in METHODS:
        m = maps[method]
        occ = m.log_odds > 0
        centres = m.spec.centers(m.flat[occ])
        panels.append((f"{method.replace('_', ' ')}: {int(occ.sum())} occupied cells", centres, m.belief()[occ]))
    for i, (name, pts, colour) in enumerate(panels):
        ax = fig.add_subplot(1, 4, i + 1, projection="3d")
        if colour is None:
            ax.scatter(*pts.T * 1e3, s=1, c="0.7", depthshade=False)
            ax.scatter(*surface_m.T * 1e3, s=1, c="tab:red", depthshade=False)
        else:
            ax.scatter(*pts.T * 1e3, s=3, c=colour, cmap="viridis", vmin=0.5, vmax=1.0, depthshade=False)
        lo, hi = (cube_lo, cube_hi) if colour is None else (zoom_lo, zoom_hi)
        ax.set_xlim((lo[0] - margin) * 1e3, (hi[0] + margin) * 1e3)
        ax.set_ylim((lo[1] - margin) * 1e3, (hi[1] + margin) * 1e3)
        ax.set_zlim((lo[2] - margin) * 1e3, (hi[2] + margin) * 1e3)
        ax.set_xlabel("x mm", fontsize=8)
        ax.set_ylabel("y mm", fontsize=8)
        ax.set_zlabel("z mm", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.view_init(elev=25, azim=55)  # from +x, +y, above: the faces the finger reaches
        ax.set_title(name, fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- runner ---------------------------------------------------------------------------------------------
def run_seed_on_worker(seed: int, config: SlamEvalConfig, keep_maps: bool) -> dict[str, Any]:
    """On a Dask worker: one seed as a runs.jsonl row. Non-finite figures (an empty map's distances
    are inf) are spelled out (dask_runs.spell_non_finite; aggregate's float() reads them back); the maps of
    ``keep_maps`` travel back in ``_maps``, ``_truth`` and ``_surface`` (not written). palpate's own error
    (or running out of memory) is the row's ``error``: the seed would fail the same way on a retry."""
    try:
        result = run_seed(seed, config, keep_maps=keep_maps)
    except MemoryError as exc:
        return {
            "seed": seed,
            "error": f"MemoryError: the run ran out of memory ({str(exc) or 'no detail'}); fewer --particles, a "
            "coarser --resolution-mm, or fewer --workers give each run more",
        }
    except PalpateError as exc:
        return {"seed": seed, "error": f"{type(exc).__name__}: {exc}"}
    row: dict[str, Any] = {
        "seed": seed,
        "rows": [spell_non_finite(r) for r in result["rows"]],
        "timing": spell_non_finite(result["timing"]),
    }
    for key in ("maps", "truth", "surface"):
        if key in result:
            row["_" + key] = result[key]
    return row


def run_seeds(
    config: SlamEvalConfig, log: RunLog, cluster: ClusterConfig, plot_seed: int | None = None
) -> tuple[list[dict[str, Any]], Outcome]:
    """Every seed of ``config`` not yet in ``log`` as a task on Dask; the finished seeds in seed order
    ({"seed", "rows", "timing"} and, for ``plot_seed`` when it ran now, "_maps", "_truth", "_surface")."""
    from palpate.evaluation.dask_runs import RunTask, run_key, run_tasks

    spec = {k: v for k, v in asdict(config).items() if k != "seeds"}
    tasks = [
        RunTask(
            key=run_key(f"slam-seed{seed}", {"seed": seed, **spec, "arguments": config.arguments(seed)}),
            function=run_seed_on_worker,
            args=(seed, config, seed == plot_seed),
            label=f"seed {seed}",
        )
        for seed in config.seeds
    ]
    outcome = run_tasks(tasks, log, cluster, foreign_rows="")
    results = []
    for r in outcome.ordered(tasks):
        if "error" in r:
            results.append(r)
            continue
        results.append(
            {
                **r,
                "rows": [read_non_finite(row) for row in r["rows"]],
                "timing": read_non_finite(r["timing"]),
            }
        )
    return results, outcome


QUICK_SEEDS = 2
FULL_SEEDS = 5


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of `palpate eval slam` (registered by palpate.commands.evaluate)."""
    parser.add_argument(
        "--quick", action="store_true", help=f"{QUICK_SEEDS} seeds (still 10 s and 100 s of exploration)"
    )
    parser.add_argument(
        "--json", action="store_true", help="end with one line of JSON (rmse_known, rmse_fastslam, ...)"
    )
    parser.add_argument(
        "--seeds", type=int, help=f"number of seeds 0..N-1 (default {FULL_SEEDS}, --quick {QUICK_SEEDS})"
    )
    parser.add_argument("--out", type=path_arg, default=DEFAULT_OUT, help="output folder (rows CSV, summary JSON, PNG)")
    parser.add_argument("--particles", type=int, default=100, help="FastSLAM particles K")
    parser.add_argument("--resolution-mm", type=float, default=2.0, help="grid resolution, mm")
    parser.add_argument("--sigma-deg", type=float, default=1.5, help="joint noise standard deviation, degrees")
    parser.add_argument(
        "--snapshots-s",
        type=_snapshot_times,
        default=SlamEvalConfig.snapshot_s,
        metavar="T1,T2",
        help="simulated exploration times at which the maps are scored; the last is each run's length "
        "(default 10,100, the paper's)",
    )
    parser.add_argument(
        "--arg",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="launch argument of launch/slam_eval.yaml (YAML value), e.g. free_reward=true or free_margin_m=null",
    )
    add_cluster_arguments(parser)
    parser.set_defaults(func=main)


def _snapshot_times(text: str) -> tuple[float, ...]:
    """``--snapshots-s``: comma-separated positive times, seconds, in increasing order."""
    try:
        times = tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of seconds such as 10,100") from None
    if not times or not all(math.isfinite(t) and t > 0 for t in times) or list(times) != sorted(set(times)):
        raise argparse.ArgumentTypeError(f"{text!r}: give increasing positive seconds, such as 10,100")
    if any(abs(t * 100 - round(t * 100)) > 1e-6 for t in times):  # maps go out at ticks only
        raise argparse.ArgumentTypeError(f"{text!r}: give multiples of the 10 ms tick, such as 0.5,2")
    return times


def main(args: argparse.Namespace) -> int:
    from palpate.launch.loader import parse_cli_args

    n = args.seeds if args.seeds is not None else (QUICK_SEEDS if args.quick else FULL_SEEDS)
    if n < 1:
        raise ConfigError(f"--seeds must be at least 1, got {n}")
    config = SlamEvalConfig(
        seeds=tuple(range(n)),
        n_particles=args.particles,
        resolution_m=args.resolution_mm * 1e-3,
        sigma_deg=args.sigma_deg,
        snapshot_s=args.snapshots_s,
        launch_args=parse_cli_args(args.arg, separator="=", option="--arg"),
    )
    check_launch(config)
    t0 = time.perf_counter()
    cluster = cluster_config(args)
    print(
        f"palpate eval slam: {n} seed(s), {config.duration_s:g} s of exploration each, K={config.n_particles}, "
        f"{args.resolution_mm:g} mm, sigma {config.sigma_deg:g} deg, {describe_cluster(cluster)}"
        + "".join(f", {k}={v}" for k, v in config.launch_args.items()),
        file=sys.stderr,
    )
    output_folder(args.out)
    with RunLog(args.out / "runs.jsonl", resume=args.resume) as log:
        finished, outcome = run_seeds(config, log, cluster, plot_seed=config.seeds[0])
    report_failures(outcome)
    errors = [r for r in finished if "error" in r]
    for r in errors:
        print(f"run failed: seed {r['seed']}: {r['error']}", file=sys.stderr)
    results = [r for r in finished if "error" not in r]
    if not results:
        print(outcome.summary(), file=sys.stderr)
        return 1
    rows = [row for r in results for row in r["rows"]]
    timing = [r["timing"] for r in results]
    summary = aggregate(rows)
    out = summary_json(summary, timing)
    out["total_wall_s"] = round(time.perf_counter() - t0, 1)
    _write_csv(args.out / "slam_rows.csv", rows)
    png = args.out / "slam_maps.png"
    plotted = results[0]
    written = [args.out / "slam_rows.csv", args.out / "slam_summary.json"]
    if "_maps" in plotted:
        written.append(png)
        plot_maps(
            png,
            plotted["_maps"],
            plotted["_truth"],
            plotted["_surface"],
            f"Rubik's cube after {config.duration_s:g} s of exploration (seed {config.seeds[0]}, "
            f"K={config.n_particles}, {args.resolution_mm:g} mm cells, sigma {config.sigma_deg:g} deg)",
        )
    else:
        why = "failed" if plotted["seed"] != config.seeds[0] else "was resumed from runs.jsonl"
        print(f"{png} not redrawn: seed {config.seeds[0]} {why}", file=sys.stderr)
    jsonio.write(args.out / "slam_summary.json", {"summary": summary, "timing": timing, **out}, indent=1)
    print(format_table(summary))
    print()
    for t in timing:
        print(
            f"seed {t['seed']}: {t['ticks']} ticks, {t['ms_per_tick']:.2f} ms/tick, mapper ms/update known "
            f"{t['ms_per_update_known']:.2f}, dead reckoning {t['ms_per_update_dead_reckoning']:.2f}, FastSLAM "
            f"{t['ms_per_update_fastslam']:.2f} ({t['resamples_fastslam']} resamples), {t['contacts']} contacts"
        )
    print(outcome.summary())
    print(f"wrote {', '.join(map(str, written))} ({out['total_wall_s']:.0f} s)")
    if args.json:
        print(jsonio.dumps(out))
    return 1 if outcome.failed or errors else 0


def check_launch(config: SlamEvalConfig, launch_path: Path = SLAM_LAUNCH) -> None:
    """The launch file with the first seed's arguments, resolved here before any worker starts: an unknown
    or bad --arg fails once, naming it, instead of in every run (LaunchError); and ConfigError for a
    mapper that would not fit in memory, cells so coarse that a map has fewer than MIN_CELLS_ACROSS
    across its region, or that the finger's free volume holds no point (nothing to score)."""
    from palpate.description import load_hand
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.nodes.mapper.core import check_fits
    from palpate.nodes.mapper.kinematics import KinematicChain
    from palpate.nodes.mapper.node import MapperNodeConfig
    from palpate.nodes.mapper.observation import capsule_lattice

    graph = resolve(load_launch(launch_path, config.arguments(config.seeds[0])))
    for node in graph.nodes:
        if not isinstance(node.config, MapperNodeConfig):
            continue
        mapper = node.config.mapper
        chain = KinematicChain.from_description(load_hand(), node.config.mount)
        check_fits(mapper, chain)  # as sweep slam does
        extent_m = min(hi - lo for lo, hi in zip(mapper.region_min_m, mapper.region_max_m, strict=True))
        if extent_m / mapper.resolution_m < MIN_CELLS_ACROSS:
            raise ConfigError(
                f"--resolution-mm {mapper.resolution_m * 1e3:g}: cells of that size leave fewer than "
                f"{MIN_CELLS_ACROSS} across the {extent_m * 1e3:g} mm region the maps cover; their maps cannot "
                f"be scored (give at most {extent_m * 1e3 / MIN_CELLS_ACROSS:g} mm)"
            )
        spacing, margin = mapper.free_lattice()
        if capsule_lattice(chain, spacing, margin).n_points == 0:  # every map scores rmse 0: nothing to compare
            raise ConfigError(
                f"--resolution-mm {mapper.resolution_m * 1e3:g}: the finger holds no free-volume point at cells of "
                f"that size (lattice spacing {spacing * 1e3:g} mm, {margin * 1e3:g} mm deep), so the maps learn "
                "from contacts only and every map's rmse is 0 (its observed cells are contact cells); give finer "
                "cells, or --arg free_spacing_m / free_margin_m"
            )


def _write_csv(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    import csv

    if not rows:
        return
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
