"""A hand's or finger's physics steps on a mesh in compiled code (numba), MuJoCo's C functions called
from the loop.

On a mesh, every step of ``Simulation.step`` runs ``mj_step1``, places the capsule spheres, queries the
exact surface for the spheres the 1-Lipschitz bound leaves near it, sets the penalty wrench in
``xfrc_applied`` and runs ``mj_step2``. In Python that is about 150 us a step around 5 to 10 us of
physics. :func:`penalty_steps` runs the whole loop for a batch of steps: ``mj_step1`` and ``mj_step2``
of MuJoCo's shared library by address (``mujoco_calls.call_void2``), the bounds of
``capsule_kernels.sphere_bounds``, each near sphere's warm-started query with
``closest_kernels.warm_query`` on its patch (:class:`WarmPatches` packs the patches of the spheres'
``WarmClosest`` queries) and the penalty wrench (:func:`penalty_wrench`). Every expression is the
numpy path's, in the same order (numba compiles without fast-math), so both give the same bits;
:func:`matches_numpy` checks the wrench on random input once per process, and a test runs both paths
side by side.

A query that needs Python ends the call *within* its step, before ``mj_step2``: a patch the
compiled build cannot make (a sphere's first, one too far or too large, a full arena), a weak sign
(Open3D's ray parity), or more than ``FEW_POINTS`` near spheres (the sensor's vectorised query,
which rounds differently). The caller answers that sphere (or the batch) into the buffers and calls
again with ``resume`` set to where the queries go on. A call that completes its steps refreshes the
frames and velocities (the functions ``mj_forward`` calls first) and asks the queries of the state it
ends in, which the contacts read and the next step's first ``mj_step1`` would ask again
(``END_QUERIED``); where one of them needs Python they are left to the contacts.
``mujoco_functions()`` returns None where MuJoCo's shared library is not found beside the bindings;
the simulation then keeps the Python loop.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numba
import numpy as np

from palpate.geometry import closest_kernels
from palpate.geometry.mesh_query import WEAK_PSEUDO_NORMAL, WEAK_SIGN_COS, ExactContactSensor, WarmClosest
from palpate.nodes.sim import capsule_kernels
from palpate.nodes.sim.mujoco_calls import call_void2, function_addresses

#: How a call ended: DONE; NEEDS_PYTHON (``at``: the position in ``near`` of the sphere to answer, or
#: BATCH for all of them); PENETRATED (a touching sphere's centre is inside); NOT_FINITE (after mj_step2).
DONE, NEEDS_PYTHON, PENETRATED, NOT_FINITE = 0, 1, 2, 3
BATCH = -1
#: Layout of the parameter vector: the patch reach, the weak-sign limits, stiffness and damping, ...
P_REACH, P_WEAK_PSEUDO_NORMAL, P_WEAK_SIGN_COS, P_STIFFNESS, P_DAMPING = range(5)
#: ... the patch limits (WarmClosest's max_distance_m, max_patch_faces), the grid's cell size and the
#: largest face radius (face_grid).
P_MAX_DISTANCE, P_MAX_FACES, P_CELL, P_LARGEST = range(5, 9)
PARAMS = 9
#: ``resume`` of :func:`penalty_steps` when the buffers already hold the queries of the current state
#: (``Simulation.contacts`` or the end of the last call made them, and nothing has moved since): its
#: first step asks nothing again.
HITS_CURRENT = -2
#: ``at`` of a :func:`penalty_steps` call that completed its steps and the queries of the state it
#: ends in (the buffers hold them, as :func:`sphere_hits` leaves them).
END_QUERIED = 1
#: Layout of the state vector: how many spheres are near, how many of them touch.
S_NEAR, S_TOUCHING = 0, 1
#: Layout of the search vector: the query point (3, shifted frame), then warm_query's face, point (3),
#: distance, inside and weak, and 1.0 while Python has to settle it.
SEARCH_P, SEARCH_FACE, SEARCH_Q, SEARCH_DIST, SEARCH_INSIDE, SEARCH_WEAK, SEARCH_PENDING = 0, 3, 4, 7, 8, 9, 10
SEARCH_SIZE = 11

A = np.ndarray


def mujoco_functions() -> tuple[int, ...] | None:
    """Addresses of ``mj_step1``, ``mj_step2``, ``mj_kinematics``, ``mj_comPos`` and ``mj_comVel`` in the
    MuJoCo library the bindings loaded."""
    return function_addresses("mj_step1", "mj_step2", "mj_kinematics", "mj_comPos", "mj_comVel")


# --- the penalty wrench --------------------------------------------------------------------------


def cross(a: A, b: A) -> A:
    """Row-wise cross product of (n, 3) arrays (np.cross is slow on small arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def numpy_forces(bodies: A, radius: A, points: A, dist: A, normals: A, cvel: A, origin: A, k: float, b: float) -> A:
    """Penalty normal force (t,) >= 0 of touching spheres, ``k (r - d) - b v_n`` (the reference).

    bodies (t,), radius (t,), surface points (t, 3), distances (t,), normals (t, 3); cvel (nbody, 6)
    MuJoCo's (angular, linear) body velocities at origin (t, 3), the subtree centre of mass of each
    sphere's root body.
    """
    vel = cvel[bodies]
    v_point = vel[:, 3:] + cross(vel[:, :3], points - origin)
    v_n = np.einsum("ij,ij->i", v_point, normals)
    return np.maximum(0.0, k * (radius - dist) - b * v_n)


def numpy_wrench(bodies: A, points: A, normals: A, forces: A, xipos: A) -> A:
    """``xfrc_applied`` (nbody, 6) of the forces (t,) along normals (t, 3) at points (t, 3) on bodies
    (t,) (the reference): force and torque about each body's centre of mass ``xipos`` (nbody, 3)."""
    f = forces[:, None] * normals
    torque = cross(points - xipos[bodies], f)
    wrench = np.zeros((len(xipos), 6))
    np.add.at(wrench, bodies, np.concatenate([f, torque], axis=1))
    return wrench


@numba.njit(cache=True)
def sphere_force(
    s: int,
    p0: float,
    p1: float,
    p2: float,
    distance: float,
    n0: float,
    n1: float,
    n2: float,
    body: A,
    radius: A,
    body_rootid: A,
    cvel: A,
    subtree_com: A,
    k: float,
    b: float,
) -> float:
    """:func:`numpy_forces` of sphere ``s`` touching at (p0, p1, p2), ``distance`` from its centre,
    along the outward normal (n0, n1, n2)."""
    bd = body[s]
    root = body_rootid[bd]
    a0, a1, a2 = cvel[bd, 0], cvel[bd, 1], cvel[bd, 2]
    r0 = p0 - subtree_com[root, 0]
    r1 = p1 - subtree_com[root, 1]
    r2 = p2 - subtree_com[root, 2]
    v0 = cvel[bd, 3] + (a1 * r2 - a2 * r1)  # v = v_lin + w x (p - com)
    v1 = cvel[bd, 4] + (a2 * r0 - a0 * r2)
    v2 = cvel[bd, 5] + (a0 * r1 - a1 * r0)
    v_n = (v0 * n0 + v2 * n2) + v1 * n1  # einsum's order
    force = k * (radius[s] - distance) - b * v_n
    if not force > 0.0:
        force = 0.0 if force <= 0.0 else force  # np.maximum: NaN stays NaN
    return force


@numba.njit(cache=True)
def penalty_forces(
    spheres: A,
    points: A,
    dist: A,
    normals: A,
    body: A,
    radius: A,
    body_rootid: A,
    cvel: A,
    subtree_com: A,
    k: float,
    b: float,
    out: A,
) -> None:
    """:func:`numpy_forces` of the touching ``spheres`` (t,) into out (t,): their hits (t, 3), distances
    (t,) and outward normals (t, 3); MuJoCo's cvel (nbody, 6) and subtree_com (nbody, 3)."""
    for j in range(spheres.shape[0]):
        out[j] = sphere_force(
            spheres[j],
            points[j, 0],
            points[j, 1],
            points[j, 2],
            dist[j],
            normals[j, 0],
            normals[j, 1],
            normals[j, 2],
            body,
            radius,
            body_rootid,
            cvel,
            subtree_com,
            k,
            b,
        )


@numba.njit(cache=True)
def penalty_wrench(
    rows: A,
    near: A,
    points: A,
    dist: A,
    faces: A,
    face_normals: A,
    body: A,
    radius: A,
    body_rootid: A,
    data: Any,
    k: float,
    b: float,
) -> None:
    """:func:`numpy_forces` and :func:`numpy_wrench` of the spheres ``near[rows]`` (their hits at
    ``rows`` of points, dist and faces), added into ``xfrc_applied`` (zero on entry).

    data: MuJoCo's (cvel (nbody, 6), subtree_com (nbody, 3), xipos (nbody, 3), xfrc_applied (nbody, 6)).
    """
    cvel, subtree_com, xipos, xfrc = data
    for j in rows:
        s = near[j]
        bd = body[s]
        n0, n1, n2 = face_normals[faces[j], 0], face_normals[faces[j], 1], face_normals[faces[j], 2]
        force = sphere_force(
            s,
            points[j, 0],
            points[j, 1],
            points[j, 2],
            dist[j],
            n0,
            n1,
            n2,
            body,
            radius,
            body_rootid,
            cvel,
            subtree_com,
            k,
            b,
        )
        f0, f1, f2 = force * n0, force * n1, force * n2
        p0 = points[j, 0] - xipos[bd, 0]
        p1 = points[j, 1] - xipos[bd, 1]
        p2 = points[j, 2] - xipos[bd, 2]
        xfrc[bd, 0] += f0
        xfrc[bd, 1] += f1
        xfrc[bd, 2] += f2
        xfrc[bd, 3] += p1 * f2 - p2 * f1  # (p - x_i) x f
        xfrc[bd, 4] += p2 * f0 - p0 * f2
        xfrc[bd, 5] += p0 * f1 - p1 * f0


@cache
def matches_numpy(samples: int = 500) -> bool:
    """Whether :func:`penalty_wrench` and :func:`penalty_forces` give the bits of :func:`numpy_forces`
    and :func:`numpy_wrench` here (random spheres, hits and velocities)."""
    rng = np.random.default_rng(20260102)
    nbody, count = 6, 40
    for _ in range(samples):
        body, radius = rng.integers(1, nbody, count), np.full(count, 0.008)
        t = int(rng.integers(1, 12))
        near = np.sort(rng.choice(count, t, replace=False))
        points = 0.05 * rng.standard_normal((t, 3))
        dist = rng.uniform(0.0, 0.009, t)
        face_normals = rng.standard_normal((t, 3))
        face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
        cvel, com, xipos = (
            rng.standard_normal((nbody, 6)),
            0.05 * rng.standard_normal((nbody, 3)),
            0.05 * rng.standard_normal((nbody, 3)),
        )
        rootid = np.array([0] + [1] * (nbody - 1))
        bodies = body[near]
        forces = numpy_forces(bodies, radius[near], points, dist, face_normals, cvel, com[rootid[bodies]], 2000.0, 5.0)
        expected = numpy_wrench(bodies, points, face_normals, forces, xipos)
        got = np.zeros((nbody, 6))
        rows, faces = np.arange(t), np.arange(t)
        penalty_wrench(
            rows, near, points, dist, faces, face_normals, body, radius, rootid, (cvel, com, xipos, got), 2000.0, 5.0
        )
        got_forces = np.empty(t)
        penalty_forces(near, points, dist, face_normals, body, radius, rootid, cvel, com, 2000.0, 5.0, got_forces)
        if got.tobytes() != expected.tobytes() or got_forces.tobytes() != forces.tobytes():
            return False
    return True


# --- the spheres' warm-started queries -------------------------------------------------------------


def load_query_kernels(sensor: ExactContactSensor) -> None:
    """Load the compiled kernels that a sphere's query calls from Python (a patch build, a weak sign,
    handing a patch back to the arena) and build the sensor's face index now, not at the first
    contact: tens of milliseconds once per process, which would otherwise stall a step of a running
    graph."""
    k = closest_kernels
    centre, triangles, signs, bound_planes, bound_offsets = sensor.query_mesh
    k.project(triangles, 0, 0.0, 0.0, 0.0)
    k.finish(triangles, signs, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, WEAK_PSEUDO_NORMAL, WEAK_SIGN_COS)
    faces, planes, offsets, lower0 = k.build_patch(
        bound_planes, bound_offsets, np.zeros(0, dtype=np.int64), 0.0, 0.0, 0.0, 1.0
    )
    k.warm_query(triangles, signs, faces, planes, offsets, lower0, 0.0, 0, 0.0, 0.0, 0.0, 0.1, 0.1)
    index = np.zeros(1, dtype=np.int64)
    drop_patch(0, index, index.copy(), index.copy())  # WarmPatches.store's
    sensor.face_index()
    cx, cy, cz = centre.tolist()
    sensor.seed_face(cx, cy, cz)  # Open3D's face query at the shifted frame's origin


class WarmPatches:
    """The ``WarmClosest`` queries of K spheres, packed for compiled code, which builds patches too.

    Per sphere: where its patch was built (K, 3), its last face (K,) (-1: none yet), where its patch
    starts in the arena and how many faces it holds (K,) (0: no patch) and its patch searches not yet
    reported (K,). The arena holds the patches one after the other (``faces``, ``planes``,
    ``offsets``, ``lower0``, ``used`` of them taken); a compiled build appends there, and when the
    arena is full Python builds and packs the live patches into a larger one.
    """

    faces: A
    planes: A
    offsets: A
    lower0: A

    def __init__(self, count: int, max_patch_faces: int, capacity: int = 0) -> None:
        self.p0 = np.full((count, 3), np.inf)
        self.face = np.full(count, -1, dtype=np.int64)
        self.start = np.zeros(count, dtype=np.int64)
        self.size = np.zeros(count, dtype=np.int64)
        self.searches = np.zeros(count, dtype=np.int64)
        self.used = np.zeros(1, dtype=np.int64)
        self._given: list[A | None] = [None] * count  # the faces each sphere's Python query last got
        self._allocate(capacity or 8 * max_patch_faces)  # faces the arena holds at first

    def arrays(self) -> tuple[A, ...]:
        """The arrays :func:`query_near` reads and writes."""
        return (
            self.p0,
            self.face,
            self.start,
            self.size,
            self.searches,
            self.faces,
            self.planes,
            self.offsets,
            self.lower0,
            self.used,
        )

    def load(self, k: int, warm: WarmClosest) -> None:
        """Hand sphere k's warm start (its patch, last face and searches) to its Python query."""
        window = slice(self.start[k], self.start[k] + self.size[k])
        faces = self.faces[window]
        warm.adopt(self.p0[k], int(self.face[k]), faces, self.planes[window], self.offsets[window], self.lower0[window])
        warm.resume(int(self.face[k]), int(self.searches[k]))
        self.searches[k] = 0
        self._given[k] = faces

    def store(self, k: int, warm: WarmClosest) -> None:
        """Take sphere k's warm start back from its Python query (a patch it built goes to the arena)."""
        p0, face, faces, planes, offsets, lower0 = warm.patch()
        self.face[k] = face
        if faces is self._given[k]:
            return
        self.p0[k] = p0
        drop_patch(k, self.start, self.size, self.used)
        if len(faces) == 0:
            return
        if self.used[0] + len(faces) > len(self.faces):
            self._allocate(2 * (int(self.size.sum()) + len(faces)) + len(self.faces))
        start = int(self.used[0])
        window = slice(start, start + len(faces))
        self.faces[window], self.planes[window], self.offsets[window], self.lower0[window] = (
            faces,
            planes,
            offsets,
            lower0,
        )
        self.start[k], self.size[k] = start, len(faces)
        self.used[0] += len(faces)

    def _allocate(self, capacity: int) -> None:
        """A new arena of ``capacity`` faces holding the live patches."""
        faces, planes = np.zeros(capacity, dtype=np.int64), np.zeros((capacity, 4, 3))
        offsets, lower0 = np.zeros((capacity, 4)), np.zeros(capacity)
        used = 0
        for k in np.flatnonzero(self.size):
            old, new = slice(self.start[k], self.start[k] + self.size[k]), slice(used, used + self.size[k])
            faces[new], planes[new], offsets[new], lower0[new] = (
                self.faces[old],
                self.planes[old],
                self.offsets[old],
                self.lower0[old],
            )
            self.start[k] = used
            used += int(self.size[k])
        self.faces, self.planes, self.offsets, self.lower0 = faces, planes, offsets, lower0
        self.used[0] = used


def query_setup(sensor: ExactContactSensor, warm: WarmClosest) -> tuple[tuple[A, ...], tuple[A, ...], A]:
    """What compiled warm queries on ``sensor`` with ``warm``'s settings read (:func:`query_near`,
    ``probe_kernels.probe_closest``): the mesh (centre, triangles, sign normals, bound planes, bound
    offsets), its :func:`face_grid` and the parameter vector with the query's entries set (reach,
    weak-sign limits, patch limits, grid cell, largest face radius); its kernels are loaded first."""
    load_query_kernels(sensor)
    mesh = sensor.query_mesh
    grid, cell_m, largest = face_grid(sensor)
    params = np.zeros(PARAMS)
    params[P_REACH] = warm.reach_m
    params[P_WEAK_PSEUDO_NORMAL] = WEAK_PSEUDO_NORMAL
    params[P_WEAK_SIGN_COS] = WEAK_SIGN_COS
    params[P_MAX_DISTANCE] = warm.max_distance_m
    params[P_MAX_FACES] = warm.max_patch_faces
    params[P_CELL] = cell_m
    params[P_LARGEST] = largest
    return mesh, grid, params


def face_grid(
    sensor: ExactContactSensor, cell_m: float = 0.004, max_cells: int = 1 << 22
) -> tuple[tuple[A, ...], float, float]:
    """A uniform grid of the face centroids (shifted frame) for compiled patch builds: (corner (3,),
    cells per axis (3,), each cell's first entry (C + 1,), the faces by cell (F,), the centroids
    (F, 3)), the cell size and the largest face radius about its centroid (``face_index``)."""
    _, _, largest = sensor.face_index()
    centroids = np.ascontiguousarray(sensor.query_mesh[1].mean(axis=1))  # of the triangles
    corner = centroids.min(axis=0)
    extent = centroids.max(axis=0) - corner
    while np.prod(np.floor(extent / cell_m) + 1) > max_cells:
        cell_m *= 2.0
    dims = (np.floor(extent / cell_m) + 1).astype(np.int64)
    ijk = np.minimum(np.floor((centroids - corner) / cell_m).astype(np.int64), dims - 1)
    cell = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(cell, kind="stable").astype(np.int64)
    first = np.concatenate([[0], np.cumsum(np.bincount(cell, minlength=int(np.prod(dims))))]).astype(np.int64)
    return (corner, dims, first, order, centroids), float(cell_m), float(largest)


@numba.njit(cache=True)
def grid_faces(grid: Any, cell_m: float, px: float, py: float, pz: float, reach: float, out: A, limit: int) -> int:
    """The faces whose centroid lies within ``reach`` of p (``face_index``'s k-d tree query), into
    out[:count]; returns count. Stops at ``limit`` + 1 faces (a patch that large is not built), so
    that a dense mesh costs at most that many per call."""
    corner, dims, first, order, centroids = grid
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    for a, v in enumerate((px, py, pz)):
        lo[a] = max(0, math.floor((v - reach - corner[a]) / cell_m))
        hi[a] = min(dims[a] - 1, math.floor((v + reach - corner[a]) / cell_m))
    count = 0
    for i in range(lo[0], hi[0] + 1):
        for j in range(lo[1], hi[1] + 1):
            for k in range(lo[2], hi[2] + 1):
                c = (i * dims[1] + j) * dims[2] + k
                for e in range(first[c], first[c + 1]):
                    f = order[e]
                    dx, dy, dz = centroids[f, 0] - px, centroids[f, 1] - py, centroids[f, 2] - pz
                    if dx * dx + dy * dy + dz * dz <= reach * reach:
                        out[count] = f
                        count += 1
                        if count > limit:
                            return count
    return count


@numba.njit(cache=True)
def drop_patch(k: int, start: A, size: A, used: A) -> None:
    """Drop sphere k's patch from the arena; when it was the arena's last, the next patch takes its room."""
    if size[k] > 0 and start[k] + size[k] == used[0]:
        used[0] = start[k]
    size[k] = 0


@numba.njit(cache=True)
def tighten(
    centroids: A,
    triangles: A,
    face: A,
    k: int,
    px: float,
    py: float,
    pz: float,
    upper: float,
    params: A,
    candidates: A,
    count: int,
) -> tuple[int, float]:
    """A patch's radius from the face of the candidate centroid nearest p, where that face is nearer
    than ``upper`` (the squared distance to sphere k's face, which may be stale: its last query
    was elsewhere), and the candidates (count,) kept in place that ``grid_faces`` would give for it,
    sphere k's face first; returns (count, radius). face[k] becomes the nearer face (any start gives
    the same answers)."""
    nearest, best = -1, math.inf
    for i in range(count):
        f = candidates[i]
        dx, dy, dz = centroids[f, 0] - px, centroids[f, 1] - py, centroids[f, 2] - pz
        squared = dx * dx + dy * dy + dz * dz
        if squared < best:
            nearest, best = f, squared
    if nearest >= 0:
        squared, _, _, _ = closest_kernels.project(triangles, nearest, px, py, pz)
        if squared < upper:
            upper, face[k] = squared, nearest
    radius = math.sqrt(upper) + 2.0 * params[P_REACH]
    reach = radius + params[P_LARGEST]
    kept = 0
    for i in range(count):
        f = candidates[i]
        dx, dy, dz = centroids[f, 0] - px, centroids[f, 1] - py, centroids[f, 2] - pz
        if dx * dx + dy * dy + dz * dz <= reach * reach:
            candidates[kept] = f
            if f == face[k]:  # the nearest face known goes first (a search's first bound)
                candidates[kept], candidates[0] = candidates[0], f
            kept += 1
    return kept, radius


@numba.njit(cache=True)
def patch_candidates(
    k: int, px: float, py: float, pz: float, mesh: Any, grid: Any, warm: Any, params: A, candidates: A
) -> tuple[int, float]:
    """The first half of ``WarmClosest._build`` for sphere k at p (shifted frame): drops its old patch
    (p left its reach; if it was the arena's last the next one takes its room), then finds the radius
    of the new one and the faces (candidates[:count]) that may lie within it. Returns (count, radius),
    count -1 where Python must answer (no face yet here or at a neighbouring sphere, too far from the
    surface, too many faces)."""
    _, triangles, _, _, _ = mesh
    _, face, start, size, _, _, _, _, _, used = warm
    drop_patch(k, start, size, used)
    if face[k] < 0:  # a first query: start from a neighbour's face (any face gives the same answer)
        for other in (k - 1, k + 1):
            if 0 <= other < face.shape[0] and face[other] >= 0:
                face[k] = face[other]
                break
        else:
            return -1, 0.0
    upper, _, _, _ = closest_kernels.project(triangles, face[k], px, py, pz)
    for other in (k - 1, k + 1):  # a neighbour's face may be nearer than this sphere's last one
        if 0 <= other < face.shape[0] and face[other] >= 0:
            squared, _, _, _ = closest_kernels.project(triangles, face[other], px, py, pz)
            if squared < upper:
                upper, face[k] = squared, face[other]
    radius = math.sqrt(upper) + 2.0 * params[P_REACH]
    if radius > params[P_MAX_DISTANCE]:
        return -1, 0.0
    limit = int(params[P_MAX_FACES])
    count = grid_faces(grid, params[P_CELL], px, py, pz, radius + params[P_LARGEST], candidates, limit)
    if count > limit:
        return -1, 0.0
    return tighten(grid[4], triangles, face, k, px, py, pz, upper, params, candidates, count)


@numba.njit(cache=True)
def store_patch(
    k: int, px: float, py: float, pz: float, mesh: Any, warm: Any, candidates: A, count: int, radius: float
) -> bool:
    """The second half of ``WarmClosest._build``: sphere k's patch of the given radius at p from
    candidates[:count] (:func:`patch_candidates`) into the arena; False when the arena is full."""
    _, _, _, bound_planes, bound_offsets = mesh
    p0, _, start, size, _, faces, planes, offsets, lower0, used = warm
    new_faces, new_planes, new_offsets, new_lower = closest_kernels.build_patch(
        bound_planes, bound_offsets, candidates[:count], px, py, pz, radius
    )
    n = new_faces.shape[0]
    if used[0] + n > faces.shape[0]:
        return False
    a = used[0]
    faces[a : a + n] = new_faces
    planes[a : a + n] = new_planes
    offsets[a : a + n] = new_offsets
    lower0[a : a + n] = new_lower
    start[k], size[k] = a, n
    used[0] += n
    p0[k, 0], p0[k, 1], p0[k, 2] = px, py, pz
    return True


@numba.njit(cache=True)
def build(k: int, px: float, py: float, pz: float, mesh: Any, grid: Any, warm: Any, params: A, candidates: A) -> bool:
    """``WarmClosest._build`` of sphere k's patch at p (shifted frame) into the arena; False where it
    needs Python (see :func:`patch_candidates` and :func:`store_patch`)."""
    count, radius = patch_candidates(k, px, py, pz, mesh, grid, warm, params, candidates)
    return count > 0 and store_patch(k, px, py, pz, mesh, warm, candidates, count, radius)


@numba.njit(cache=True)
def query_near(
    j0: int,
    centres: A,
    near: A,
    count: int,
    sphere_reach: A,
    mesh: Any,
    grid: Any,
    warm: Any,
    params: A,
    points: A,
    dist: A,
    hit_faces: A,
    candidates: A,
    search: A,
) -> int:
    """``WarmClosest.query`` for the spheres near[j0:count] at their centres (K, 3),
    as far as it needs no Python: writes each answer at its position j in points (K, 3), dist (K,) and
    hit_faces (K,). Returns count, or the first position whose query needs Python. sphere_reach (K,):
    each sphere's radius plus tolerance (the spheres' ``reach`` of :func:`sphere_hits`).

    mesh: the sensor's (centre (3,), triangles (F, 3, 3), sign normals (F, 7, 3), bound planes (F, 4,
    3), bound offsets (F, 4)); grid: :func:`face_grid`'s; warm: :meth:`WarmPatches.arrays`;
    candidates (F,): scratch. A search that ends in a weak sign leaves p and its result in
    ``search`` (the SEARCH_* layout; SEARCH_PENDING 1) for ``WarmClosest.settle``.
    """
    centre, triangles, sign_normals, bound_planes, bound_offsets = mesh
    p0, face, start, size, searches, faces, planes, offsets, lower0, _ = warm
    reach = params[P_REACH]
    for j in range(j0, count):
        k = near[j]
        x, y, z = centres[k, 0], centres[k, 1], centres[k, 2]
        if not math.isfinite(x + y + z):
            return j
        px, py, pz = x - centre[0], y - centre[1], z - centre[2]
        x0, y0, z0 = p0[k, 0], p0[k, 1], p0[k, 2]
        if size[k] == 0 or (px - x0) ** 2 + (py - y0) ** 2 + (pz - z0) ** 2 > reach**2:
            found_count, radius = patch_candidates(k, px, py, pz, mesh, grid, warm, params, candidates)
            if found_count <= 0:  # Python's query (none found: only where rounding left out the face)
                return j
            # The candidates' closest face: the answer a search of the patch built from them would give
            # (the closest face, exact ties to the lowest id).
            found, qx, qy, qz, unsigned, inside, weak = closest_kernels.ring_query(
                triangles,
                sign_normals,
                candidates[:found_count],
                bound_planes,
                bound_offsets,
                px,
                py,
                pz,
                params[P_WEAK_PSEUDO_NORMAL],
                params[P_WEAK_SIGN_COS],
            )
            # A sphere farther out than its reach plus the patch reach is asked again only once it has
            # moved more than the patch's reach (sphere_bounds), so its patch would never be searched:
            # none is kept for it.
            once = not (inside or weak) and unsigned - sphere_reach[k] > reach * (1.0 + 1e-6)
            if not once and not store_patch(k, px, py, pz, mesh, warm, candidates, found_count, radius):
                return j
        else:
            moved = math.sqrt((px - x0) ** 2 + (py - y0) ** 2 + (pz - z0) ** 2)
            a, e = start[k], start[k] + size[k]
            found, qx, qy, qz, unsigned, inside, weak = closest_kernels.warm_query(
                triangles,
                sign_normals,
                faces[a:e],
                planes[a:e],
                offsets[a:e],
                lower0[a:e],
                moved * (1.0 + 1e-12) + 1e-18,
                face[k],
                px,
                py,
                pz,
                params[P_WEAK_PSEUDO_NORMAL],
                params[P_WEAK_SIGN_COS],
            )
        if weak:  # a weak sign: Python decides it by ray parity
            search[SEARCH_P], search[SEARCH_P + 1], search[SEARCH_P + 2] = px, py, pz
            search[SEARCH_FACE] = found
            search[SEARCH_Q], search[SEARCH_Q + 1], search[SEARCH_Q + 2] = qx, qy, qz
            search[SEARCH_DIST], search[SEARCH_INSIDE], search[SEARCH_WEAK] = unsigned, inside, weak
            search[SEARCH_PENDING] = 1.0
            return j
        face[k] = found
        searches[k] += 1
        points[j, 0], points[j, 1], points[j, 2] = qx + centre[0], qy + centre[1], qz + centre[2]
        dist[j] = -unsigned if inside else unsigned
        hit_faces[j] = found
    return count


@numba.njit(cache=True)
def sphere_hits(
    resume: int, few_points: int, frames: Any, spheres: Any, mesh: Any, grid: Any, warm: Any, buffers: Any, params: A
) -> tuple[int, int]:
    """``PenaltyContacts._sphere_hits`` (nodes/sim/penalty_contact.py): with resume < 0 the bounds
    (``capsule_kernels.sphere_bounds``) of the current kinematics (more than ``few_points`` near
    spheres: BATCH), then the queries from position ``resume`` on (:func:`query_near`); once all are
    answered, the caches of the near spheres and, in buffers' touch[:state[S_TOUCHING]], the
    positions of those that touch. Returns (DONE | NEEDS_PYTHON, the position to answer | BATCH).

    frames: MuJoCo's (geom_xpos, geom_xmat); spheres: (geoms, offsets, radius, reach, body, cache_p,
    cache_d); mesh and grid as in :func:`query_near`; buffers: (centres (K, 3), near (K,), points (K, 3),
    dist (K,), hit_faces (K,), touch (K,), state (2,), candidates (F,), search (SEARCH_SIZE,)).
    """
    xpos, xmat = frames
    geoms, offsets, _, reach, _, cache_p, cache_d = spheres
    centres, near, points, dist, hit_faces, touch, state, candidates, search = buffers
    if resume < 0:
        state[S_NEAR] = capsule_kernels.sphere_bounds(
            xpos, xmat, geoms, offsets, cache_p, cache_d, reach, centres, near
        )
        if state[S_NEAR] > few_points:
            return NEEDS_PYTHON, BATCH  # the sensor's vectorised query
        resume = 0
    count = state[S_NEAR]
    j = query_near(
        resume, centres, near, count, reach, mesh, grid, warm, params, points, dist, hit_faces, candidates, search
    )
    if j < count:
        return NEEDS_PYTHON, j
    touching = 0
    for j in range(count):
        k = near[j]
        cache_p[k, 0], cache_p[k, 1], cache_p[k, 2] = centres[k, 0], centres[k, 1], centres[k, 2]
        cache_d[k] = dist[j]
        if dist[j] <= reach[k]:
            touch[touching] = j
            touching += 1
    state[S_TOUCHING] = touching
    return DONE, 0


@numba.njit(cache=True)
def penalty_steps(
    functions: tuple[int, int, int, int, int, int, int],
    steps: int,
    resume: int,
    few_points: int,
    qpos: A,
    frames: Any,
    dynamics: Any,
    spheres: Any,
    mesh: Any,
    grid: Any,
    face_normals: A,
    warm: Any,
    buffers: Any,
    params: A,
) -> tuple[int, int, int]:
    """Up to ``steps`` steps of ``Simulation.step`` on the exact-mesh path. resume >= 0 goes on with the
    queries of a step that ended a call with NEEDS_PYTHON; HITS_CURRENT takes the first step's queries
    from the buffers (the same bits: each query's answer depends only on its point). Returns (steps completed, DONE |
    NEEDS_PYTHON | PENETRATED | NOT_FINITE, the position to answer | BATCH). A call that completes
    its steps then refreshes the frames and velocities and asks the queries of its final state
    (:func:`end_queries`): DONE with ``at`` END_QUERIED when it answered them all, 0 when one needs Python.

    functions: (mj_step1, mj_step2, mj_kinematics, mj_comPos, mj_comVel, model, data) addresses;
    dynamics: (body_rootid, (cvel, subtree_com, xipos, xfrc_applied)); the rest as in :func:`sphere_hits`.
    """
    step1, step2, _, _, _, model, data = functions
    body_rootid, body_data = dynamics
    _, _, radius, _, body, _, _ = spheres
    _, near, points, dist, hit_faces, touch, state, _, _ = buffers
    xfrc = body_data[3]
    taken = 0
    while taken < steps:
        if resume < 0:
            call_void2(step1, model, data)  # kinematics and velocities of the current state
        if resume == HITS_CURRENT:
            status, at = DONE, 0
        else:
            status, at = sphere_hits(resume, few_points, frames, spheres, mesh, grid, warm, buffers, params)
        resume = -1
        if status != DONE:
            return taken, status, at
        rows = touch[: state[S_TOUCHING]]
        for j in rows:
            if dist[j] < 0.0:
                return taken, PENETRATED, 0
        xfrc[:] = 0.0
        penalty_wrench(
            rows,
            near,
            points,
            dist,
            hit_faces,
            face_normals,
            body,
            radius,
            body_rootid,
            body_data,
            params[P_STIFFNESS],
            params[P_DAMPING],
        )
        call_void2(step2, model, data)  # forces, acceleration, integration
        taken += 1
        for i in range(qpos.shape[0]):
            if not math.isfinite(qpos[i]):
                return taken, NOT_FINITE, 0
    return taken, DONE, end_queries(functions, few_points, frames, spheres, mesh, grid, warm, buffers, params)


@numba.njit(cache=True)
def end_queries(
    functions: tuple[int, int, int, int, int, int, int],
    few_points: int,
    frames: Any,
    spheres: Any,
    mesh: Any,
    grid: Any,
    warm: Any,
    buffers: Any,
    params: A,
) -> int:
    """The frames and velocities of the current state (``mj_kinematics``, ``mj_comPos``, ``mj_comVel``:
    what ``Simulation._refresh`` calls, so the same values) and its sphere queries into the buffers,
    as :func:`sphere_hits` from -1; END_QUERIED, or 0 where one needs Python (a batch, a sphere's
    first query, a weak sign: the partial answers are dropped, and a pending weak sign too)."""
    _, _, kinematics, com_pos, com_vel, model, data = functions
    call_void2(kinematics, model, data)
    call_void2(com_pos, model, data)
    call_void2(com_vel, model, data)
    status, _ = sphere_hits(-1, few_points, frames, spheres, mesh, grid, warm, buffers, params)
    if status == DONE:
        return END_QUERIED
    buffers[8][SEARCH_PENDING] = 0.0
    return 0
