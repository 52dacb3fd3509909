"""Compiled (numba) scalar kernels of the exact closest-point queries of ``palpate.geometry.mesh_query``.

One point against one triangle (Ericson's Voronoi regions, the pseudo-normal sign), the bound that
prunes faces, and the warm-started patch search of ``WarmClosest``. ``ExactContactSensor``'s
few-point path and ``WarmClosest`` both call these, so they compute the same bits; the vectorised
numpy path (``closest_points_on_triangles``) agrees with them to rounding (about 1e-17 m,
tests/unit/geometry/test_mesh_query_few_points.py). :func:`refine_batch` is that vectorised path's
refinement with its own arithmetic (numpy's einsum and norm orders), so its bits, which
``mesh_query.refine_matches_numpy`` checks once per process before the sensor uses it. Compiled
without fast-math (no reassociation, no fused multiply-add), once per machine, and cached on disk
beside this module (``cache=True``): one point and one triangle cost about a microsecond from
Python, a patch of a few hundred faces a few microseconds.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Region codes, as in mesh_query (FACE, VERTEX_A, VERTEX_B, VERTEX_C, EDGE_AB, EDGE_BC, EDGE_CA).
_FACE, _VERTEX_A, _VERTEX_B, _VERTEX_C, _EDGE_AB, _EDGE_BC, _EDGE_CA = range(7)


@numba.njit(cache=True, error_model="numpy")  # a degenerate triangle divides by zero as numpy does
def closest_region(d1: float, d2: float, d3: float, d4: float, d5: float, d6: float) -> tuple[int, float, float]:
    """Region of the closest point of a triangle and its weights (Ericson 5.1.5).

    d1 = ab.ap, d2 = ac.ap, d3 = ab.bp, d4 = ac.bp, d5 = ab.cp, d6 = ac.cp. Returns the region code
    and the weights (wb, wc) of the closest point q = a + wb ab + wc ac; the same priority order and
    formulas as the vectorised ``closest_points_on_triangles``.
    """
    if d1 <= 0.0 and d2 <= 0.0:
        return _VERTEX_A, 0.0, 0.0
    if d3 >= 0.0 and d4 <= d3:
        return _VERTEX_B, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _EDGE_AB, d1 / (d1 - d3), 0.0
    if d6 >= 0.0 and d5 <= d6:
        return _VERTEX_C, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _EDGE_CA, 0.0, d2 / (d2 - d6)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 >= d3 and d5 >= d6:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return _EDGE_BC, 1.0 - t, t
    denom = 1.0 / (va + vb + vc)
    return _FACE, vb * denom, vc * denom


@numba.njit(cache=True)
def project(triangles: np.ndarray, face: int, px: float, py: float, pz: float) -> tuple[float, int, float, float]:
    """Squared distance, region and weights (wb, wc) of p projected onto ``triangles[face]``
    (triangles (F, 3, 3), p in the same frame)."""
    ax, ay, az = triangles[face, 0, 0], triangles[face, 0, 1], triangles[face, 0, 2]
    bx, by, bz = triangles[face, 1, 0], triangles[face, 1, 1], triangles[face, 1, 2]
    cx, cy, cz = triangles[face, 2, 0], triangles[face, 2, 1], triangles[face, 2, 2]
    abx, aby, abz, acx, acy, acz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    x, y, z = px - ax, py - ay, pz - az  # ap
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    region, wb, wc = closest_region(
        abx * x + aby * y + abz * z,
        acx * x + acy * y + acz * z,
        abx * bpx + aby * bpy + abz * bpz,
        acx * bpx + acy * bpy + acz * bpz,
        abx * cpx + aby * cpy + abz * cpz,
        acx * cpx + acy * cpy + acz * cpz,
    )
    ox, oy, oz = x - wb * abx - wc * acx, y - wb * aby - wc * acy, z - wb * abz - wc * acz  # p - q
    return ox * ox + oy * oy + oz * oz, region, wb, wc


@numba.njit(cache=True)
def bound_squared(planes: np.ndarray, offsets: np.ndarray, i: int, px: float, py: float, pz: float) -> float:
    """Lower bound of the squared distance from p to face row ``i`` of planes (N, 4, 3) and offsets
    (N, 4) (``ExactContactSensor``'s bound planes): plane^2 + max(0, max_e out_e)^2."""
    plane = planes[i, 0, 0] * px + planes[i, 0, 1] * py + planes[i, 0, 2] * pz - offsets[i, 0]
    outside = 0.0
    for e in range(1, 4):
        out = planes[i, e, 0] * px + planes[i, e, 1] * py + planes[i, e, 2] * pz - offsets[i, e]
        if out > outside:
            outside = out
    return plane * plane + outside * outside


@numba.njit(cache=True)
def finish(
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    face: int,
    region: int,
    wb: float,
    wc: float,
    px: float,
    py: float,
    pz: float,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
) -> tuple[float, float, float, float, bool, bool]:
    """The closest point q of p whose projection onto ``face`` is (region, wb, wc), the unsigned
    distance, inside by the pseudo-normal of the feature holding q (``sign_normals`` (F, 7, 3)), and
    whether that sign is weak (the pseudo-normal is short, or nearly orthogonal to p - q: then the
    caller decides by ray parity)."""
    ax, ay, az = triangles[face, 0, 0], triangles[face, 0, 1], triangles[face, 0, 2]
    bx, by, bz = triangles[face, 1, 0], triangles[face, 1, 1], triangles[face, 1, 2]
    cx, cy, cz = triangles[face, 2, 0], triangles[face, 2, 1], triangles[face, 2, 2]
    qx = ax + wb * (bx - ax) + wc * (cx - ax)
    qy = ay + wb * (by - ay) + wc * (cy - ay)
    qz = az + wb * (bz - az) + wc * (cz - az)
    ox, oy, oz = px - qx, py - qy, pz - qz
    dist = math.sqrt(ox * ox + oy * oy + oz * oz)
    nx, ny, nz = sign_normals[face, region, 0], sign_normals[face, region, 1], sign_normals[face, region, 2]
    side = ox * nx + oy * ny + oz * nz
    strength = math.sqrt(nx * nx + ny * ny + nz * nz)
    weak = strength < weak_pseudo_normal or abs(side) < weak_sign_cos * dist * strength
    return qx, qy, qz, dist, side < 0.0, weak


@numba.njit(cache=True)
def warm_query(
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    faces: np.ndarray,
    planes: np.ndarray,
    offsets: np.ndarray,
    lower0: np.ndarray,
    moved: float,
    start: int,
    px: float,
    py: float,
    pz: float,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
) -> tuple[int, float, float, float, float, bool, bool]:
    """One query of ``mesh_query.WarmClosest`` on its patch: search and finish in one call.

    faces (K,): patch faces sorted by ``lower0`` (K,), a lower bound of each face's distance from the
    point where the patch was built, which lies ``moved`` from p; planes (K, 4, 3) and offsets (K, 4):
    their lower-bound planes. A face is skipped when either bound (lower0 - moved, 1-Lipschitz, or
    the plane bound at p) cannot reach the best so far; the sorted ``lower0`` ends the loop early.
    Faces at the same squared distance (a vertex or edge they share) resolve to the lowest id, as in
    the sensor, so the answer does not depend on ``start`` or on the order of the search.
    Returns (face, qx, qy, qz, distance, inside, weak); ``weak``: the sign needs ray parity.
    """
    best, region, wb, wc = project(triangles, start, px, py, pz)
    face = start
    for k in range(faces.shape[0]):
        slack = best * (1.0 + 1e-9) + 1e-24
        reach = lower0[k] - moved
        if reach > 0.0 and reach * reach > slack * (1.0 + 1e-9):
            break  # sorted: every further face is at least as far
        h = faces[k]
        if h == start:
            continue
        if bound_squared(planes, offsets, k, px, py, pz) > slack:
            continue
        squared, h_region, h_wb, h_wc = project(triangles, h, px, py, pz)
        if squared < best or (squared == best and h < face):
            best, face, region, wb, wc = squared, h, h_region, h_wb, h_wc
    qx, qy, qz, dist, inside, weak = finish(
        triangles, sign_normals, face, region, wb, wc, px, py, pz, weak_pseudo_normal, weak_sign_cos
    )
    return face, qx, qy, qz, dist, inside, weak


@numba.njit(cache=True)
def ring_query(
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    ring: np.ndarray,
    planes: np.ndarray,
    offsets: np.ndarray,
    px: float,
    py: float,
    pz: float,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
) -> tuple[int, float, float, float, float, bool, bool]:
    """``ExactContactSensor``'s few-point query of p on one ring (Open3D's face first, then the faces
    around it, ``face_rings``): a face is projected unless its plane bound (planes (F, 4, 3), offsets
    (F, 4)) cannot reach the best so far; exact ties go to the lowest id. Returns (face, qx, qy, qz,
    distance, inside, weak) as :func:`warm_query`."""
    best, face, region, wb, wc = np.inf, -1, _FACE, 0.0, 0.0
    for k in range(ring.shape[0]):
        h = ring[k]
        # slack above the bound's rounding (~1e-17 m), so faces that may tie are projected
        if k and bound_squared(planes, offsets, h, px, py, pz) > best * (1.0 + 1e-9) + 1e-24:
            continue
        squared, h_region, h_wb, h_wc = project(triangles, h, px, py, pz)
        if squared < best or (squared == best and h < face):
            best, face, region, wb, wc = squared, h, h_region, h_wb, h_wc
    qx, qy, qz, dist, inside, weak = finish(
        triangles, sign_normals, face, region, wb, wc, px, py, pz, weak_pseudo_normal, weak_sign_cos
    )
    return face, qx, qy, qz, dist, inside, weak


@numba.njit(cache=True)
def build_patch(
    planes: np.ndarray, offsets: np.ndarray, near: np.ndarray, px: float, py: float, pz: float, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The patch of ``mesh_query.WarmClosest``: of the faces ``near`` (K0,), those whose lower bound at
    p (plane, then edges; rounded down) is at most ``radius``, sorted by that bound. Returns their ids
    (K,), bound planes (K, 4, 3), offsets (K, 4) and bounds (K,)."""
    count = near.shape[0]
    lower = np.empty(count)
    for i in range(count):
        lower[i] = math.sqrt(bound_squared(planes, offsets, near[i], px, py, pz)) * (1.0 - 1e-12)
    order = np.argsort(lower, kind="mergesort")
    kept = 0
    while kept < count and lower[order[kept]] <= radius * (1.0 + 1e-9):
        kept += 1
    faces = np.empty(kept, dtype=np.int64)
    patch_planes = np.empty((kept, 4, 3))
    patch_offsets = np.empty((kept, 4))
    patch_lower = np.empty(kept)
    for k in range(kept):
        i = order[k]
        h = near[i]
        faces[k] = h
        patch_planes[k] = planes[h]
        patch_offsets[k] = offsets[h]
        patch_lower[k] = lower[i]
    return faces, patch_planes, patch_offsets, patch_lower


@numba.njit(cache=True)
def _dot_einsum(ax: float, ay: float, az: float, bx: float, by: float, bz: float) -> float:
    """numpy's ``einsum("ij,ij->i")`` of one row of three: (x + z) + y (``refine_matches_numpy`` checks it)."""
    return (ax * bx + az * bz) + ay * by


@numba.njit(cache=True, error_model="numpy")
def refine_batch(
    local: np.ndarray,
    found: np.ndarray,
    ring: np.ndarray,
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
    faces_out: np.ndarray,
    points_out: np.ndarray,
    distance_out: np.ndarray,
    inside_out: np.ndarray,
    weak_out: np.ndarray,
) -> None:
    """The float64 refinement of ``ExactContactSensor.closest``'s vectorised path, point by point with
    its arithmetic (numpy's einsum and norm orders, its NaN and tie rules), so the same bits.

    local (n, 3) points (shifted frame), found (n,) Open3D's faces, ring (F, K) each face's ring
    (``face_rings``); writes each point's face, closest point, unsigned distance, inside (by the
    pseudo-normal) and whether that sign is weak (then the caller counts ray crossings).
    """
    K = ring.shape[1]
    squared = np.empty(K)
    regions = np.empty(K, dtype=np.int64)
    weights = np.empty((K, 2))
    for i in range(local.shape[0]):
        px, py, pz = local[i, 0], local[i, 1], local[i, 2]
        row = ring[found[i]]
        least = np.inf
        has_nan = False
        for k in range(K):
            f = row[k]
            ax, ay, az = triangles[f, 0, 0], triangles[f, 0, 1], triangles[f, 0, 2]
            abx, aby, abz = triangles[f, 1, 0] - ax, triangles[f, 1, 1] - ay, triangles[f, 1, 2] - az
            acx, acy, acz = triangles[f, 2, 0] - ax, triangles[f, 2, 1] - ay, triangles[f, 2, 2] - az
            apx, apy, apz = px - ax, py - ay, pz - az
            bpx, bpy, bpz = px - triangles[f, 1, 0], py - triangles[f, 1, 1], pz - triangles[f, 1, 2]
            cpx, cpy, cpz = px - triangles[f, 2, 0], py - triangles[f, 2, 1], pz - triangles[f, 2, 2]
            region, wb, wc = closest_region(
                _dot_einsum(abx, aby, abz, apx, apy, apz),
                _dot_einsum(acx, acy, acz, apx, apy, apz),
                _dot_einsum(abx, aby, abz, bpx, bpy, bpz),
                _dot_einsum(acx, acy, acz, bpx, bpy, bpz),
                _dot_einsum(abx, aby, abz, cpx, cpy, cpz),
                _dot_einsum(acx, acy, acz, cpx, cpy, cpz),
            )
            dx = ((ax + wb * abx) + wc * acx) - px  # q - p, q = a + wb ab + wc ac
            dy = ((ay + wb * aby) + wc * acy) - py
            dz = ((az + wb * abz) + wc * acz) - pz
            d = _dot_einsum(dx, dy, dz, dx, dy, dz)
            squared[k], regions[k], weights[k, 0], weights[k, 1] = d, region, wb, wc
            if d != d:
                has_nan = True
            elif d < least:
                least = d
        best = 0  # numpy's min is NaN when one is: no ring face ties with it, and argmin takes the first
        if not has_nan:
            lowest = np.iinfo(np.int64).max
            for k in range(K):
                if squared[k] == least and row[k] < lowest:
                    best, lowest = k, row[k]
        f = row[best]
        wb, wc = weights[best, 0], weights[best, 1]
        ax, ay, az = triangles[f, 0, 0], triangles[f, 0, 1], triangles[f, 0, 2]
        qx = (ax + wb * (triangles[f, 1, 0] - ax)) + wc * (triangles[f, 2, 0] - ax)
        qy = (ay + wb * (triangles[f, 1, 1] - ay)) + wc * (triangles[f, 2, 1] - ay)
        qz = (az + wb * (triangles[f, 1, 2] - az)) + wc * (triangles[f, 2, 2] - az)
        ox, oy, oz = px - qx, py - qy, pz - qz
        distance = math.sqrt((ox * ox + oy * oy) + oz * oz)  # numpy's norm: left to right
        region = regions[best]
        nx, ny, nz = sign_normals[f, region, 0], sign_normals[f, region, 1], sign_normals[f, region, 2]
        side = _dot_einsum(ox, oy, oz, nx, ny, nz)
        strength = math.sqrt((nx * nx + ny * ny) + nz * nz)
        faces_out[i] = f
        points_out[i, 0], points_out[i, 1], points_out[i, 2] = qx, qy, qz
        distance_out[i] = distance
        inside_out[i] = side < 0.0
        weak_out[i] = strength < weak_pseudo_normal or abs(side) < weak_sign_cos * distance * strength
