"""Exploration metrics of paper 002, Section 3.2: coverage, surface RMSE, prediction miss, contact angle.

Meshes are given either as a ``(vertices (V, 3), faces (F, 3))`` pair or as any object with
``vertices`` and ``faces`` attributes (a trimesh.Trimesh). Units are metres. Point-to-mesh distances
come from Open3D's ``RaycastingScene`` (exact, in C++); trimesh's proximity queries misreport
distances on metre-scale meshes (see the YCB README).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from palpate.errors import MeshError
from palpate.geometry.mesh_query import MeshScene

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Thinnest covering of the plane by equal discs (hexagonal): density 2 pi / sqrt(27) ~ 1.2092.
COVERING_DENSITY = 2.0 * np.pi / np.sqrt(27.0)


class MeshLike(Protocol):
    """Anything with vertex positions and triangle indices (trimesh.Trimesh, for example)."""

    @property
    def vertices(self) -> Any: ...

    @property
    def faces(self) -> Any: ...


Mesh = MeshLike | tuple[ArrayLike, ArrayLike]


def point_rows(points: ArrayLike, name: str) -> FloatArray:
    """``points`` as finite float64 rows (n, 3) (a single point (3,) as one row), else ValueError naming it."""
    P = np.asarray(points, dtype=np.float64)
    if P.shape == (3,) or P.size == 0:
        P = P.reshape(-1, 3)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {P.shape}")
    if not np.isfinite(P).all():
        raise ValueError(f"{name} must be finite (got NaN or infinity)")
    return P


def mesh_arrays(mesh: Mesh) -> tuple[FloatArray, IntArray]:
    """(vertices (V, 3) float64, faces (F, 3) int64) of a mesh, validated."""
    if isinstance(mesh, tuple):
        V, F = mesh
    else:
        V, F = mesh.vertices, mesh.faces
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0:
        raise MeshError(f"a mesh needs vertices (V, 3) and faces (F>0, 3), got {V.shape} and {F.shape}")
    if not np.all(np.isfinite(V)):
        raise MeshError("mesh vertices hold NaN or infinity")
    if F.min() < 0 or F.max() >= V.shape[0]:
        raise MeshError(f"face indices out of range [0, {V.shape[0]}): min {F.min()}, max {F.max()}")
    return V, F


def triangle_areas(V: FloatArray, F: IntArray) -> FloatArray:
    """Area of each triangle (F,), square metres."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.asarray(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1), dtype=np.float64)


def mesh_area(mesh: Mesh) -> float:
    """Total surface area, square metres."""
    V, F = mesh_arrays(mesh)
    return float(triangle_areas(V, F).sum())


def sample_surface(mesh: Mesh, count: int, rng: np.random.Generator) -> FloatArray:
    """``count`` points uniform by area on the mesh surface, (count, 3) metres."""
    V, F = mesh_arrays(mesh)
    area = triangle_areas(V, F)
    total = area.sum()
    if not total > 0.0:
        raise MeshError("the mesh has zero surface area")
    tri = rng.choice(F.shape[0], size=count, p=area / total)
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0  # fold the unit square onto the triangle: uniform barycentric coordinates
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    a, b, c = V[F[tri, 0]], V[F[tri, 1]], V[F[tri, 2]]
    return np.asarray(a + u[:, None] * (b - a) + v[:, None] * (c - a), dtype=np.float64)


class DistanceField:
    """Exact unsigned distance from points to a triangle mesh (Open3D RaycastingScene, float32)."""

    def __init__(self, mesh: Mesh) -> None:
        V, F = mesh_arrays(mesh)
        # shifted to the mean vertex: the absolute float32 error stays ~1e-8 m (rounding relative to
        # the object size, not to the world origin)
        self._scene = MeshScene(V, F, origin_m=V.mean(axis=0))

    def distance(self, points: ArrayLike) -> FloatArray:
        """Distance of each point to the surface, (n,) metres. points: (n, 3), finite."""
        P = point_rows(points, "points")
        if P.shape[0] == 0:
            return np.zeros(0)
        return self._scene.distance(P - self._scene.origin_m)


