"""Cubic Bezier curves for fingertip trajectories (paper 002, Section 2.5, Eqs. 9 and 13-17).

A curve is its control points ``P`` with shape ``(..., 4, 3)`` (metres): every function broadcasts over
the leading dimensions, so the planner can measure hundreds of candidate paths in one call. The curve
parameter is ``tau`` in [0, 1]; ``T(0) = p0`` is the start and ``T(1) = p3`` the target.

Beyond ``tau = 1`` the trajectory controller continues along the end tangent (Algorithm 1 line 26
tests ``tau > 1``): ``Cubic`` uses that straight continuation ``T(1) + (tau - 1) T'(1)``,
which is C1 with the curve.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.geometry import bezier_kernels

FloatArray = NDArray[np.float64]

#: Control-point scaling of Eqs. 15 and 17: beta = |r - t_p| / 3.
CONTROL_SCALE = 1.0 / 3.0


def _bernstein(tau: FloatArray) -> FloatArray:
    """Cubic Bernstein basis, shape (k, 4)."""
    s = 1.0 - tau
    return np.stack([s**3, 3.0 * tau * s**2, 3.0 * tau**2 * s, tau**3], axis=-1)


def bezier_point(P: ArrayLike, tau: ArrayLike) -> FloatArray:
    """Points T(tau) (Eq. 13). P: (..., 4, 3); tau: (k,) -> (..., k, 3) metres."""
    P = np.asarray(P, dtype=np.float64)
    t = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    return np.einsum("kj,...jd->...kd", _bernstein(t), P)


def bezier_derivative(P: ArrayLike, tau: ArrayLike) -> FloatArray:
    """dT/dtau. P: (..., 4, 3); tau: (k,) -> (..., k, 3) metres per unit tau."""
    P = np.asarray(P, dtype=np.float64)
    t = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    s = 1.0 - t
    # T'(tau) = 3 [(1-tau)^2 (p1-p0) + 2 tau (1-tau) (p2-p1) + tau^2 (p3-p2)]
    basis = np.stack([s**2, 2.0 * t * s, t**2], axis=-1)  # (k, 3)
    d = np.diff(P, axis=-2)  # (..., 3, 3): p1-p0, p2-p1, p3-p2
    return 3.0 * np.einsum("kj,...jd->...kd", basis, d)


def bezier_second_derivative(P: ArrayLike, tau: ArrayLike) -> FloatArray:
    """d2T/dtau2. P: (..., 4, 3); tau: (k,) -> (..., k, 3)."""
    P = np.asarray(P, dtype=np.float64)
    t = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    # T''(tau) = 6 [(1-tau) (p2 - 2 p1 + p0) + tau (p3 - 2 p2 + p1)]
    basis = np.stack([1.0 - t, t], axis=-1)  # (k, 2)
    dd = np.diff(P, n=2, axis=-2)  # (..., 2, 3)
    return 6.0 * np.einsum("kj,...jd->...kd", basis, dd)


@lru_cache(maxsize=16)
def _gauss_legendre(nodes: int, segments: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Composite Gauss-Legendre rule on [0, 1]: nodes (k,), weights (k,), and the products of the
    derivative's basis functions at the nodes (k, 9), for k = nodes * segments."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    edges = np.linspace(0.0, 1.0, segments + 1)
    half = 0.5 * np.diff(edges)  # (segments,)
    mid = 0.5 * (edges[:-1] + edges[1:])
    tau = (mid[:, None] + half[:, None] * x[None, :]).ravel()
    weight = (half[:, None] * w[None, :]).ravel()
    s = 1.0 - tau
    basis = np.stack([s**2, 2.0 * tau * s, tau**2], axis=-1)  # T' = 3 basis @ diff(P)
    products = (basis[:, :, None] * basis[:, None, :]).reshape(-1, 9)
    for a in (tau, weight, products):
        a.setflags(write=False)
    return tau, weight, products


def bezier_length(
    P: ArrayLike, tau0: float = 0.0, tau1: float = 1.0, *, nodes: int = 8, segments: int = 8
) -> FloatArray:
    """Arc length Len(T) = integral of |dT/dtau| over [tau0, tau1] (Eq. 9), metres.

    Composite Gauss-Legendre quadrature (``segments`` pieces of ``nodes`` points each). The default
    64 evaluations are exact to ~1e-10 relative on smooth curves, ~1e-7 on the looping curves of
    far-off candidate normals, and ~1e-3 at an exact cusp (where |T'| has a kink).
    |T'|^2 is evaluated as a quadratic form in the Gram matrix of the control-point differences,
    one (..., 9) @ (9, k) product for all curves (20x faster than forming T' itself).
    P: (..., 4, 3) -> (...).
    """
    if not tau1 >= tau0:
        raise ValueError(f"bezier_length needs tau0 <= tau1, got {tau0} > {tau1}")
    P = np.asarray(P, dtype=np.float64)
    u, w, _ = _gauss_legendre(nodes, segments)
    tau = tau0 + (tau1 - tau0) * u
    s = 1.0 - tau
    basis = np.stack([s**2, 2.0 * tau * s, tau**2], axis=-1)
    if tau0 == 0.0 and tau1 == 1.0:
        products = _gauss_legendre(nodes, segments)[2]
    else:
        products = (basis[:, :, None] * basis[:, None, :]).reshape(-1, 9)
    d = np.diff(P, axis=-2)  # (..., 3, 3)
    gram = np.einsum("...id,...jd->...ij", d, d).reshape(*d.shape[:-2], 9)
    speed = 3.0 * np.sqrt(np.maximum(gram @ products.T, 0.0))  # |T'(tau_k)|, (..., k)
    return np.asarray((tau1 - tau0) * (speed @ w), dtype=np.float64)


#: Bernstein -> power basis: T(tau) = sum_k A[k] tau^k with A = _TO_POWER @ P.
_TO_POWER = np.array([[1.0, 0.0, 0.0, 0.0], [-3.0, 3.0, 0.0, 0.0], [3.0, -6.0, 3.0, 0.0], [-1.0, 3.0, -3.0, 1.0]])


@lru_cache(maxsize=8)
def _unit_grid(samples: int) -> FloatArray:
    grid = np.linspace(0.0, 1.0, samples)
    grid.setflags(write=False)
    return grid


class Cubic:
    """One cubic Bezier, in power form, for fast evaluation at scalar tau (the controller's inner loop).

    ``point`` and ``derivative`` continue straight along T'(1) beyond tau = 1 (see the module doc).
    """

    def __init__(self, P: ArrayLike) -> None:
        self.P = np.array(P, dtype=np.float64)
        if self.P.shape != (4, 3):
            raise ValueError(f"a cubic Bezier needs control points (4, 3), got {self.P.shape}")
        self.A = _TO_POWER @ self.P  # T(tau) = A0 + A1 tau + A2 tau^2 + A3 tau^3
        self.end = self.P[3].copy()
        self.end_tangent = 3.0 * (self.P[3] - self.P[2])  # T'(1)
        # per axis as Python floats: the controller's scalar paths (numpy's elementwise bits, no call overhead)
        self._axes = list(zip(*self.A.tolist(), self.end.tolist(), self.end_tangent.tolist(), strict=True))

    def point(self, tau: float) -> FloatArray:
        """T(tau), (3,) metres."""
        return np.array(self.point_xyz(tau))

    def derivative(self, tau: float) -> FloatArray:
        """dT/dtau, (3,)."""
        return np.array(self.derivative_xyz(tau))

    def point_xyz(self, tau: float) -> list[float]:
        """T(tau) as three floats, metres (``point`` without numpy)."""
        if tau > 1.0:
            return [e + (tau - 1.0) * d for _, _, _, _, e, d in self._axes]
        return [a0 + tau * (a1 + tau * (a2 + tau * a3)) for a0, a1, a2, a3, _, _ in self._axes]

    def derivative_xyz(self, tau: float) -> list[float]:
        """dT/dtau as three floats (``derivative`` without numpy)."""
        if tau > 1.0:
            return [d for *_, d in self._axes]
        three_tau = 3.0 * tau
        return [a1 + tau * (2.0 * a2 + three_tau * a3) for _, a1, a2, a3, _, _ in self._axes]

    def closest_tau(
        self,
        r: ArrayLike,
        tau_min: float = 0.0,
        tau_max: float = 1.0,
        *,
        samples: int = 33,
        newton_steps: int = 5,
    ) -> float:
        """argmin over tau in [tau_min, tau_max] of |r - T(tau)| (Algorithm 1 line 25), r: (3,) metres.

        For ``tau_max > 1`` the straight continuation past T(1) is searched too. Dense sampling finds
        the best bracket, Newton's method on g = (T - r) . T' refines inside it (compiled:
        ``bezier_kernels.closest_search``).
        """
        if not tau_max >= tau_min:
            raise ValueError(f"closest_tau needs tau_min <= tau_max, got {tau_min} > {tau_max}")
        if samples < 2:
            raise ValueError(f"closest_tau needs samples >= 2 (both ends of the range), got {samples}")
        r_ = np.asarray(r, dtype=np.float64)
        if r_.shape != (3,):
            raise ValueError(f"closest_tau needs a point r of shape (3,), got shape {r_.shape}")
        x, y, z = r_.tolist()
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ValueError(f"closest_tau needs a finite point r, got {[x, y, z]}")
        return float(
            bezier_kernels.closest_search(
                self.A,
                self.end,
                self.end_tangent,
                r_,
                float(tau_min),
                float(tau_max),
                _unit_grid(samples),
                newton_steps,
            )
        )


def approach_curve(
    c_p: ArrayLike,
    v_n: ArrayLike,
    t_p: ArrayLike,
    t_n: ArrayLike,
    scale: float = CONTROL_SCALE,
    min_chord_m: float = 0.0,
) -> FloatArray:
    """Eq. 15: bezier(r, r - v_n beta, t_p + t_n beta, t_p) with beta = scale |r - t_p|, r = c_p.

    Retracts along -v_n (v_n: the unit velocity just before the last contact, or zero for no
    retraction) and reaches the target against its outward unit normal t_n; directions of another
    length are refused (ValueError), not normalised. Broadcasts: (..., 3) inputs -> (..., 4, 3).
    ``scale`` = 1/3 is Eq. 15; 1 is the literal reading of Algorithm 2 line 4 (see the planner).
    ``min_chord_m`` floors |r - t_p| in beta so that a target at the start point still gives a
    (small) retract-and-return loop instead of a curve collapsed to a point.
    """
    r = np.asarray(c_p, dtype=np.float64)
    t = np.asarray(t_p, dtype=np.float64)
    v = _directions("v_n", v_n, allow_zero=True)
    n = _directions("t_n", t_n, allow_zero=False)
    beta = scale * np.maximum(np.linalg.norm(r - t, axis=-1, keepdims=True), min_chord_m)
    r, t = np.broadcast_arrays(r, t)
    p1 = r - v * beta
    p2 = t + n * beta
    return np.stack(np.broadcast_arrays(r, p1, p2, t), axis=-2)


#: How far from 1 a direction's length may be: the messages' tolerance (palpate.inputs.UNIT_TOLERANCE, the
#: same value; the geometry layer imports no input checks), which nodes pass on as they take it (a driver's
#: approach direction of norm 1.005 reaches the planner's curves).
UNIT_TOLERANCE = 1e-2
#: Squared lengths within UNIT_TOLERANCE of 1, a hair wider (a length the messages take passes here).
_UNIT_SQUARED = ((1.0 - UNIT_TOLERANCE - 1e-12) ** 2, (1.0 + UNIT_TOLERANCE + 1e-12) ** 2)


def _directions(name: str, value: ArrayLike, *, allow_zero: bool) -> FloatArray:
    """``value`` as float64 (..., 3), checked to hold unit vectors (or zeros with ``allow_zero``)."""
    d = np.asarray(value, dtype=np.float64)
    if d.shape[-1:] != (3,):
        raise ValueError(f"{name} needs 3-vectors (..., 3), got shape {d.shape}")
    squared = (d * d).sum(axis=-1)
    ok = (_UNIT_SQUARED[0] <= squared) & (squared <= _UNIT_SQUARED[1])  # False for NaN
    if allow_zero:
        ok |= squared == 0.0
    if not ok.all():
        first = float(np.ravel(squared)[np.flatnonzero(~np.ravel(ok))[0]])
        if not math.isfinite(first):
            raise ValueError(f"{name} needs finite vectors, got NaN or inf")
        unit = "unit vectors (or zero)" if allow_zero else "unit vectors"
        raise ValueError(f"{name} needs {unit}, got one of length {math.sqrt(first):.6g}")
    return d


def recovery_curve(
    r: ArrayLike,
    v_n: ArrayLike,
    t_p: ArrayLike,
    t_n: ArrayLike,
    scale: float = CONTROL_SCALE,
    min_chord_m: float = 0.0,
) -> FloatArray:
    """Eq. 17: bezier(r, r + v_n beta, t_p - t_n beta, t_p) with beta = scale |r - t_p|.

    Continues the current motion v_n (velocity stays continuous after a missed prediction) and reaches
    t_p moving along +t_n, i.e. from inside the object when t_p is a known surface point.
    Broadcasts: (..., 3) inputs -> (..., 4, 3). ``min_chord_m`` as in ``approach_curve``.
    """
    # Eq. 15 with v_n and t_n reversed: r - (-v_n) beta and t_p + (-t_n) beta are the same floats
    back, into = -np.asarray(v_n, dtype=np.float64), -np.asarray(t_n, dtype=np.float64)
    return approach_curve(r, back, t_p, into, scale, min_chord_m)
