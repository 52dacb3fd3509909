"""Admissibility of touch targets by where they lie and how the fingertip gets there (not in the
paper): targets away from remembered points (``away_from``), and fingertip curves that keep clear of
the estimated surface (``curves_clear``, against a ``CurveSurface``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from palpate.geometry.bezier import approach_curve, bezier_point
from palpate.nodes.planner.checks import points

FloatArray = NDArray[np.float64]


def away_from(points_m: ArrayLike, avoid_m: ArrayLike, radius_m: float) -> NDArray[np.bool_]:
    """Which points (m, 3) lie at least radius_m from every point of avoid_m (k, 3): a mask (m,)."""
    P = points("points_m", points_m)
    A = np.asarray(avoid_m, dtype=np.float64).reshape(-1, 3)
    if len(A) == 0 or len(P) == 0 or radius_m <= 0.0:
        return np.ones(len(P), dtype=bool)
    dist, _ = cKDTree(A).query(P, distance_upper_bound=radius_m)
    return np.asarray(~np.isfinite(dist))


def curves_clear(
    vertices: ArrayLike,
    vertex_normals: ArrayLike,
    start_m: ArrayLike,
    v_n: ArrayLike,
    centres_m: ArrayLike,
    target_normals: ArrayLike,
    clearance_m: float,
    *,
    samples: int = 16,
    min_chord_m: float = 1e-4,
    max_reach_m: float = 0.03,
    tree: cKDTree | None = None,
) -> NDArray[np.bool_]:
    """Which fingertip curves keep clear of the estimated surface: a boolean mask (m,).

    Each curve is the one the controller runs (Eq. 15): from the fingertip centre ``start_m`` (3,),
    retracting along -v_n (3,), to the fingertip centre at the target ``centres_m`` (m, 3) reached
    against the target normal (m, 3). The estimated surface is the mesh ``vertices`` (k, 3) with outward
    unit ``vertex_normals`` (k, 3) (the local GPIS mesh); the signed distance of a point q is
    approximated by (q - v) . n_v at its nearest vertex v (negative inside). A curve is clear when that
    is >= ``clearance_m`` at ``samples`` points with tau in (0, 1) (the fingertip sphere of radius
    about clearance_m does not touch the estimate before the end); points farther than
    ``max_reach_m`` from every vertex (beyond the meshed patch) count as clear. Not in the paper.
    ``tree``: a ``cKDTree`` of ``vertices``, for callers that check several batches on one mesh.
    """
    V = points("vertices", vertices)
    N = np.asarray(vertex_normals, dtype=np.float64)
    C = points("centres_m", centres_m)
    if C.shape[0] == 0 or V.shape[0] == 0:
        return np.ones(C.shape[0], dtype=bool)
    P = approach_curve(start_m, v_n, C, target_normals, min_chord_m=min_chord_m)  # (m, 4, 3)
    tau = (np.arange(samples) + 0.5) / samples
    Q = bezier_point(P, tau).reshape(-1, 3)  # (m * samples, 3)
    dist, idx = (cKDTree(V) if tree is None else tree).query(Q, distance_upper_bound=max_reach_m)
    near = np.isfinite(dist)
    signed = np.full(len(Q), np.inf)
    signed[near] = np.einsum("ij,ij->i", Q[near] - V[idx[near]], N[idx[near]])
    return np.asarray(np.all(signed.reshape(C.shape[0], samples) >= clearance_m, axis=1))


@dataclass
class CurveSurface:
    """What ``curves_clear`` checks the fingertip's curves against: the local mesh's vertices (k, 3) m and
    outward unit vertex normals (k, 3), the fingertip centre (3,) m, and (built on first use, once per
    plan) the vertices' k-d tree."""

    vertices_m: FloatArray
    vertex_normals: FloatArray
    fingertip_m: FloatArray

    @cached_property
    def tree(self) -> cKDTree:
        return cKDTree(self.vertices_m)
