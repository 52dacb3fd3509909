"""Kernel derivative blocks against central finite differences, symmetry, and the fast contractions."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.gpis import kernels
from palpate.nodes.gpis.kernels import GaussianKernel, IsotropicKernel, ThinPlateKernel

R = 0.7  # thin-plate R (m); distances up to 0.9 R are tested
SIGMA = 0.05  # Gaussian length scale (m)


def _kernels() -> list[tuple[IsotropicKernel, float]]:
    """(kernel, its length scale) pairs; step sizes and separations are multiples of the scale."""
    return [(ThinPlateKernel(R), R), (GaussianKernel(SIGMA, 0.3), SIGMA)]


KERNELS = pytest.mark.parametrize(("kernel", "scale"), _kernels(), ids=["thin_plate", "gaussian"])


def _pair(r: float, rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Two points (1, 3) at distance r in a random direction, away from the origin."""
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    x = rng.uniform(-0.1, 0.1, 3) * scale
    return x[None, :], (x - r * u)[None, :]


def _fd(f: Callable[[np.ndarray], np.ndarray], p: np.ndarray, h: float) -> np.ndarray:
    """Central differences of f (array-valued) w.r.t. the 3 coordinates of p (1, 3): shape f(p).shape + (3,)."""
    cols = []
    for k in range(3):
        e = np.zeros((1, 3))
        e[0, k] = h
        cols.append((f(p + e) - f(p - e)) / (2.0 * h))
    return np.stack(cols, axis=-1)


# Separations (in units of the kernel scale) where FD is well conditioned for every block: the
# first derivatives come from k ~ k(0) + O(r^2), so at r -> 0 their FD loses digits to cancellation
# (eps k(0) / h against a derivative ~ r); 1e-3 is the smallest r where 1e-6 relative still holds.
FAR = [0.9, 0.5, 0.1, 1e-2, 1e-3]
# Near r = 0 (including exactly 0, and below the FD step) the second-derivative block is O(1) and
# is checked to 1e-6 relative; it is where the thin-plate g2 d d^T = 6 d d^T / r term needs care.
NEAR = [1e-4, 1e-6, 1e-9, 0.0]


@KERNELS
@pytest.mark.parametrize("r_rel", FAR)
def test_first_derivative_blocks_match_finite_differences(kernel: IsotropicKernel, scale: float, r_rel: float) -> None:
    rng = np.random.default_rng(int(r_rel * 1e6) + 1)
    x, y = _pair(r_rel * scale, rng, scale)
    h = 3e-5 * scale  # truncation ~ h^2 |phi'''|, rounding ~ eps k(0) / h: both < 1e-7 of the block
    fd_y = _fd(lambda q: kernel.k(x, q)[0, 0], y, h)  # d k / d y
    fd_x = _fd(lambda q: kernel.k(q, y)[0, 0], x, h)  # d k / d x
    an_fg = kernel.k_fg(x, y)[0, 0]
    an_gf = kernel.k_gf(x, y)[0, 0]
    mag = np.abs(an_fg).max()
    np.testing.assert_allclose(an_fg, fd_y, rtol=1e-6, atol=1e-6 * mag)
    np.testing.assert_allclose(an_gf, fd_x, rtol=1e-6, atol=1e-6 * mag)


@KERNELS
@pytest.mark.parametrize("r_rel", FAR + NEAR)
def test_second_derivative_block_matches_finite_differences(
    kernel: IsotropicKernel, scale: float, r_rel: float
) -> None:
    rng = np.random.default_rng(int(r_rel * 1e9) + 7)
    x, y = _pair(r_rel * scale, rng, scale)
    # k_fg ~ r carries no large constant, so small steps are safe; near 0 the step must be below r
    # (third derivatives of r d grow like 1/r) or, when r < h, the O(h) error is still 1e-8 of 6 R.
    h = (1e-5 if r_rel >= 1e-3 else 1e-8) * scale
    an = kernel.k_gg(x, y)[0, 0]  # [i, j] = d^2 k / d x_i d y_j
    fd_from_fg = _fd(lambda q: kernel.k_fg(q, y)[0, 0], x, h)  # [j, i] = d/dx_i of d k / d y_j
    fd_from_gf = _fd(lambda q: kernel.k_gf(x, q)[0, 0], y, h)  # [i, j] = d/dy_j of d k / d x_i
    mag = np.abs(an).max()
    np.testing.assert_allclose(an, fd_from_fg.T, rtol=1e-6, atol=1e-6 * mag)
    np.testing.assert_allclose(an, fd_from_gf, rtol=1e-6, atol=1e-6 * mag)


