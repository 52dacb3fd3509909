"""Isotropic covariance kernels with the derivative blocks that gradient observations need.

A kernel is a radial profile k(x, y) = phi(r), r = |d|, d = x - y. With

    g1(r) = phi'(r) / r                       and   g2(r) = (phi''(r) - phi'(r) / r) / r^2

the blocks that a GP with value and gradient observations needs are (derivatives of phi(|x - y|)):

    cov(f(x), f(y))              = phi(r)
    cov(f(x), d f(y) / d y_j)    = -g1(r) d_j                          (k_fg, 3 columns)
    cov(d f(x) / d x_i, f(y))    = +g1(r) d_i                          (k_gf)
    cov(d f(x)/d x_i, d f(y)/d y_j) = -(g2(r) d_i d_j + g1(r) delta_ij)  (k_gg, 3 x 3)

Thin-plate (Williams and Fitzgibbon's GPIS kernel, paper 002 Sec. 3.2):
    phi = 2 r^3 - 3 R r^2 + R^3,  g1 = 6 r - 6 R,  g2 = 6 / r.
g1 is finite at r = 0, and g2 d_i d_j = 6 d_i d_j / r -> 0 there (|.| <= 6 r), so every block is
continuous at r = 0 and is evaluated exactly: the d d^T term is set to 0 at r = 0 instead of 0/0.
R must be at least the largest distance ever queried (beyond R the profile is not a covariance);
``ThinPlateKernel`` raises EstimationError when a distance exceeds R. Measured: with gradient
observations the joint covariance stays positive definite only while the contacts span about
0.8 R or less (a ball of diameter 0.83 R already gives negative eigenvalues), so choose
R >= 1.25 x the object's diameter.

Gaussian (paper 002 Eq. 5, with an amplitude s2):
    phi = s2 exp(-r^2 / sigma^2),  g1 = -2 s2 / sigma^2 exp(.),  g2 = 4 s2 / sigma^4 exp(.).

Observation order used throughout palpate's GPIS: per point the four rows [f, df/dx, df/dy, df/dz].
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.gpis import dense_kernels
from palpate.nodes.gpis.local_kernels import GAUSSIAN, THIN_PLATE

FloatArray = NDArray[np.float64]

#: Number of observation rows per contact: one value and three gradient components.
ROWS_PER_POINT = 4

# Kernel entries per chunk of query points on the numpy paths (bounds their (m, n) temporaries).
_CHUNK_ENTRIES = 1 << 18

# Distances are compared with R with this relative slack, so that a query exactly at R (rounded) passes.
_R_SLACK = 1e-12


def _differences(x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """d = x_i - y_j (m, n, 3) and r = |d| (m, n), computed directly (exact near r = 0)."""
    d = x[:, None, :] - y[None, :, :]
    r = np.sqrt(np.einsum("mnk,mnk->mn", d, d))
    return d, r


def _by_row_chunks(
    contract: Callable[[FloatArray, FloatArray, FloatArray], FloatArray], x: FloatArray, y: FloatArray, w: FloatArray
) -> FloatArray:
    """contract(x, y, w) on chunks of the rows of x, so that its (m, n) temporaries stay small."""
    step = max(1, _CHUNK_ENTRIES // max(1, len(y)))
    if len(x) <= step:
        return contract(x, y, w)
    return np.concatenate([contract(x[s : s + step], y, w) for s in range(0, len(x), step)])


def _as_points(x: FloatArray, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise EstimationError(f"{name} must have shape (m, 3), got {a.shape}")
    return a


class IsotropicKernel(ABC):
    """A radial covariance phi(|x - y|) with its first and second derivative blocks."""

    name: str = "isotropic"

    @abstractmethod
    def radial(self, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        """phi(r) and g1(r) = phi'(r) / r for r >= 0, both shaped like r (exact at r = 0)."""

    @abstractmethod
    def radial_g2(self, r: FloatArray) -> FloatArray:
        """g2(r) = (phi'' - phi'/r) / r^2 for r > 0; at r = 0 any finite value (it multiplies d d^T = 0)."""

    def check_distances(self, r_max: float) -> None:  # noqa: B027 (optional hook, valid everywhere by default)
        """Raise EstimationError when the kernel is not valid at distance r_max (m). Default: always valid."""

    def compiled(self) -> tuple[int, float, float] | None:
        """(kind, p1, p2) of the compiled loops (``dense_kernels``, ``local_kernels``); None: numpy only."""
        return None

    def check_range(self, x: FloatArray, y: FloatArray) -> None:
        """``check_distances`` for every pair of x (m, 3) and y (n, 3), without forming the (m, n) distances
        when a bound passes: first the farthest corners of the two bounding boxes, then (O(n)) the corner
        of x's box farthest from each y; only when both fail, the largest distance itself."""
        if not (len(x) and len(y)):
            return
        lower, upper = x.min(axis=0), x.max(axis=0)
        span = np.maximum(upper - y.min(axis=0), y.max(axis=0) - lower)
        try:
            self.check_distances(float(np.sqrt(span @ span)))
            return
        except EstimationError:
            pass
        farthest = np.maximum(np.abs(y - lower), np.abs(y - upper))
        try:
            self.check_distances(float(np.sqrt(np.max(np.einsum("ij,ij->i", farthest, farthest)))))
        except EstimationError:
            self.check_distances(dense_kernels.max_distance(x, y))

    @property
    def value_variance(self) -> float:
        """k(x, x) = phi(0)."""
        return float(self.radial(np.zeros(1))[0][0])

    @property
    def gradient_variance(self) -> float:
        """Var(df/dx_i) at any point = -g1(0)."""
        return float(-self.radial(np.zeros(1))[1][0])

    # --- blocks ------------------------------------------------------------------------------------
    def k(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """cov(f(x), f(y)): (m, n) for x (m, 3), y (n, 3)."""
        _, r = self._checked(x, y)
        return self.radial(r)[0]

    def k_fg(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """cov(f(x), grad f(y)) = d k / d y: (m, n, 3)."""
        d, r = self._checked(x, y)
        return -self.radial(r)[1][..., None] * d

    def k_gf(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """cov(grad f(x), f(y)) = d k / d x: (m, n, 3)."""
        d, r = self._checked(x, y)
        return self.radial(r)[1][..., None] * d

    def k_gg(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """cov(grad f(x), grad f(y)) = d^2 k / d x d y: (m, n, 3, 3), index [i, j] = (x_i, y_j)."""
        d, r = self._checked(x, y)
        return self._gg(d, r, self.radial(r)[1])

    def observation_cov(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Covariance between the observations [f, grad f] at x and at y: (4 m, 4 n).

        Rows 4a..4a+3 are [f(x_a), df/dx(x_a), df/dy(x_a), df/dz(x_a)], columns likewise for y.
        """
        d, r = self._checked(x, y)
        phi, g1 = self.radial(r)
        m, n = r.shape
        B = np.empty((m, ROWS_PER_POINT, n, ROWS_PER_POINT))
        B[:, 0, :, 0] = phi
        B[:, 0, :, 1:] = -g1[..., None] * d
        B[:, 1:, :, 0] = np.moveaxis(g1[..., None] * d, 2, 1)
        B[:, 1:, :, 1:] = np.moveaxis(self._gg(d, r, g1), 2, 1)
        return B.reshape(ROWS_PER_POINT * m, ROWS_PER_POINT * n)

    def value_obs_cov(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """cov(f(x), observations at y): (m, 4 n), the k_* rows of Eq. 2 with gradient observations."""
        x, y, params = self._prepared(x, y)
        if params is None:
            return self._value_obs_cov_numpy(x, y)
        out = np.empty((len(x), ROWS_PER_POINT * len(y)))
        dense_kernels.value_obs_cov(x, y, *params, out)
        return out

    # --- contractions with weights (posterior mean and gradient without forming k_*) ----------------
    def value_contract(self, x: FloatArray, y: FloatArray, w: FloatArray) -> FloatArray:
        """sum_j cov(f(x), obs_j) w_j for weights w (n, 4) on the observations at y: (m,).

        = sum_j [w_j0 phi(r_j) - g1(r_j) (x - y_j) . w_j(1:4)], compiled (``dense_kernels``) for the
        built-in kernels; ``value_obs_cov(x, y) @ w.ravel()`` is the slow reference.
        """
        x, y, params = self._prepared(x, y)
        if params is None:
            return _by_row_chunks(self._value_contract_numpy, x, y, w)
        out = np.zeros(len(x))
        dense_kernels.add_values(np.ascontiguousarray(x.T), y, np.ascontiguousarray(w, dtype=np.float64), *params, out)
        return out

    def gradient_contract(self, x: FloatArray, y: FloatArray, w: FloatArray) -> FloatArray:
        """sum_j cov(grad f(x), obs_j) w_j for weights w (n, 4): (m, 3).

        = sum_j [g1 d w_j0 - g2 d (d . w_j(1:4)) - g1 w_j(1:4)], d = x - y_j.
        """
        x, y, params = self._prepared(x, y)
        if params is None:
            return _by_row_chunks(self._gradient_contract_numpy, x, y, w)
        out = np.zeros((3, len(x)))
        weights = np.ascontiguousarray(w, dtype=np.float64)
        dense_kernels.add_gradients(np.ascontiguousarray(x.T), y, weights, *params, out)
        return np.ascontiguousarray(out.T)

    def _prepared(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray, tuple[int, float, float] | None]:
        """x (m, 3), y (n, 3) as arrays and the compiled loops' parameters, with the range checked for
        them; None for a kernel without compiled loops (its numpy paths check the distances they form)."""
        x = _as_points(x, "x")
        y = _as_points(y, "y")
        params = self.compiled()
        if params is not None:
            self.check_range(x, y)
        return x, y, params

    # --- numpy paths (kernels without compiled loops; the references of the tests) ----------------
    def _value_obs_cov_numpy(self, x: FloatArray, y: FloatArray) -> FloatArray:
        d, r = self._checked_components(x, y)
        phi, g1 = self.radial(r)
        B = np.empty((*r.shape, ROWS_PER_POINT))
        B[..., 0] = phi
        for k in range(3):
            np.multiply(g1, d[k], out=B[..., 1 + k])
            np.negative(B[..., 1 + k], out=B[..., 1 + k])
        return B.reshape(r.shape[0], ROWS_PER_POINT * r.shape[1])

    def _value_contract_numpy(self, x: FloatArray, y: FloatArray, w: FloatArray) -> FloatArray:
        d, r = self._checked_components(x, y)
        phi, g1 = self.radial(r)
        dw = d[0] * w[:, 1] + d[1] * w[:, 2] + d[2] * w[:, 3]
        return phi @ w[:, 0] - np.einsum("mn,mn->m", g1, dw)

    def _gradient_contract_numpy(self, x: FloatArray, y: FloatArray, w: FloatArray) -> FloatArray:
        d, r = self._checked_components(x, y)
        _, g1 = self.radial(r)
        g2 = self.radial_g2(r)
        dw = d[0] * w[:, 1] + d[1] * w[:, 2] + d[2] * w[:, 3]
        coef = g1 * w[:, 0] - g2 * dw
        out = np.empty((r.shape[0], 3))
        for k in range(3):
            out[:, k] = np.einsum("mn,mn->m", coef, d[k])
        out -= g1 @ w[:, 1:]
        return out

    # --- helpers -----------------------------------------------------------------------------------
    def _checked(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        d, r = _differences(_as_points(x, "x"), _as_points(y, "y"))
        if r.size:
            self.check_distances(float(r.max()))
        return d, r

    def _checked_components(self, x: FloatArray, y: FloatArray) -> tuple[list[FloatArray], FloatArray]:
        """Components [dx, dy, dz] of d = x_i - y_j, each (m, n), and r (m, n); checks r against R."""
        x = _as_points(x, "x")
        y = _as_points(y, "y")
        d = [x[:, None, k] - y[None, :, k] for k in range(3)]
        r = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if r.size:
            self.check_distances(float(r.max()))
        return d, r

    def _gg(self, d: FloatArray, r: FloatArray, g1: FloatArray) -> FloatArray:
        g2 = self.radial_g2(r)
        out = -(g2[..., None, None] * d[..., :, None] * d[..., None, :])
        out -= g1[..., None, None] * np.eye(3)
        return out


class ThinPlateKernel(IsotropicKernel):
    """phi(r) = a (2 r^3 - 3 R r^2 + R^3) (paper 002 Sec. 3.2, a = 1), valid for r <= R.

    The amplitude a (default 1, the paper's kernel) exists for scale invariance: Var f = a R^3 and
    Var grad f = 6 a R, so with a proportional to 1 / R the fit of a scaled object is the scaled fit.
    """

    name = "thin_plate"

    def __init__(self, R_m: float, amplitude: float = 1.0) -> None:
        if not (np.isfinite(R_m) and R_m > 0):
            raise ConfigError(f"thin-plate R_m must be a positive finite distance in metres, got {R_m!r}")
        if not (np.isfinite(amplitude) and amplitude > 0):
            raise ConfigError(f"thin-plate amplitude must be positive and finite, got {amplitude!r}")
        self.R_m = float(R_m)
        self.amplitude = float(amplitude)

    def radial(self, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        R, a = self.R_m, self.amplitude
        phi = a * ((2.0 * r - 3.0 * R) * r * r + R**3)  # a (2 r^3 - 3 R r^2 + R^3)
        g1 = a * (6.0 * r - 6.0 * R)  # phi' / r = a (6 r^2 - 6 R r) / r
        return phi, g1

    def radial_g2(self, r: FloatArray) -> FloatArray:
        # (phi'' - phi'/r) / r^2 = a (12 r - 6 R - 6 r + 6 R) / r^2 = 6 a / r; 0 at r = 0 where d d^T = 0.
        out = np.zeros_like(r)
        np.divide(6.0 * self.amplitude, r, out=out, where=r > 0)
        return out

    def check_distances(self, r_max: float) -> None:
        if r_max > self.R_m * (1.0 + _R_SLACK):
            raise EstimationError(
                f"distance {r_max:.6g} m exceeds the thin-plate kernel's R_m = {self.R_m:.6g} m; the kernel "
                "is only a covariance for r <= R. Raise GPISConfig.R_m above the largest distance between "
                "contacts and query points (>= 1.25 x the object's diameter) or query a smaller region"
            )

    def compiled(self) -> tuple[int, float, float]:
        return THIN_PLATE, self.R_m, self.amplitude


class GaussianKernel(IsotropicKernel):
    """phi(r) = s2 exp(-r^2 / sigma^2) (paper 002 Eq. 5 with amplitude s2 in m^2)."""

    name = "gaussian"

    def __init__(self, length_scale_m: float, variance_m2: float) -> None:
        if not (np.isfinite(length_scale_m) and length_scale_m > 0):
            raise ConfigError(f"Gaussian length_scale_m must be positive and finite, got {length_scale_m!r}")
        if not (np.isfinite(variance_m2) and variance_m2 > 0):
            raise ConfigError(f"Gaussian variance_m2 must be positive and finite, got {variance_m2!r}")
        self.length_scale_m = float(length_scale_m)
        self.variance_m2 = float(variance_m2)

    def radial(self, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        s2, inv = self.variance_m2, 1.0 / self.length_scale_m**2
        phi = s2 * np.exp(-r * r * inv)
        return phi, -2.0 * inv * phi

    def radial_g2(self, r: FloatArray) -> FloatArray:
        inv = 1.0 / self.length_scale_m**2
        return 4.0 * inv * inv * self.variance_m2 * np.exp(-r * r * inv)

    def compiled(self) -> tuple[int, float, float]:
        return GAUSSIAN, self.length_scale_m**2, self.variance_m2
