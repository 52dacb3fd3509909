"""Timing of one GPIS update plus the local surface (issue 5 goal: < 20 ms at 200 contacts).

The measuring code behind ``palpate bench gpis`` (palpate/bench/gpis.py prints the table and the goal
check; docs/benchmarks.md holds its output: numbers belong there, not here). Contacts lie on an
ellipsoid with semi-axes 6 x 4 x 3 cm (a YCB-sized object); the local surface is the planning patch
around the newest contact. Each step of Algorithm 1 adds one contact and meshes the patch around it,
with the GP variance at every vertex (Eq. 6; GP-V needs it) or without (IGEF). Timings are medians of
wall-clock and of process CPU ms: with single-threaded BLAS (palpate sets OPENBLAS_NUM_THREADS=1 at
import) CPU time is the time on one core, and it is not inflated by other jobs on a busy machine.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.surface import LOCAL_HALF_EXTENT_M, LOCAL_RESOLUTION_M, local_surface

FloatArray = NDArray[np.float64]

ELLIPSOID_AXES_M = np.array([0.06, 0.04, 0.03])

#: The timed quantities of one step (keys of a row with and without the ``cpu_`` prefix, in ms).
TIMED = ("add_contact", "local_surface", "local_surface_without_variance", "vertex_variance")


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
    resolutions_m: Sequence[float] = (LOCAL_RESOLUTION_M,),
    half_extent_m: float = LOCAL_HALF_EXTENT_M,
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
    prefix, and the mesh size of the last step (n_vertices, n_faces).
    """
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


def benchmark_update(
    n_contacts: int = 200,
    *,
    resolution_m: float = LOCAL_RESOLUTION_M,
    half_extent_m: float = LOCAL_HALF_EXTENT_M,
    config: GPISConfig | None = None,
    repeats: int = 7,
    seed: int = 0,
) -> dict[str, float]:
    """:func:`benchmark_steps` at one resolution: its single row."""
    return benchmark_steps(
        n_contacts,
        resolutions_m=(resolution_m,),
        half_extent_m=half_extent_m,
        config=config,
        repeats=repeats,
        seed=seed,
    )[0]


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
