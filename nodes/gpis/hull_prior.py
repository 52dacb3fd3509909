"""A smooth convex prior mean from the contacts: their convex hull, seen from K even directions and blended.

For K unit directions u_k spread evenly over the sphere (a Fibonacci lattice), the contacts' support
planes u_k . x = h(u_k), h(u) = max_j u . p_j, bound their convex hull from outside; with
s_k(x) = u_k . x - h(u_k) the signed distance of x beyond plane k,

    m(x) = tau log (1/K) sum_k exp(s_k(x) / tau),   grad m(x) = sum_k w_k(x) u_k,
    w(x) = softmax(s(x) / tau),

a smooth maximum of the planes (the smooth convexes of CvxNet, Deng et al., CVPR 2020): the hull's
shape with its edges blended over about tau, and a gradient that turns smoothly from one side's
normal to the next. It is the prior of a whole-object mesh (``GPISNodeConfig.whole_prior``): the GP
then extrapolates the unexplored parts from the shape the contacts span, not from a sphere at the
first contact. The planes are fixed directions, not the hull's faces, so the cost is K per query
point however many contacts there are, and every direction weighs alike. m lies between the largest
s_k minus tau log K and the largest s_k; as the mean over the directions it tends to a limit as K
grows (at the centre of a ball of contacts it is minus the radius). Near the surface it lies below
the hull's distance by tau times the log of the share of directions whose planes pass within about
tau, which depends on the hull's curvature there (least at a sharp corner, most on a flat face):
several tau, which the GP's residual takes up near the contacts.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Query points x planes per chunk (about 2 MB of float64: the passes stay in cache).
_CHUNK_ENTRIES = 1 << 18


def even_directions(count: int) -> FloatArray:
    """count unit vectors (count, 3) spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


class SmoothHull:
    """The prior m(x) above for planes u_k . x + d_k = 0 (U (K, 3) unit normals, d (K,)) and tau > 0 m."""

    def __init__(self, U: FloatArray, d: FloatArray, tau_m: float) -> None:
        self.U, self.d, self.tau_m = U, d, tau_m

    @classmethod
    def of(cls, points_m: FloatArray, tau_m: float, directions: int) -> SmoothHull | None:
        """The prior of points (n, 3) seen from ``directions`` even directions, or None where their hull
        is no solid at tau's scale: fewer than four points, or thinner than 2 tau along one of the
        directions or a principal axis (a flat patch seen from one side: its hull says nothing about
        the inside)."""
        if len(points_m) < 4:
            return None
        U = even_directions(directions)
        support = (points_m @ U.T).max(axis=0)  # h(u_k)
        axes = np.linalg.eigh(np.cov(points_m.T))[1]  # principal axes: the thinnest direction among them
        along = points_m @ np.concatenate([U, axes.T]).T
        if (along.max(axis=0) - along.min(axis=0)).min() < 2.0 * tau_m:  # the extent along each
            return None
        return cls(U, -support, tau_m)

    def mean(self, x: FloatArray) -> FloatArray:
        """m(x) (m,) at x (m, 3)."""
        return self._evaluate(x, gradient=False)[0]

    def gradient(self, x: FloatArray) -> FloatArray:
        """grad m(x) (m, 3) at x (m, 3)."""
        return self.mean_and_gradient(x)[1]

    def mean_and_gradient(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(m(x) (m,), grad m(x) (m, 3))."""
        return self._evaluate(x, gradient=True)

    def _evaluate(self, x: FloatArray, *, gradient: bool) -> tuple[FloatArray, FloatArray]:
        """m(x) and, when asked, grad m(x) (zeros otherwise), in chunks that stay in cache."""
        value, grad = np.empty(len(x)), np.zeros((len(x), 3))
        step = max(1, _CHUNK_ENTRIES // len(self.U))
        for start in range(0, len(x), step):
            chunk = slice(start, start + step)
            s = x[chunk] @ self.U.T
            s += self.d  # signed distances beyond the planes (k, K)
            top = s.max(axis=1, keepdims=True)
            s -= top
            s *= 1.0 / self.tau_m
            np.exp(s, out=s)  # every term <= 1: no overflow
            total = s.sum(axis=1)
            value[chunk] = top[:, 0] + self.tau_m * np.log(total / len(self.U))
            if gradient:
                grad[chunk] = (s @ self.U) / total[:, None]
        return value, grad
