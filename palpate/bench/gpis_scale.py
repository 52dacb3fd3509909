"""`palpate bench gpis` (issue 11): the GPIS step at 200, 2000 and 10,000 contacts, exact and local.

Per shape (a 12 x 8 x 6 cm ellipsoid, and the YCB coffee can 002_master_chef_can when the YCB folder
is there; on request a 1 m cube, whose rows hold the memory of a large object) and number of contacts
n, one fresh subprocess builds the estimator from n - repeats contacts sampled uniformly on the true
surface (one batch, not timed) and then times `repeats` steps of Algorithm 1, each adding one contact:

    IGEF step = add_contact + local surface around it without vertex variance
    GP-V step = IGEF step + GP variance (Eq. 6) at the vertices GP-V rates (the GPIS node's default
                vertex_variance "candidates": one per 5 mm voxel within 6 cm of the contact)

(medians of process CPU ms; the GPIS node's defaults: thin-plate kernel, +-6 cm patch, 5 mm grid).
The estimator is the node's default (GPISConfig.estimator = "auto": the exact GP up to
auto_local_above_contacts contacts, local experts above); where the exact GP fits (n <= EXACT_MAX) a
second subprocess runs it as the reference. Per row:

- surface_err_mm_mean / _p95: distance from the mesh vertices of the timed steps to the true surface
  (ellipsoid: first-order algebraic distance |g| / |grad g|; mesh: Open3D's closest point);
- approx_vs_exact_mm_p95: where both ran, |f_default(v) - f_exact(v)| / |grad f_exact(v)| at the exact
  mesh's vertices v, the first-order distance between the two zero level sets (0 when both are exact);
- peak_mb: the subprocess's peak resident memory (getrusage ru_maxrss) less its resident memory after
  the imports and before the first contact: the estimator, its temporaries and the meshes.

Goals (issue 11): 200 contacts IGEF <= 10 ms, GP-V <= 20 ms; 2000: 20 / 40 ms and <= 300 MB; 10,000:
50 / 100 ms and <= 1 GB; the approximation within 0.2 mm (p95) of the exact GP where both run.
`pass` is true when every row meets its goals. docs/benchmarks.md holds the output.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from palpate import jsonio
from palpate.errors import BenchmarkError
from palpate.text_table import Column, fixed_width_table

if TYPE_CHECKING:
    from palpate.nodes.gpis.core import GPISConfig

FloatArray = NDArray[np.float64]

CONTACTS = (200, 2000, 10_000)
QUICK_CONTACTS = (200, 2000)
REPEATS = 7
QUICK_REPEATS = 3
#: The exact reference runs up to this many contacts (its factor needs 128 n^2 bytes: 512 MB at 2000).
EXACT_MAX = 2000
YCB_OBJECT = "002_master_chef_can"
SHAPES = ("ellipsoid", "ycb")
#: Shapes `--shapes` also takes: "box", a cube of BOX_EDGE_M (a large object: the GP's kernel range grows
#: to hold it, as the GPIS node's does, and the local estimator's far field reaches its cap).
EXTRA_SHAPES = ("box",)
BOX_EDGE_M = 1.0
ELLIPSOID_AXES_M = np.array([0.06, 0.04, 0.03])
#: Goals per number of contacts: IGEF ms, GP-V ms, peak MB (None: no memory goal).
GOALS: dict[int, tuple[float, float, float | None]] = {200: (10.0, 20.0, None), 2000: (20.0, 40.0, 300.0),
                                                       10_000: (50.0, 100.0, 1024.0)}  # fmt: skip
APPROX_GOAL_MM = 0.2


# --- one row, in its own process -------------------------------------------------------------------


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _ellipsoid(n: int, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    from palpate.bench.gpis import ellipsoid_contacts

    return ellipsoid_contacts(n, rng, ELLIPSOID_AXES_M)


def _ellipsoid_distance_m(v: FloatArray) -> FloatArray:
    """First-order distance |g| / |grad g| to the ellipsoid g = |x / a| - 1 = 0 (exact to O(d^2 / radius))."""
    q = v / ELLIPSOID_AXES_M
    r = np.linalg.norm(q, axis=1)
    grad = (q / ELLIPSOID_AXES_M) / r[:, None]
    return np.abs(r - 1.0) / np.linalg.norm(grad, axis=1)


class _Shape:
    """Contacts sampled on a true surface and distances to it."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._scene: Any = None
        if name == "ycb":
            import trimesh

            from palpate.paths import YCB_DIR_ENV, ycb_dir

            root = ycb_dir()
            path = None if root is None else root / f"{YCB_OBJECT}.stl"
            if path is None or not path.is_file():
                raise BenchmarkError(f"{YCB_OBJECT}.stl not found: set {YCB_DIR_ENV} to the YCB mesh folder")
            mesh: Any = trimesh.load(path, force="mesh")
            self._mesh = mesh
            self.centre = np.asarray(mesh.bounds, dtype=np.float64).mean(axis=0)
        elif name == "box":
            import trimesh

            self._mesh = trimesh.creation.box(extents=(BOX_EDGE_M,) * 3)
            self.centre = np.zeros(3)

    def config(self, gp: GPISConfig) -> GPISConfig:
        """The GPIS node's parameters for this shape: R_m grown, as the node grows it, to hold the shape."""
        if self.name != "box":
            return gp
        from palpate.nodes.gpis.reach import HEADROOM

        R_m = gp.R_m
        while R_m < HEADROOM * BOX_EDGE_M * np.sqrt(3.0):
            R_m *= 2.0
        return dataclasses.replace(gp, R_m=R_m)

    def contacts(self, n: int, seed: int) -> tuple[FloatArray, FloatArray]:
        rng = np.random.default_rng(seed)
        if self.name == "ellipsoid":
            return _ellipsoid(n, rng)
        import trimesh

        P, faces = trimesh.sample.sample_surface(self._mesh, n, seed=seed)
        normals = np.asarray(self._mesh.face_normals, dtype=np.float64)[faces]
        return np.asarray(P, dtype=np.float64) - self.centre, normals

    def distance_m(self, v: FloatArray) -> FloatArray:
        if self.name == "ellipsoid":
            return _ellipsoid_distance_m(v)
        if self._scene is None:
            from palpate.geometry.mesh_query import MeshScene

            self._scene = MeshScene(np.asarray(self._mesh.vertices) - self.centre, np.asarray(self._mesh.faces))
        return self._scene.distance(np.asarray(v) - self._scene.origin_m)


