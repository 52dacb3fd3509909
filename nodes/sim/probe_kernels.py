"""The probe's physics steps in compiled code (numba): MuJoCo's own C functions called from the loop.

``Simulation._probe_advance`` spends most of a contact step in Python around the engine: setting the
commanded twist, the 1-Lipschitz bound, the warm-started exact query, the projection out of the
surface. :func:`probe_steps` runs that loop for a batch of steps in one call: it calls ``mj_step``
and ``mju_quat2Mat`` of MuJoCo's shared library by address (the same library the Python bindings
use, so the same code), searches the warm query's patch with ``closest_kernels.warm_query`` and
projects the probe. Every expression is the one of the Python path, in the same order (numpy's
3-element dot products and 3x3 matrix-vector products sum left to right; numba compiles without
fast-math, so without fused multiply-adds), so both paths give the same bits; a test runs them side
by side. Whatever needs Python (a new patch, a tie settled by Open3D, a weak sign decided by ray
parity, a non-finite state) ends the call right after that step's ``mj_step``, and the caller
finishes the step on the Python path and calls again.

``mujoco_functions()`` returns None where MuJoCo's shared library is not found beside the bindings;
the simulation then keeps the Python loop.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from palpate.geometry import closest_kernels
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
    centre: np.ndarray,
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    face_normals: np.ndarray,
    reach: float,
    p0: np.ndarray,
    start_face: int,
    faces: np.ndarray,
    planes: np.ndarray,
    offsets: np.ndarray,
    lower0: np.ndarray,
    ties: np.ndarray,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
) -> tuple[int, int, int]:
    """``Simulation._probe_closest`` at the probe's centre qpos[0:3]: (NO_HIT | HIT, written into
    ``cache`` | NEEDS_PYTHON, the warm face, 1 when the warm patch was searched)."""
    x, y, z = qpos[0], qpos[1], qpos[2]
    if cache[HAS_HIT] == 1.0 and x == cache[CACHE_P] and y == cache[CACHE_P + 1] and z == cache[CACHE_P + 2]:
        return HIT, start_face, 0
    ox, oy, oz = x - cache[CACHE_P], y - cache[CACHE_P + 1], z - cache[CACHE_P + 2]
    bound = cache[CACHE_D] - math.sqrt(ox * ox + oy * oy + oz * oz)
    if bound > radius + tol:
        return NO_HIT, start_face, 0
    # WarmClosest.query, as far as it needs no Python
    if not math.isfinite(x + y + z):
        return NEEDS_PYTHON, start_face, 0
    px, py, pz = x - centre[0], y - centre[1], z - centre[2]
    if faces.shape[0] == 0 or start_face < 0:
        return NEEDS_PYTHON, start_face, 0
    dx, dy, dz = px - p0[0], py - p0[1], pz - p0[2]
    if dx**2 + dy**2 + dz**2 > reach**2:
        return NEEDS_PYTHON, start_face, 0
    moved = math.sqrt((px - p0[0]) ** 2 + (py - p0[1]) ** 2 + (pz - p0[2]) ** 2)
    status, face, qx, qy, qz, dist, inside, weak = closest_kernels.warm_query(
        triangles,
        sign_normals,
        faces,
        planes,
        offsets,
        lower0,
        moved * (1.0 + 1e-12) + 1e-18,
        start_face,
        px,
        py,
        pz,
        weak_pseudo_normal,
        weak_sign_cos,
        ties,
        False,
    )
    if status == 1 or weak:
        return NEEDS_PYTHON, start_face, 0
    signed = -dist if inside else dist
    qx, qy, qz = qx + centre[0], qy + centre[1], qz + centre[2]
    # the contact normal of a sphere: from the surface point to the centre; inside, the mesh normal
    nx, ny, nz = face_normals[face, 0], face_normals[face, 1], face_normals[face, 2]
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
    return HIT, face, 1


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
    centre: np.ndarray,
    triangles: np.ndarray,
    sign_normals: np.ndarray,
    face_normals: np.ndarray,
    reach: float,
    p0: np.ndarray,
    start_face: int,
    faces: np.ndarray,
    planes: np.ndarray,
    offsets: np.ndarray,
    lower0: np.ndarray,
    ties: np.ndarray,
    weak_pseudo_normal: float,
    weak_sign_cos: float,
) -> tuple[int, int, bool, int, int]:
    """Up to ``steps`` probe steps of ``Simulation._probe_advance`` (without its final drop of the
    inward velocity). Returns (steps taken, DONE | NEEDS_PYTHON, projected, the warm face, patch
    searches). With NEEDS_PYTHON the last step's ``mj_step`` has run but not its projection."""
    taken = 0
    projected = False
    face = start_face
    searches = 0
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
        status, face, searched = probe_closest(
            qpos,
            cache,
            radius,
            tol,
            centre,
            triangles,
            sign_normals,
            face_normals,
            reach,
            p0,
            face,
            faces,
            planes,
            offsets,
            lower0,
            ties,
            weak_pseudo_normal,
            weak_sign_cos,
        )
        searches += searched
        if status == NEEDS_PYTHON:
            return taken, NEEDS_PYTHON, projected, face, searches
        projected = False
        if status == HIT and cache[HIT_DIST] < radius:
            for i in range(3):
                qpos[i] = cache[HIT_POINT + i] + radius * cache[HIT_NORMAL + i]
            projected = True
    return taken, DONE, projected, face, searches
