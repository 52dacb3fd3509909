"""`palpate bench gpis [--quick] [--json] [--contacts N ...]`: one GPIS update plus the local surface.

A thin wrapper around ``palpate.nodes.gpis.bench`` (method in its docstring). Per number of contacts
n (default 50, 100, 200, 400, 1000; --quick: 200 only) and marching-cubes grid step (2, 3, 4, 5 mm),
the median CPU ms over the last steps of: add_contact, the local surface without vertex variance
(what IGEF needs) and with it (GP-V), and the mesh's vertex count. The GP and the patch are the GPIS
node's defaults (``GPISNodeConfig``: thin-plate kernel, +-6 cm patch; 5 mm grid). Goal (issue 5):
add_contact + local surface < 20 ms at 200 contacts at the default grid, checked for IGEF (without
vertex variance) and GP-V (with it). BLAS runs one thread (palpate sets OPENBLAS_NUM_THREADS=1 at
import unless the environment says otherwise; the header says which). With --json the last line is
one JSON object with every row (wall and CPU medians), the goal check and the load average. Exit
code 1 when the goal is missed.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any

from palpate.errors import BenchmarkError
from palpate.text_table import Column, fixed_width_table

CONTACTS = (50, 100, 200, 400, 1000)
QUICK_CONTACTS = (200,)
RESOLUTIONS_MM = (2.0, 3.0, 4.0, 5.0)
#: Timed steps per number of contacts (--quick: QUICK_REPEATS).
REPEATS = 7
QUICK_REPEATS = 3
GOAL_MS = 20.0
GOAL_CONTACTS = 200


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench gpis` beyond the shared --quick and --json."""
    parser.add_argument(
        "--contacts",
        type=int,
        nargs="+",
        metavar="N",
        help=f"numbers of contacts (default {' '.join(map(str, CONTACTS))}; --quick {GOAL_CONTACTS})",
    )
    parser.add_argument(
        "--resolutions",
        type=float,
        nargs="+",
        metavar="MM",
        help=f"marching-cubes grid steps in mm (default {' '.join(f'{r:g}' for r in RESOLUTIONS_MM)})",
    )
    parser.add_argument(
        "--repeats", type=int, help=f"timed steps per number of contacts (default {REPEATS}, --quick {QUICK_REPEATS})"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the contacts on the ellipsoid")


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


def main(args: argparse.Namespace) -> int:
    """Print the table and the goal check (and with --json a last line of JSON); 1 when the goal is missed."""
    from palpate.nodes.gpis.bench import benchmark_steps
    from palpate.nodes.gpis.node import GPISNodeConfig

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
        print(json.dumps(out, sort_keys=True, allow_nan=False))
    return 0 if passed else 1
