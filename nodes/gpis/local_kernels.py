"""Compiled (numba) contraction of many local GPs at once, for ``local.LocalGPIS``.

Each pair (query point q, expert e) with blend weight w and weight gradient g contributes the
expert's residual r_e(x) = sum_j cov(f(x), obs_j) alpha_j over the expert's contacts j (Eq. 2 minus
the prior mean, which every expert shares) and its gradient:

    r_e(x)      = sum_j [a_j phi(r) - g1(r) d . b_j],                     d = x - p_j, r = |d|
    grad r_e(x) = sum_j [g1(r) d a_j - g2(r) d (d . b_j) - g1(r) b_j]     (kernels.py's blocks)

    f_out[q] += w r_e(x_q),   g_out[q] += w grad r_e(x_q) + r_e(x_q) g

(the prior mean m(x) is added once by the caller: the weights sum to 1 and their gradients to 0).
Contacts and weights of the experts in play are concatenated: expert slot s owns rows
starts[s]:ends[s] of P (T, 3) and A (T, 4) = [a_j, b_j]. Kernels: 0 thin plate with
phi = c (2 r^3 - 3 R r^2 + R^3), g1 = c (6 r - 6 R), g2 = 6 c / r (0 at r = 0, where d d^T = 0);
1 Gaussian with phi = s2 exp(-r^2 / sigma^2), g1 = -2 phi / sigma^2, g2 = 4 phi / sigma^4.
Compiled once per machine and cached beside this module; no fast-math. It agrees with the
numpy contractions of ``kernels`` to rounding (tests/unit/gpis/test_local.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

THIN_PLATE, GAUSSIAN = 0, 1


@numba.njit(cache=True)
def contract_pairs(
    x: np.ndarray,
    pair_point: np.ndarray,
    pair_slot: np.ndarray,
    pair_weight: np.ndarray,
    pair_weight_grad: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    P: np.ndarray,
    A: np.ndarray,
    kind: int,
    p1: float,
    p2: float,
    want_gradient: bool,
    f_out: np.ndarray,
    g_out: np.ndarray,
) -> float:
    """Accumulate the weighted residuals (and gradients) of every pair into f_out (m,) and g_out (m, 3).

    kind THIN_PLATE: p1 = R, p2 = amplitude c; kind GAUSSIAN: p1 = sigma^2, p2 = s2. Returns the
    largest point-contact distance met (m), for the caller's kernel range check.
    """
    r_max = 0.0
    for k in range(pair_point.shape[0]):
        q = pair_point[k]
        s = pair_slot[k]
        x0, x1, x2 = x[q, 0], x[q, 1], x[q, 2]
        f = 0.0
        gx = 0.0
        gy = 0.0
        gz = 0.0
        for j in range(starts[s], ends[s]):
            d0 = x0 - P[j, 0]
            d1 = x1 - P[j, 1]
            d2 = x2 - P[j, 2]
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            r = math.sqrt(r2)
            r_max = max(r_max, r)
            if kind == THIN_PLATE:
                phi = p2 * ((2.0 * r - 3.0 * p1) * r2 + p1 * p1 * p1)
                g1 = p2 * (6.0 * r - 6.0 * p1)
                g2 = 6.0 * p2 / r if r > 0.0 else 0.0
            else:
                phi = p2 * math.exp(-r2 / p1)
                g1 = -2.0 / p1 * phi
                g2 = 4.0 / (p1 * p1) * phi
            a = A[j, 0]
            db = d0 * A[j, 1] + d1 * A[j, 2] + d2 * A[j, 3]
            f += a * phi - g1 * db
            if want_gradient:
                c = g1 * a - g2 * db
                gx += c * d0 - g1 * A[j, 1]
                gy += c * d1 - g1 * A[j, 2]
                gz += c * d2 - g1 * A[j, 3]
        w = pair_weight[k]
        f_out[q] += w * f
        if want_gradient:
            g_out[q, 0] += w * gx + f * pair_weight_grad[k, 0]
            g_out[q, 1] += w * gy + f * pair_weight_grad[k, 1]
            g_out[q, 2] += w * gz + f * pair_weight_grad[k, 2]
    return r_max
