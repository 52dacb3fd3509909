"""Compiled (numba) search of ``Cubic.closest_tau``: the controller runs it on every tick.

The same operations in the same order as the numpy grid and the Python Newton steps it replaces,
compiled without fast-math (no reassociation, no fused multiply-add), so it gives the same bits
(tests/unit/geometry/test_bezier.py compares both on random curves). Cached on disk beside this
module (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def newton_terms(
    A: np.ndarray, end: np.ndarray, end_tangent: np.ndarray, t: float, r: np.ndarray
) -> tuple[float, float]:
    """g = (T - r) . T' and g' = |T'|^2 + (T - r) . T'' at t of the curve in power form A (4, 3), which
    continues straight from end (3,) along end_tangent (3,) beyond t = 1."""
    g = 0.0
    dg = 0.0
    if t > 1.0:
        for k in range(3):
            d = end_tangent[k]
            diff = end[k] + (t - 1.0) * d - r[k]
            g += diff * d
            dg += d * d
        return g, dg
    for k in range(3):
        diff = A[0, k] + t * (A[1, k] + t * (A[2, k] + t * A[3, k])) - r[k]
        d1 = A[1, k] + t * (2.0 * A[2, k] + 3.0 * t * A[3, k])
        d2 = 2.0 * A[2, k] + 6.0 * t * A[3, k]
        g += diff * d1
        dg += d1 * d1 + diff * d2
    return g, dg


@numba.njit(cache=True)
def closest_search(
    A: np.ndarray,
    end: np.ndarray,
    end_tangent: np.ndarray,
    r: np.ndarray,
    tau_min: float,
    tau_max: float,
    unit_grid: np.ndarray,
    newton_steps: int,
) -> float:
    """``Cubic.closest_tau``: the grid search, the Newton refinement, and Newton's tau when its squared
    distance is no larger than the best grid tau's, else that grid tau."""
    samples = unit_grid.shape[0]
    grid = np.empty(samples)
    best = -1
    best_d2 = 0.0
    for j in range(samples):
        tau = tau_min + (tau_max - tau_min) * unit_grid[j]
        grid[j] = tau
        g = tau if tau < 1.0 else 1.0  # np.minimum(grid, 1.0)
        beyond = tau - 1.0
        beyond = beyond if beyond > 0.0 else 0.0  # np.maximum(grid - 1.0, 0.0)
        d2 = 0.0
        for k in range(3):
            p = A[0, k] + g * (A[1, k] + g * (A[2, k] + g * A[3, k]))
            diff = p + beyond * end_tangent[k] - r[k]
            d2 += diff * diff
        if best < 0 or d2 < best_d2 or (d2 != d2 and best_d2 == best_d2):  # np.argmin: first minimum, NaN first
            best, best_d2 = j, d2
    lo = grid[max(best - 1, 0)]
    hi = grid[min(best + 1, samples - 1)]
    best_tau = grid[best]
    t = best_tau
    for _ in range(newton_steps):
        g, dg = newton_terms(A, end, end_tangent, t, r)
        if dg <= 1e-300:
            break
        step = t - g / dg
        clipped = lo if lo > step else step  # min(max(step, lo), hi) as Python's min and max decide
        t_new = hi if hi < clipped else clipped
        converged = abs(t_new - t) < 1e-12
        t = t_new
        if converged:
            break
    d2 = 0.0  # |T(t) - r|^2 as Cubic.point gives T(t)
    for k in range(3):
        if t > 1.0:
            diff = end[k] + (t - 1.0) * end_tangent[k] - r[k]
        else:
            diff = A[0, k] + t * (A[1, k] + t * (A[2, k] + t * A[3, k])) - r[k]
        d2 += diff * diff
    return t if d2 <= best_d2 else best_tau
