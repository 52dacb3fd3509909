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
def _radial(r: float, r2: float, kind: int, p1: float, p2: float) -> tuple[float, float]:
    """phi(r) and g1(r) = phi'(r) / r of the kernel (r2 = r^2)."""
    if kind == THIN_PLATE:
        return p2 * ((2.0 * r - 3.0 * p1) * r2 + p1 * p1 * p1), p2 * (6.0 * r - 6.0 * p1)
    phi = p2 * math.exp(-r2 / p1)
    return phi, -2.0 / p1 * phi


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
            phi, g1 = _radial(r, r2, kind, p1, p2)
            g2 = 4.0 / (p1 * p1) * phi  # Gaussian; thin plate: 6 c / r, 0 at r = 0 (d d^T = 0 there)
            if kind == THIN_PLATE:
                g2 = 6.0 * p2 / r if r > 0.0 else 0.0
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


@numba.njit(cache=True)
def _smooth(v: float) -> tuple[float, float]:
    """s(v) = 3 v^2 - 2 v^3 and s'(v) = 6 v (1 - v)."""
    return v * v * (3.0 - 2.0 * v), 6.0 * v * (1.0 - v)


@numba.njit(cache=True)
def blend_pairs(
    x: np.ndarray, cell_m: float, blend_m: float, table: np.ndarray, key_bits: int, want_gradient: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(point, table position, weight, weight gradient (k, 3)) of every (point, existing expert) pair
    with a non-zero weight, and the far field's weight (m,) and gradient (m, 3) (local.py's partition).

    table: sorted packed keys (e,) of the experts that exist. Per axis: t = x / h, i = floor(t),
    u = t - i, beta = b / h; u < beta: cells (i - 1, i) with v = (u + beta) / (2 beta); u > 1 - beta:
    cells (i, i + 1) with v = (u - 1 + beta) / (2 beta); else cell i alone. w_upper = s(v).
    """
    m = x.shape[0]
    beta = blend_m / cell_m
    offset = 1 << (key_bits - 1)
    point = np.empty(8 * m, dtype=np.int64)
    pos = np.empty(8 * m, dtype=np.int64)
    weight = np.empty(8 * m)
    wgrad = np.zeros((8 * m, 3)) if want_gradient else np.zeros((0, 3))
    far_w = np.ones(m)
    far_g = np.zeros((m, 3))
    lower = np.empty(3, dtype=np.int64)
    w_ax = np.empty((2, 3))
    d_ax = np.empty((2, 3))
    k = 0
    e = table.shape[0]
    for q in range(m):
        for a in range(3):
            t = x[q, a] / cell_m
            i = math.floor(t)
            u = t - i
            if u < beta:
                lower[a] = i - 1
                v = (u + beta) / (2.0 * beta)
            elif u > 1.0 - beta:
                lower[a] = i
                v = (u - 1.0 + beta) / (2.0 * beta)
            else:
                lower[a] = i
                v = 0.0
            s, ds = _smooth(v)
            w_ax[0, a], w_ax[1, a] = 1.0 - s, s
            d_ax[0, a], d_ax[1, a] = -ds / (2.0 * blend_m), ds / (2.0 * blend_m)
        for c in range(8):
            c0, c1, c2 = (c >> 2) & 1, (c >> 1) & 1, c & 1
            w = w_ax[c0, 0] * w_ax[c1, 1] * w_ax[c2, 2]
            if w <= 0.0 or e == 0:
                continue
            key = (
                ((lower[0] + c0 + offset) << (2 * key_bits))
                | ((lower[1] + c1 + offset) << key_bits)
                | (lower[2] + c2 + offset)
            )
            j = np.searchsorted(table, key)
            if j >= e or table[j] != key:
                continue
            point[k], pos[k], weight[k] = q, j, w
            far_w[q] -= w
            if want_gradient:
                g0 = d_ax[c0, 0] * w_ax[c1, 1] * w_ax[c2, 2]
                g1 = w_ax[c0, 0] * d_ax[c1, 1] * w_ax[c2, 2]
                g2 = w_ax[c0, 0] * w_ax[c1, 1] * d_ax[c2, 2]
                wgrad[k, 0], wgrad[k, 1], wgrad[k, 2] = g0, g1, g2
                far_g[q, 0] -= g0
                far_g[q, 1] -= g1
                far_g[q, 2] -= g2
            k += 1
    return point[:k], pos[:k], weight[:k], wgrad[:k] if want_gradient else wgrad, far_w, far_g


@numba.njit(cache=True)
def value_obs_blocks(
    x: np.ndarray,
    columns: np.ndarray,
    col_starts: np.ndarray,
    P: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    offsets: np.ndarray,
    kind: int,
    p1: float,
    p2: float,
    out: np.ndarray,
) -> float:
    """k_* of Eq. 6 for every expert's query points, each block (4 m_e, k_e) in column-major order.

    Expert s has contacts P[starts[s]:ends[s]] (m_e of them) and query points x[columns[col_starts[s]:
    col_starts[s + 1]]] (k_e); its block starts at out[offsets[s]]. Column c, rows 4 j .. 4 j + 3 hold
    cov(f(x_c), [f, grad f](p_j)) = [phi(r), -g1(r) d] with d = x_c - p_j (kernels.value_obs_cov).
    Returns the largest distance met (m), for the kernel's range check.
    """
    r_max = 0.0
    for s in range(starts.shape[0]):
        rows = 4 * (ends[s] - starts[s])
        base = offsets[s]
        for c in range(col_starts[s + 1] - col_starts[s]):
            q = columns[col_starts[s] + c]
            at = base + c * rows
            for j in range(starts[s], ends[s]):
                d0 = x[q, 0] - P[j, 0]
                d1 = x[q, 1] - P[j, 1]
                d2 = x[q, 2] - P[j, 2]
                r2 = d0 * d0 + d1 * d1 + d2 * d2
                r = math.sqrt(r2)
                r_max = max(r_max, r)
                phi, g1 = _radial(r, r2, kind, p1, p2)
                out[at] = phi
                out[at + 1] = -g1 * d0
                out[at + 2] = -g1 * d1
                out[at + 3] = -g1 * d2
                at += 4
    return r_max


@numba.njit(cache=True)
def column_sums_of_squares(
    blocks: np.ndarray, col_starts: np.ndarray, rows: np.ndarray, offsets: np.ndarray, out: np.ndarray
) -> None:
    """out[col] = |v_col|^2 for every column of every expert's solved block V = L^{-1} k_* (Eq. 6)."""
    for s in range(rows.shape[0]):
        at = offsets[s]
        for c in range(col_starts[s], col_starts[s + 1]):
            acc = 0.0
            for i in range(rows[s]):
                v = blocks[at + i]
                acc += v * v
            out[c] = acc
            at += rows[s]
