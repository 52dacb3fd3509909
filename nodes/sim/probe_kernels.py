"""The probe's physics steps in compiled code (numba): MuJoCo's own C functions called from the loop.

``ProbeContact.advance`` (nodes/sim/probe_contact.py) spends most of a contact step in Python around
the engine: setting the commanded twist, the 1-Lipschitz bound, the warm-started exact query, the
projection out of the surface. :func:`probe_steps` runs that loop for a batch of steps in one call: it calls ``mj_step``
and ``mju_quat2Mat`` of MuJoCo's shared library by address (the same library the Python bindings
use, so the same code), builds and searches the warm query's patch (``penalty_kernels.build``, as
for a hand's spheres, and ``closest_kernels.warm_query``) and projects the probe. Every expression
is the one of the Python path, in the same order (numpy's 3-element dot products and 3x3
matrix-vector products sum left to right; numba compiles without fast-math, so without fused
multiply-adds), so both paths give the same bits where numpy's BLAS sums left to right (OpenBLAS's
AVX2 kernels; with its AVX-512 ones, which fuse multiply-adds, the Python path differs in the last
bits); a test runs them side by side. Whatever needs
Python (the first query, a patch too far from the surface or too large, a weak sign decided by
Open3D's ray parity, a non-finite state) ends the call right after that step's ``mj_step``, and the
caller finishes the step on the Python path and calls again.

``mujoco_functions()`` returns None where MuJoCo's shared library is not found beside the bindings;
the simulation then keeps the Python loop.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from palpate.geometry import closest_kernels
from palpate.nodes.sim import penalty_kernels
from palpate.nodes.sim.mujoco_calls import call_void2, function_addresses

#: Layout of the probe's cache vector (float64): the last query's centre (3), its signed distance,
#: the closest point (3), its distance, the contact normal (3), and 1.0 when a hit is held.
CACHE_P, CACHE_D, HIT_POINT, HIT_DIST, HIT_NORMAL, HAS_HIT = 0, 3, 4, 7, 8, 11
CACHE_SIZE = 12
#: How a call of :func:`probe_steps` ended (DONE, NEEDS_PYTHON) and what :func:`probe_closest` found
#: (HIT, NO_HIT, NEEDS_PYTHON).
DONE, HIT, NEEDS_PYTHON, NO_HIT = 0, 0, 1, -1


def mujoco_functions() -> tuple[int, ...] | None:
    """Addresses of ``mj_step`` and ``mju_quat2Mat`` in the MuJoCo library the bindings loaded."""
    return function_addresses("mj_step", "mju_quat2Mat")


@numba.njit(cache=True)
def probe_closest(
    qpos: np.ndarray,
    cache: np.ndarray,
    radius: float,
    tol: float,
    mesh: Any,
    face_normals: np.ndarray,
    grid: Any,
    warm: Any,
    params: np.ndarray,
    candidates: np.ndarray,
) -> int:
    """``ProbeContact._closest`` at the probe's centre qpos[0:3]: NO_HIT, HIT (written into
    ``cache``) or NEEDS_PYTHON.

    mesh, grid, params and candidates as in ``penalty_kernels.query_near``; warm: the probe's patch,
    ``penalty_kernels.WarmPatches.arrays()`` of one sphere, rebuilt here (``penalty_kernels.build``)
    when the probe leaves its reach. The query repeats ``penalty_kernels.query_near``'s for one
    sphere: calling it would cost the probe's hot path the unboxing of its buffers on every call."""
    x, y, z = qpos[0], qpos[1], qpos[2]
    if cache[HAS_HIT] == 1.0 and x == cache[CACHE_P] and y == cache[CACHE_P + 1] and z == cache[CACHE_P + 2]:
        return HIT
    ox, oy, oz = x - cache[CACHE_P], y - cache[CACHE_P + 1], z - cache[CACHE_P + 2]
    bound = cache[CACHE_D] - math.sqrt(ox * ox + oy * oy + oz * oz)
    if bound > radius + tol:
        return NO_HIT
    # WarmClosest.query, as far as it needs no Python
    if not math.isfinite(x + y + z):
        return NEEDS_PYTHON
    centre, triangles, sign_normals, _, _ = mesh
    p0, face, start, size, searches, faces, planes, offsets, lower0, _ = warm
    px, py, pz = x - centre[0], y - centre[1], z - centre[2]
    dx, dy, dz = px - p0[0, 0], py - p0[0, 1], pz - p0[0, 2]
    out_of_reach = size[0] == 0 or dx**2 + dy**2 + dz**2 > params[penalty_kernels.P_REACH] ** 2
    # the one patch is always the arena's last, so a new one takes its room
    if out_of_reach and not penalty_kernels.build(0, px, py, pz, mesh, grid, warm, params, candidates):
        return NEEDS_PYTHON
    moved = math.sqrt((px - p0[0, 0]) ** 2 + (py - p0[0, 1]) ** 2 + (pz - p0[0, 2]) ** 2)
    a, e = start[0], start[0] + size[0]
    found, qx, qy, qz, dist, inside, weak = closest_kernels.warm_query(
        triangles,
        sign_normals,
        faces[a:e],
        planes[a:e],
        offsets[a:e],
        lower0[a:e],
        moved * (1.0 + 1e-12) + 1e-18,
        face[0],
        px,
        py,
        pz,
        params[penalty_kernels.P_WEAK_PSEUDO_NORMAL],
        params[penalty_kernels.P_WEAK_SIGN_COS],
    )
    if weak:
        return NEEDS_PYTHON
    face[0] = found
    searches[0] += 1
    signed = -dist if inside else dist
    qx, qy, qz = qx + centre[0], qy + centre[1], qz + centre[2]
    # the contact normal of a sphere: from the surface point to the centre; inside, the mesh normal
    nx, ny, nz = face_normals[found, 0], face_normals[found, 1], face_normals[found, 2]
    ox, oy, oz = x - qx, y - qy, z - qz
    length = math.sqrt(ox * ox + oy * oy + oz * oz)
    if signed > 0 and length > 1e-9:
        nx, ny, nz = ox / length, oy / length, oz / length
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    cache[CACHE_P], cache[CACHE_P + 1], cache[CACHE_P + 2] = x, y, z
    cache[CACHE_D] = signed
    cache[HIT_POINT], cache[HIT_POINT + 1], cache[HIT_POINT + 2] = qx, qy, qz
    cache[HIT_DIST] = signed
    cache[HIT_NORMAL], cache[HIT_NORMAL + 1], cache[HIT_NORMAL + 2] = nx / norm, ny / norm, nz / norm
    cache[HAS_HIT] = 1.0
    return HIT


