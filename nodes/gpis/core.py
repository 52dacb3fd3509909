"""Gaussian process implicit surface from contact positions and normals (paper 002, Sec. 2.3, Eq. 2-6).

The implicit function f: R^3 -> R is a GP with a prior mean m(x) and an isotropic kernel k (see
``kernels``). Each contact (c_p, c_n) is four observations: f(c_p) = 0 (one value row) and
grad f(c_p) = c_n (three gradient rows, c_n the outward unit normal), with noise variances
value_noise_m^2 and gradient_noise^2. Sign convention: f < 0 inside the object, f > 0 outside, and
grad f points outwards. The prior that fixes this sign far from the contacts is a sphere,

    m(x) = prior_scale (|x - c| - r0),

with r0 = prior_radius_m and centre c either given or, by default, placed at the first contact as
c = c_p - r0 c_n (the sphere touches the first contact with the measured normal). The GP models the
residual f - m, so with Eq. 2 and 6 (K~ = K + noise):

    mean(x)     = m(x) + k_*(x)^T K~^{-1} (y - m_obs)          (Eq. 2)
    variance(x) = k(x, x) - k_*(x)^T K~^{-1} k_*(x)            (Eq. 6, clamped at 0)

Factorisation: K~ = L L^T grows by a block Cholesky update per contact (or per batch), O(n^2):

    [L11   0 ]      L11 X = K12,   L22 = chol(K22 - X^T X),
    [X^T  L22]

never a refit from scratch. z = L^{-1} (y - m_obs) grows with it (z2 = L22^{-1} (y2 - X^T z1)), and
alpha = L^{-T} z is recomputed lazily (one triangular solve) when a mean or gradient is asked for.
L lives in a buffer with spare capacity that grows geometrically (``factor.GrowingCholesky``): the
new block rows are written in place, and the solves run on the buffer itself, bit for bit the
solves of a contiguous L.

This is the exact GP: the reference, and the default for small problems. ``local.LocalGPIS`` blends
exact GPs over local regions and scales to thousands of contacts; ``make_estimator`` picks one from
GPISConfig.estimator.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from typing import Annotated, Protocol

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from palpate.config import NonNegativeFloat, OneOf, Positive, PositiveFloat, Range, Validated
from palpate.errors import ConfigError, EstimationError
from palpate.nodes.gpis.factor import GrowingCholesky
from palpate.nodes.gpis.kernels import ROWS_PER_POINT, GaussianKernel, IsotropicKernel, ThinPlateKernel

FloatArray = NDArray[np.float64]

KERNELS = ("thin_plate", "gaussian")
PRIORS = ("sphere", "zero")
ESTIMATORS = ("exact", "local", "auto")

#: Object size (m) that the default config is tuned for (YCB objects are at most 0.23 m across).
REFERENCE_SIZE_M = 0.2

# A normal shorter than this is treated as missing rather than normalised.
_MIN_NORMAL_NORM = 1e-9
#: A free-space point's gradient rows carry this many times the prior's gradient variance as noise:
#: next to it, the prior's own (and the contacts') say everything (``GPIS.add_free_space``).
FREE_SPACE_GRADIENT_VARIANCE = 1e6
# Entries of k_* per chunk in variance(): large, so the triangular solve sees many right-hand sides.
_VARIANCE_CHUNK_ENTRIES = 1 << 22


@dataclass(frozen=True, kw_only=True)
class GPISConfig(Validated):
    """GPIS parameters. Defaults suit objects up to ~0.4 m across (YCB); see ``for_object_size``.

    kernel: "thin_plate" (paper 002 Sec. 3.2) or "gaussian" (Eq. 5).
    R_m: thin-plate R; must be >= every contact-contact and query-contact distance, and >= 1.25 x
        the object's diameter for the covariance with gradients to stay positive definite.
    thin_plate_scale: amplitude a of the thin-plate kernel (1 = the paper's kernel). Var f = a R^3 and
        Var grad f = 6 a R while the noise is fixed in m and in normal units, so the fit depends on
        the object's scale unless a ~ 1 / R; ``for_object_size`` sets it that way.
    length_scale_m: Gaussian sigma in exp(-r^2 / sigma^2).
    gaussian_variance_m2: Gaussian amplitude; None gives length_scale_m^2 / 2 (unit prior variance of
        each gradient component, matching unit normals).
    value_noise_m, gradient_noise: standard deviations of the value rows (m) and of the normal rows.
    jitter: added to the diagonal as a fraction of the prior variances (only matters with zero noise).
    prior: "sphere" (m(x) = prior_scale (|x - c| - prior_radius_m)) or "zero". The sphere should lie
        inside the object: give GPIS(prior_centre_m=...) the initial target of Algorithm 1 when known.
        The thin-plate fit barely depends on it (box test: same error for r0 = 1, 2, 5 cm); the
        Gaussian kernel reverts to the prior within a few length scales of the contacts, so there a
        sphere that bulges out of the object leaves spurious surface (measured: 3 cm errors).
    estimator: "exact" (one GP over every contact: the reference, O(n^2) per touch and in memory),
        "local" (``local.LocalGPIS``: exact GPs over voxels of edge local_cell_m, each holding the
        contacts within local_cell_m + local_margin_m, blended smoothly; cost per touch set by the
        local density, not the history) or "auto": exact up to auto_local_above_contacts contacts,
        then local (rebuilt once from every contact). docs/exploration.md says when to pick which.
    local_blend_m: half-width of the band around each voxel face where two experts hand over.
    local_far_cell_m: the local estimator's far-field GP keeps one contact per voxel of this edge.
    local_far_max_contacts: a far field holding more doubles its voxel edge until it holds at most
        this many (its memory, 128 n^2 bytes, stays bounded on objects of any size).
    local_max_contacts: an expert holding more contacts halves its margin and is rebuilt (down to
        margin 0): dense regions keep small experts, sparse ones the full local_margin_m.
    """

    kernel: Annotated[str, OneOf(KERNELS)] = "thin_plate"
    R_m: PositiveFloat = 0.5
    thin_plate_scale: PositiveFloat = 1.0
    length_scale_m: PositiveFloat = 0.03
    gaussian_variance_m2: Annotated[float | None, Positive] = None
    value_noise_m: NonNegativeFloat = 1e-4
    gradient_noise: NonNegativeFloat = 0.1
    jitter: NonNegativeFloat = 1e-10
    prior: Annotated[str, OneOf(PRIORS)] = "sphere"
    #: Radius r0 of the sphere prior, metres; with no prior_centre_m the sphere touches the first contact.
    prior_radius_m: PositiveFloat = 0.02
    #: Slope of the sphere prior's mean, prior_scale (|x - c| - r0) (1: the signed distance to the sphere).
    prior_scale: PositiveFloat = 1.0
    estimator: Annotated[str, OneOf(ESTIMATORS)] = "auto"
    #: Estimator "auto": the exact GP while it holds at most this many contacts; a touch that would take it
    #: past them switches to the local estimator.
    auto_local_above_contacts: Annotated[int, Positive] = 1500
    #: Voxel edge of the local estimator, metres: one exact GP (expert) per voxel with contacts.
    local_cell_m: PositiveFloat = 0.008
    local_blend_m: PositiveFloat = 0.0015
    #: An expert also holds the contacts up to local_blend_m + this outside its voxel on each axis, metres.
    local_margin_m: NonNegativeFloat = 0.003
    local_far_cell_m: PositiveFloat = 0.02
    local_far_max_contacts: Annotated[int, Range(ge=8)] = 1000  # 8 octants about the origin: fewer never fit
    local_max_contacts: Annotated[int, Positive] = 64

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.jitter == 0 and (self.value_noise_m == 0 or self.gradient_noise == 0):
            zero = ", ".join(k for k in ("value_noise_m", "gradient_noise") if getattr(self, k) == 0)
            raise ConfigError(
                f"GPISConfig: {zero} and jitter are 0; duplicate contacts would make the covariance singular "
                "(their value or normal rows are the same). Set jitter > 0 (e.g. 1e-10)"
            )
        if self.local_blend_m > 0.5 * self.local_cell_m:
            raise ConfigError(
                f"GPISConfig: local_blend_m = {self.local_blend_m!r} exceeds half of local_cell_m = "
                f"{self.local_cell_m!r}; the blend bands of opposite voxel faces would overlap. Lower it"
            )

    @classmethod
    def for_object_size(cls, size_m: float, **overrides: object) -> GPISConfig:
        """The defaults with every length scaled by s = size_m / REFERENCE_SIZE_M (0.2 m).

        R_m, length_scale_m, value_noise_m, prior_radius_m and the local estimator's cells scale by s,
        thin_plate_scale by 1 / s;
        gradient_noise (on unit normals) and jitter do not change. Then K + noise transforms as
        D (K + noise) D with D = diag(s, 1, 1, 1) per contact, and the posterior mean of the scaled
        object is exactly s times the reference one (variance s^2 times). Overrides apply last.
        """
        if not (np.isfinite(size_m) and size_m > 0):
            raise ConfigError(f"object size must be a positive distance in metres, got {size_m!r}")
        base = cls()
        s = size_m / REFERENCE_SIZE_M
        scaled = cls(
            R_m=base.R_m * s,
            thin_plate_scale=base.thin_plate_scale / s,
            length_scale_m=base.length_scale_m * s,
            value_noise_m=base.value_noise_m * s,
            prior_radius_m=base.prior_radius_m * s,
            local_cell_m=base.local_cell_m * s,
            local_blend_m=base.local_blend_m * s,
            local_margin_m=base.local_margin_m * s,
            local_far_cell_m=base.local_far_cell_m * s,
        )
        return dataclasses.replace(scaled, **overrides)  # type: ignore[arg-type]

    def make_kernel(self) -> IsotropicKernel:
        """The configured covariance function."""
        if self.kernel == "thin_plate":
            return ThinPlateKernel(self.R_m, self.thin_plate_scale)
        variance = self.gaussian_variance_m2
        if variance is None:
            variance = self.length_scale_m**2 / 2.0  # -g1(0) = 2 s2 / sigma^2 = 1
        return GaussianKernel(self.length_scale_m, variance)


def _points(x: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1 and a.shape == (3,):
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise EstimationError(f"{name} must have shape (m, 3), got {np.shape(x)}")
    if not np.all(np.isfinite(a)):
        bad = int(np.argwhere(~np.isfinite(a))[0, 0])
        raise EstimationError(f"{name} row {bad} is not finite: {a[bad]}")
    return a


def _unit_normals(normals: ArrayLike, count: int) -> FloatArray:
    """Validate contact normals (count, 3) and normalise them; reject NaN, inf and zero length."""
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim == 1 and n.shape == (3,):
        n = n[None, :]
    if n.shape != (count, 3):
        raise EstimationError(f"contact normals must have shape ({count}, 3), got {np.shape(normals)}")
    for i, row in enumerate(n):
        if not np.all(np.isfinite(row)):
            raise EstimationError(
                f"contact normal {i} is not finite ({row}); the sensor must report a measured outward "
                "normal with every contact (drop the contact instead)"
            )
    norms = np.linalg.norm(n, axis=1)
    short = np.flatnonzero(norms < _MIN_NORMAL_NORM)
    if short.size:
        i = int(short[0])
        raise EstimationError(
            f"contact normal {i} has zero length ({n[i]}, |n| = {norms[i]:.3g}); a zero vector has no "
            "direction and is not normalised silently: drop the contact or supply the measured normal"
        )
    return n / norms[:, None]


def prior_mean(config: GPISConfig, x: FloatArray, centre: FloatArray | None) -> FloatArray:
    """m(x) (m,) at x (m, 3): prior_scale (|x - c| - prior_radius_m), or 0 (zero prior / no centre yet)."""
    if config.prior == "zero" or centre is None:
        return np.zeros(len(x))
    return config.prior_scale * (np.linalg.norm(x - centre, axis=1) - config.prior_radius_m)


def prior_gradient(config: GPISConfig, x: FloatArray, centre: FloatArray | None) -> FloatArray:
    """grad m(x) (m, 3) at x (m, 3)."""
    if config.prior == "zero" or centre is None:
        return np.zeros_like(x)
    d = x - centre
    r = np.linalg.norm(d, axis=1, keepdims=True)
    out = np.zeros_like(d)
    np.divide(d, r, out=out, where=r > 0)  # grad |x - c| (0 at the centre itself)
    return config.prior_scale * out


def one_contact(position_m: ArrayLike, normal: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A single contact's position (3,) and normal (3,) as (1, 3) arrays; EstimationError on other shapes."""
    p = np.asarray(position_m, dtype=np.float64)
    if p.shape != (3,):
        raise EstimationError(f"contact position must have shape (3,), got {p.shape}")
    n = np.asarray(normal, dtype=np.float64)
    if n.shape != (3,):
        raise EstimationError(f"contact normal must have shape (3,), got {n.shape}")
    return p[None, :], n[None, :]


def first_centre(config: GPISConfig, centre: FloatArray | None, P: FloatArray, N: FloatArray) -> FloatArray | None:
    """The sphere prior's centre: the given one, else c = c_p - r0 c_n from the first contact of P (b, 3)."""
    if centre is None and config.prior == "sphere":
        return P[0] - config.prior_radius_m * N[0]
    return centre


class PriorMean(Protocol):
    """A prior mean given as a function (``GPIS.replaced_prior``), e.g. ``hull_prior.SmoothHull``."""

    def mean(self, x: FloatArray) -> FloatArray: ...

    def gradient(self, x: FloatArray) -> FloatArray: ...

    def mean_and_gradient(self, x: FloatArray) -> tuple[FloatArray, FloatArray]: ...


class SurfaceEstimator(Protocol):
    """What the surface mesher, the node and the benchmark need from a GPIS (exact or local)."""

    config: GPISConfig
    kernel: IsotropicKernel

    @property
    def n_contacts(self) -> int: ...

    @property
    def positions_m(self) -> FloatArray: ...

    @property
    def normals(self) -> FloatArray: ...

    @property
    def supports_free_space(self) -> bool: ...

    @property
    def prior_centre_m(self) -> FloatArray | None: ...

    def add_contact(self, position_m: ArrayLike, normal: ArrayLike) -> None: ...

    def add_free_space(self, points_m: ArrayLike, distance_m: float) -> None: ...

    def drop_free_space(self) -> None: ...

    @property
    def supports_replaced_prior(self) -> bool: ...

    @property
    def prior_replaced(self) -> bool: ...

    def replaced_prior(self, prior: PriorMean) -> AbstractContextManager[None]: ...

    def add_contacts(self, positions_m: ArrayLike, normals: ArrayLike) -> None: ...

    def mean(self, x: ArrayLike) -> FloatArray: ...

    def gradient(self, x: ArrayLike) -> FloatArray: ...

    def variance(self, x: ArrayLike) -> FloatArray: ...


class GPIS:
    """Incrementally factorised GPIS. Positions in metres; normals are outward unit vectors.

    Not thread-safe. ``add_contact``/``add_contacts`` are atomic: on error the state is unchanged.
    """

    def __init__(self, config: GPISConfig | None = None, *, prior_centre_m: ArrayLike | None = None) -> None:
        self.config = config if config is not None else GPISConfig()
        self.kernel: IsotropicKernel = self.config.make_kernel()
        self._centre: FloatArray | None = None
        if prior_centre_m is not None:
            self._centre = _points(prior_centre_m, "prior_centre_m")[0].copy()
        self._given_centre = self._centre
        self._replacement: PriorMean | None = None  # the prior within ``replaced_prior``
        self._P = np.zeros((0, 3))  # every observed point: the contacts and the free-space points
        self._N = np.zeros((0, 3))  # their normals (zero rows for free-space points)
        self._is_contact = np.zeros(0, dtype=bool)
        self._n_contacts = 0
        self._L = GrowingCholesky()  # lower Cholesky factor of K + noise, (4n, 4n), in a larger buffer
        self._z = np.zeros(0)  # L^{-1} (y - m_obs), (4n,)
        self._alpha: FloatArray | None = None  # K~^{-1} (y - m_obs) as (n, 4), computed lazily
        cfg, kern = self.config, self.kernel
        # Diagonal added per contact: noise variances plus jitter relative to the prior variances.
        self._diag = np.array(
            [cfg.value_noise_m**2 + cfg.jitter * kern.value_variance]
            + [cfg.gradient_noise**2 + cfg.jitter * kern.gradient_variance] * 3
        )
        # ... and per free-space point: its gradient rows carry no information (see add_free_space).
        self._free_diag = self._diag.copy()
        self._free_diag[1:] = FREE_SPACE_GRADIENT_VARIANCE * kern.gradient_variance

    # --- state -------------------------------------------------------------------------------------
    @property
    def n_contacts(self) -> int:
        return self._n_contacts

    @property
    def n_free_space(self) -> int:
        """Free-space observations held (``add_free_space``)."""
        return len(self._P) - self._n_contacts

    @property
    def positions_m(self) -> FloatArray:
        """Contact positions (n, 3), a copy."""
        return self._P.copy() if self.n_free_space == 0 else self._P[self._is_contact]

    @property
    def normals(self) -> FloatArray:
        """Contact unit normals (n, 3), a copy."""
        return self._N.copy() if self.n_free_space == 0 else self._N[self._is_contact]

    @property
    def supports_free_space(self) -> bool:
        return True

    @property
    def prior_centre_m(self) -> FloatArray | None:
        """Centre c of the sphere prior (3,), or None before the first contact when not given."""
        return None if self._centre is None else self._centre.copy()

    @property
    def supports_replaced_prior(self) -> bool:
        return True

    @property
    def prior_replaced(self) -> bool:
        """Within ``replaced_prior``."""
        return self._replacement is not None

    @property
    def observation_noise(self) -> FloatArray:
        """Variances (4,) added to the diagonal per contact: value row, then the three gradient rows."""
        return self._diag.copy()

    def cholesky_factor(self) -> FloatArray:
        """The incrementally grown lower factor L (4n, 4n) of K + noise, a copy."""
        return self._L.view().copy()

    @property
    def factor_bytes(self) -> int:
        """Memory held by the factor's buffer (bytes), spare capacity included."""
        return self._L.nbytes

    def observation_covariance(self) -> FloatArray:
        """K + noise (4n, 4n) recomputed from scratch (for checks; the GP itself never does this)."""
        K = self.kernel.observation_cov(self._P, self._P)
        K[np.diag_indices_from(K)] += np.where(self._is_contact[:, None], self._diag, self._free_diag).ravel()
        return K

    # --- updates -----------------------------------------------------------------------------------
    def add_contact(self, position_m: ArrayLike, normal: ArrayLike) -> None:
        """Add one contact: position (3,) in metres and outward normal (3,) (normalised here)."""
        self.add_contacts(*one_contact(position_m, normal))

    def add_contacts(self, positions_m: ArrayLike, normals: ArrayLike) -> None:
        """Add b contacts (b, 3) with one block Cholesky update, O(n^2 b + n b^2 + b^3)."""
        P = _points(positions_m, "contact positions")
        N = _unit_normals(normals, len(P))
        if len(P) == 0:
            return
        if self._replacement is not None:
            raise EstimationError("contacts cannot be added while the prior is replaced (see replaced_prior)")
        centre = first_centre(self.config, self._centre, P, N)
        # Residual targets y - m_obs: value rows 0 - m(c_p), gradient rows c_n - grad m(c_p).
        targets = np.empty((len(P), ROWS_PER_POINT))
        targets[:, 0] = -self._prior_mean(P, centre)
        targets[:, 1:] = N - self._prior_gradient(P, centre)
        self._append(P, N, targets, self._diag, centre, contact=True)

    def add_free_space(self, points_m: ArrayLike, distance_m: float) -> None:
        """Observe f = distance_m at points of free space (k, 3), value rows only (their gradient rows
        carry FREE_SPACE_GRADIENT_VARIANCE times the prior's gradient variance: no information).

        For the inequality f >= r at points a fingertip of radius r swept without a contact: add the
        points where the mean breaks it, with distance_m = r (``free_space.enforce``). They are no
        contacts: n_contacts, positions_m and normals leave them out. Atomic, like add_contacts.
        """
        P = _points(points_m, "free-space points")
        if not (math.isfinite(distance_m) and distance_m >= 0.0):
            raise EstimationError(f"free-space distance must be finite and >= 0, got {distance_m!r}")
        if len(P) == 0:
            return
        if self._n_contacts == 0:
            raise EstimationError("free space needs a contact first (the prior's centre comes from it)")
        centre = self._require_centre()
        targets = np.zeros((len(P), ROWS_PER_POINT))
        targets[:, 0] = distance_m - self._prior_mean(P, centre)
        self._append(P, np.zeros_like(P), targets, self._free_diag, centre, contact=False)

    def _append(
        self,
        P: FloatArray,
        N: FloatArray,
        targets: FloatArray,
        diag: FloatArray,
        centre: FloatArray | None,
        *,
        contact: bool,
    ) -> None:
        """Add b observed points (b, 3) with residual targets (b, 4) and diagonal (4,) by one block
        Cholesky update; nothing changes on error."""
        n_old, b = len(self._P), len(P)
        m_add = ROWS_PER_POINT * b
        what = "contact" if contact else "free-space point"
        y2 = targets.ravel()

        K22 = self.kernel.observation_cov(P, P)
        K22[np.diag_indices_from(K22)] += np.tile(diag, b)
        if n_old:
            K12 = self.kernel.observation_cov(self._P, P)  # (4 n_old, 4 b)
            X = self._L.solve(K12)  # L11 X = K12
            S = K22 - X.T @ X  # Schur complement K22 - K21 K11^{-1} K12
        else:
            X = np.zeros((0, m_add))
            S = K22
        S = 0.5 * (S + S.T)
        try:
            L22 = np.linalg.cholesky(S)
        except np.linalg.LinAlgError as exc:
            raise EstimationError(
                f"GPIS covariance is not positive definite after adding {b} {what}(s) to {n_old}: "
                + (
                    f"the contacts probably span more than about 0.8 R_m = {0.8 * self.config.R_m:.3g} m "
                    "(raise GPISConfig.R_m to >= 1.25 x the object's diameter)"
                    if self.config.kernel == "thin_plate"
                    else "increase value_noise_m, gradient_noise or jitter"
                )
            ) from exc
        z2 = scipy.linalg.solve_triangular(L22, y2 - X.T @ self._z, lower=True, check_finite=False)

        # Commit (nothing above mutated self): L = [L11 0; X^T L22], written in place.
        self._L.append(X.T, L22)
        self._centre = centre
        self._z = np.concatenate([self._z, z2])
        self._P = np.vstack([self._P, P])
        self._N = np.vstack([self._N, N])
        self._is_contact = np.concatenate([self._is_contact, np.full(b, contact)])
        self._n_contacts += b if contact else 0
        self._alpha = None

    def drop_free_space(self) -> None:
        """Remove the free-space observations, which must all come after the last contact (exact: the
        factor's leading block is the contacts' own, as in ``truncate``)."""
        if self.n_free_space == 0:
            return
        n = self._n_contacts
        if not self._is_contact[:n].all():  # the n contacts are not the leading block
            raise EstimationError("free-space observations lie between contacts; they cannot be dropped")
        self._L.truncate(ROWS_PER_POINT * n)
        self._z = self._z[: ROWS_PER_POINT * n].copy()
        self._P, self._N = self._P[:n].copy(), self._N[:n].copy()
        self._is_contact = self._is_contact[:n].copy()
        self._alpha = None

    @contextmanager
    def replaced_prior(self, prior: PriorMean) -> Iterator[None]:
        """Within the block the GP has the prior mean ``prior`` in place of the configured one, on the
        same contacts: the residual targets y - m_obs change, the factor does not (one solve, O(n^2)).
        Free space added within the block is dropped with it, and the GP is then as before, to the bit.
        Refused while the GP holds free space (its targets would need the old prior)."""
        if self.n_free_space:
            raise EstimationError("a prior cannot be replaced while free-space observations are held")
        if self._replacement is not None:
            raise EstimationError("the prior is replaced already")
        saved = self._z, self._alpha
        if len(self._P):
            m, g = prior.mean_and_gradient(self._P)
            targets = np.concatenate([-m[:, None], self._N - g], axis=1)
            self._z = self._L.solve(targets.ravel())
        self._alpha, self._replacement = None, prior
        try:
            yield
        finally:
            try:
                self.drop_free_space()
            finally:
                (self._z, self._alpha), self._replacement = saved, None

    def truncate(self, n_contacts: int) -> None:
        """Keep the first n_contacts contacts only (exact: the factor's leading block is their factor)."""
        if not 0 <= n_contacts <= self.n_contacts:
            raise EstimationError(f"cannot keep {n_contacts} of {self.n_contacts} contacts")
        if self.n_free_space:
            raise EstimationError("cannot truncate a GP that holds free-space observations")
        if self._replacement is not None:
            raise EstimationError("cannot truncate a GP while its prior is replaced")
        rows = ROWS_PER_POINT * n_contacts
        self._L.truncate(rows)
        self._z = self._z[:rows].copy()
        self._P, self._N = self._P[:n_contacts].copy(), self._N[:n_contacts].copy()
        self._is_contact = self._is_contact[:n_contacts].copy()
        self._n_contacts = n_contacts
        self._alpha = None
        if n_contacts == 0 and self._given_centre is None:
            self._centre = None

    # --- queries -----------------------------------------------------------------------------------
    def mean(self, x: ArrayLike) -> FloatArray:
        """Posterior mean f(x) (m,) for points x (m, 3), Eq. 2; negative inside, positive outside."""
        x = _points(x, "query points")
        out = self._prior_mean(x, self._require_centre())
        if len(self._P):
            out += self.kernel.value_contract(x, self._P, self._weights())
        return out

    def gradient(self, x: ArrayLike) -> FloatArray:
        """Gradient of the posterior mean (m, 3) at x (m, 3); outward where f = 0."""
        x = _points(x, "query points")
        out = self._prior_gradient(x, self._require_centre())
        if len(self._P):
            out += self.kernel.gradient_contract(x, self._P, self._weights())
        return out

    def variance(self, x: ArrayLike) -> FloatArray:
        """Posterior variance of f (m,) at x (m, 3), Eq. 6, in m^2 (clamped at 0)."""
        x = _points(x, "query points")
        out = np.full(len(x), self.kernel.value_variance)
        if len(self._P):
            for s in self._chunks(len(x), ROWS_PER_POINT * len(self._P)):
                out[s] -= self.explained_variance(x[s])
        return np.maximum(out, 0.0, out=out)

    def mean_and_variance(self, x: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(mean (m,), variance (m,)) at x (m, 3)."""
        return self.mean(x), self.variance(x)

    def prior_mean(self, x: ArrayLike) -> FloatArray:
        """m(x) (m,) of the configured prior."""
        return self._prior_mean(_points(x, "query points"), self._require_centre())

    def residual_weights(self) -> tuple[FloatArray, FloatArray]:
        """(contact positions (n, 3), alpha = K~^{-1} (y - m_obs) as (n, 4)): the GP's own arrays, not
        copies (``local.LocalGPIS`` reads them for hundreds of experts per query); do not modify them.

        mean(x) = m(x) + sum_j cov(f(x), obs_j) alpha_j (Eq. 2): what a caller needs to evaluate the
        posterior mean with its own contraction.
        """
        return self._P, (self._weights() if len(self._P) else np.zeros((0, ROWS_PER_POINT)))

    def solve_factor_in_place(self, B: FloatArray) -> None:
        """Overwrite the column-major B (4n, k) with L^{-1} B (for callers that build k_* themselves)."""
        self._L.solve_in_place(B)

    def explained_variance(self, x: FloatArray) -> FloatArray:
        """k_*^T K~^{-1} k_* (m,) at validated points x (m, 3), the term that Eq. 6 subtracts (one chunk).

        k_* rows (m, 4n); L V = k_*^T with every point's column in one triangular solve.
        """
        if not len(self._P):
            return np.zeros(len(x))
        V = self.kernel.value_obs_cov(x, self._P).T  # column-major (4n, m): solved in place
        self._L.solve_in_place(V)
        return np.einsum("ij,ij->j", V, V)

    # --- internals ---------------------------------------------------------------------------------
    def _weights(self) -> FloatArray:
        """alpha = K~^{-1} (y - m_obs) = L^{-T} z as (n, 4)."""
        if self._alpha is None:
            alpha = self._L.solve(self._z, trans=True)
            self._alpha = alpha.reshape(len(self._P), ROWS_PER_POINT)
        return self._alpha

    def _require_centre(self) -> FloatArray | None:
        if self.config.prior == "sphere" and self._centre is None:
            raise EstimationError(
                "the sphere prior has no centre yet: pass prior_centre_m to GPIS() or add a contact first"
            )
        return self._centre

    def _prior_mean(self, x: FloatArray, centre: FloatArray | None) -> FloatArray:
        if self._replacement is not None:
            return self._replacement.mean(x)
        return prior_mean(self.config, x, centre)

    def _prior_gradient(self, x: FloatArray, centre: FloatArray | None) -> FloatArray:
        if self._replacement is not None:
            return self._replacement.gradient(x)
        return prior_gradient(self.config, x, centre)

    @staticmethod
    def _chunks(m: int, entries_per_row: int, budget: int = _VARIANCE_CHUNK_ENTRIES) -> list[slice]:
        step = max(1, budget // max(1, entries_per_row))
        return [slice(s, min(s + step, m)) for s in range(0, m, step)]
