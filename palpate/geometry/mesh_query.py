"""Queries on a triangle mesh: closest points, signed distances, sphere touches, inside tests, rays.

``MeshScene`` is the one Open3D ``RaycastingScene`` set-up (a BVH in float32): the mesh is shifted by
an origin (by default its bounding-box centre) before Open3D sees it, so float32 coordinates stay
small (a 0.2 m object: 1.5e-8 m spacing instead of that of its world position). Open3D is imported
when the first scene is built (loading it takes about a second).

``ExactContactSensor`` answers "where is the closest surface point, how far, and on which side" for
the real (non-convex) mesh; MuJoCo collides mesh geoms as their convex hulls, so its contacts are
wrong in holes and cups. The simulator's touch sensor and the exploration metrics both use it:

1. Open3D's ``compute_closest_points`` (``MeshScene.closest``) picks the closest triangle.
2. The closest point on that triangle and on the triangles sharing a vertex with it is recomputed
   in float64 (Ericson, Real-Time Collision Detection, 5.1.5), so points and distances carry float64
   precision; float32 only decides near-ties between triangles that are equally close to within
   about 1e-8 m. Triangles at exactly the same float64 squared distance (a vertex or an edge they
   share) resolve to the lowest face id, so the answer does not depend on the order of Open3D's
   search, and a warm-started search (``WarmClosest``) finds the same face without asking Open3D.
3. The sign (inside < 0) comes from the angle-weighted pseudo-normal of the face, edge or vertex
   holding the closest point (Baerentzen and Aanaes 2005), exact for closed, outward-wound meshes
   without folds. Where the offset is nearly orthogonal to that pseudo-normal (folded scan
   triangles cancel it: seen on the legacy ``block_of_wood_6in``), Open3D's ray parity decides.

Measured by ``palpate bench contacts`` against a brute-force float64 reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import MeshError

if TYPE_CHECKING:
    import trimesh

#: Region of the triangle that holds the closest point (result of closest_points_on_triangles).
FACE, VERTEX_A, VERTEX_B, VERTEX_C, EDGE_AB, EDGE_BC, EDGE_CA = range(7)
#: Below this cosine between the offset and the pseudo-normal, the sign comes from ray parity.
WEAK_SIGN_COS = 0.1
#: Below this length of the (mean) pseudo-normal, the sign comes from ray parity.
WEAK_PSEUDO_NORMAL = 0.3
#: Queries below this count run Open3D single-threaded.
SMALL_BATCH = 64
#: Largest face-ring table (faces x 3 x the largest vertex degree) built, 16.8 M entries (YCB meshes:
#: at most 1.5 M); a mesh that needs more (thousands of faces fanning around one vertex) is refused.
MAX_RING_ENTRIES = 1 << 24
#: Queries of at most this many points take the scalar path (same maths, far less numpy overhead).
FEW_POINTS = 4


def closest_points_on_triangles(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on triangle (a_i, b_i, c_i) to p_i, pairwise, in float64.

    p, a, b, c: (n, 3). Returns the points (n, 3) and the region code (n,) (FACE, VERTEX_*, EDGE_*).
    Ericson's Voronoi-region test, vectorised; the first matching region wins, as in the scalar code.
    """
    p, a, b, c = (np.asarray(x, dtype=np.float64) for x in (p, a, b, c))
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        region = np.full(len(p), FACE)
        wb, wc = vb * denom, vc * denom
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        # lowest priority first: a later (higher-priority) region overwrites an earlier one
        cases = (
            ((va <= 0) & (d4 >= d3) & (d5 >= d6), EDGE_BC, 1.0 - t_bc, t_bc),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), EDGE_CA, 0.0, d2 / (d2 - d6)),
            ((d6 >= 0) & (d5 <= d6), VERTEX_C, 0.0, 1.0),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), EDGE_AB, d1 / (d1 - d3), 0.0),
            ((d3 >= 0) & (d4 <= d3), VERTEX_B, 1.0, 0.0),
            ((d1 <= 0) & (d2 <= 0), VERTEX_A, 0.0, 0.0),
        )
        for mask, code, case_b, case_c in cases:
            region = np.where(mask, code, region)
            wb = np.where(mask, case_b, wb)
            wc = np.where(mask, case_c, wc)
    q = a + wb[:, None] * ab + wc[:, None] * ac
    return q, region


