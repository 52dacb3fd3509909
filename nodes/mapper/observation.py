"""Which cells one observation touches, for K finger poses at once.

An observation is the finger's joint angles and its contacts, each given as the link it is felt on
and the position in that link's frame. For a pose (one particle, or the known pose):

- occupied cells: the cells that hold the contacts (update log(0.9/0.1));
- free cells: the cells that hold the finger's own volume (update log(0.1/0.9)). The volume is
  sampled by a lattice of points fixed in the links (spacing ``spacing_m``), inside each capsule
  shrunk by ``margin_m``. The margin keeps the free update off the cells the finger only partly
  covers: with the finger resting on a surface, the cells that straddle the surface hold object
  too and must not be cleared. A point at depth >= margin inside the finger lies in a cell whose
  points are all within one cell diagonal of it, so margin = resolution is exact for faces aligned
  with the grid and margin = sqrt(3) * resolution for any orientation; the default is the
  resolution (a contact penetrating 1 mm into a soft finger is absorbed by the same margin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from palpate.nodes.mapper.grid import CellKeys, LogOddsGrids
from palpate.nodes.mapper.kinematics import KinematicChain

FloatArray = NDArray[np.floating]


@dataclass(frozen=True)
class FreeVolume:
    """Points filling the finger, fixed in its links: per link l, local_m[l] (P_l, 3) in metres, and
    depth_m[l] (P_l,), each point's distance to its capsule's surface (empty tuple: not kept)."""

    local_m: tuple[NDArray[np.float64], ...]
    depth_m: tuple[NDArray[np.float64], ...] = ()

    @property
    def n_points(self) -> int:
        return int(sum(len(p) for p in self.local_m))

    def depth_cells(self, resolution_m: float) -> tuple[NDArray[np.float32], ...]:
        """Per link, the points' depths in cells of ``resolution_m`` (float32), for ``whole_cells``."""
        return tuple((d / resolution_m).astype(np.float32) for d in self.depth_m)

    def homogeneous(self) -> tuple[NDArray[np.float32], ...]:
        """Per link, the points as homogeneous columns (4, P_l) float32."""
        return tuple(np.vstack([p.T, np.ones((1, len(p)))]).astype(np.float32) for p in self.local_m)


def capsule_grid(radius_m: float, length_m: float, spacing_m: float, margin_m: float) -> tuple[float, int, int] | None:
    """The lattice box of a capsule shrunk by margin_m: its radius r and the nodes either side of its
    centre across (nr) and along (nz) the axis, or None when the capsule is no thicker than the margin."""
    r = radius_m - margin_m
    if r <= 0:
        return None
    return r, math.floor(r / spacing_m), math.floor((length_m / 2 + r) / spacing_m)


def capsule_lattice(chain: KinematicChain, spacing_m: float, margin_m: float) -> FreeVolume:
    """A cubic lattice of spacing ``spacing_m`` inside every capsule of the chain shrunk by margin_m.

    The lattice is laid in each capsule's own frame (axis along z), so it moves rigidly with its
    link. A capsule thinner than the margin contributes no point: with cells as large as the finger's
    radius, points on its axis lie in the cells it touches and would clear the contacts' cells.
    """
    per_link: list[list[NDArray[np.float64]]] = [[] for _ in range(chain.n_links)]
    depth_of: list[list[NDArray[np.float64]]] = [[] for _ in range(chain.n_links)]
    for cap in chain.capsule_list:
        a, b = cap.a_local_m, cap.b_local_m
        length = float(np.linalg.norm(b - a))
        z = (b - a) / length if length > 0 else np.array([0.0, 0.0, 1.0])
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        grid = capsule_grid(cap.radius_m, length, spacing_m, margin_m)
        if grid is None:  # too thin to hold a whole cell: no free volume one margin deep
            continue
        r, nr, nz = grid
        u = np.arange(-nr, nr + 1) * spacing_m
        w = np.arange(-nz, nz + 1) * spacing_m + length / 2
        gu, gv, gw = np.meshgrid(u, u, w, indexing="ij")
        local = np.stack([gu.ravel(), gv.ravel(), gw.ravel()], axis=1)  # capsule frame
        along = np.clip(local[:, 2], 0.0, length)
        dist = np.hypot(np.hypot(local[:, 0], local[:, 1]), local[:, 2] - along)
        inside = dist <= r
        local = local[inside]
        per_link[cap.link].append(a + local[:, :1] * x + local[:, 1:2] * y + local[:, 2:3] * z)
        depth_of[cap.link].append(cap.radius_m - dist[inside])
    return FreeVolume(
        local_m=tuple(np.concatenate(p) if p else np.zeros((0, 3)) for p in per_link),
        depth_m=tuple(np.concatenate(d) if d else np.zeros(0) for d in depth_of),
    )


