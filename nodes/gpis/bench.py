"""Timing of one GPIS update plus the local surface (issue 5 goal: < 20 ms at 200 contacts).

Run ``OPENBLAS_NUM_THREADS=1 python -m palpate.nodes.gpis.bench`` for the resolution trade table.
Contacts lie on an ellipsoid with semi-axes 6 x 4 x 3 cm (a YCB-sized object); the local surface is
the paper's planning patch, +-5 cm around the newest contact.

Measured at 200 contacts, thin-plate, single-threaded BLAS, CPU ms (median; the 2-core machine was
shared with other jobs at load 5-7, so wall-clock was 2-4x higher and is not representative):

    grid   add_contact   local surface   of which vertex variance   vertices
    2 mm       1.7           196                 ~120                 3734
    3 mm       1.4            86                  ~55                 1721
    4 mm       1.5            49                  ~31                 1017
    5 mm       1.4            28                  ~17                  619   (default)

At 5 mm: update + surface without variance = 11.7 ms; with Eq. 6 only at the ~260 candidates the
planner keeps (5 mm thinning) = 18 ms; with Eq. 6 at every vertex = 26-30 ms. The variance is a
triangular solve with 4n rows per vertex (n^2 V flops, BLAS-bound at ~40 GFlop/s on one core).
Multithreaded OpenBLAS on a busy 2-core machine stalls (surface 120 ms CPU instead of 28): run the
GPIS process with OPENBLAS_NUM_THREADS=1.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.surface import LOCAL_HALF_EXTENT_M, LOCAL_RESOLUTION_M, local_surface

FloatArray = NDArray[np.float64]

ELLIPSOID_AXES_M = np.array([0.06, 0.04, 0.03])


def ellipsoid_contacts(
    n: int, rng: np.random.Generator, axes_m: FloatArray = ELLIPSOID_AXES_M
) -> tuple[FloatArray, FloatArray]:
    """n contact positions (n, 3) on the ellipsoid sum (x_i / a_i)^2 = 1 and outward unit normals (n, 3)."""
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = u * axes_m
    normal = p / axes_m**2
    return p, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def benchmark_update(
    n_contacts: int = 200,
    *,
    resolution_m: float = LOCAL_RESOLUTION_M,
    half_extent_m: float = LOCAL_HALF_EXTENT_M,
    config: GPISConfig | None = None,
    repeats: int = 7,
    seed: int = 0,
) -> dict[str, float]:
    """Median wall-clock ms of add_contact and of local_surface when the GP reaches n_contacts.

    The first n_contacts - repeats contacts are added in one batch (setup, not timed); each of the last
    `repeats` contacts is then added alone and followed by a local surface around it, as in one step
    of Algorithm 1. Returns medians of wall-clock ms (add_contact_ms, local_surface_ms, total_ms,
    local_surface_without_variance_ms, vertex_variance_ms), the same as process CPU ms under a
    ``cpu_`` prefix (equal to wall time on an idle core when BLAS runs one thread; with several BLAS
    threads CPU time sums them), and the mesh size of the last call.
    """
    if n_contacts < repeats + 1:
        raise ValueError(f"n_contacts ({n_contacts}) must exceed repeats ({repeats})")
    rng = np.random.default_rng(seed)
    P, N = ellipsoid_contacts(n_contacts, rng)
    gp = GPIS(config if config is not None else GPISConfig())
    n0 = n_contacts - repeats
    gp.add_contacts(P[:n0], N[:n0])
    wall: dict[str, list[float]] = {"add": [], "surface": [], "novar": []}
    cpu: dict[str, list[float]] = {"add": [], "surface": [], "novar": []}
    mesh = None
    for i in range(n0, n_contacts):
        with _Timer(wall["add"], cpu["add"]):
            gp.add_contact(P[i], N[i])
        with _Timer(wall["surface"], cpu["surface"]):
            mesh = local_surface(gp, P[i], half_extent_m, resolution_m)
        with _Timer(wall["novar"], cpu["novar"]):
            local_surface(gp, P[i], half_extent_m, resolution_m, with_variance=False)
    assert mesh is not None
    var_wall: list[float] = []
    var_cpu: list[float] = []
    for _ in range(repeats):
        with _Timer(var_wall, var_cpu):
            gp.variance(mesh.vertices)
    out = {"n_contacts": float(n_contacts), "resolution_m": resolution_m}
    for prefix, times in (("", wall), ("cpu_", cpu)):
        out[f"{prefix}add_contact_ms"] = float(np.median(times["add"]))
        out[f"{prefix}local_surface_ms"] = float(np.median(times["surface"]))
        out[f"{prefix}total_ms"] = out[f"{prefix}add_contact_ms"] + out[f"{prefix}local_surface_ms"]
        out[f"{prefix}local_surface_without_variance_ms"] = float(np.median(times["novar"]))
    out["vertex_variance_ms"] = float(np.median(var_wall))
    out["cpu_vertex_variance_ms"] = float(np.median(var_cpu))
    out["n_vertices"] = float(len(mesh.vertices))
    out["n_faces"] = float(len(mesh.faces))
    return out


class _Timer:
    """Appends wall-clock and process CPU milliseconds of a with-block to two lists."""

    def __init__(self, wall: list[float], cpu: list[float]) -> None:
        self.wall, self.cpu = wall, cpu

    def __enter__(self) -> None:
        self.t_wall, self.t_cpu = time.perf_counter(), time.process_time()

    def __exit__(self, *exc: object) -> None:
        self.wall.append(1e3 * (time.perf_counter() - self.t_wall))
        self.cpu.append(1e3 * (time.process_time() - self.t_cpu))


def main() -> None:
    """Print the resolution trade at 200 contacts for both kernels (wall ms, CPU ms in brackets)."""
    print("kernel      res_mm  add_ms        surface_ms     total_ms       no_var_ms      var_ms  vertices")
    for kernel in ("thin_plate", "gaussian"):
        for res in (0.002, 0.003, 0.004, 0.005):
            r = benchmark_update(200, resolution_m=res, config=GPISConfig(kernel=kernel))
            cols = ["add_contact_ms", "local_surface_ms", "total_ms", "local_surface_without_variance_ms"]
            cells = "".join(f"  {r[c]:6.2f} ({r['cpu_' + c]:5.1f})" for c in cols)
            print(f"{kernel:10s}  {res * 1e3:6.0f}{cells}  {r['vertex_variance_ms']:6.2f}  {r['n_vertices']:8.0f}")


if __name__ == "__main__":
    main()