def measure_row(shape: str, n: int, estimator: str, repeats: int, seed: int) -> dict[str, Any]:
    """Build the estimator with n - repeats contacts, time `repeats` steps; one row (see the module doc).

    Also returns the last step's exact-reference inputs: the contacts (for the other estimator's run)
    are the same for the same (shape, n, seed).
    """
    from palpate.geometry.thinning import thin_near
    from palpate.nodes.gpis.local import make_estimator
    from palpate.nodes.gpis.session import GPISNodeConfig
    from palpate.nodes.gpis.surface import local_surface

    node = GPISNodeConfig()
    truth = _Shape(shape)
    P, N = truth.contacts(n, seed)
    config = truth.config(dataclasses.replace(node.gp, estimator=estimator))
    truth.distance_m(P[:1])  # load the distance query (Open3D) before the memory baseline
    base_mb = _rss_mb()
    gp = make_estimator(config)
    n0 = n - repeats
    t0 = time.perf_counter()
    gp.add_contacts(P[:n0], N[:n0])
    build_s = time.perf_counter() - t0
    add, surf, var, errs, sites = [], [], [], [], []
    mesh = None
    for i in range(n0, n):
        c0 = time.process_time()
        gp.add_contact(P[i], N[i])
        c1 = time.process_time()
        mesh = local_surface(gp, P[i], node.local_half_extent_m, node.local_resolution_m, with_variance=False)
        c2 = time.process_time()
        at = thin_near(mesh.vertices, P[i], node.variance_step_m, node.variance_radius_m)
        gp.variance(mesh.vertices[at])
        c3 = time.process_time()
        sites.append(len(at))
        add.append(c1 - c0)
        surf.append(c2 - c1)
        var.append(c3 - c2)
        errs.append(truth.distance_m(mesh.vertices))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3 - base_mb
    err_mm = 1e3 * np.concatenate(errs)
    assert mesh is not None
    ms = [1e3 * float(np.median(t)) for t in (add, surf, var)]
    kind = type(getattr(gp, "estimator", gp)).__name__
    return {
        "shape": shape,
        "contacts": n,
        "estimator": estimator,
        "ran": "local" if kind == "LocalGPIS" else "exact",
        "build_s": build_s,
        "add_ms": ms[0],
        "surface_ms": ms[1],
        "variance_ms": ms[2],
        "igef_ms": ms[0] + ms[1],
        "gpv_ms": ms[0] + ms[1] + ms[2],
        "peak_mb": peak_mb,
        "n_vertices": len(mesh.vertices),
        "n_variance": int(np.median(sites)),
        "surface_err_mm_mean": float(err_mm.mean()),
        "surface_err_mm_p95": float(np.percentile(err_mm, 95)),
        "vertices_m": mesh.vertices.tolist(),
        "field": _field_at(gp, mesh.vertices),
    }


