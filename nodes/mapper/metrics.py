"""Map quality against a known object: map RMSE and mean surface distances.

Map RMSE (what ``map_rmse`` computes). Let d(c) be the signed distance from the centre of cell c
to the true surface (negative inside the object) and h = resolution / 2. The ground-truth
occupancy of a cell is 1 when d(c) <= h (its centre lies inside the object or within half a cell
outside it: the cells the surface passes through, where contacts fall) and 0 otherwise. A face
that lies exactly on cell boundaries (the evaluation's grids keep the cube's faces 0.5 mm inside
their cells) leaves its shell on the outer side: a contact exactly on a face at the low end of an
axis falls in the inner cell, at d = -h, outside the band. The evaluation region is the surface band

    B = { c : -h < d(c) <= h + band_m }

(optionally intersected with a caller's mask or set of cells): the one-cell shell of cells that
straddle the surface (truth 1) plus the free cells within band_m outside it (truth 0). Then

    RMSE = sqrt( mean_{c in B} (bel(c) - truth(c))^2 ),   bel = 1 - 1 / (1 + exp(l)),

with bel = 0.5 for cells the map never touched. The headline ``rmse`` of ``palpate eval slam`` and
``palpate sweep slam`` (docs/slam.md) takes the region B intersect O, O the cells the finger observed
at its true pose (the cells whose log-odds the known-pose mapper changed during the run); their
``rmse_explored`` takes B intersect E, E the cells within 10 mm of a true contact point.

Why this region: touch never observes the inside of an object, so interior cells would stay at 0.5
for every method; and the count of far free cells, which the finger may never visit, depends only
on how large a margin the grid was given. Over all cells the RMSE would thus measure the grid's
margin, not the map. Over the band, a band cell not yet observed costs 0.5^2 and a well-mapped one
~0, so the RMSE falls as exploration covers the region (the paper's 0.35 at 10 s and 0.20 at 100 s
for the known pose fall the same way; its region is not stated). band_m defaults to 4 mm (the
coarsest resolution of the sweep), so every resolution is judged on the same physical band.

Readable figures (``surface_distances_mm``): the mean distance in mm from the centres of occupied
cells (bel > 0.5) to the true surface (accuracy), and from points sampled on the true surface to
the nearest occupied cell centre (completeness).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from palpate.nodes.mapper.grid import GridSpec, SparseMap, belief

FloatArray = NDArray[np.float64]
Sdf = Callable[[FloatArray], FloatArray]


def box_sdf(points_m: FloatArray, center_m: FloatArray, half_extents_m: FloatArray) -> FloatArray:
    """Signed distance (n,) in metres from points (n, 3) to an axis-aligned box (negative inside)."""
    q = np.abs(np.asarray(points_m, dtype=np.float64) - np.asarray(center_m)) - np.asarray(half_extents_m)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(np.max(q, axis=-1), 0.0)
    return np.asarray(outside + inside)


def box_surface_points(center_m: FloatArray, half_extents_m: FloatArray, spacing_m: float) -> FloatArray:
    """Points (n, 3) on the faces of an axis-aligned box, on a square lattice of about spacing_m."""
    c = np.asarray(center_m, dtype=np.float64)
    h = np.asarray(half_extents_m, dtype=np.float64)
    pts = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        su = np.linspace(-h[u], h[u], max(2, math.ceil(2 * h[u] / spacing_m) + 1))
        sv = np.linspace(-h[v], h[v], max(2, math.ceil(2 * h[v] / spacing_m) + 1))
        gu, gv = np.meshgrid(su, sv, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((gu.size, 3))
            p[:, axis] = sign * h[axis]
            p[:, u] = gu.ravel()
            p[:, v] = gv.ravel()
            pts.append(p + c)
    return np.unique(np.concatenate(pts), axis=0)


def surface_band(
    spec: GridSpec,
    sdf: Sdf,
    band_m: float = 0.004,
    mask: Callable[[FloatArray], NDArray[np.bool_]] | None = None,
    batch: int = 1 << 20,
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """The evaluation region B and its truth: (flat indices (n,) ascending, occupied (n,) bool).

    B = {c : -h < d(c) <= h + band_m}, truth = d(c) <= h, h = resolution / 2 (module docstring);
    ``mask`` (centres (m, 3) -> (m,) bool) keeps only part of it.
    """
    h = spec.resolution_m / 2
    flats, truths = [], []
    for start in range(0, spec.n_cells, batch):
        flat = np.arange(start, min(start + batch, spec.n_cells), dtype=np.int64)
        c = spec.centers(flat)
        d = sdf(c)
        keep = (d > -h) & (d <= h + band_m)
        if mask is not None:
            keep &= mask(c)
        flats.append(flat[keep])
        truths.append(d[keep] <= h)
    return np.concatenate(flats), np.concatenate(truths)


def map_rmse(m: SparseMap, region_flat: NDArray[np.int64], truth: NDArray[np.bool_]) -> float:
    """RMSE between belief and truth over the region (module docstring); untouched cells bel 0.5."""
    if len(region_flat) == 0:
        return math.nan
    bel = np.full(len(region_flat), 0.5)
    pos = np.searchsorted(m.flat, region_flat)
    pos = np.minimum(pos, max(len(m.flat) - 1, 0))
    hit = (m.flat[pos] == region_flat) if len(m.flat) else np.zeros(len(region_flat), dtype=np.bool_)
    bel[hit] = belief(m.log_odds[pos[hit]].astype(np.float64))
    return float(np.sqrt(np.mean((bel - truth.astype(np.float64)) ** 2)))


def surface_distances_mm(m: SparseMap, sdf: Sdf, surface_points_m: FloatArray) -> tuple[float, float]:
    """(accuracy, completeness) in mm: mean |d| of occupied cell centres (bel > 0.5) to the surface,
    and mean distance from surface points (n, 3) to the nearest occupied cell centre.

    Both are +inf when no cell is occupied.
    """
    occ = m.flat[m.log_odds > 0]
    if len(occ) == 0:
        return math.inf, math.inf
    centres = m.spec.centers(occ)
    accuracy = float(np.mean(np.abs(sdf(centres)))) * 1e3
    dist, _ = cKDTree(centres).query(np.asarray(surface_points_m, dtype=np.float64))
    return accuracy, float(np.mean(dist)) * 1e3