@KERNELS
@pytest.mark.parametrize("r_rel", NEAR)
def test_first_derivative_blocks_near_zero(kernel: IsotropicKernel, scale: float, r_rel: float) -> None:
    """Near r = 0 the first-derivative FD is limited by cancellation: check to 1e-6 of the r = 1e-3 value."""
    rng = np.random.default_rng(3)
    x, y = _pair(r_rel * scale, rng, scale)
    h = 3e-5 * scale
    fd_y = _fd(lambda q: kernel.k(x, q)[0, 0], y, h)
    floor = -kernel.radial(np.zeros(1))[1][0] * 1e-3 * scale  # |k_fg| at r = 1e-3 scale
    np.testing.assert_allclose(kernel.k_fg(x, y)[0, 0], fd_y, rtol=1e-6, atol=1e-6 * floor)
    # k_fg = -g1 d exactly: 0 at r = 0, and g1(0) is finite.
    if r_rel == 0.0:
        assert np.all(kernel.k_fg(x, y) == 0.0)


def test_thin_plate_is_exact_at_zero_distance() -> None:
    k = ThinPlateKernel(R)
    x = np.array([[0.1, -0.2, 0.05]])
    assert k.k(x, x)[0, 0] == pytest.approx(R**3, rel=1e-15)
    np.testing.assert_array_equal(k.k_gg(x, x)[0, 0], 6.0 * R * np.eye(3))  # -g1(0) I, no 0/0
    assert k.value_variance == pytest.approx(R**3)
    assert k.gradient_variance == pytest.approx(6.0 * R)


@KERNELS
def test_blocks_are_symmetric_under_swapping_points(kernel: IsotropicKernel, scale: float) -> None:
    rng = np.random.default_rng(5)
    x = rng.uniform(-0.3, 0.3, (6, 3)) * scale
    y = rng.uniform(-0.3, 0.3, (4, 3)) * scale
    np.testing.assert_allclose(kernel.k(x, y), kernel.k(y, x).T, rtol=1e-14)
    np.testing.assert_allclose(kernel.k_gf(x, y), kernel.k_fg(y, x).transpose(1, 0, 2), rtol=1e-14)
    np.testing.assert_allclose(kernel.k_gg(x, y), kernel.k_gg(y, x).transpose(1, 0, 3, 2), rtol=1e-14)


@KERNELS
def test_observation_cov_assembles_the_blocks(kernel: IsotropicKernel, scale: float) -> None:
    rng = np.random.default_rng(6)
    x = rng.uniform(-0.3, 0.3, (5, 3)) * scale
    y = np.vstack([rng.uniform(-0.3, 0.3, (3, 3)) * scale, x[:1]])  # includes r = 0
    K = kernel.observation_cov(x, y).reshape(5, 4, 4, 4)
    np.testing.assert_allclose(K[:, 0, :, 0], kernel.k(x, y), rtol=1e-14)
    np.testing.assert_allclose(K[:, 0, :, 1:], kernel.k_fg(x, y), rtol=1e-14)
    np.testing.assert_allclose(K[:, 1:, :, 0], kernel.k_gf(x, y).transpose(0, 2, 1), rtol=1e-14)
    np.testing.assert_allclose(K[:, 1:, :, 1:], kernel.k_gg(x, y).transpose(0, 2, 1, 3), rtol=1e-14)
    np.testing.assert_allclose(kernel.value_obs_cov(x, y), K[:, 0].reshape(5, 16), rtol=1e-14)


@KERNELS
def test_contractions_match_explicit_blocks(kernel: IsotropicKernel, scale: float) -> None:
    """The fast mean/gradient contractions equal k_* @ w built from the blocks (incl. r = 0)."""
    rng = np.random.default_rng(8)
    y = rng.uniform(-0.3, 0.3, (30, 3)) * scale
    w = rng.standard_normal((30, 4))
    x = np.vstack([rng.uniform(-0.3, 0.3, (200, 3)) * scale, y[:4], y[:2] + 1e-9 * scale])
    ref_value = kernel.value_obs_cov(x, y) @ w.ravel()
    grad_blocks = kernel.observation_cov(x, y).reshape(len(x), 4, 30 * 4)[:, 1:, :]
    ref_grad = grad_blocks @ w.ravel()
    tol = 1e-12 * np.abs(w).sum() * kernel.value_variance
    gtol = 1e-12 * np.abs(w).sum() * kernel.gradient_variance * 10
    assert kernel.compiled() is not None  # the compiled loops (dense_kernels) ...
    np.testing.assert_allclose(kernel.value_contract(x, y, w), ref_value, rtol=0, atol=tol)
    np.testing.assert_allclose(kernel.gradient_contract(x, y, w), ref_grad, rtol=0, atol=gtol)
    # ... and the numpy paths that kernels without them take
    np.testing.assert_allclose(kernel._value_contract_numpy(x, y, w), ref_value, rtol=0, atol=tol)
    np.testing.assert_allclose(kernel._gradient_contract_numpy(x, y, w), ref_grad, rtol=0, atol=gtol)
    np.testing.assert_allclose(kernel._value_obs_cov_numpy(x, y), kernel.value_obs_cov(x, y), rtol=1e-13, atol=0)