@numba.njit(cache=True)
def probe_steps(
    step_function: int,
    quat2mat_function: int,
    model_address: int,
    data_address: int,
    steps: int,
    qpos: np.ndarray,
    qvel: np.ndarray,
    cmd_lin: np.ndarray,
    cmd_ang: np.ndarray,
    turning: bool,
    speed_per_step: float,
    R: np.ndarray,
    cache: np.ndarray,
    radius: float,
    tol: float,
    mesh: Any,
    face_normals: np.ndarray,
    grid: Any,
    warm: Any,
    params: np.ndarray,
    candidates: np.ndarray,
) -> tuple[int, int, bool]:
    """Up to ``steps`` probe steps of ``ProbeContact.advance``. Returns (steps taken, DONE |
    NEEDS_PYTHON, projected). With NEEDS_PYTHON the last step's ``mj_step`` has run but not its
    projection. A call that completes its steps also ends the batch as ``ProbeContact.advance`` does: it
    drops the inward velocity of a last projection (numpy's lines, the dot product summed left to
    right) and then asks :func:`probe_closest` at the projected centre, the query the contacts make
    next (it holds the hit in ``cache``; one that needs Python is left to them), and returns
    projected False. The rest as in :func:`probe_closest`."""
    taken = 0
    projected = False
    qpos_address = qpos.ctypes.data + 3 * 8  # the quaternion qpos[3:7]
    while taken < steps:
        remaining = steps - taken
        qvel[0], qvel[1], qvel[2] = cmd_lin[0], cmd_lin[1], cmd_lin[2]
        if turning:
            # angular velocity in the body frame: R^T w, R from MuJoCo's own conversion
            call_void2(quat2mat_function, R.ctypes.data, qpos_address)
            for i in range(3):
                qvel[3 + i] = R[i] * cmd_ang[0] + R[3 + i] * cmd_ang[1] + R[6 + i] * cmd_ang[2]
        else:
            qvel[3], qvel[4], qvel[5] = 0.0, 0.0, 0.0
        ox, oy, oz = qpos[0] - cache[CACHE_P], qpos[1] - cache[CACHE_P + 1], qpos[2] - cache[CACHE_P + 2]
        margin = cache[CACHE_D] - math.sqrt(ox * ox + oy * oy + oz * oz) - radius - tol
        free = 0
        if math.isfinite(margin) and margin > 0:
            free = remaining if speed_per_step == 0 else min(remaining, int(margin / speed_per_step))
        if free > 0:
            for _ in range(free):
                call_void2(step_function, model_address, data_address)
            taken += free
            projected = False
            continue
        call_void2(step_function, model_address, data_address)
        taken += 1
        total = 0.0
        for i in range(qpos.shape[0]):
            total += qpos[i]
        if not math.isfinite(total):
            projected = False
            continue
        status = probe_closest(qpos, cache, radius, tol, mesh, face_normals, grid, warm, params, candidates)
        if status == NEEDS_PYTHON:
            return taken, NEEDS_PYTHON, projected
        projected = False
        if status == HIT and cache[HIT_DIST] < radius:
            for i in range(3):
                qpos[i] = cache[HIT_POINT + i] + radius * cache[HIT_NORMAL + i]
            projected = True
    if projected and cache[HAS_HIT] == 1.0:
        nx, ny, nz = cache[HIT_NORMAL], cache[HIT_NORMAL + 1], cache[HIT_NORMAL + 2]
        inward = qvel[0] * nx + qvel[1] * ny + qvel[2] * nz
        if inward < 0.0:
            qvel[0], qvel[1], qvel[2] = qvel[0] - inward * nx, qvel[1] - inward * ny, qvel[2] - inward * nz
        probe_closest(qpos, cache, radius, tol, mesh, face_normals, grid, warm, params, candidates)
    return taken, DONE, False