class CoverageTracker:
    """Explored fraction of the true surface (Section 3.2): a surface point counts as explored once a
    contact lies within ``radius_m`` (Euclidean) of it.

    ``coverage``: fraction of ``samples`` points drawn uniformly by area (the paper's definition,
    standard error about sqrt(p (1 - p) / samples)). ``vertex_coverage``: fraction of mesh vertices
    explored, the alternative reading that can explain the paper's low contact counts.
    """

    def __init__(
        self,
        mesh: Mesh,
        radius_m: float = 0.006,
        samples: int = 20000,
        rng: np.random.Generator | None = None,
    ) -> None:
        if not radius_m > 0.0 or samples < 1:
            raise ValueError(f"radius_m must be > 0 and samples >= 1, got {radius_m!r}, {samples!r}")
        V, F = mesh_arrays(mesh)
        self.radius_m = float(radius_m)
        self.area_m2 = float(triangle_areas(V, F).sum())
        self.points_m = sample_surface((V, F), samples, rng if rng is not None else np.random.default_rng(0))
        self._tree = cKDTree(self.points_m)
        self._vertex_tree = cKDTree(V)
        self._explored = np.zeros(samples, dtype=bool)
        self._vertex_explored = np.zeros(V.shape[0], dtype=bool)
        self.contacts = 0

    def add_contact(self, p: ArrayLike) -> float:
        """Mark the surface within radius_m of contact p (3,) as explored; returns the new coverage."""
        return self.add_contacts(point_rows(p, "contact").reshape(1, 3))

    def add_contacts(self, points: ArrayLike) -> float:
        """Mark several contacts (n, 3) at once; returns the new coverage."""
        P = point_rows(points, "contacts")
        for tree, explored in ((self._tree, self._explored), (self._vertex_tree, self._vertex_explored)):
            hits = tree.query_ball_point(P, self.radius_m, return_sorted=False)  # one list per contact
            for h in hits:
                explored[np.asarray(h, dtype=np.int64)] = True
        self.contacts += P.shape[0]
        return self.coverage

    @property
    def coverage(self) -> float:
        """Explored fraction of the surface area (0..1)."""
        return float(self._explored.mean())

    @property
    def vertex_coverage(self) -> float:
        """Explored fraction of the mesh vertices (0..1)."""
        return float(self._vertex_explored.mean())

    @property
    def explored_mask(self) -> NDArray[np.bool_]:
        """Which area samples are explored, (samples,)."""
        return self._explored.copy()


def covering_bound_contacts(area_m2: float, fraction: float = 0.8, radius_m: float = 0.006) -> float:
    """The issue's contact estimate: COVERING_DENSITY * fraction * A / (pi r^2), with the density
    2 pi / sqrt(27) ~ 1.21 of the thinnest covering of the plane by discs of radius r.

    This is the fewest discs for covering ALL of a flat surface, scaled by ``fraction``. For a partial
    coverage it is not a strict lower bound: up to 90.7 % of a plane can be covered by disjoint discs,
    so ``packing_bound_contacts`` is the strict one (a real exploration needs more than either)."""
    _check_bound_args(area_m2, fraction, radius_m)
    return float(COVERING_DENSITY * fraction * area_m2 / (np.pi * radius_m**2))


def _check_bound_args(area_m2: float, fraction: float, radius_m: float) -> None:
    """ValueError unless the area is >= 0, the fraction in [0, 1] and the radius > 0 (all finite)."""
    if not (np.isfinite(area_m2) and area_m2 >= 0.0):
        raise ValueError(f"area_m2 must be finite and >= 0, got {area_m2!r}")
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must lie in [0, 1], got {fraction!r}")
    if not (np.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"radius_m must be finite and > 0, got {radius_m!r}")


def packing_bound_contacts(area_m2: float, fraction: float = 0.8, radius_m: float = 0.006) -> float:
    """Strict lower bound on the contacts that explore ``fraction`` of a surface of area A:
    fraction * A / (pi r^2), since one contact explores at most pi r^2 of a surface that is flat or
    convexly curved at the scale r (exactly pi r^2 on a sphere). Thin walls (both sides within r),
    concave corners and gaps can beat it."""
    _check_bound_args(area_m2, fraction, radius_m)
    return float(fraction * area_m2 / (np.pi * radius_m**2))


@dataclass(frozen=True)
class SurfaceRmse:
    """RMSE between an estimated and the true surface, metres.

    estimate_to_truth_m: one-sided, estimate samples to the true mesh (penalises wrong surface);
    truth_to_estimate_m: one-sided, true samples to the estimate (penalises missing surface);
    symmetric_m: RMS over both sets of distances together (equal sample counts).
    """

    estimate_to_truth_m: float
    truth_to_estimate_m: float
    symmetric_m: float


