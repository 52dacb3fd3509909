"""`palpate bench contacts [--objects DIR] [--json]`: accuracy of the exact-mesh contact sensor.

A thin wrapper around ``palpate.nodes.sim.contact_bench`` (method in its docstring): per object,
the 95th percentile of the contact position error (mm) and of the normal error (deg) over many probe
touches, and the phantom contacts (touches reported by free probes). Default objects: the issue's
banana, clamp, ten stacking cups and fork from the YCB folder (``palpate.paths.ycb_dir``);
``--objects DIR`` benchmarks every mesh file in DIR. Goals: p95 position <= 0.5 mm and p95 normal
<= 5 deg on every object, no phantom contact. With --json the last line is one JSON object holding
``position_p95_mm_max``, ``normal_p95_deg_max`` (worst object), ``phantom_contacts`` (total) and the
per-object rows. Exit code 1 when a goal is missed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from palpate.errors import BenchmarkError
from palpate.paths import YCB_DIR_ENV, ycb_dir

#: Touches per object (--quick: QUICK_TOUCHES).
TOUCHES = 1000
QUICK_TOUCHES = 200


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench contacts` beyond the shared --quick and --json."""
    parser.add_argument("--objects", type=Path, metavar="DIR", help="benchmark every mesh file in DIR")
    parser.add_argument(
        "--touches", type=int, help=f"probe touches per object (default {TOUCHES}, --quick {QUICK_TOUCHES})"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the sampled touches and free probes")


def object_paths(objects: Path | None) -> list[Path]:
    """Mesh files to benchmark; BenchmarkError saying what to do when there are none."""
    from palpate.nodes.sim.contact_bench import DEFAULT_OBJECTS, MESH_SUFFIXES, mesh_paths

    if objects is not None:
        if not objects.is_dir():
            raise BenchmarkError(f"--objects {objects}: not a directory; give a folder of mesh files in metres")
        paths = mesh_paths(objects)
        if not paths:
            raise BenchmarkError(f"--objects {objects}: no mesh files ({', '.join(MESH_SUFFIXES)}) in this folder")
        return paths
    root = ycb_dir()
    if root is None:
        raise BenchmarkError(
            f"the YCB meshes were not found: set {YCB_DIR_ENV} to the folder of YCB STL files (in metres) "
            "or pass --objects DIR"
        )
    paths = []
    for pattern in DEFAULT_OBJECTS:
        found = sorted(root.glob(pattern))
        if not found:
            raise BenchmarkError(f"{root}: no file matches {pattern!r}; is {YCB_DIR_ENV} the YCB mesh folder?")
        paths.extend(found)
    return sorted(paths)


def main(args: argparse.Namespace) -> int:
    """Print the per-object table (and with --json a last line of JSON); 1 when a goal is missed."""
    import numpy as np

    from palpate.nodes.sim.contact_bench import format_table, run_contact_bench, summary

    paths = object_paths(getattr(args, "objects", None))
    touches = getattr(args, "touches", None) or (QUICK_TOUCHES if args.quick else TOUCHES)
    seed = int(getattr(args, "seed", 0) or 0)
    print(
        f"palpate bench contacts: {len(paths)} objects from {paths[0].parent}, {touches} touches each, seed {seed}",
        flush=True,
    )
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    start = time.perf_counter()
    for path in paths:
        rows.extend(run_contact_bench(None, touches, rng, paths=[path]))
        row = rows[-1]
        print(
            f"  {row['object']}: p95 {row['position_p95_mm']:.2e} mm, {row['normal_p95_deg']:.2e} deg, "
            f"phantom {row['phantom_contacts']}",
            file=sys.stderr,
            flush=True,
        )
    print(format_table(rows))
    out = summary(rows)
    if args.json:
        out = {
            **out,
            "touches_per_object": touches,
            "seed": seed,
            "seconds": time.perf_counter() - start,
            "rows": rows,
        }
        print(json.dumps(out, sort_keys=True, allow_nan=False))
    return 0 if out["pass"] else 1
