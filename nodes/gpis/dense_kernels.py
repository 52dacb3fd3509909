"""Compiled (numba) contractions of one GP's contacts with many query points (issue 11).

The exact GP's mean, gradient and k_* (``kernels.IsotropicKernel``) at m query points against n
contacts are O(m n) loops. Here each loop runs over the contacts outside and the query points
inside, on coordinate columns xt (3, m): the inner loop has no reduction and no branch on the kernel,
so LLVM vectorises it without fast-math (the results stay IEEE, in a fixed order, the same on every
run). With d = x - p_j, r = |d| and alpha_j = [a_j, b_j] (kernels.py's blocks):

    mean:      f(x)      += sum_j [a_j phi(r) - g1(r) d . b_j]
    gradient:  grad f(x) += sum_j [(g1(r) a_j - g2(r) d . b_j) d - g1(r) b_j]
    k_*:       row x, columns 4 j .. 4 j + 3 = [phi(r), -g1(r) d]

Kernels (``local_kernels``' codes): THIN_PLATE with p1 = R, p2 = amplitude c: phi = c (2 r^3 -
3 R r^2 + R^3), g1 = c (6 r - 6 R), g2 = 6 c / r (0 at r = 0, where d d^T = 0); GAUSSIAN with
p1 = sigma^2, p2 = s2: phi = s2 exp(-r^2 / sigma^2), g1 = -2 phi / sigma^2, g2 = 4 phi / sigma^4.
The range check of the thin plate (r <= R) is the caller's: ``max_distance`` gives the largest r.
Compiled once per machine and cached beside this module.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from palpate.nodes.gpis.local_kernels import THIN_PLATE


@numba.njit(cache=True)
def add_values(xt: np.ndarray, P: np.ndarray, A: np.ndarray, kind: int, p1: float, p2: float, out: np.ndarray) -> None:
    """out (m,) += sum_j cov(f(x), obs_j) A_j for query columns xt (3, m), contacts P (n, 3), A (n, 4)."""
    x0, x1, x2 = xt[0], xt[1], xt[2]
    for j in range(P.shape[0]):
        q0, q1, q2 = P[j, 0], P[j, 1], P[j, 2]
        a, b0, b1, b2 = A[j, 0], A[j, 1], A[j, 2], A[j, 3]
        if kind == THIN_PLATE:
            for i in range(out.shape[0]):
                d0, d1, d2 = x0[i] - q0, x1[i] - q1, x2[i] - q2
                r2 = d0 * d0 + d1 * d1 + d2 * d2
                r = math.sqrt(r2)
                phi = p2 * ((2.0 * r - 3.0 * p1) * r2 + p1 * p1 * p1)
                g1 = p2 * (6.0 * r - 6.0 * p1)
                out[i] += a * phi - g1 * (d0 * b0 + d1 * b1 + d2 * b2)
        else:
            for i in range(out.shape[0]):
                d0, d1, d2 = x0[i] - q0, x1[i] - q1, x2[i] - q2
                phi = p2 * math.exp(-(d0 * d0 + d1 * d1 + d2 * d2) / p1)
                out[i] += phi * (a + 2.0 / p1 * (d0 * b0 + d1 * b1 + d2 * b2))


@numba.njit(cache=True)
def add_gradients(
    xt: np.ndarray, P: np.ndarray, A: np.ndarray, kind: int, p1: float, p2: float, out: np.ndarray
) -> None:
    """out (3, m) += sum_j cov(grad f(x), obs_j) A_j (columns as in ``add_values``)."""
    x0, x1, x2 = xt[0], xt[1], xt[2]
    o0, o1, o2 = out[0], out[1], out[2]
    for j in range(P.shape[0]):
        q0, q1, q2 = P[j, 0], P[j, 1], P[j, 2]
        a, b0, b1, b2 = A[j, 0], A[j, 1], A[j, 2], A[j, 3]
        for i in range(o0.shape[0]):
            d0, d1, d2 = x0[i] - q0, x1[i] - q1, x2[i] - q2
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            if kind == THIN_PLATE:
                r = math.sqrt(r2)
                g1 = p2 * (6.0 * r - 6.0 * p1)
                g2 = 6.0 * p2 / r if r > 0.0 else 0.0
            else:
                phi = p2 * math.exp(-r2 / p1)
                g1 = -2.0 / p1 * phi
                g2 = 4.0 / (p1 * p1) * phi
            c = g1 * a - g2 * (d0 * b0 + d1 * b1 + d2 * b2)
            o0[i] += c * d0 - g1 * b0
            o1[i] += c * d1 - g1 * b1
            o2[i] += c * d2 - g1 * b2


@numba.njit(cache=True)
def value_obs_cov(x: np.ndarray, P: np.ndarray, kind: int, p1: float, p2: float, out: np.ndarray) -> None:
    """k_* rows: out (m, 4 n) C-ordered (a column-major (4 n, m) for the triangular solve), x (m, 3)."""
    for i in range(x.shape[0]):
        for j in range(P.shape[0]):
            d0, d1, d2 = x[i, 0] - P[j, 0], x[i, 1] - P[j, 1], x[i, 2] - P[j, 2]
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            if kind == THIN_PLATE:
                r = math.sqrt(r2)
                phi = p2 * ((2.0 * r - 3.0 * p1) * r2 + p1 * p1 * p1)
                g1 = p2 * (6.0 * r - 6.0 * p1)
            else:
                phi = p2 * math.exp(-r2 / p1)
                g1 = -2.0 / p1 * phi
            out[i, 4 * j] = phi
            out[i, 4 * j + 1] = -g1 * d0
            out[i, 4 * j + 2] = -g1 * d1
            out[i, 4 * j + 3] = -g1 * d2


@numba.njit(cache=True)
def max_distance(x: np.ndarray, P: np.ndarray) -> float:
    """Largest |x_i - p_j| (m) over query points x (m, 3) and contacts P (n, 3); 0 when either is empty."""
    best = 0.0
    for j in range(P.shape[0]):
        for i in range(x.shape[0]):
            d0, d1, d2 = x[i, 0] - P[j, 0], x[i, 1] - P[j, 1], x[i, 2] - P[j, 2]
            best = max(best, d0 * d0 + d1 * d1 + d2 * d2)
    return math.sqrt(best)
