"""Triangulated estimate of the surface f = 0 (paper 002 Sec. 2.1: marching cubes near the latest contact).

The GP mean is evaluated on a regular grid in vectorised batches (``GPIS.mean``), coarse to fine:
first on every other node; then, exactly, only on the fine nodes of the coarse cells that the surface
may enter (a corner with |f| < REFINE_BAND x coarse step, or corners of both signs); elsewhere the
fine values are trilinear interpolations of same-signed coarse values, which cannot create a zero
crossing. The band is safe while |grad f| < REFINE_BAND / (sqrt(3)/2) = 1.7 near the surface (the
GP fits unit normals, so |grad f| ~ 1 there); ``refine=False`` evaluates every node. scikit-image's
marching cubes extracts the zero level set, and the vertex normals and variances come from the GP
itself (``GPIS.gradient``, ``GPIS.variance``) at the vertices only, not at every grid node. Faces
are wound so that their right-hand normals point outwards (towards f > 0). A box without a zero
crossing gives an empty mesh, not an exception.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from skimage.measure import marching_cubes

from palpate.errors import EstimationError, InputError
from palpate.geometry.thinning import thin_near
from palpate.inputs import coordinates, unit_vectors
from palpate.nodes.gpis.core import SurfaceEstimator

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int32]
#: Which vertices (v, 3) get the GP variance: their ascending indices.
VarianceSites = Callable[[FloatArray], NDArray[np.integer]]

#: Default local patch: +-5 cm around the latest contact (the planner samples candidates up to 5 cm,
#: GP-V up to 6 cm in a straight line from it, which the box corners cover).
LOCAL_HALF_EXTENT_M = 0.05
#: Default grid step. Marching-cubes vertices then lie at most one step apart, so the planner's
#: candidates (vertices thinned to one per 5 mm voxel) keep the paper's 0.5 cm candidate step.
LOCAL_RESOLUTION_M = 0.005
#: Coarse cells with a corner |f| below REFINE_BAND x coarse step are evaluated on the fine grid.
REFINE_BAND = 1.5
#: Largest grid accepted (nodes), to refuse a resolution that would exhaust memory or take minutes.
MAX_GRID_NODES = 50_000_000


@dataclass(frozen=True, kw_only=True)
class SurfaceMeshArrays:
    """A triangle mesh of the estimated surface (metres, world frame).

    vertices (v, 3), faces (f, 3) int32 indices into vertices (counter-clockwise seen from outside),
    vertex_normals (v, 3) outward unit normals from the GP gradient, variance_vertices (k,) ascending
    int32 indices of the vertices with a variance (all, none, or the planner's candidates) and
    vertex_variance (k,) the GP variance of f there in m^2 (Eq. 6; never negative: ``GPIS.variance``
    clamps round-off at 0).
    """

    vertices: FloatArray
    faces: IntArray
    vertex_normals: FloatArray
    variance_vertices: IntArray
    vertex_variance: FloatArray

    @classmethod
    def empty(cls) -> SurfaceMeshArrays:
        """A mesh with no vertices and no faces."""
        return cls(
            vertices=np.zeros((0, 3)),
            faces=np.zeros((0, 3), dtype=np.int32),
            vertex_normals=np.zeros((0, 3)),
            variance_vertices=np.zeros(0, dtype=np.int32),
            vertex_variance=np.zeros(0),
        )

    @property
    def is_empty(self) -> bool:
        return len(self.faces) == 0

    def face_centres(self) -> FloatArray:
        """Centroid of each triangle (f, 3): the candidate points of paper 002 Sec. 2.1."""
        return self.vertices[self.faces].mean(axis=1)


def axis_nodes(extent_m: float, resolution_m: float) -> int:
    """Nodes of a grid axis spanning extent_m at step resolution_m (``grid_axes``): an odd number >= 3."""
    count = max(math.ceil(extent_m / resolution_m - 1e-9) + 1, 3)
    return count + 1 - count % 2


def fitting_resolution(extent_m: ArrayLike, resolution_m: float, max_nodes: int | None = None) -> float:
    """The step, at least resolution_m, of a grid over a box of extent_m (3,) with at most max_nodes nodes
    (None: MAX_GRID_NODES): a whole-object mesh of a large object (or at a very fine step) coarsened by 2 %
    steps until it fits."""
    limit = MAX_GRID_NODES if max_nodes is None else max_nodes
    extent = [float(e) for e in np.asarray(extent_m, dtype=np.float64)]
    step = float(resolution_m)
    while math.prod(axis_nodes(e, step) for e in extent) > limit:
        step *= 1.02
    return step


def grid_axes(bounds_min: ArrayLike, bounds_max: ArrayLike, resolution_m: float) -> list[FloatArray]:
    """Per-axis node coordinates covering [bounds_min, bounds_max] with step resolution_m, centred.

    Each axis gets an odd number >= 3 of nodes (ceil(extent / resolution) + 1, plus one if even), so
    the grid covers the box and overhangs it by at most one step, split evenly between both sides;
    every other node forms the coarse grid of ``sample_mean``.
    """
    lo = np.asarray(bounds_min, dtype=np.float64)
    hi = np.asarray(bounds_max, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise EstimationError(f"grid bounds must be finite 3-vectors, got {lo} and {hi}")
    if np.any(hi < lo):
        raise EstimationError(f"grid bounds_max {hi} is below bounds_min {lo}")
    if not (np.isfinite(resolution_m) and resolution_m > 0):
        raise EstimationError(f"grid resolution_m must be positive, got {resolution_m!r}")
    counts = np.array([axis_nodes(float(e), resolution_m) for e in hi - lo])
    if int(np.prod(counts)) > MAX_GRID_NODES:
        raise EstimationError(
            f"grid of {counts.tolist()} nodes at resolution {resolution_m} m exceeds {MAX_GRID_NODES} nodes; "
            "use a coarser resolution_m or smaller bounds"
        )
    centre = 0.5 * (lo + hi)
    return [centre[k] + (np.arange(counts[k]) - 0.5 * (counts[k] - 1)) * resolution_m for k in range(3)]


# Corner offsets of a cell, and fine-node offsets (0, 1, 2 per axis) of a coarse cell.
_CUBE = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
_CUBE3 = [(i, j, k) for i in (0, 1, 2) for j in (0, 1, 2) for k in (0, 1, 2)]


def _grid_points(axes: list[FloatArray]) -> FloatArray:
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


def _upsample(v: FloatArray, axis: int) -> FloatArray:
    """Insert midpoints along one axis: n nodes -> 2 n - 1 (linear interpolation)."""
    v = np.moveaxis(v, axis, 0)
    out = np.empty((2 * v.shape[0] - 1, *v.shape[1:]))
    out[::2] = v
    out[1::2] = 0.5 * (v[:-1] + v[1:])
    return np.moveaxis(out, 0, axis)


def sample_mean(gp: SurfaceEstimator, axes: list[FloatArray], *, refine: bool = True) -> FloatArray:
    """GP mean on the grid of the three node-coordinate axes (odd lengths): (nx, ny, nz).

    refine=True evaluates the coarse grid (every other node) and then only the fine nodes of coarse
    cells within REFINE_BAND coarse steps of a zero crossing; other nodes hold trilinear values.
    """
    shape = tuple(len(a) for a in axes)
    if not refine or min(shape) < 5 or any(n % 2 == 0 for n in shape):
        return gp.mean(_grid_points(axes)).reshape(shape)
    coarse_axes = [a[::2] for a in axes]
    fc = gp.mean(_grid_points(coarse_axes)).reshape(tuple(len(a) for a in coarse_axes))
    band = REFINE_BAND * max(float(a[1] - a[0]) for a in coarse_axes)
    corners = [fc[i : i + fc.shape[0] - 1, j : j + fc.shape[1] - 1, k : k + fc.shape[2] - 1] for i, j, k in _CUBE]
    cmin = np.minimum.reduce(corners)
    cmax = np.maximum.reduce(corners)
    active = (cmin < band) & (cmax > -band)  # some corner has |f| < band, or the signs differ
    volume = _upsample(_upsample(_upsample(fc, 0), 1), 2)
    mask = np.zeros(shape, dtype=bool)
    nc = active.shape
    for a, b, c in _CUBE3:  # fine nodes 2i + a, a in {0, 1, 2}, of every active coarse cell i
        mask[a : a + 2 * nc[0] : 2, b : b + 2 * nc[1] : 2, c : c + 2 * nc[2] : 2] |= active
    mask[::2, ::2, ::2] = False  # coarse nodes are already exact
    idx = np.nonzero(mask)
    if idx[0].size:
        pts = np.column_stack([axes[0][idx[0]], axes[1][idx[1]], axes[2][idx[2]]])
        volume[idx] = gp.mean(pts)
    return volume


def mesh_from_grid(
    gp: SurfaceEstimator,
    axes: list[FloatArray],
    *,
    with_variance: bool = True,
    variance_sites: VarianceSites | None = None,
    refine: bool = True,
) -> SurfaceMeshArrays:
    """Marching cubes of the GP mean sampled on the grid given by three node-coordinate axes.

    with_variance=False skips Eq. 6 (no vertex carries a variance), for callers that only need shape;
    variance_sites picks the vertices that get one (default: all);
    refine=False evaluates the mean at every grid node (reference for the coarse-to-fine sampling).
    """
    volume = sample_mean(gp, axes, refine=refine)
    if not np.all(np.isfinite(volume)):
        raise EstimationError("the GP mean is not finite on the surface grid; check the contacts and config")
    if not (volume.min() < 0.0 < volume.max()):
        return SurfaceMeshArrays.empty()
    spacing = tuple(float(a[1] - a[0]) for a in axes)
    # f increases outwards; skimage's "descent" winds faces so their normals point towards increasing f
    # (checked by test_faces_are_wound_outwards).
    verts, faces, _, _ = marching_cubes(volume, level=0.0, spacing=spacing, gradient_direction="descent")
    vertices = np.asarray(verts, dtype=np.float64) + np.array([a[0] for a in axes])
    grad = gp.gradient(vertices)
    norm = np.linalg.norm(grad, axis=1, keepdims=True)
    normals = np.zeros_like(grad)
    np.divide(grad, norm, out=normals, where=norm > 0)
    if not with_variance:
        sites = np.zeros(0, dtype=np.int32)
    elif variance_sites is None:
        sites = np.arange(len(vertices), dtype=np.int32)
    else:
        sites = np.asarray(variance_sites(vertices), dtype=np.int32)
    variance = gp.variance(vertices[sites])
    return SurfaceMeshArrays(
        vertices=vertices,
        faces=np.ascontiguousarray(faces, dtype=np.int32),
        vertex_normals=normals,
        variance_vertices=sites,
        vertex_variance=variance,
    )


def local_surface(
    gp: SurfaceEstimator,
    centre_m: ArrayLike,
    half_extent_m: float = LOCAL_HALF_EXTENT_M,
    resolution_m: float = LOCAL_RESOLUTION_M,
    *,
    with_variance: bool = True,
    refine: bool = True,
) -> SurfaceMeshArrays:
    """Surface mesh in the cube centre_m +- half_extent_m (normally around the latest contact)."""
    c = np.asarray(centre_m, dtype=np.float64)
    if c.shape != (3,):
        raise EstimationError(f"local surface centre must have shape (3,), got {c.shape}")
    if not (np.isfinite(half_extent_m) and half_extent_m > 0):
        raise EstimationError(f"local surface half_extent_m must be positive, got {half_extent_m!r}")
    axes = grid_axes(c - half_extent_m, c + half_extent_m, resolution_m)
    return mesh_from_grid(gp, axes, with_variance=with_variance, refine=refine)


def global_surface(
    gp: SurfaceEstimator,
    bounds_min: ArrayLike,
    bounds_max: ArrayLike,
    resolution_m: float,
    *,
    with_variance: bool = True,
    refine: bool = True,
) -> SurfaceMeshArrays:
    """Surface mesh over the box [bounds_min, bounds_max] (the whole object, on request)."""
    axes = grid_axes(bounds_min, bounds_max, resolution_m)
    return mesh_from_grid(gp, axes, with_variance=with_variance, refine=refine)


def whole_surface(
    gp: SurfaceEstimator, margin_m: float, resolution_m: float, *, with_variance: bool = True, refine: bool = True
) -> SurfaceMeshArrays:
    """Surface mesh over the contacts' bounding box grown by margin_m on every side (the whole object
    as touched so far); an empty mesh before the first contact. ``whole_resolution`` gives the step whose
    grid fits MAX_GRID_NODES."""
    if gp.n_contacts == 0:
        return SurfaceMeshArrays.empty()
    lower, upper = whole_box(gp.positions_m, margin_m)
    return global_surface(gp, lower, upper, resolution_m, with_variance=with_variance, refine=refine)


def whole_resolution(gp: SurfaceEstimator, margin_m: float, resolution_m: float) -> float:
    """The step for ``whole_surface``: resolution_m, or coarser where its grid would exceed MAX_GRID_NODES."""
    if gp.n_contacts == 0:
        return resolution_m
    lower, upper = whole_box(gp.positions_m, margin_m)
    return fitting_resolution(upper - lower, resolution_m)


def whole_box(points_m: FloatArray, margin_m: float) -> tuple[FloatArray, FloatArray]:
    """The box ``whole_surface`` meshes: the bounding box of points_m (n, 3), n >= 1, grown by margin_m
    on every side, as (lower (3,), upper (3,))."""
    return points_m.min(axis=0) - margin_m, points_m.max(axis=0) + margin_m


def grid_reach(points_m: FloatArray, centre_m: FloatArray, half_extents_m: FloatArray | float) -> float:
    """Largest distance, metres, from one of points_m (n, 3), n >= 1, to a point of the box of half
    extents half_extents_m (3,) or one for every axis around centre_m (3,): the box corner farthest
    from each point, sqrt(sum_i (|p_i - c_i| + e_i)^2)."""
    return float(np.sqrt(np.max(np.sum((np.abs(points_m - centre_m) + half_extents_m) ** 2, axis=1))))


#: ``add_touch`` halves its grid at most this many times where the surface at the touch is thinner
#: than the grid (5 mm -> 0.625 mm by default).
FINER_LOCAL_GRIDS = 3


@dataclass(frozen=True)
class TouchMesh:
    """The local mesh ``add_touch`` made and the grid step it took (finer than asked where the surface
    at the touch was thinner than the grid)."""

    mesh: SurfaceMeshArrays
    resolution_m: float


def meshes_point(mesh: SurfaceMeshArrays, point_m: FloatArray, resolution_m: float) -> bool:
    """Whether some vertex of `mesh` lies within a grid cell's diagonal of `point_m` (3,): marching cubes
    puts one there wherever the surface through the point crosses the grid."""
    if mesh.is_empty:
        return False
    nearest = float(np.min(np.linalg.norm(mesh.vertices - point_m, axis=1)))
    return nearest <= math.sqrt(3.0) * resolution_m


def add_touch(
    gp: SurfaceEstimator,
    position_m: ArrayLike,
    normal: ArrayLike,
    half_extent_m: float = LOCAL_HALF_EXTENT_M,
    resolution_m: float = LOCAL_RESOLUTION_M,
    *,
    with_variance: bool = True,
    variance_near: tuple[float, float] | None = None,
    finer_grids: int = FINER_LOCAL_GRIDS,
) -> TouchMesh:
    """Add a touch (position (3,) m, outward unit normal (3,)) to the GP and mesh the surface around it.

    variance_near = (step_m, radius_m): the variance only at the vertices a planner samples around this
    touch (``thinning.thin_near``, one per step_m voxel within radius_m); None: at every vertex.

    Where the surface through the touch is thinner than the grid (a needle, a wire, a rim: no grid edge
    crosses it, so the mesh has no vertex near the touch), the mesh is made again with half the step,
    up to ``finer_grids`` times: first over the same box, then over half the box each time (the same
    number of nodes as the first refinement). When none meshes the touch, the first mesh is returned.

    Atomic: InputError (naming the TouchEvent field) leaves the GP as it was, for a position beyond
    palpate.inputs' bounds, a normal that is not unit, or a touch the kernel cannot hold together with
    the contacts so far (thin plate: some point of its local grid, or of an earlier contact's, would be
    farther than R_m from a contact, the touch included, so that this mesh and every later one would
    fail).
    """
    p = coordinates(position_m, "position_m")
    n = unit_vectors(normal, "normal")
    axes = grid_axes(p - half_extent_m, p + half_extent_m, resolution_m)
    # every local grid has these half extents, so the same bound holds both ways round
    e = np.array([0.5 * float(a[-1] - a[0]) for a in axes])
    reach = grid_reach(np.vstack([gp.positions_m, p]), np.asarray(p), e)
    try:
        gp.kernel.check_distances(reach)
    except EstimationError as exc:
        held = f"to its {gp.n_contacts} contacts" if gp.n_contacts else "(its first) with its local mesh"
        raise InputError("position_m", f"the GPIS cannot add this touch {held}: {exc}") from exc
    gp.add_contact(p, n)
    sites = None if variance_near is None else (lambda v: thin_near(v, p, *variance_near))
    coarse = mesh_from_grid(gp, axes, with_variance=with_variance, variance_sites=sites)
    mesh, step, half = coarse, resolution_m, half_extent_m
    for level in range(finer_grids):
        if meshes_point(mesh, p, step):
            return TouchMesh(mesh, step)
        step, half = 0.5 * step, (half_extent_m if level == 0 else 0.5 * half)
        try:
            finer = grid_axes(p - half, p + half, step)
        except EstimationError:  # more nodes than a grid may have: the touch is added, so keep what there is
            break
        mesh = mesh_from_grid(gp, finer, with_variance=with_variance, variance_sites=sites)
    if meshes_point(mesh, p, step):
        return TouchMesh(mesh, step)
    return TouchMesh(coarse, resolution_m)  # no grid meshed the touch: the full view, as it was
