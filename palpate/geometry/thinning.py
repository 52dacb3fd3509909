"""Voxel thinning of surface points near a centre: the planner's candidates (paper 002 Sec. 2.4).

The planner samples the estimated surface "starting from the last contact position" with a 0.5 cm
step up to 5 cm (6 cm for GP-V); the surface estimator computes the GP variance only at those points
(issue 11: variance where the planner asks for it). Both call ``thin_near`` so that they agree.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def thin_near(points: FloatArray, centre: FloatArray, step_m: float, radius_m: float) -> IntArray:
    """Ascending indices of the points (k, 3) kept: within radius_m of centre (3,), one per voxel.

    A voxel grid of edge step_m with a voxel centred on ``centre`` keeps, per occupied voxel, the point
    nearest the voxel centre (ties: the lower index). Thinning the kept points again with the same
    centre, step and radius keeps them all.
    """
    rel = points - centre
    inside = np.flatnonzero(np.einsum("ij,ij->i", rel, rel) <= radius_m**2)
    grid = rel[inside] / step_m
    key3 = np.floor(grid + 0.5).astype(np.int64)  # voxel of each point; the centre sits at a voxel centre
    off = grid - key3
    dist2 = np.einsum("ij,ij->i", off, off)
    K = int(np.abs(key3).max(initial=0)) + 1  # voxels span -K..K (radius_m may be inf: no limit)
    side = 2 * K + 1
    key = ((key3[:, 0] + K) * side + (key3[:, 1] + K)) * side + (key3[:, 2] + K)
    order = np.lexsort((dist2, key))  # by voxel, nearest-to-centre first (stable: lower index on ties)
    first = np.ones(order.size, dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    return np.sort(inside[order[first]])
