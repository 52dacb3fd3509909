"""`palpate bench contacts [--objects DIR] [--json]`: accuracy of the exact-mesh contact sensor.

Per object, the 95th percentile of the contact position error (mm) and of the normal error (deg)
over many probe touches, and the phantom contacts (touches reported by free probes). Default
objects: the issue's banana, clamp, ten stacking cups and fork from the YCB folder
(``palpate.paths.ycb_dir``); ``--objects DIR`` benchmarks every mesh file in DIR. Goals: p95 position
<= 0.5 mm and p95 normal <= 5 deg on every object, no phantom contact. With --json the last line is
one JSON object holding ``position_p95_mm_max``, ``normal_p95_deg_max`` (worst object),
``phantom_contacts`` (total) and the per-object rows. Exit code 1 when a goal is missed.

Method, per object (probe radius r = 8 mm, sensor tolerance 0.1 mm):
- Touches: surface points p sampled uniformly by area with their face normal n; the probe centre is
  c = p + n (r - delta), delta ~ U(0, 0.3 mm) a press depth. The true contact of that sphere is the
  closest point of the mesh to c, computed by a slow float64 brute-force reference (every triangle
  that can be closest, found by an exact bound on a k-d tree, then Ericson's point-triangle
  projection). Usually it is p; in concavities the sphere meets another part of the surface first.
  Centres that end up inside the object (thin parts) are skipped.
- Position error: distance from the reported point to the true contact point; also the reported
  point's distance to the mesh. Normal error: angle between the reported normal and the normal of
  the true contact triangle (any triangle equally close, to 0.1 um, counts: edges and vertices).
- Phantom contacts: free probes that must not touch: centres on the outward normal at r + tol + g
  with g ~ U(1 um, 0.5 mm) (near misses) and U(0.5, 20) mm, and centres sampled inside the convex
  hull but outside the mesh (holes, cups, between tines) - where MuJoCo's hull collision would
  report contact. A free probe is one whose reference distance exceeds r + tol + 1 um and which is
  outside (generalised winding number < 0.5). Any reported touch there is a phantom contact.
- The simulated probe's own query, ``WarmClosest`` (warm-started from the last answer), on the same
  touches and free probes: its largest deviation from the sensor's points, and its missed and phantom
  contacts; and its time per query along slides of 0.1 mm steps.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from palpate import jsonio
from palpate.argtypes import add_scale_argument, bounded_positive_int, non_negative_int, path_arg
from palpate.errors import BenchmarkError, MeshError
from palpate.paths import MESH_SUFFIXES, YCB_DIR_ENV, ycb_dir
from palpate.text_table import Column, fixed_width_table

# `palpate bench` imports this module to build its parser: scipy, trimesh and the sensor (open3d)
# are imported where they are used
if TYPE_CHECKING:
    import trimesh

    from palpate.geometry.mesh_query import ExactContactSensor

#: Default objects of the issue's check (file-name globs in the YCB folder).
DEFAULT_OBJECTS = ("011_banana.stl", "051_large_clamp.stl", "065-*_cups.stl", "030_fork.stl")
#: Touches per object (--quick: QUICK_TOUCHES).
TOUCHES = 1000
QUICK_TOUCHES = 200
#: Most touches per object --touches takes (each is a probe sample held in memory).
MAX_TOUCHES = 10_000_000
#: The warm-started query answers as the sensor does, bit for bit (tests/unit/geometry/test_warm_closest.py);
#: the benchmark allows rounding.
WARM_DEVIATION_MAX_M = 1e-12


@dataclass(frozen=True, kw_only=True)
class ContactBenchConfig:
    """Probe and placement parameters of the contact benchmark."""

    probe_radius_m: float = 0.008
    press_depth_max_m: float = 0.0003
    tolerance_m: float = 1e-4
    near_miss_max_m: float = 0.0005
    far_miss_max_m: float = 0.02
    #: free probes must clear r + tol by this much in the reference (sensor distance error margin)
    free_margin_m: float = 1e-6
    #: triangles within this distance of the closest one also count as "the" contact triangle
    tie_m: float = 1e-7
    #: single-point queries timed per object
    timed_single_queries: int = 200


# --- reference -------------------------------------------------------------------------------------
class ReferenceMesh:
    """Slow float64 ground truth: exact closest points by bounded brute force, inside by winding number."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        from scipy.spatial import cKDTree

        self.triangles = np.asarray(mesh.triangles, dtype=np.float64)
        self.normals = np.asarray(mesh.face_normals, dtype=np.float64)
        centroids = self.triangles.mean(axis=1)
        self._radius = float(np.linalg.norm(self.triangles - centroids[:, None], axis=2).max())
        self._vertex_tree = cKDTree(np.asarray(mesh.vertices, dtype=np.float64))
        self._centroid_tree = cKDTree(centroids)

    def closest(self, points: np.ndarray, tie_m: float, max_pairs: int = 2_000_000) -> dict[str, Any]:
        """Closest points (n, 3), distances (n,) and, per point, the faces within ``tie_m`` of the closest.

        Exact: a face is skipped only when |p - centroid| - R_max exceeds the distance to the nearest
        vertex, an upper bound of the true distance.
        """
        from palpate.geometry.mesh_query import closest_points_on_triangles

        n = len(points)
        out_q = np.zeros((n, 3))
        out_d = np.zeros(n)
        tie_point: list[np.ndarray] = []
        tie_face: list[np.ndarray] = []
        upper, _ = self._vertex_tree.query(points)
        start = 0
        while start < n:
            stop = start + 1
            lists = [self._centroid_tree.query_ball_point(points[start], upper[start] + self._radius + 1e-12)]
            total = len(lists[0])
            while stop < n and total < max_pairs:
                more = self._centroid_tree.query_ball_point(points[stop], upper[stop] + self._radius + 1e-12)
                lists.append(more)
                total += len(more)
                stop += 1
            counts = np.array([len(x) for x in lists])
            index = np.repeat(np.arange(start, stop), counts)
            faces = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists])
            tri = self.triangles[faces]
            q, _ = closest_points_on_triangles(points[index], tri[:, 0], tri[:, 1], tri[:, 2])
            d = np.linalg.norm(points[index] - q, axis=1)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            d_min = np.minimum.reduceat(d, starts)
            best = np.zeros(stop - start, dtype=np.int64)
            is_min = d == d_min[index - start]
            best[index[is_min][::-1] - start] = np.flatnonzero(is_min)[::-1]
            out_q[start:stop] = q[best]
            out_d[start:stop] = d_min
            tied = d <= d_min[index - start] + tie_m
            tie_point.append(index[tied])
            tie_face.append(faces[tied])
            start = stop
        return {
            "points": out_q,
            "distance": out_d,
            "tie_point": np.concatenate(tie_point),
            "tie_face": np.concatenate(tie_face),
        }

    def winding_number(self, points: np.ndarray, chunk_pairs: int = 1_000_000) -> np.ndarray:
        """Generalised winding number (n,): about 1 inside a closed outward mesh, 0 outside.

        Sum of the signed solid angles of all triangles (Van Oosterom and Strackee 1983) / 4 pi.
        """
        F = len(self.triangles)
        out = np.zeros(len(points))
        step = max(1, chunk_pairs // F)
        for s in range(0, len(points), step):
            rel = self.triangles[None] - points[s : s + step, None, None, :]  # (c, F, 3, 3)
            a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
            la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
            det = np.einsum("...i,...i->...", a, np.cross(b, c))
            dot = lambda x, y: np.einsum("...i,...i->...", x, y)  # noqa: E731
            denom = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
            out[s : s + step] = (2.0 * np.arctan2(det, denom)).sum(axis=1) / (4.0 * math.pi)
        return out


def _angles_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    cos = np.clip(np.einsum("ij,ij->i", u, v), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def _min_tie_angle_deg(reference: ReferenceMesh, ref: dict[str, Any], normals: np.ndarray) -> np.ndarray:
    """Per point: smallest angle between ``normals`` and any triangle tied for closest."""
    point, face = ref["tie_point"], ref["tie_face"]
    angle = _angles_deg(normals[point], reference.normals[face])
    best = np.full(len(normals), np.inf)
    np.minimum.at(best, point, angle)
    return best


# --- probes ----------------------------------------------------------------------------------------
def _hull_interior_samples(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform points (<= count, 3) in the bounding box of the mesh that lie inside its convex hull."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(np.asarray(mesh.vertices, dtype=np.float64))
    lo, hi = mesh.bounds
    pts = lo + rng.random((count, 3)) * (hi - lo)
    inside = np.all(pts @ hull.equations[:, :3].T + hull.equations[:, 3] <= 0.0, axis=1)
    return np.asarray(pts[inside])


def bench_mesh(
    name: str,
    mesh: trimesh.Trimesh,
    touches: int,
    rng: np.random.Generator,
    config: ContactBenchConfig | None = None,
    sensor: ExactContactSensor | None = None,
) -> dict[str, Any]:
    """Benchmark the sensor (by default an ExactContactSensor on ``mesh``) against the true ``mesh``.

    Returns the row described in the module docstring.
    """
    from palpate.geometry.mesh_query import ExactContactSensor
    from palpate.nodes.sim.objects import sample_surface_faces

    cfg = config or ContactBenchConfig()
    r, tol = cfg.probe_radius_m, cfg.tolerance_m
    sensor = sensor if sensor is not None else ExactContactSensor(mesh)
    reference = ReferenceMesh(mesh)

    # touches
    p, n, _ = sample_surface_faces(mesh, touches, rng)
    h = r - rng.uniform(0.0, cfg.press_depth_max_m, touches)
    centres = p + n * h[:, None]
    ref = reference.closest(centres, cfg.tie_m)
    clean = ref["distance"] >= h - 1e-9  # the sphere meets the surface at p: centre provably outside
    outside = clean.copy()
    if np.any(~clean):
        outside[~clean] = reference.winding_number(centres[~clean]) < 0.5
    centres, ref_points = centres[outside], ref["points"][outside]
    ref = reference.closest(centres, cfg.tie_m)  # ties for the kept centres only

    start = time.perf_counter()
    touching, got = sensor.touch(centres, r, tol)
    batch_s = time.perf_counter() - start
    position_mm = 1000.0 * np.linalg.norm(got.points_m - ref_points, axis=1)
    on_surface = reference.closest(got.points_m, cfg.tie_m)
    surface_mm = 1000.0 * on_surface["distance"]
    normal_deg = _min_tie_angle_deg(reference, ref, got.normals)
    distance_err_mm = 1000.0 * np.abs(got.distance_m - ref["distance"])
    raw_mm = 1000.0 * np.linalg.norm(sensor.closest_float32(centres) - ref_points, axis=1)

    # free probes: near and far misses along the normal, and points in the hull but off the mesh
    half = touches // 2
    pf, nf, _ = sample_surface_faces(mesh, 2 * half, rng)
    gap = np.concatenate(
        [
            rng.uniform(cfg.free_margin_m, cfg.near_miss_max_m, half),
            rng.uniform(cfg.near_miss_max_m, cfg.far_miss_max_m, half),
        ]
    )
    free = np.concatenate([pf + nf * (r + tol + gap)[:, None], _hull_interior_samples(mesh, half, rng)])
    ref_free = reference.closest(free, cfg.tie_m)
    clear = ref_free["distance"] > r + tol + cfg.free_margin_m
    free = free[clear]
    free = free[reference.winding_number(free) < 0.5]
    free_touching, _ = sensor.touch(free, r, tol)

    warm = _warm_check(sensor, centres, free, got, p[outside], n[outside], r, tol)

    single = centres[: cfg.timed_single_queries]
    start = time.perf_counter()
    for c in single:
        sensor.touch(c[None], r, tol)
    single_s = (time.perf_counter() - start) / max(len(single), 1)

    def p95(x: np.ndarray) -> float:
        return float(np.percentile(x, 95)) if len(x) else 0.0

    return {
        "object": name,
        "faces": len(mesh.faces),
        "touches": len(centres),
        "position_p95_mm": p95(position_mm),
        "normal_p95_deg": p95(normal_deg),
        "phantom_contacts": int(free_touching.sum()),
        "free_probes": len(free),
        "missed_contacts": int((~touching).sum()),
        "position_max_mm": float(position_mm.max(initial=0.0)),
        "normal_max_deg": float(normal_deg.max(initial=0.0)),
        "surface_distance_p95_mm": p95(surface_mm),
        "distance_error_max_mm": float(distance_err_mm.max(initial=0.0)),
        "float32_position_p95_mm": p95(raw_mm),
        "concave_touches": int((~clean[outside]).sum()),
        "batch_query_us": 1e6 * batch_s / max(len(centres), 1),
        "single_query_us": 1e6 * single_s,
        **warm,
    }


def _warm_check(
    sensor: ExactContactSensor,
    centres: np.ndarray,
    free: np.ndarray,
    got: Any,
    points: np.ndarray,
    normals: np.ndarray,
    r: float,
    tol: float,
) -> dict[str, Any]:
    """The simulated probe's query (``WarmClosest``, warm-started) on the same touches and free probes:
    its largest deviation from the sensor (m), its missed and phantom contacts, and its time per query
    along 50-step slides (0.1 mm per step, as the probe moves at 5 cm/s) from the first 20 touches."""
    from palpate.geometry.mesh_query import WarmClosest

    warm = WarmClosest(sensor)
    deviation, missed, phantom = 0.0, 0, 0
    for c, expected in zip(centres, got.points_m, strict=True):
        point, distance, _ = warm.query(c)
        deviation = max(deviation, float(np.abs(np.array(point) - expected).max()))
        missed += distance > r + tol
    for c in free:
        phantom += warm.query(c)[1] <= r + tol
    tangent = np.cross(normals[:20], [0.0, 0.0, 1.0])
    tangent[np.linalg.norm(tangent, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    walk = (centres[:20, None, :] + 1e-4 * np.arange(50)[None, :, None] * tangent[:, None, :]).reshape(-1, 3)
    slide = WarmClosest(sensor)
    start = time.perf_counter()
    for c in walk:
        slide.query(c)
    return {
        "warm_deviation_max_m": deviation,
        "warm_missed_contacts": int(missed),
        "warm_phantom_contacts": int(phantom),
        "warm_slide_query_us": 1e6 * (time.perf_counter() - start) / max(len(walk), 1),
    }


def mesh_paths(objects_dir: Path) -> list[Path]:
    """Every mesh file in ``objects_dir`` (not recursive), sorted by name; BenchmarkError naming an entry
    with a mesh suffix that is no file (a folder, a dangling link, a fifo: it would be left out unsaid)."""
    named = sorted(p for p in objects_dir.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    odd = [p.name for p in named if not p.is_file()]
    if odd:
        raise BenchmarkError(
            f"--objects {objects_dir}: {', '.join(odd)} named like meshes but not regular files; move or remove them"
        )
    return named


def run_contact_bench(
    paths: Sequence[Path],
    touches_per_object: int,
    rng: np.random.Generator,
    config: ContactBenchConfig | None = None,
    scale: float = 1.0,
) -> list[dict[str, Any]]:
    """One row per mesh file (see ``object_paths``; metres after ``scale``), with a progress bar over the
    files on stderr."""
    from tqdm import tqdm

    from palpate.nodes.sim.objects import read_mesh_file

    rows = []
    for path in tqdm(paths, unit="object", leave=False, disable=len(paths) < 2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a non-watertight mesh is benchmarked all the same
            mesh = read_mesh_file(path, scale)
        rows.append(bench_mesh(path.stem, mesh, touches_per_object, rng, config))
    return rows


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Worst object's p95 errors, total phantom and missed contacts, and whether the goals hold."""
    position = max((row["position_p95_mm"] for row in rows), default=0.0)
    normal = max((row["normal_p95_deg"] for row in rows), default=0.0)
    phantoms = sum(row["phantom_contacts"] for row in rows)
    warm = max((row["warm_deviation_max_m"] for row in rows), default=0.0)
    return {
        "objects": len(rows),
        "touches": sum(row["touches"] for row in rows),
        "free_probes": sum(row["free_probes"] for row in rows),
        "position_p95_mm_max": position,
        "normal_p95_deg_max": normal,
        "phantom_contacts": phantoms,
        "missed_contacts": sum(row["missed_contacts"] for row in rows),
        "batch_query_us_mean": float(np.mean([row["batch_query_us"] for row in rows])) if rows else 0.0,
        "single_query_us_mean": float(np.mean([row["single_query_us"] for row in rows])) if rows else 0.0,
        "warm_deviation_max_m": warm,
        "warm_missed_contacts": sum(row["warm_missed_contacts"] for row in rows),
        "warm_phantom_contacts": sum(row["warm_phantom_contacts"] for row in rows),
        "warm_slide_query_us_mean": float(np.mean([row["warm_slide_query_us"] for row in rows])) if rows else 0.0,
        "pass": bool(
            position <= 0.5
            and normal <= 5.0
            and phantoms == 0
            and warm <= WARM_DEVIATION_MAX_M
            and not any(row["warm_missed_contacts"] + row["warm_phantom_contacts"] for row in rows)
        ),
    }


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """Plain-text table of the rows and the summary."""
    columns = [
        Column("object", 28, "object", align="<"),
        Column("touch", 6, "touches"),
        Column("pos p95 mm", 12, "position_p95_mm", ".2e"),
        Column("pos max mm", 12, "position_max_mm", ".2e"),
        Column("nrm p95 deg", 12, "normal_p95_deg", ".2e"),
        Column("nrm max deg", 12, "normal_max_deg", ".2e"),
        Column("f32 p95 mm", 12, "float32_position_p95_mm", ".2e"),
        Column("free", 6, "free_probes"),
        Column("phantom", 8, "phantom_contacts"),
        Column("missed", 7, "missed_contacts"),
        Column("us/query", 9, "batch_query_us", ".2f"),
    ]
    table = fixed_width_table(columns, rows)
    s = summary(rows)
    lines = [table, table.split("\n", 2)[1]]  # closing rule as long as the header
    lines.append(
        f"worst p95 position {s['position_p95_mm_max']:.2e} mm (goal <= 0.5), worst p95 normal "
        f"{s['normal_p95_deg_max']:.2e} deg (goal <= 5), phantom contacts {s['phantom_contacts']} (goal 0), "
        f"missed {s['missed_contacts']}; query {s['batch_query_us_mean']:.2f} us batched, "
        f"{s['single_query_us_mean']:.0f} us single; the sim probe's warm-started query: largest deviation "
        f"{s['warm_deviation_max_m']:.1e} m, missed {s['warm_missed_contacts']}, phantom "
        f"{s['warm_phantom_contacts']}, {s['warm_slide_query_us_mean']:.0f} us per query sliding: "
        f"{'PASS' if s['pass'] else 'FAIL'}"
    )
    return "\n".join(lines)


# --- the command ----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench contacts` beyond the shared --quick and --json."""
    parser.add_argument("--objects", type=path_arg, metavar="DIR", help="benchmark every mesh file in DIR")
    add_scale_argument(parser)
    parser.add_argument(
        "--touches",
        type=_touches,
        help=f"probe touches per object, at least 2: half of them are free probes (default {TOUCHES}, "
        f"--quick {QUICK_TOUCHES})",
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the sampled touches and free probes")


def _touches(text: str) -> int:
    """--touches: 2 to MAX_TOUCHES (one touch left no free probe, and the reference query failed)."""
    value = bounded_positive_int(MAX_TOUCHES)(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"{text!r}: give at least 2 (half of the touches are free probes)")
    return value


def object_paths(objects: Path | None, ycb: Path | None = None) -> list[Path]:
    """Mesh files to benchmark: every one in ``objects``, or without it the default objects in the
    YCB folder (``ycb``, by default ``palpate.paths.ycb_dir()``); BenchmarkError saying what to do
    when there are none."""
    if objects is not None:
        if not objects.is_dir():
            raise BenchmarkError(f"--objects {objects}: not a directory; give a folder of mesh files (see --scale)")
        paths = mesh_paths(objects)
        if not paths:
            raise BenchmarkError(f"--objects {objects}: no mesh files ({', '.join(MESH_SUFFIXES)}) in this folder")
        return paths
    root = ycb if ycb is not None else ycb_dir()
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
    paths = object_paths(getattr(args, "objects", None))
    touches = getattr(args, "touches", None) or (QUICK_TOUCHES if args.quick else TOUCHES)
    seed = int(getattr(args, "seed", 0) or 0)
    scale = float(getattr(args, "scale", 1.0))
    print(
        f"palpate bench contacts: {len(paths)} objects from {paths[0].parent}, {touches} touches each, seed {seed}",
        flush=True,
    )
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    refused: dict[str, str] = {}  # file name -> why the simulator would not load it
    start = time.perf_counter()
    for path in paths:
        try:
            rows.extend(run_contact_bench([path], touches, rng, scale=scale))
        except MeshError as exc:  # one bad file in a folder: the others are still benchmarked
            refused[path.name] = str(exc)
            print(f"  {path.name}: refused: {exc}", file=sys.stderr, flush=True)
            continue
        row = rows[-1]
        print(
            f"  {row['object']}: p95 {row['position_p95_mm']:.2e} mm, {row['normal_p95_deg']:.2e} deg, "
            f"phantom {row['phantom_contacts']}",
            file=sys.stderr,
            flush=True,
        )
    if rows:
        print(format_table(rows))
    out = summary(rows)
    if refused:  # every object asked for must pass: a refused one did not
        out["pass"] = False
        print(f"{len(refused)} of {len(paths)} mesh files refused (FAIL): " + "; ".join(refused.values()))
    if args.json:
        out = {
            **out,
            "refused": refused,
            "touches_per_object": touches,
            "seed": seed,
            "seconds": time.perf_counter() - start,
            "rows": rows,
        }
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if out["pass"] else 1