def whole_cells(f: NDArray[np.float32], depth_cells: NDArray[np.float32]) -> NDArray[np.bool_]:
    """Which points lie so deep in the finger that their whole cell does: (K, P) bool for cell
    coordinates f (K, 3, P) of points whose depths are ``depth_cells`` (P,), in cells. A cell lies
    inside the ball of a point's depth when its farthest corner does: whatever the grid's alignment
    with the object, a free update by these points clears no cell that holds surface."""
    frac = f - np.floor(f)
    np.maximum(frac, 1.0 - frac, out=frac)  # per axis, the distance to the cell's farther face
    np.square(frac, out=frac)
    return np.asarray(frac.sum(axis=1) <= np.square(depth_cells))


def cell_affine(grids: LogOddsGrids, rots: FloatArray, pos: FloatArray) -> NDArray[np.float32]:
    """Per pose and link, M (K, L, 3, 4) float32 with f = M [p; 1] = (R p + x - origin) / resolution:
    the cell coordinates of a link point p."""
    inv = 1.0 / grids.spec.resolution_m
    m = np.empty((*rots.shape[:2], 3, 4), dtype=np.float32)
    m[..., :3] = rots * inv
    m[..., 3] = (pos - np.asarray(grids.spec.origin_m)) * inv
    return m


def observation_keys(
    grids: LogOddsGrids,
    rots: FloatArray,
    pos: FloatArray,
    free_h: tuple[NDArray[np.float32], ...],
    contact_links: NDArray[np.integer],
    contact_local_m: FloatArray,
    free_depth_cells: tuple[NDArray[np.float32], ...] = (),
) -> tuple[CellKeys, CellKeys]:
    """Cells of one observation for K link poses rots (K, L, 3, 3), pos (K, L, 3); map k = pose k.

    free_h: the free volume per link as homogeneous columns (FreeVolume.homogeneous()).
    free_depth_cells: per link, the points' depths in cells; given, a point clears its cell only when
    the whole cell lies in the finger (``whole_cells``), else it is an invalid entry (not counted as
    outside the region).
    Returns (free cells (K, P), contact cells (K, n)); points outside the region are marked invalid.
    """
    K = rots.shape[0]
    m = cell_affine(grids, rots, pos)
    sizes = [h.shape[1] for h in free_h]
    # a link whose points lie outside the region at every pose would add invalid entries only (they
    # change no map): leave it out, and count its points as outside (a link of the finger's base often
    # lies above the mapped region, and culling it halves the update time of the finger scene)
    keep = [bool(h.shape[1]) and _may_enter(m[:, link], h, grids.spec.shape) for link, h in enumerate(free_h)]
    culled = sum(n for n, k in zip(sizes, keep, strict=True) if not k)
    f = np.empty((K, 3, sum(sizes) - culled), dtype=np.float32)
    start = 0
    for link, h in enumerate(free_h):
        if keep[link]:
            np.matmul(m[:, link], h, out=f[:, :, start : start + sizes[link]])  # (K, 3, P_l)
            start += sizes[link]
    links = np.asarray(contact_links, dtype=np.intp)
    local = np.asarray(contact_local_m, dtype=np.float64).reshape(-1, 3)
    local_h = np.concatenate([local, np.ones((len(local), 1))], axis=1).astype(np.float32)
    fc = np.matmul(m[:, links], local_h[None, :, :, None])[..., 0]  # (K, n, 3)
    shallow = 0
    if free_depth_cells and f.shape[2]:
        depth = np.concatenate([d for d, k in zip(free_depth_cells, keep, strict=True) if k])
        part = ~whole_cells(f, depth)
        inside = np.all((f >= 0) & (f < np.asarray(grids.spec.shape, dtype=f.dtype)[None, :, None]), axis=1)
        shallow = int(np.count_nonzero(part & inside))  # the others count as outside the region, as before
        f[np.broadcast_to(part[:, None, :], f.shape)] = np.nan  # an invalid entry: changes no map
    free = grids.cell_keys(f)
    if culled or shallow:
        free = replace(free, n_outside=free.n_outside + K * culled - shallow)
    return free, grids.cell_keys(np.ascontiguousarray(fc.transpose(0, 2, 1)))


def _may_enter(m: NDArray[np.float32], h: NDArray[np.float32], shape: tuple[int, int, int]) -> bool:
    """False when the points h (4, P) (homogeneous, link frame) lie outside the grid at all K poses
    m (K, 3, 4) (link -> cell coordinates): their bounding sphere misses the grid box by a cell."""
    centre = h.mean(axis=1)  # (4,), last entry 1
    radius_cells = float(np.sqrt(np.max(np.sum((h[:3] - centre[:3, None]) ** 2, axis=0))))
    radius_cells *= float(np.linalg.norm(m[0, 0, :3]))  # m = [R / resolution | t]: rows of norm 1 / resolution
    c = m @ centre  # (K, 3) cell coordinates of the centre
    outside = (c + radius_cells < -1.0) | (c - radius_cells > np.asarray(shape, dtype=np.float32) + 1.0)
    return bool(not np.all(np.any(outside, axis=1)))