def closest_region(d1: float, d2: float, d3: float, d4: float, d5: float, d6: float) -> tuple[int, float, float]:
    """Scalar twin of :func:`closest_points_on_triangles` for one point and triangle (compiled:
    ``closest_kernels.closest_region``).

    d1 = ab.ap, d2 = ac.ap, d3 = ab.bp, d4 = ac.bp, d5 = ab.cp, d6 = ac.cp (Ericson 5.1.5). Returns the
    region code and the weights (wb, wc) of the closest point q = a + wb ab + wc ac; same priority
    order and formulas as the vectorised kernel.
    """
    from palpate.geometry import closest_kernels

    region, wb, wc = closest_kernels.closest_region(d1, d2, d3, d4, d5, d6)
    return int(region), float(wb), float(wc)


def edge_uses(faces: np.ndarray) -> NDArray[np.int64]:
    """How many of the triangles ``faces`` (F, 3) hold each of their distinct edges (a closed surface: 2 each;
    1: an open edge; more: a non-manifold one)."""
    edges = np.sort(np.asarray(faces)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return np.asarray(counts, dtype=np.int64)


def pseudo_normals(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Angle-weighted pseudo-normals per face corner (F, 3, 3) and per face edge (F, 3, 3).

    Edge k of a face joins corners k and k+1 (AB, BC, CA); its pseudo-normal is the mean of the
    normals of the faces sharing it. The corner pseudo-normal is the mean of the incident face normals
    weighted by the face angle at that vertex. Not normalised: the length (1 on a flat patch, 0.71 on
    a cube's edge, near 0 where a folded triangle cancels its neighbours) measures how reliable it is.
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)
    angles = np.asarray(mesh.face_angles, dtype=np.float64)
    vertex = np.zeros((len(mesh.vertices), 3))
    weight = np.zeros(len(mesh.vertices))
    for k in range(3):
        np.add.at(vertex, faces[:, k], normals * angles[:, k : k + 1])
        np.add.at(weight, faces[:, k], angles[:, k])
    vertex /= np.maximum(weight, 1e-300)[:, None]
    edge_ids = np.asarray(mesh.faces_unique_edges, dtype=np.int64)
    edge = np.zeros((len(mesh.edges_unique), 3))
    count = np.zeros(len(mesh.edges_unique))
    for k in range(3):
        np.add.at(edge, edge_ids[:, k], normals)
        np.add.at(count, edge_ids[:, k], 1.0)
    edge /= np.maximum(count, 1.0)[:, None]
    return vertex[faces], edge[edge_ids]


def face_rings(mesh: trimesh.Trimesh) -> np.ndarray:
    """Per face: itself, then every face sharing a vertex with it (F, K), padded by repeating itself."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    own = np.arange(len(faces))
    # the largest vertex degree first: trimesh's vertex_faces table is (V, max degree) and would itself
    # be the allocation the limit is there to prevent (a fan of 20,000 faces: 15 s and 7 GB)
    degree = int(np.bincount(faces.ravel(), minlength=1).max(initial=0)) if len(faces) else 0
    if len(faces) * 3 * degree > MAX_RING_ENTRIES:
        raise MeshError(
            f"{len(faces)} faces with a vertex shared by {degree} of them: the face rings would "
            f"hold {len(faces) * 3 * degree} entries (at most {MAX_RING_ENTRIES}); remesh it"
        )
    vertex_faces = np.asarray(mesh.vertex_faces, dtype=np.int64)  # (V, max degree), -1 padded
    ring = vertex_faces[faces].reshape(len(faces), -1)
    ring = np.where(ring < 0, own[:, None], ring)
    # drop duplicates within a row: sort, mark repeats as the face itself, keep it first
    ring = np.sort(ring, axis=1)
    repeat = np.zeros_like(ring, dtype=bool)
    repeat[:, 1:] = ring[:, 1:] == ring[:, :-1]
    is_own = repeat | (ring == own[:, None])
    others = int((~is_own).sum(axis=1).max(initial=0))
    order = np.argsort(is_own, axis=1, kind="stable")  # other faces first, then padding
    ring = np.take_along_axis(np.where(is_own, own[:, None], ring), order, axis=1)[:, :others]
    return np.ascontiguousarray(np.concatenate([own[:, None], ring], axis=1))


class MeshScene:
    """Open3D ``RaycastingScene`` of one triangle mesh: closest points, distances, inside tests, rays.

    Open3D works in float32 on the mesh shifted by ``origin_m`` (default: the bounding-box centre).
    Every query takes and returns coordinates in that shifted frame, ``local = world - origin_m``,
    so callers that refine in float64 (``ExactContactSensor``) subtract the origin once. Queries of
    fewer than ``SMALL_BATCH`` points run single-threaded (26 instead of 67 us for one point: no
    thread-pool start-up); the thread count does not change the answers.

    vertices_m: (V, 3) metres; faces: (F, 3) vertex indices; origin_m: (3,) metres.
    """

    def __init__(self, vertices_m: ArrayLike, faces: ArrayLike, origin_m: ArrayLike | None = None) -> None:
        import open3d as o3d  # imported here: loading Open3D takes about a second

        V = np.asarray(vertices_m, dtype=np.float64)
        F = np.asarray(faces)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise MeshError(f"a mesh scene needs vertices (V, 3) and faces (F > 0, 3), got {V.shape} and {F.shape}")
        self.origin_m = 0.5 * (V.min(axis=0) + V.max(axis=0)) if origin_m is None else np.asarray(origin_m, np.float64)
        self._o3d: Any = o3d
        # kept alive: Open3D's tensors share this memory
        self._vertices = np.ascontiguousarray(V - self.origin_m, dtype=np.float32)
        self._faces = np.ascontiguousarray(F, dtype=np.uint32)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor.from_numpy(self._vertices), o3d.core.Tensor.from_numpy(self._faces))

    def _tensor(self, local_m: np.ndarray) -> Any:
        return self._o3d.core.Tensor.from_numpy(np.ascontiguousarray(local_m, dtype=np.float32))

    @staticmethod
    def _threads(n: int) -> int:
        return 1 if n < SMALL_BATCH else 0  # 0: Open3D's default, all cores

    def _closest_answer(self, local_m: np.ndarray) -> Any:
        return self._scene.compute_closest_points(self._tensor(local_m), nthreads=self._threads(len(local_m)))

    def closest(self, local_m: np.ndarray) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Closest triangle of each point (n, 3), shifted frame: face ids (n,) and points (n, 3) (float32 values)."""
        answer = self._closest_answer(local_m)
        return answer["primitive_ids"].numpy().astype(np.int64), answer["points"].numpy().astype(np.float64)

    def closest_face_ids(self, local_m: np.ndarray) -> list[int]:
        """Face ids of :meth:`closest` as Python ints, for a few points (skips the points' conversion)."""
        ids: list[int] = self._closest_answer(local_m)["primitive_ids"].numpy().tolist()
        return ids

    def distance(self, local_m: np.ndarray) -> NDArray[np.float64]:
        """Unsigned distance (n,) metres of points (n, 3), shifted frame, to the surface (float32 values)."""
        d = self._scene.compute_distance(self._tensor(local_m), nthreads=self._threads(len(local_m)))
        return np.asarray(d.numpy(), dtype=np.float64)

    def occupied(self, local_m: np.ndarray, rays: int = 3) -> NDArray[np.bool_]:
        """Inside test (n,) of points (n, 3), shifted frame, by ray parity (majority of ``rays`` rays)."""
        n = len(local_m)
        occupancy = self._scene.compute_occupancy(self._tensor(local_m), nthreads=self._threads(n), nsamples=rays)
        return np.asarray(occupancy.numpy() > 0.5)

    def ray_hit_distance(self, origins_m: np.ndarray, directions: np.ndarray) -> NDArray[np.float64]:
        """Ray parameter t of the first hit (n,) (inf: no hit) of rays origin + t direction, shifted frame.

        origins_m, directions: (n, 3); with unit directions t is the distance in metres.
        """
        rays = np.concatenate([origins_m, directions], axis=-1).reshape(-1, 6).astype(np.float32)
        hit = self._scene.cast_rays(self._tensor(rays), nthreads=self._threads(len(rays)))
        return np.asarray(hit["t_hit"].numpy(), dtype=np.float64)


@dataclass(frozen=True)
class ClosestPoints:
    """Closest surface points of n query points.

    points_m: (n, 3) closest points on the surface, world frame, metres.
    distance_m: (n,) signed distance query -> surface, < 0 inside the object.
    normals: (n, 3) outward unit normal of the triangle holding the closest point.
    face_ids: (n,) index of that triangle in the mesh.
    """

    points_m: np.ndarray
    distance_m: np.ndarray
    normals: np.ndarray
    face_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class ExactContactSensor:
    """Closest points, signed distances and sphere touches on a triangle mesh (world frame, metres)."""

    def __init__(self, mesh: trimesh.Trimesh, *, warm_up: bool = True) -> None:
        """``warm_up``: make one query of each kind now (see :meth:`_warm_up`)."""
        if len(mesh.faces) == 0:
            raise ValueError("ExactContactSensor needs a mesh with faces")
        self.mesh = mesh
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        # shifted to the bounding-box centre: float32 inside Open3D then resolves ~1e-8 m on a 0.2 m object
        self._scene = MeshScene(vertices, faces)
        self._centre = self._scene.origin_m
        local = vertices - self._centre
        self._triangles = local[faces]  # (F, 3, 3) float64
        self._face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        #: Outward unit normal of each face (F, 3).
        self.face_normals = self._face_normals
        corner, edge = pseudo_normals(mesh)
        # pseudo-normal per face and region code: FACE, VERTEX_A..C, EDGE_AB..CA -> (F, 7, 3)
        self._sign_normals = np.concatenate([self._face_normals[:, None], corner, edge], axis=1)
        self._ring = face_rings(mesh)
        from palpate.geometry import closest_kernels  # numba: compiled on first use, then cached on disk

        self._kernels = closest_kernels
        self._centre_list: list[float] = self._centre.tolist()
        self._index: tuple[Any, np.ndarray, float] | None = None
        # lower bound of a face's distance for the few-point path, as planes g . p - h (F, 4): the face's
        # plane (unit normal), then per edge AB, BC, CA its outward unit normal within that plane.
        # Zero rows on degenerate faces (no pruning there).
        ab = self._triangles[:, 1] - self._triangles[:, 0]
        cross = np.cross(ab, self._triangles[:, 2] - self._triangles[:, 0])
        length = np.linalg.norm(cross, axis=1, keepdims=True)
        unit = np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)
        edges = np.roll(self._triangles, -1, axis=1) - self._triangles  # b - a, c - b, a - c
        outward = np.cross(edges, unit[:, None, :])
        length = np.linalg.norm(outward, axis=2, keepdims=True)
        outward = np.divide(outward, length, out=np.zeros_like(outward), where=length > 0)
        self._bound_planes = np.ascontiguousarray(np.concatenate([unit[:, None], outward], axis=1))
        self._bound_offsets = np.concatenate(
            [
                np.einsum("fj,fj->f", unit, self._triangles[:, 0])[:, None],
                np.einsum("fej,fej->fe", outward, self._triangles),
            ],
            axis=1,
        )
        if warm_up:
            self._warm_up()

    def _warm_up(self) -> None:
        """One query of each kind now (a point, a batch, a ray-parity test at the mesh's centre): Open3D
        builds its search structures and numba loads the kernels at the first query (10 ms and more), which
        would otherwise stall the first contact of a running simulation."""
        centre = self._centre[None, :]
        self.closest(centre)
        self.closest(np.repeat(centre, FEW_POINTS + 1, axis=0))
        self._scene.occupied(np.zeros((1, 3)))

    def _check(self, points_m: np.ndarray) -> np.ndarray:
        p = np.asarray(points_m, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"query points must have shape (n, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("query points must be finite (got NaN or infinity)")
        return p - self._centre

    def closest(self, points_m: np.ndarray) -> ClosestPoints:
        """Closest surface points of ``points_m`` (n, 3); float64 results, see :class:`ClosestPoints`."""
        local = self._check(points_m)
        if len(local) == 0:
            empty = np.zeros((0, 3))
            return ClosestPoints(empty, np.zeros(0), empty.copy(), np.zeros(0, dtype=np.int64))
        if len(local) <= FEW_POINTS:
            return self._closest_few(local)
        found, _ = self._scene.closest(local)
        refine = self._refine_compiled if refine_matches_numpy() else self._refine
        faces, q, distance, inside, weak = refine(local, found)
        if np.any(weak):
            inside[weak] = self._scene.occupied(local[weak])
        return ClosestPoints(
            points_m=q + self._centre,
            distance_m=np.where(inside, -distance, distance),
            normals=self._face_normals[faces].copy(),
            face_ids=faces,
        )

    def _refine(self, local: np.ndarray, found: np.ndarray) -> tuple[np.ndarray, ...]:
        """The vectorised path's float64 refinement of Open3D's faces ``found`` (n,) for points (n, 3):
        faces, closest points (shifted frame), unsigned distances, inside by the pseudo-normal, weak."""
        # float64 projection onto Open3D's triangle and the faces around it (float32 near-ties);
        # exact ties go to the lowest face id
        ring = self._ring[found]  # (n, K)
        n, K = ring.shape
        tri = self._triangles[ring.ravel()]
        q_all, region_all = closest_points_on_triangles(np.repeat(local, K, axis=0), tri[:, 0], tri[:, 1], tri[:, 2])
        d_all = np.einsum("ij,ij->i", q_all - np.repeat(local, K, axis=0), q_all - np.repeat(local, K, axis=0))
        d_all = d_all.reshape(n, K)
        tied = d_all == d_all.min(axis=1, keepdims=True)
        best = np.arange(n) * K + np.argmin(np.where(tied, ring, np.iinfo(np.int64).max), axis=1)
        faces, q, region = ring.ravel()[best], q_all[best], region_all[best]
        offset = local - q
        distance = np.linalg.norm(offset, axis=1)
        # sign from the pseudo-normal of the feature (face, edge, vertex) holding q
        pseudo = self._sign_normals[faces, region]
        side = np.einsum("ij,ij->i", offset, pseudo)
        # A folded scan (a triangle turned back against its neighbours) cancels the pseudo-normal of
        # its vertices and edges: where it is short, or nearly orthogonal to the offset, the caller
        # counts ray crossings instead (also taken at knife edges, where it is merely slower).
        strength = np.linalg.norm(pseudo, axis=1)
        weak = (strength < WEAK_PSEUDO_NORMAL) | (np.abs(side) < WEAK_SIGN_COS * distance * strength)
        return faces, q, distance, side < 0.0, weak

    def _refine_compiled(self, local: np.ndarray, found: np.ndarray) -> tuple[np.ndarray, ...]:
        """:meth:`_refine` in compiled code (``closest_kernels.refine_batch``), the same bits."""
        n = len(local)
        faces, q, distance = np.empty(n, dtype=np.int64), np.empty((n, 3)), np.empty(n)
        inside, weak = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        self._kernels.refine_batch(
            local,
            np.ascontiguousarray(found, dtype=np.int64),
            self._ring,
            self._triangles,
            self._sign_normals,
            WEAK_PSEUDO_NORMAL,
            WEAK_SIGN_COS,
            faces,
            q,
            distance,
            inside,
            weak,
        )
        return faces, q, distance, inside, weak

    def _closest_few(self, local: np.ndarray) -> ClosestPoints:
        """:meth:`closest` for a few points (n <= FEW_POINTS, shifted frame): same answer, less overhead.

        The same steps as the vectorised path (Open3D's face, float64 projection onto it and onto its
        ring, pseudo-normal sign, ray parity where the sign is weak), point by point in compiled
        scalar code (``closest_kernels.ring_query``), whose cost is a fraction of numpy's per-call
        overhead on arrays of 3 to 20 elements. A ring face is
        projected only when its distance can beat the best so far: its lower bound is
        plane^2 + max(0, max_e out_e)^2 (squared distance to the face's plane plus how far the point
        lies outside the face's edges within that plane; exact on the face and edge regions). Exact
        ties go to the lowest face id. Only the rounding of the dot products differs from the
        vectorised path (about 1e-17 m), so a face that ties here may be a hair nearer there.
        """
        found = self._scene.closest_face_ids(local)
        points, distance, faces = [], [], []
        for p, f in zip(local.tolist(), found, strict=True):
            face, qx, qy, qz, dist, inside, weak = self._kernels.ring_query(
                self._triangles,
                self._sign_normals,
                self._ring[f],
                self._bound_planes,
                self._bound_offsets,
                p[0],
                p[1],
                p[2],
                WEAK_PSEUDO_NORMAL,
                WEAK_SIGN_COS,
            )
            if weak:
                inside = bool(self._scene.occupied(np.array([p]))[0])
            points.append((qx, qy, qz))
            distance.append(-dist if inside else dist)
            faces.append(face)
        face_ids = np.array(faces, dtype=np.int64)
        return ClosestPoints(
            points_m=np.array(points, dtype=np.float64) + self._centre,
            distance_m=np.array(distance, dtype=np.float64),
            normals=self._face_normals[face_ids],
            face_ids=face_ids,
        )

    @property
    def query_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What compiled queries (``closest_kernels``) read of the mesh: the centre (3,) that shifts the
        world frame to the sensor's, the triangles (F, 3, 3) and each face's sign pseudo-normals
        (F, 7, 3) in the shifted frame, and the faces' lower-bound planes (F, 4, 3) and offsets (F, 4)
        (see :meth:`_closest_few`). The sensor's own arrays: read them, do not write."""
        return self._centre, self._triangles, self._sign_normals, self._bound_planes, self._bound_offsets

    def seed_face(self, x: float, y: float, z: float) -> int:
        """Open3D's closest face to the world point (x, y, z): where a warm-started query that has no
        face yet starts, as :class:`WarmClosest` seeds its own."""
        cx, cy, cz = self._centre_list
        return self._scene.closest_face_ids(np.array([[x - cx, y - cy, z - cz]]))[0]

    def face_index(self) -> tuple[Any, np.ndarray, float]:
        """A k-d tree of the face centroids (shifted frame), each face's radius about its centroid (F,)
        and the largest radius: every point of face f lies within radius[f] of centroid[f]. Built once."""
        if self._index is None:
            from scipy.spatial import cKDTree

            centroids = self._triangles.mean(axis=1)
            radius = np.linalg.norm(self._triangles - centroids[:, None, :], axis=2).max(axis=1)
            self._index = (cKDTree(centroids), radius, float(radius.max()))
        return self._index

    def closest_float32(self, points_m: np.ndarray) -> np.ndarray:
        """Open3D's raw float32 closest points (n, 3), world frame, without the float64 refinement."""
        local = self._check(points_m)
        _, raw = self._scene.closest(local)
        return raw + self._centre

    def touch(
        self, centres_m: np.ndarray, radius_m: float, tolerance_m: float = 1e-4
    ) -> tuple[np.ndarray, ClosestPoints]:
        """Which spheres (centres (n, 3), radius m) touch or penetrate the surface.

        A sphere touches when its centre's signed distance is at most ``radius_m + tolerance_m``
        (centres inside the object always touch). Returns the mask (n,) and the closest points.
        """
        closest = self.closest(centres_m)
        return closest.distance_m <= radius_m + tolerance_m, closest


@cache
def refine_matches_numpy(samples: int = 900) -> bool:
    """Whether ``closest_kernels.refine_batch`` gives the bits of ``ExactContactSensor._refine`` here:
    points on, near, inside and far from a sphere and a box (vertices, edges, faces), checked once per
    process; where it does not, the sensor keeps numpy's path."""
    import trimesh

    rng = np.random.default_rng(20261127)
    for mesh in (trimesh.creation.icosphere(subdivisions=2, radius=0.05), trimesh.creation.box((0.04, 0.03, 0.02))):
        sensor = ExactContactSensor(mesh, warm_up=False)  # its warm-up asks this function
        corners = np.asarray(mesh.vertices)[rng.integers(len(mesh.vertices), size=samples // 3)]
        on = np.asarray(mesh.sample(samples // 3, seed=1))
        points = np.concatenate([corners, on, 0.06 * rng.standard_normal((samples // 3, 3))])
        scale = rng.choice([0.0, 1e-9, 1e-4, 0.005], size=(len(points), 1))
        points = points + scale * rng.standard_normal(points.shape)
        local = points - sensor._centre
        found, _ = sensor._scene.closest(local)
        for got, expected in zip(sensor._refine_compiled(local, found), sensor._refine(local, found), strict=True):
            if got.dtype != expected.dtype or got.tobytes() != expected.tobytes():
                return False
    return True


class WarmClosest:
    """The exact closest point of one query point that moves a little between queries (a fingertip).

    The answer is :meth:`ExactContactSensor.closest`'s for that point, bit for bit: the same face,
    projected in float64 by the same scalar arithmetic (compiled: ``closest_kernels``), with the same
    sign rule. Only the search differs. Instead of Open3D's search over the whole mesh and a Python
    loop over that face's ring, each query searches a *patch* in compiled code, warm-started from the
    last answer's face:

    - The patch, built at a point p0, holds every face whose distance to p0 is at most e + 2 reach
      (e: the distance from p0 to any face, an upper bound of the distance d(p0) to the surface). For a
      query point p within ``reach_m`` of p0 the closest face is in it: d(p) <= e + |p - p0|, and a
      face at distance d(p) from p lies within d(p) + |p - p0| <= e + 2 reach of p0. Faces come from a
      k-d tree of the face centroids (a face lies within its radius of its centroid), kept by the
      lower bound below. The patch is rebuilt when p leaves the ball of radius reach about p0.
    - A query projects p onto the last answer's face (an upper bound of d(p)) and then onto every
      patch face whose lower bound (its plane, then how far p lies outside its edges: the bound of the
      few-point path, with the same slack) can reach the best so far.
    - Exact ties (faces at the same squared distance to the last bit: a vertex or edge they share)
      go to the lowest face id, as in the sensor, so the face (and its normal) is the sensor's too,
      up to the caveat below.
    - Far from the surface (e + 2 reach > ``max_distance_m``), or where a patch would hold more than
      ``max_patch_faces`` faces, the query is the sensor's own.

    The one way the answers could differ: the sensor searches only the ring of Open3D's face (the
    faces sharing a vertex with it). Where that ring misses the true closest face (a near-tie of
    non-adjacent faces within float32 rounding, about 1e-8 m), or a lower-id face tied with it (an
    exact tie of faces that share no vertex, or Open3D's face a float32 near-tie that does not hold the
    tied vertex), the sensor answers with the best face of that ring and this search with the true
    closest, lowest-id face. Neither was seen on the test meshes or the 30 shared objects.
    """

    def __init__(
        self,
        sensor: ExactContactSensor,
        reach_m: float = 0.001,
        max_distance_m: float = 0.03,
        max_patch_faces: int = 4096,
    ) -> None:
        if not reach_m > 0.0 or not max_distance_m > 0.0:
            raise ValueError(f"reach_m and max_distance_m must be > 0, got {reach_m!r} and {max_distance_m!r}")
        self._kernels = sensor._kernels
        self.sensor = sensor
        self.reach_m = float(reach_m)
        self.max_distance_m = float(max_distance_m)
        self.max_patch_faces = int(max_patch_faces)
        self._face = -1  # the last answer's face (-1: none yet)
        self._p0 = (math.inf, math.inf, math.inf)  # where the patch was built (shifted frame)
        self._faces: NDArray[np.int64] | None = None  # patch faces, by their lower bound at p0
        self._planes = np.zeros((0, 4, 3))  # their bound planes (K, 4, 3), offsets (K, 4), bounds at p0 (K,)
        self._offsets = np.zeros((0, 4))
        self._lower0 = np.zeros(0)
        #: How many queries built a patch, searched one or took the sensor's own search (a compiled
        #: caller reports its searches through :meth:`resume`; the patches it builds are not counted).
        self.counts = {"builds": 0, "patch": 0, "full": 0}

    def query(self, point_m: ArrayLike) -> tuple[tuple[float, float, float], float, int]:
        """Closest surface point (3 floats, world frame, metres), signed distance (m, < 0 inside) and
        face id of one finite point (3,)."""
        s = self.sensor
        point = point_m if type(point_m) is np.ndarray and point_m.shape == (3,) else np.asarray(point_m, np.float64)
        x, y, z = (float(v) for v in point.reshape(3).tolist())
        if not math.isfinite(x + y + z):
            raise ValueError("query point must be finite (got NaN or infinity)")
        cx, cy, cz = s._centre_list
        px, py, pz = x - cx, y - cy, z - cz  # shifted frame, as ExactContactSensor._check computes it
        x0, y0, z0 = self._p0
        if self._faces is None or (px - x0) ** 2 + (py - y0) ** 2 + (pz - z0) ** 2 > self.reach_m**2:
            self._build(px, py, pz)
        if self._faces is None:
            self.counts["full"] += 1
            hit = s.closest(np.array([[x, y, z]]))
            self._face = int(hit.face_ids[0])
            q = hit.points_m[0].tolist()
            return (q[0], q[1], q[2]), float(hit.distance_m[0]), self._face
        self.counts["patch"] += 1
        k = self._kernels
        x0, y0, z0 = self._p0
        moved = math.sqrt((px - x0) ** 2 + (py - y0) ** 2 + (pz - z0) ** 2)
        search = k.warm_query(
            s._triangles,
            s._sign_normals,
            self._faces,
            self._planes,
            self._offsets,
            self._lower0,
            moved * (1.0 + 1e-12) + 1e-18,  # rounded up: the bound stays a bound
            self._face,
            px,
            py,
            pz,
            WEAK_PSEUDO_NORMAL,
            WEAK_SIGN_COS,
        )
        return self.settle([px, py, pz], search)

    def settle(
        self, p: list[float], search: tuple[int, float, float, float, float, bool, bool]
    ) -> tuple[tuple[float, float, float], float, int]:
        """The answer at p (3 floats, shifted frame) from a patch search (``closest_kernels.warm_query``'s
        result): a weak sign decided by ray parity, as the sensor decides it. For :meth:`query`, and for
        compiled callers that search patches themselves."""
        s = self.sensor
        face, qx, qy, qz, dist, inside, weak = search
        if weak:
            inside = bool(s._scene.occupied(np.array([p]))[0])
        signed = -dist if inside else dist
        self._face = face
        cx, cy, cz = s._centre_list
        return (qx + cx, qy + cy, qz + cz), signed, face

    def patch(self) -> tuple[np.ndarray, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The warm start for a compiled caller of ``closest_kernels.warm_query``: where the patch was
        built (3,) (shifted frame; inf before the first), the last answer's face (-1: none), and the
        patch's faces, bound planes, offsets and bounds (no faces: no patch, ask :meth:`query`). A
        caller that answers queries itself reports back through :meth:`resume`."""
        faces = np.zeros(0, dtype=np.int64) if self._faces is None else self._faces
        return np.array(self._p0), self._face, faces, self._planes, self._offsets, self._lower0

    def adopt(
        self, p0: np.ndarray, face: int, faces: np.ndarray, planes: np.ndarray, offsets: np.ndarray, lower0: np.ndarray
    ) -> None:
        """Take the warm start of a compiled caller that builds patches too (the arrays of :meth:`patch`;
        no faces: no patch). Any valid patch gives the same answers: it holds every face that can be
        closest, or tie, within its reach."""
        self._p0 = (float(p0[0]), float(p0[1]), float(p0[2]))
        self._face = int(face)
        self._faces = faces if len(faces) else None
        self._planes, self._offsets, self._lower0 = planes, offsets, lower0

    def resume(self, face: int, searches: int) -> None:
        """After a compiled caller answered ``searches`` queries on :meth:`patch`, the last one on ``face``."""
        self._face = int(face)
        self.counts["patch"] += int(searches)

    def _build(self, px: float, py: float, pz: float) -> None:
        """The patch about p (shifted frame); the first query seeds the warm face with Open3D's."""
        s = self.sensor
        self._faces = None
        if self._face < 0:
            self._face = s._scene.closest_face_ids(np.array([[px, py, pz]]))[0]
        upper, _, _, _ = self._kernels.project(s._triangles, self._face, px, py, pz)
        radius = math.sqrt(upper) + 2.0 * self.reach_m
        if radius > self.max_distance_m:
            return
        tree, _, largest = s.face_index()
        near = np.asarray(tree.query_ball_point([px, py, pz], radius + largest), dtype=np.int64)
        if len(near) > self.max_patch_faces:
            return
        faces, planes, offsets, lower = self._kernels.build_patch(
            s._bound_planes, s._bound_offsets, near, px, py, pz, radius
        )
        self._faces, self._planes, self._offsets, self._lower0 = faces, planes, offsets, lower
        self._p0 = (px, py, pz)
        self.counts["builds"] += 1
