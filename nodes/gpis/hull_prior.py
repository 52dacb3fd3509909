"""A smooth convex prior mean from the contacts: the log-sum-exp of their convex hull's face planes.

With the hull's faces as planes a_i . x + d_i = 0 (a_i outward unit normals, a_i . x + d_i <= 0
inside),

    m(x) = tau log sum_i exp((a_i . x + d_i) / tau),   grad m(x) = sum_i w_i(x) a_i,
    w(x) = softmax((A x + d) / tau),

a smooth maximum of the signed plane distances (as the smooth convexes of CvxNet, Deng et al., CVPR
2020): the hull's shape with its edges blended over about tau, and a gradient that turns smoothly
from one face's normal to the next. Used as the prior of a whole-object mesh
(``GPISNodeConfig.whole_prior``): the GP then extrapolates the unexplored parts from the shape the
contacts span rather than from a sphere at the first contact. m exceeds the hard maximum by up to
tau log(faces); the thin-plate kernel takes up such a near-constant offset (its constant term has
variance R_m^3), so the shape of m, not its level, is what the prior gives.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

FloatArray = NDArray[np.float64]

#: Query points x faces per chunk of the plane distances (about 32 MB of float64).
_CHUNK_ENTRIES = 1 << 22


class SmoothHull:
    """The prior m(x) above for planes A (F, 3) (outward unit normals) and offsets d (F,), at tau > 0 m."""

    def __init__(self, A: FloatArray, d: FloatArray, tau_m: float) -> None:
        self.A, self.d, self.tau_m = A, d, tau_m

    @classmethod
    def of(cls, points_m: FloatArray, tau_m: float) -> SmoothHull | None:
        """The prior of the convex hull of points (n, 3), or None where the hull is no solid at tau's
        scale: fewer than four points, all in a plane, or thinner than 2 tau across any face's
        direction (a patch seen from one side: its hull says nothing about the inside)."""
        if len(points_m) < 4:
            return None
        try:
            hull = ConvexHull(points_m)
        except QhullError:  # flat or otherwise degenerate
            return None
        A, d = hull.equations[:, :3].copy(), hull.equations[:, 3].copy()
        widths = -(points_m[hull.vertices] @ A.T + d).min(axis=0)  # per face: how far the hull reaches behind it
        if widths.min() < 2.0 * tau_m:
            return None
        return cls(A, d, tau_m)

    def mean(self, x: FloatArray) -> FloatArray:
        """m(x) (m,) at x (m, 3)."""
        return self.mean_and_gradient(x)[0]

    def gradient(self, x: FloatArray) -> FloatArray:
        """grad m(x) (m, 3) at x (m, 3)."""
        return self.mean_and_gradient(x)[1]

    def mean_and_gradient(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(m(x) (m,), grad m(x) (m, 3)), in chunks of bounded memory."""
        value, grad = np.empty(len(x)), np.empty((len(x), 3))
        step = max(1, _CHUNK_ENTRIES // len(self.A))
        for start in range(0, len(x), step):
            s = x[start : start + step] @ self.A.T + self.d  # signed plane distances (k, F)
            top = s.max(axis=1, keepdims=True)
            w = np.exp((s - top) / self.tau_m)  # every term <= 1: no overflow
            total = w.sum(axis=1, keepdims=True)
            value[start : start + step] = top[:, 0] + self.tau_m * np.log(total[:, 0])
            grad[start : start + step] = (w / total) @ self.A
        return value, grad
