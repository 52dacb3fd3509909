"""`palpate bench gpis [--quick] [--json] [--contacts N ...] [--resolutions MM ...]`.

Without --resolutions: the scaling benchmark of issue 11 (``gpis_scale``: 200, 2000 and 10,000
contacts, exact and local estimators, memory and surface error). With --resolutions: the grid-step
sweep of issue 5 below, one GPIS update plus the local surface per grid step.

Per number of contacts n (default 50, 100, 200, 400, 1000; --quick: 200 only) and marching-cubes
grid step (2, 3, 4, 5 mm), the median CPU ms over the last steps of: add_contact, the local surface
without vertex variance (what IGEF needs) and with it (GP-V), and the mesh's vertex count. The GP and
the patch are the GPIS node's defaults (``GPISNodeConfig``: thin-plate kernel, +-6 cm patch; 5 mm
grid). Goal (issue 5): add_contact + local surface < 20 ms at 200 contacts at the default grid,
checked for IGEF (without vertex variance) and GP-V (with it). With --json the last line is one JSON
object with every row (wall and CPU medians), the goal check and the load average. Exit code 1 when
the goal is missed. docs/benchmarks.md holds the output: numbers belong there, not here.

Method: contacts lie on an ellipsoid with semi-axes 6 x 4 x 3 cm (a YCB-sized object); the local
surface is the planning patch around the newest contact. Each step of Algorithm 1 adds one contact
and meshes the patch around it, with the GP variance at every vertex (Eq. 6; GP-V needs it) or
without (IGEF). Timings are medians of wall-clock and of process CPU ms: with single-threaded BLAS
(palpate sets OPENBLAS_NUM_THREADS=1 at import unless the environment says otherwise; the header
says which) CPU time is the time on one core, and it is not inflated by other jobs on a busy machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from palpate import jsonio
from palpate.argtypes import non_negative_int, positive_float, positive_int
from palpate.errors import BenchmarkError
from palpate.text_table import Column, fixed_width_table

# `palpate bench` imports this module to build its parser: the GPIS node's modules (scipy,
# scikit-image) are imported where they are used
if TYPE_CHECKING:
    from palpate.nodes.gpis.core import GPISConfig

FloatArray = NDArray[np.float64]

CONTACTS = (50, 100, 200, 400, 1000)
QUICK_CONTACTS = (200,)
RESOLUTIONS_MM = (2.0, 3.0, 4.0, 5.0)
#: Timed steps per number of contacts (--quick: QUICK_REPEATS).
REPEATS = 7
QUICK_REPEATS = 3
GOAL_MS = 20.0
GOAL_CONTACTS = 200
ELLIPSOID_AXES_M = np.array([0.06, 0.04, 0.03])
#: The timed quantities of one step (keys of a row with and without the ``cpu_`` prefix, in ms).
TIMED = ("add_contact", "local_surface", "local_surface_without_variance", "vertex_variance")


# --- measuring ------------------------------------------------------------------------------------


def ellipsoid_contacts(
    n: int, rng: np.random.Generator, axes_m: FloatArray = ELLIPSOID_AXES_M
) -> tuple[FloatArray, FloatArray]:
    """n contact positions (n, 3) on the ellipsoid sum (x_i / a_i)^2 = 1 and outward unit normals (n, 3)."""
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = u * axes_m
    normal = p / axes_m**2
    return p, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def benchmark_steps(
    n_contacts: int = 200,
    *,
    resolutions_m: Sequence[float] | None = None,
    half_extent_m: float | None = None,
    config: GPISConfig | None = None,
    repeats: int = 7,
    seed: int = 0,
) -> list[dict[str, float]]:
    """Median ms of add_contact and of the local surface when the GP reaches n_contacts; one row per resolution.

    The first n_contacts - repeats contacts are added in one batch (setup, not timed); each of the last
    `repeats` contacts is then added alone (timed once, shared by every row) and, per resolution, the
    local surface around it is meshed with vertex variance, without it, and the variance at the mesh
    vertices is timed alone. Each row holds n_contacts, resolution_m, medians of wall-clock ms
    (add_contact_ms, local_surface_ms, local_surface_without_variance_ms, vertex_variance_ms, total_ms =
    add + surface, total_without_variance_ms), the same medians of process CPU ms under a ``cpu_``
    prefix, and the mesh size of the last step (n_vertices, n_faces). The grid steps and the patch
    default to the GPIS node's (one row at its default step).
    """
    from palpate.nodes.gpis.core import GPIS, GPISConfig
    from palpate.nodes.gpis.surface import LOCAL_HALF_EXTENT_M, LOCAL_RESOLUTION_M, local_surface

    resolutions_m = (LOCAL_RESOLUTION_M,) if resolutions_m is None else resolutions_m
    half_extent_m = LOCAL_HALF_EXTENT_M if half_extent_m is None else half_extent_m
    if repeats < 1 or n_contacts < repeats + 1:
        raise ValueError(f"n_contacts ({n_contacts}) must exceed repeats ({repeats}) and repeats must be >= 1")
    rng = np.random.default_rng(seed)
    P, N = ellipsoid_contacts(n_contacts, rng)
    gp = GPIS(config if config is not None else GPISConfig())
    n0 = n_contacts - repeats
    gp.add_contacts(P[:n0], N[:n0])
    add = _Times()
    per_res = [{name: _Times() for name in TIMED[1:]} for _ in resolutions_m]
    sizes = [(0, 0)] * len(resolutions_m)
    for i in range(n0, n_contacts):
        with add:
            gp.add_contact(P[i], N[i])
        for j, res in enumerate(resolutions_m):
            t = per_res[j]
            with t["local_surface"]:
                mesh = local_surface(gp, P[i], half_extent_m, res)
            with t["local_surface_without_variance"]:
                local_surface(gp, P[i], half_extent_m, res, with_variance=False)
            with t["vertex_variance"]:
                gp.variance(mesh.vertices)
            sizes[j] = (len(mesh.vertices), len(mesh.faces))
    rows = []
    for res, t, (n_vertices, n_faces) in zip(resolutions_m, per_res, sizes, strict=True):
        row = {"n_contacts": float(n_contacts), "resolution_m": float(res)}
        for prefix in ("", "cpu_"):
            for name, times in (("add_contact", add), *t.items()):
                row[f"{prefix}{name}_ms"] = times.median(cpu=prefix == "cpu_")
            add_ms = row[f"{prefix}add_contact_ms"]
            row[f"{prefix}total_ms"] = add_ms + row[f"{prefix}local_surface_ms"]
            row[f"{prefix}total_without_variance_ms"] = add_ms + row[f"{prefix}local_surface_without_variance_ms"]
        row["n_vertices"], row["n_faces"] = float(n_vertices), float(n_faces)
        rows.append(row)
    return rows


class _Times:
    """Wall-clock and process CPU milliseconds of every run of a with-block."""

    def __init__(self) -> None:
        self.wall: list[float] = []
        self.cpu: list[float] = []

    def __enter__(self) -> None:
        self.t_wall, self.t_cpu = time.perf_counter(), time.process_time()

    def __exit__(self, *exc: object) -> None:
        self.wall.append(1e3 * (time.perf_counter() - self.t_wall))
        self.cpu.append(1e3 * (time.process_time() - self.t_cpu))

    def median(self, *, cpu: bool) -> float:
        return float(np.median(self.cpu if cpu else self.wall))


# --- the command ----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench gpis` beyond the shared --quick and --json."""
    from palpate.bench.gpis_scale import EXTRA_SHAPES, SHAPES

    parser.add_argument(
        "--contacts",
        type=positive_int,
        nargs="+",
        metavar="N",
        help="numbers of contacts (default 200 2000 10000, --quick 200 2000; with --resolutions "
        f"{' '.join(map(str, CONTACTS))}, --quick {GOAL_CONTACTS})",
    )
    parser.add_argument(
        "--resolutions",
        type=positive_float,
        nargs="+",
        metavar="MM",
        help="run the grid-step sweep at these marching-cubes steps in mm "
        f"(e.g. {' '.join(f'{r:g}' for r in RESOLUTIONS_MM)})",
    )
    parser.add_argument(
        "--repeats",
        type=positive_int,
        help=f"timed steps per number of contacts (default {REPEATS}, --quick {QUICK_REPEATS})",
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the contacts on the ellipsoid")
    parser.add_argument(
        "--shapes",
        nargs="+",
        choices=(*SHAPES, *EXTRA_SHAPES),
        help="scaling benchmark: true surfaces (default ellipsoid ycb; --quick ellipsoid; box: a 1 m cube)",
    )
    parser.add_argument(
        "--estimator",
        choices=("auto", "local", "exact"),
        help="scaling benchmark: the GPIS estimator timed (default auto, the node's); the exact GP is the reference",
    )


def main(args: argparse.Namespace) -> int:
    """The scaling benchmark (``gpis_scale``), or the grid-step sweep when --resolutions is given."""
    if getattr(args, "resolutions", None):
        return grid_main(args)
    from palpate.bench import gpis_scale

    return gpis_scale.main(args)


def table(rows: Sequence[Mapping[str, float]]) -> str:
    """Plain-text table of CPU medians (ms): one line per (contacts, grid step)."""
    columns = [
        Column("contacts", 8, "n_contacts", ".0f"),
        Column("grid mm", 9, lambda r: 1e3 * r["resolution_m"], "g"),
        Column("vertices", 10, "n_vertices", ".0f"),
        Column("add", 8, "cpu_add_contact_ms", ".2f"),
        Column("surface", 10, "cpu_local_surface_without_variance_ms", ".1f"),
        Column("+variance", 11, "cpu_local_surface_ms", ".1f"),
        Column("IGEF total", 12, "cpu_total_without_variance_ms", ".1f"),
        Column("GP-V total", 12, "cpu_total_ms", ".1f"),
    ]
    return fixed_width_table(columns, rows)


def goal_check(rows: Sequence[Mapping[str, float]], resolution_m: float) -> dict[str, Any] | None:
    """The goal at GOAL_CONTACTS and the default grid step: CPU ms and pass for IGEF and GP-V; None when not run."""
    for r in rows:
        if r["n_contacts"] == GOAL_CONTACTS and abs(r["resolution_m"] - resolution_m) < 1e-9:
            igef, gpv = r["cpu_total_without_variance_ms"], r["cpu_total_ms"]
            return {
                "n_contacts": GOAL_CONTACTS,
                "resolution_m": resolution_m,
                "goal_ms": GOAL_MS,
                "igef_cpu_ms": igef,
                "gpv_cpu_ms": gpv,
                "igef_pass": igef < GOAL_MS,
                "gpv_pass": gpv < GOAL_MS,
            }
    return None


def grid_main(args: argparse.Namespace) -> int:
    """Print the table and the goal check (and with --json a last line of JSON); 1 when the goal is missed."""
    from palpate.nodes.gpis.session import GPISNodeConfig

    node = GPISNodeConfig()
    contacts = list(getattr(args, "contacts", None) or (QUICK_CONTACTS if args.quick else CONTACTS))
    resolutions_m = [1e-3 * r for r in (getattr(args, "resolutions", None) or RESOLUTIONS_MM)]
    repeats = getattr(args, "repeats", None) or (QUICK_REPEATS if args.quick else REPEATS)
    seed = int(getattr(args, "seed", 0) or 0)
    if repeats < 1 or min(contacts) <= repeats:
        raise BenchmarkError(
            f"--contacts {min(contacts)} with --repeats {repeats}: the last {repeats} contacts are timed, "
            f"so every N must exceed it; give N >= {repeats + 1}"
        )
    if min(resolutions_m) <= 0:
        raise BenchmarkError(f"--resolutions {min(resolutions_m) * 1e3:g}: grid steps must be positive (mm)")
    blas = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    load_start = os.getloadavg()[0]
    print(
        f"palpate bench gpis: {node.gp.kernel} kernel, local patch +-{1e3 * node.local_half_extent_m:g} mm, "
        f"contacts on a 12 x 8 x 6 cm ellipsoid, n = {' '.join(map(str, contacts))}, "
        f"grids {' '.join(f'{1e3 * r:g}' for r in resolutions_m)} mm, median of {repeats} steps, seed {seed}; "
        f"OPENBLAS_NUM_THREADS={blas}; {os.cpu_count()} cores, load average {load_start:.1f}",
        flush=True,
    )
    rows: list[dict[str, float]] = []
    start = time.perf_counter()
    for n in contacts:
        print(f"  {n} contacts ...", file=sys.stderr, flush=True)
        rows.extend(
            benchmark_steps(
                n,
                resolutions_m=resolutions_m,
                half_extent_m=node.local_half_extent_m,
                config=node.gp,
                repeats=repeats,
                seed=seed,
            )
        )
    load_end = os.getloadavg()[0]
    print(table(rows))
    print(
        "CPU ms (process time, medians): add = add_contact; surface = local surface without vertex "
        "variance; +variance = with it (Eq. 6 at every vertex); IGEF total = add + surface; "
        f"GP-V total = add + surface with variance. Load average at the end {load_end:.1f}."
    )
    goal = goal_check(rows, node.local_resolution_m)
    if goal is None:
        print(
            f"goal check: not run (needs n = {GOAL_CONTACTS} and the default {1e3 * node.local_resolution_m:g} mm grid)"
        )
    else:
        verdicts = [
            f"{name} {goal[key + '_cpu_ms']:.1f} ms ({'met' if goal[key + '_pass'] else 'MISSED'})"
            for name, key in (("IGEF, no vertex variance:", "igef"), ("GP-V, with vertex variance:", "gpv"))
        ]
        print(
            f"goal (update + local surface < {GOAL_MS:g} ms at {GOAL_CONTACTS} contacts, default "
            f"{1e3 * node.local_resolution_m:g} mm grid, CPU): " + "; ".join(verdicts)
        )
    passed = goal is None or (goal["igef_pass"] and goal["gpv_pass"])
    if args.json:
        out = {
            "kernel": node.gp.kernel,
            "half_extent_m": node.local_half_extent_m,
            "repeats": repeats,
            "seed": seed,
            "quick": bool(args.quick),
            "openblas_num_threads": blas,
            "load_average": [load_start, load_end],
            "seconds": time.perf_counter() - start,
            "rows": rows,
            "goal": goal,
            "pass": passed,
        }
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if passed else 1
