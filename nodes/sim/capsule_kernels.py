"""The broad phase of a hand's or finger's exact-mesh penalty contacts, in compiled code (numba).

Before every physics step, ``PenaltyContacts._sphere_hits`` places the capsule spheres (K of them: 42
for a finger, 194 for a hand) in the world and keeps those whose 1-Lipschitz bound on the signed
distance, ``d_last - |c - c_last|``, does not rule out a contact; most steps keep none. In numpy that
is a dozen calls on (K, 3) arrays, about a third of a finger's step. :func:`sphere_bounds` does it in
one loop with numpy's own order of operations: a centre is ``xpos + R @ offset`` where numpy's
einsum sums the three products of a row as ``(p0 + p2) + p1``, and a norm sums its three squares
left to right; numba compiles without fast-math, so without fused multiply-adds. That order is
numpy's choice, not a promise, so :func:`matches_numpy` compares both on random input once per
process and the simulation keeps the numpy path where they differ.
"""

from __future__ import annotations

import math
from functools import cache

import numba
import numpy as np

A = np.ndarray  # the arrays of both functions, as sphere_bounds documents them


@numba.njit(cache=True)
def place(k: int, xpos: A, xmat: A, geoms: A, offsets: A, centres: A) -> None:
    """World centre of sphere k into centres[k], as :func:`sphere_bounds` documents the arrays."""
    g = geoms[k]
    o0, o1, o2 = offsets[k, 0], offsets[k, 1], offsets[k, 2]
    for i in range(3):
        p0 = xmat[g, 3 * i] * o0
        p1 = xmat[g, 3 * i + 1] * o1
        p2 = xmat[g, 3 * i + 2] * o2
        centres[k, i] = xpos[g, i] + ((p0 + p2) + p1)  # c = x + R o, in einsum's order


@numba.njit(cache=True)
def place_all(xpos: A, xmat: A, geoms: A, offsets: A, centres: A) -> None:
    """World centres (K, 3) of all spheres (``capsules.sphere_centres``' bits, where :func:`matches_numpy`)."""
    for k in range(geoms.shape[0]):
        place(k, xpos, xmat, geoms, offsets, centres)


@numba.njit(cache=True)
def sphere_bounds(
    xpos: np.ndarray,
    xmat: np.ndarray,
    geoms: np.ndarray,
    offsets: np.ndarray,
    cache_p: np.ndarray,
    cache_d: np.ndarray,
    reach: np.ndarray,
    centres: np.ndarray,
    near: np.ndarray,
) -> int:
    """World centres of the spheres and those that may touch; returns how many may.

    xpos (G, 3) and xmat (G, 9) geom frames (MuJoCo's ``geom_xpos``, ``geom_xmat``, row-major);
    geoms (K,) each sphere's geom, offsets (K, 3) its centre in the geom frame; cache_p (K, 3) and
    cache_d (K,) each sphere's last query point and signed distance; reach (K,) radius plus tolerance.
    Writes centres (K, 3) and, into near[:count], the indices k with
    ``cache_d[k] - |centres[k] - cache_p[k]| <= reach[k]`` in increasing order.
    """
    count = 0
    for k in range(geoms.shape[0]):
        place(k, xpos, xmat, geoms, offsets, centres)
        d0 = centres[k, 0] - cache_p[k, 0]
        d1 = centres[k, 1] - cache_p[k, 1]
        d2 = centres[k, 2] - cache_p[k, 2]
        bound = cache_d[k] - math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)  # 1-Lipschitz: d(c) >= bound
        if bound <= reach[k]:
            near[count] = k
            count += 1
    return count


def numpy_bounds(xpos: A, xmat: A, geoms: A, offsets: A, cache_p: A, cache_d: A, reach: A) -> tuple[A, A]:
    """:func:`sphere_bounds` in numpy (the reference): centres (K, 3) and the indices that may touch."""
    R = xmat[geoms].reshape(-1, 3, 3)
    centres = xpos[geoms] + np.einsum("kij,kj->ki", R, offsets)
    bound = cache_d - np.linalg.norm(centres - cache_p, axis=1)
    return centres, np.flatnonzero(bound <= reach)


@cache
def matches_numpy(samples: int = 200) -> bool:
    """Whether :func:`sphere_bounds` gives numpy's bits here (random frames, offsets and caches)."""
    rng = np.random.default_rng(20260101)
    for _ in range(samples):
        geoms = rng.integers(0, 8, 24)
        xpos, xmat = rng.standard_normal((8, 3)), rng.standard_normal((8, 9))
        offsets = rng.standard_normal((24, 3))
        cache_p = xpos[geoms] + 0.1 * rng.standard_normal((24, 3))
        cache_d = 2.0 * rng.standard_normal(24)
        reach = np.full(24, 0.5)
        centres, near = numpy_bounds(xpos, xmat, geoms, offsets, cache_p, cache_d, reach)
        got, found = np.empty((24, 3)), np.empty(24, dtype=np.int64)
        count = sphere_bounds(xpos, xmat, geoms, offsets, cache_p, cache_d, reach, got, found)
        if got.tobytes() != centres.tobytes() or not np.array_equal(found[:count], near):
            return False
    return True