def surface_rmse(
    estimate: Mesh | ArrayLike,
    true_mesh: Mesh,
    samples: int = 20000,
    rng: np.random.Generator | None = None,
) -> SurfaceRmse:
    """Surface RMSE of Section 3.2 between the estimated surface and the true mesh.

    ``estimate`` is a mesh (sampled by area) or a point set (n, 3) used as is; for a point set the
    truth-to-estimate distance is to the nearest estimate point (a KD-tree), an upper bound on the
    distance to the surface those points came from. rng draws the true samples, then the estimate's.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    truth_pts = sample_surface(true_mesh, samples, rng)
    return _rmse_against(estimate, DistanceField(true_mesh), truth_pts, samples, rng)


class RmseScorer:
    """``surface_rmse`` of many estimates against one true mesh, to the bit, with the true mesh's
    distance field and samples made once: ``score(e)`` is ``surface_rmse(e, true_mesh, samples,
    np.random.default_rng(seed))`` (each estimate's draw starts where that generator stands after the
    true samples)."""

    def __init__(self, true_mesh: Mesh, samples: int = 20000, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.samples = samples
        self._truth_points = sample_surface(true_mesh, samples, rng)
        self._after_truth = rng.bit_generator.state
        self._field = DistanceField(true_mesh)

    def score(self, estimate: Mesh | ArrayLike) -> SurfaceRmse:
        """``surface_rmse`` of one estimate (a mesh or a point set, as there)."""
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = self._after_truth
        return _rmse_against(estimate, self._field, self._truth_points, self.samples, rng)


def _rmse_against(
    estimate: Mesh | ArrayLike, true_field: DistanceField, truth_pts: FloatArray, samples: int, rng: np.random.Generator
) -> SurfaceRmse:
    """``surface_rmse`` once the true mesh's field and samples are made (rng then draws the estimate's)."""
    if isinstance(estimate, tuple) or hasattr(estimate, "faces"):
        est_mesh: Mesh = estimate  # type: ignore[assignment]
        est_pts = sample_surface(est_mesh, samples, rng)
        d_truth_to_est = DistanceField(est_mesh).distance(truth_pts)
    else:
        est_pts = np.asarray(estimate, dtype=np.float64)
        if est_pts.ndim != 2 or est_pts.shape[1] != 3 or est_pts.shape[0] == 0:
            raise MeshError(f"the estimate must be a mesh or points (n>0, 3), got {est_pts.shape}")
        if not np.isfinite(est_pts).all():
            raise MeshError("the estimate's points must be finite (got NaN or infinity)")
        d_truth_to_est, _ = cKDTree(est_pts).query(truth_pts)
    d_est_to_truth = true_field.distance(est_pts)
    e2t = float(np.sqrt(np.mean(d_est_to_truth**2)))
    t2e = float(np.sqrt(np.mean(np.asarray(d_truth_to_est) ** 2)))
    both = np.concatenate([d_est_to_truth, np.asarray(d_truth_to_est, dtype=np.float64)])
    return SurfaceRmse(estimate_to_truth_m=e2t, truth_to_estimate_m=t2e, symmetric_m=float(np.sqrt(np.mean(both**2))))


def confident_faces(faces: ArrayLike, vertex_variance: ArrayLike, max_sigma_m: float) -> IntArray:
    """The faces (k, 3) of a surface estimate whose three vertices have GP standard deviation
    <= max_sigma_m: the part of the estimate the GP claims to know to that precision.

    faces: (f, 3) vertex indices; vertex_variance: (v,) GP variance of f at the vertices, m^2.
    """
    F = np.asarray(faces, dtype=np.int64)
    F = F.reshape(0, 3) if F.size == 0 else F
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"faces must have shape (f, 3), got {F.shape}")
    var = np.asarray(vertex_variance, dtype=np.float64)
    if len(F) and (var.ndim != 1 or len(var) <= int(F.max())):
        raise ValueError(f"vertex_variance {var.shape} has no value for vertex {int(F.max())} that the faces use")
    ok = var <= max_sigma_m**2  # False for NaN
    return F[ok[F].all(axis=1)] if len(F) else F


def angle_to_normal_deg(fingertip_axis: ArrayLike, true_normals: ArrayLike) -> FloatArray:
    """Angle between the fingertip's poking axis and the inward true normal at contact, degrees (n,).

    0 means the fingertip pokes straight into the surface (axis = -normal), the quantity of the
    paper's Fig. 9. Inputs (n, 3) or (3,); need not be unit length. NaN where either vector is zero
    (it has no direction; arctan2 alone would call that a perfect 0).
    """
    a = np.atleast_2d(np.asarray(fingertip_axis, dtype=np.float64))
    n = -np.atleast_2d(np.asarray(true_normals, dtype=np.float64))
    cross = np.linalg.norm(np.cross(a, n), axis=1)
    dot = np.einsum("ij,ij->i", a, n)
    angle = np.degrees(np.arctan2(cross, dot))
    undefined = (np.abs(a).max(axis=1) == 0.0) | (np.abs(n).max(axis=1) == 0.0)
    return np.asarray(np.where(undefined, np.nan, angle), dtype=np.float64)


def prediction_miss_m(predicted: ArrayLike, actual: ArrayLike) -> FloatArray:
    """Prediction miss |predicted - actual contact| per touch (n,), metres. Inputs (n, 3) or (3,)."""
    p = np.atleast_2d(np.asarray(predicted, dtype=np.float64))
    q = np.atleast_2d(np.asarray(actual, dtype=np.float64))
    if p.shape != q.shape or p.shape[1:] != (3,):
        raise ValueError(f"predicted {p.shape} and actual {q.shape} must be the same (n, 3) or (3,)")
    return np.asarray(np.linalg.norm(p - q, axis=1), dtype=np.float64)