def _field_at(gp: Any, v: FloatArray) -> dict[str, list[float]]:
    g = gp.gradient(v)
    return {"f": gp.mean(v).tolist(), "grad_norm": np.linalg.norm(g, axis=1).tolist()}


def _row_in_subprocess(shape: str, n: int, estimator: str, repeats: int, seed: int) -> dict[str, Any]:
    code = (
        "from palpate import jsonio; from palpate.bench.gpis_scale import measure_row; "
        f"print(jsonio.dumps(measure_row({shape!r}, {n}, {estimator!r}, {repeats}, {seed})))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise BenchmarkError(f"{estimator} GP, {n} contacts: {_why_failed(done)}")
    out: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def _why_failed(done: subprocess.CompletedProcess[str]) -> str:
    """A failed row's process in one line: its error's last line, or the signal that killed it."""
    if done.returncode < 0:
        name = signal.Signals(-done.returncode).name
        hint = " (the kernel's out-of-memory killer sends SIGKILL)" if name == "SIGKILL" else ""
        return f"its process was killed by {name}{hint}"
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    return lines[-1].strip() if lines else f"its process exited {done.returncode} without a word"


def run_rows(
    shapes: Sequence[str],
    contacts: Sequence[int],
    repeats: int,
    seed: int,
    *,
    exact_max: int = EXACT_MAX,
    estimator: str = "auto",
) -> list[dict[str, Any]]:
    """One row per (shape, n): the estimator (default: the node's "auto"), and the exact reference
    where n <= exact_max. A row whose process fails (out of memory, say) holds its ``error``."""
    rows = []
    for shape in shapes:
        for n in contacts:
            print(f"  {shape}, {n} contacts ...", file=sys.stderr, flush=True)
            try:
                rows.append(_row(shape, n, repeats, seed, exact_max, estimator))
            except BenchmarkError as exc:
                print(f"  {shape}, {n} contacts failed: {exc}", file=sys.stderr, flush=True)
                rows.append({"shape": shape, "contacts": n, "ran": estimator, "error": str(exc)})
    return rows


def _row(shape: str, n: int, repeats: int, seed: int, exact_max: int, estimator: str) -> dict[str, Any]:
    """The row of ``shape`` at ``n`` contacts (BenchmarkError when a process of it fails)."""
    default = _row_in_subprocess(shape, n, estimator, repeats, seed)
    row = {k: v for k, v in default.items() if k not in ("vertices_m", "field")}
    if n <= exact_max:
        exact = _row_in_subprocess(shape, n, "exact", repeats, seed)
        for key in ("igef_ms", "gpv_ms", "peak_mb", "surface_err_mm_p95", "surface_err_mm_mean"):
            row[f"exact_{key}"] = exact[key]
        if default["ran"] == "exact":
            row["approx_vs_exact_mm_p95"] = 0.0
        else:
            default_at = _field_in_subprocess(shape, n, repeats, seed, exact["vertices_m"], estimator)
            f_e = np.asarray(exact["field"]["f"])
            g_e = np.asarray(exact["field"]["grad_norm"])
            row["approx_vs_exact_mm_p95"] = float(np.percentile(1e3 * np.abs(default_at - f_e) / g_e, 95))
    return row


def default_field_at(
    shape: str, n: int, repeats: int, seed: int, vertices: list[list[float]], estimator: str = "auto"
) -> list[float]:
    """The estimator's mean at the given points after all n contacts (the same build as measure_row)."""
    from palpate.nodes.gpis.local import make_estimator
    from palpate.nodes.gpis.session import GPISNodeConfig

    truth = _Shape(shape)
    P, N = truth.contacts(n, seed)
    gp = make_estimator(truth.config(dataclasses.replace(GPISNodeConfig().gp, estimator=estimator)))
    gp.add_contacts(P[: n - repeats], N[: n - repeats])
    for i in range(n - repeats, n):
        gp.add_contact(P[i], N[i])
    out: list[float] = gp.mean(np.asarray(vertices)).tolist()
    return out


def _field_in_subprocess(
    shape: str, n: int, repeats: int, seed: int, vertices: list[list[float]], estimator: str
) -> FloatArray:
    code = (
        "import json, sys; from palpate import jsonio; from palpate.bench.gpis_scale import default_field_at; "
        "a = json.loads(sys.stdin.read()); print(jsonio.dumps(default_field_at(*a)))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        input=jsonio.dumps([shape, n, repeats, seed, vertices, estimator]),
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise BenchmarkError(f"{estimator} GP's field, {n} contacts: {_why_failed(done)}")
    return np.asarray(json.loads(done.stdout.strip().splitlines()[-1]))


# --- goals and output ------------------------------------------------------------------------------


def check_row(row: Mapping[str, Any]) -> list[str]:
    """The goals a row misses (empty: all met, or none set for its number of contacts)."""
    if "error" in row:
        return [row["error"]]
    missed = []
    goal = GOALS.get(int(row["contacts"]))
    if goal is not None:
        igef, gpv, mb = goal
        if row["igef_ms"] > igef:
            missed.append(f"IGEF {row['igef_ms']:.1f} > {igef:g} ms")
        if row["gpv_ms"] > gpv:
            missed.append(f"GP-V {row['gpv_ms']:.1f} > {gpv:g} ms")
        if mb is not None and row["peak_mb"] > mb:
            missed.append(f"peak {row['peak_mb']:.0f} > {mb:g} MB")
    approx = row.get("approx_vs_exact_mm_p95")
    if approx is not None and approx > APPROX_GOAL_MM:
        missed.append(f"vs exact {approx:.3f} > {APPROX_GOAL_MM:g} mm")
    return missed


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """One line per (shape, contacts): the default estimator's step, memory and errors, the exact's step."""

    def exact(key: str) -> Any:
        return lambda r: r.get(f"exact_{key}", float("nan"))

    columns = [
        Column("shape", 10, "shape", "s"),
        Column("contacts", 9, "contacts", ".0f"),
        Column("ran", 6, "ran", "s"),
        Column("IGEF ms", 9, "igef_ms", ".1f"),
        Column("GP-V ms", 9, "gpv_ms", ".1f"),
        Column("peak MB", 9, "peak_mb", ".0f"),
        Column("err mean", 9, "surface_err_mm_mean", ".3f"),
        Column("err p95", 8, "surface_err_mm_p95", ".3f"),
        Column("vs exact", 9, lambda r: r.get("approx_vs_exact_mm_p95", float("nan")), ".4f"),
        Column("exact IGEF", 11, exact("igef_ms"), ".1f"),
        Column("exact GP-V", 11, exact("gpv_ms"), ".1f"),
        Column("exact MB", 9, exact("peak_mb"), ".0f"),
    ]
    nan = float("nan")  # a failed row's cells (its error is printed with the goals)
    shown = [{**r, "ran": "error"} if "error" in r else r for r in rows]
    blank = {c.value: nan for c in columns if isinstance(c.value, str)}
    return fixed_width_table(columns, [{**blank, **r} for r in shown])


def main(args: argparse.Namespace) -> int:
    """Print the table and the goal verdicts (with --json a last line of JSON); 1 when a goal is missed."""
    from palpate.paths import ycb_dir

    contacts = list(getattr(args, "contacts", None) or (QUICK_CONTACTS if args.quick else CONTACTS))
    repeats = getattr(args, "repeats", None) or (QUICK_REPEATS if args.quick else REPEATS)
    seed = int(getattr(args, "seed", 0) or 0)
    shapes = list(getattr(args, "shapes", None) or (("ellipsoid",) if args.quick else SHAPES))
    if repeats < 1 or min(contacts) <= repeats:
        raise BenchmarkError(
            f"--contacts {min(contacts)} with --repeats {repeats}: the last {repeats} contacts are timed, "
            f"so every N must exceed it; give N >= {repeats + 1}"
        )
    notes, skipped = [], []
    if "ycb" in shapes and (ycb_dir() is None or not (ycb_dir() / f"{YCB_OBJECT}.stl").is_file()):  # type: ignore[operator]
        shapes.remove("ycb")
        skipped.append("ycb")
        notes.append(f"YCB {YCB_OBJECT} skipped: set PALPATE_YCB_DIR to the YCB mesh folder")
    if not shapes:  # nothing left to measure: no pass
        raise BenchmarkError(f"--shapes: nothing to measure; {'; '.join(notes)}")
    exact_max = EXACT_MAX if not args.quick else min(EXACT_MAX, 200)
    blas = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    load_start = os.getloadavg()[0]
    print(
        f"palpate bench gpis: estimator {getattr(args, 'estimator', None) or 'auto'}, shapes {' '.join(shapes)}, "
        f"n = {' '.join(map(str, contacts))}, median of {repeats} "
        f"steps, seed {seed}, exact reference up to {exact_max} contacts; OPENBLAS_NUM_THREADS={blas}; "
        f"{os.cpu_count()} cores, load average {load_start:.1f}",
        flush=True,
    )
    for note in notes:
        print(note)
    start = time.perf_counter()
    estimator = getattr(args, "estimator", None) or "auto"
    rows = run_rows(shapes, contacts, repeats, seed, exact_max=exact_max, estimator=estimator)
    print(table(rows))
    print(
        "CPU ms (medians): IGEF = add_contact + local surface (5 mm grid, +-6 cm) without vertex variance; "
        "GP-V = with it. peak MB: ru_maxrss of the row's own process less its memory before the first "
        "contact. err: vertex distance to the true surface (mm); vs exact: p95 distance between the "
        f"default's and the exact GP's zero level sets (mm). Load average at the end {os.getloadavg()[0]:.1f}."
    )
    verdicts = {f"{r['shape']} {r['contacts']}": check_row(r) for r in rows}
    for name, missed in verdicts.items():
        print(f"goal {name}: " + ("met" if not missed else "MISSED (" + "; ".join(missed) + ")"))
    passed = all(not m for m in verdicts.values())
    if args.json:
        out = {
            "rows": rows,
            "pass": passed,
            "missed": {k: v for k, v in verdicts.items() if v},
            "skipped": skipped,  # shapes asked for and not measured (their goals are not judged)
            "repeats": repeats,
            "seed": seed,
            "quick": bool(args.quick),
            "openblas_num_threads": blas,
            "load_average": [load_start, os.getloadavg()[0]],
            "seconds": time.perf_counter() - start,
        }
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if passed else 1