def test_range_check_without_distances_is_exact() -> None:
    """check_range passes when the bounding boxes are farther apart than R but every pair is within R."""
    k = ThinPlateKernel(1.0)
    x = np.array([[0.0, 0.0, 0.0], [0.7, 0.7, 0.0]])
    y = np.array([[0.7, 0.0, 0.0], [0.0, 0.7, 0.0]])  # box corners 0.99 apart, every pair 0.7
    k.check_range(np.vstack([x, [[0.7, 0.7, 0.7]]]), y)  # corner bound sqrt(3) 0.7 > 1, every pair <= 0.99
    with pytest.raises(EstimationError, match="R_m"):
        k.check_range(x * 1.5, y * 1.5)
    k.value_contract(x, y, np.ones((2, 4)))


def test_range_check_bounds_each_contact_before_forming_distances(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the two boxes' corners are farther apart than R, the corner of x's box farthest from each
    y decides without the (m, n) distances; a pair beyond R is still refused."""
    k = ThinPlateKernel(1.0)
    x = np.zeros((1, 3))
    y = np.array([[0.8, 0.0, 0.0], [0.0, 0.8, 0.0]])  # box corners 1.13 apart, every pair 0.8
    with monkeypatch.context() as patched:
        patched.setattr(kernels.dense_kernels, "max_distance", lambda *_: pytest.fail("formed the distances"))
        k.check_range(x, y)
    with pytest.raises(EstimationError, match="R_m"):
        k.check_range(x, y * 1.3)


def test_thin_plate_covariance_positive_definite_within_its_valid_span() -> None:
    """Measured limit: with gradient rows PD while the points span 0.8 R; a ball of radius 0.45 R is not."""
    rng = np.random.default_rng(9)
    k = ThinPlateKernel(1.0)

    def ball(radius: float) -> np.ndarray:
        p = rng.uniform(-1, 1, (4000, 3))
        return p[np.linalg.norm(p, axis=1) < 1][:150] * radius

    inside = ball(0.4)
    assert np.linalg.eigvalsh(k.observation_cov(inside, inside))[0] > 0.0
    outside = ball(0.45)
    assert np.linalg.eigvalsh(k.observation_cov(outside, outside))[0] < 0.0


def test_thin_plate_rejects_distances_beyond_r() -> None:
    k = ThinPlateKernel(0.1)
    x = np.zeros((1, 3))
    k.k(x, np.array([[0.1, 0.0, 0.0]]))  # exactly R is fine
    with pytest.raises(EstimationError, match="R_m"):
        k.k(x, np.array([[0.1001, 0.0, 0.0]]))
    with pytest.raises(EstimationError, match="R_m"):
        k.value_contract(x, np.array([[0.0, 0.2, 0.0]]), np.ones((1, 4)))
    with pytest.raises(EstimationError, match="R_m"):
        k.gradient_contract(x, np.array([[0.0, 0.2, 0.0]]), np.ones((1, 4)))


def test_range_check_finds_the_farthest_pair_on_either_side() -> None:
    k = ThinPlateKernel(1.0)
    w = np.ones((2, 4))
    origin = np.zeros((1, 3))
    # contacts either side of the query: the farthest is 1.5 m away on -x, though the box of y ends at +0.5
    straddle = np.array([[-1.5, 0.0, 0.0], [0.5, 0.0, 0.0]])
    for contract in (k.value_contract, k.gradient_contract):
        with pytest.raises(EstimationError, match="R_m"):
            contract(origin, straddle, w)
    # queries either side of one contact: the query at 2 m is beyond R, the one at 0 m is not
    with pytest.raises(EstimationError, match="R_m"):
        k.value_contract(np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), origin, w[:1])
    # within R on both sides (0.9 m each way) passes
    k.check_range(origin, np.array([[-0.9, 0.0, 0.0], [0.9, 0.0, 0.0]]))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_kernel_parameters_are_config_errors(bad: float) -> None:
    with pytest.raises(ConfigError):
        ThinPlateKernel(bad)
    with pytest.raises(ConfigError):
        GaussianKernel(bad, 1.0)
    with pytest.raises(ConfigError):
        GaussianKernel(1.0, bad)


def test_a_kernel_without_compiled_loops_takes_the_numpy_paths_in_row_chunks() -> None:
    """More query points than one chunk holds: the numpy paths agree with the compiled loops."""

    class NumpyThinPlate(ThinPlateKernel):
        def compiled(self) -> None:
            return None

    rng = np.random.default_rng(10)
    y = rng.uniform(-0.1, 0.1, (40, 3))
    w = rng.standard_normal((40, 4))
    x = rng.uniform(-0.1, 0.1, (9000, 3))  # 360,000 pairs: two chunks of 2^18 entries at most
    compiled, numpy_only = ThinPlateKernel(0.5), NumpyThinPlate(0.5)
    np.testing.assert_allclose(numpy_only.value_contract(x, y, w), compiled.value_contract(x, y, w), rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        numpy_only.gradient_contract(x, y, w), compiled.gradient_contract(x, y, w), rtol=0, atol=1e-11
    )
