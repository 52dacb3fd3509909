"""GPIS core: incremental factorisation, posterior, sign convention, robustness at the extremes."""

from __future__ import annotations

import copy
import time

import numpy as np
import pytest

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.gpis.core import GPIS, GPISConfig

AXES = np.array([0.06, 0.04, 0.03])  # ellipsoid semi-axes (m), a YCB-sized object
CENTRE = np.array([0.02, -0.01, 0.1])


def ellipsoid(n: int, rng: np.random.Generator, axes: np.ndarray = AXES) -> tuple[np.ndarray, np.ndarray]:
    """n points on the ellipsoid around CENTRE and their outward unit normals."""
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = u * axes
    normal = p / axes**2
    return CENTRE + p, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def sphere(n: int, rng: np.random.Generator, radius: float, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return centre + radius * u, u


def _fresh_solve_mean_var(gp: GPIS, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slow reference: Eq. 2 and 6 with a dense solve of K + noise built from scratch."""
    K = gp.observation_covariance()
    P, N = gp.positions_m, gp.normals
    y = np.empty((len(P), 4))
    y[:, 0] = -gp.prior_mean(P)
    c = gp.prior_centre_m
    assert c is not None
    y[:, 1:] = N - (P - c) / np.linalg.norm(P - c, axis=1, keepdims=True) * gp.config.prior_scale
    ks = gp.kernel.value_obs_cov(x, P)
    mean = gp.prior_mean(x) + ks @ np.linalg.solve(K, y.ravel())
    var = gp.kernel.value_variance - np.einsum("ij,ji->i", ks, np.linalg.solve(K, ks.T))
    return mean, var


# --- configuration ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs",
    [
        {"kernel": "rbf"},
        {"prior": "cube"},
        {"R_m": 0.0},
        {"R_m": float("nan")},
        {"length_scale_m": -1.0},
        {"value_noise_m": -1e-4},
        {"gradient_noise": float("inf")},
        {"gaussian_variance_m2": 0.0},
        {"value_noise_m": 0.0, "gradient_noise": 0.0, "jitter": 0.0},
    ],
)
def test_bad_config_is_rejected_with_the_value(kwargs: dict[str, object]) -> None:
    with pytest.raises(ConfigError, match=next(iter(kwargs))):
        GPISConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("zero", ["value_noise_m", "gradient_noise"])
def test_no_jitter_needs_both_noises_as_duplicate_contacts_would_repeat_a_row(zero: str) -> None:
    """An outside audit: value_noise_m = jitter = 0 was accepted (only all three 0 were refused), and three
    identical contacts then failed with advice about R_m."""
    with pytest.raises(ConfigError, match=rf"^GPISConfig: {zero} and jitter are 0; duplicate contacts"):
        GPISConfig(**{zero: 0.0, "jitter": 0.0})  # type: ignore[arg-type]
    gp = GPIS(GPISConfig(**{zero: 0.0}))  # type: ignore[arg-type]  # the default jitter holds them
    gp.add_contacts(np.repeat([[0.0, 0.0, 0.05]], 3, axis=0), np.repeat([[0.0, 0.0, 1.0]], 3, axis=0))
    assert gp.n_contacts == 3


def test_for_object_size_scales_lengths_only() -> None:
    base, big = GPISConfig(), GPISConfig.for_object_size(1.0, gradient_noise=0.2)
    assert big.R_m == pytest.approx(5 * base.R_m)
    assert big.value_noise_m == pytest.approx(5 * base.value_noise_m)
    assert big.prior_radius_m == pytest.approx(5 * base.prior_radius_m)
    assert big.length_scale_m == pytest.approx(5 * base.length_scale_m)
    assert big.thin_plate_scale == pytest.approx(base.thin_plate_scale / 5)
    assert big.gradient_noise == 0.2 and big.jitter == base.jitter


def test_default_gaussian_amplitude_gives_unit_gradient_variance() -> None:
    # s2 = sigma^2 / 2, so Var df/dx_i = -g1(0) = 2 s2 / sigma^2 = 1, the variance of a unit normal's component
    kernel = GPISConfig(kernel="gaussian", length_scale_m=0.04).make_kernel()
    assert kernel.value_variance == pytest.approx(0.04**2 / 2, rel=1e-12)
    assert kernel.gradient_variance == pytest.approx(1.0, rel=1e-12)
    explicit = GPISConfig(kernel="gaussian", length_scale_m=0.04, gaussian_variance_m2=0.3).make_kernel()
    assert explicit.value_variance == pytest.approx(0.3)
    assert explicit.gradient_variance == pytest.approx(2 * 0.3 / 0.04**2)  # 2 s2 / sigma^2


# --- factorisation ----------------------------------------------------------------------------------
def test_incremental_factor_equals_fresh_cholesky_after_200_contacts() -> None:
    rng = np.random.default_rng(0)
    P, N = ellipsoid(200, rng)
    gp = GPIS()
    for p, n in zip(P, N, strict=True):
        gp.add_contact(p, n)
    L = gp.cholesky_factor()
    fresh = np.linalg.cholesky(gp.observation_covariance())
    assert L.shape == (800, 800)
    np.testing.assert_allclose(L, fresh, rtol=0, atol=1e-9 * np.abs(fresh).max())
    np.testing.assert_allclose(L @ L.T, gp.observation_covariance(), rtol=0, atol=1e-12)


def test_batch_and_single_updates_agree() -> None:
    rng = np.random.default_rng(1)
    P, N = ellipsoid(40, rng)
    one = GPIS()
    for p, n in zip(P, N, strict=True):
        one.add_contact(p, n)
    batch = GPIS()
    batch.add_contacts(P[:15], N[:15])
    batch.add_contacts(P[15:], N[15:])
    L = one.cholesky_factor()
    np.testing.assert_allclose(batch.cholesky_factor(), L, rtol=0, atol=1e-9 * np.abs(L).max())
    x = CENTRE + rng.uniform(-0.07, 0.07, (50, 3))
    np.testing.assert_allclose(batch.mean(x), one.mean(x), rtol=0, atol=1e-10)


def test_single_update_factorises_only_the_new_4x4_block(monkeypatch: pytest.MonkeyPatch) -> None:
    """O(n^2) per contact: the only Cholesky in add_contact is of the 4 x 4 Schur complement."""
    rng = np.random.default_rng(2)
    P, N = ellipsoid(60, rng)
    gp = GPIS()
    gp.add_contacts(P[:50], N[:50])
    sizes: list[tuple[int, ...]] = []
    real = np.linalg.cholesky

    def spy(a: np.ndarray) -> np.ndarray:
        sizes.append(a.shape)
        return real(a)

    monkeypatch.setattr(np.linalg, "cholesky", spy)
    for p, n in zip(P[50:], N[50:], strict=True):
        gp.add_contact(p, n)
    assert sizes == [(4, 4)] * 10
    monkeypatch.undo()
    L = gp.cholesky_factor()
    np.testing.assert_allclose(L, np.linalg.cholesky(gp.observation_covariance()), rtol=0, atol=1e-9 * np.abs(L).max())


# --- posterior ------------------------------------------------------------------------------------
@pytest.mark.parametrize("kernel", ["thin_plate", "gaussian"])
def test_mean_is_zero_at_contacts_and_gradient_follows_normals(kernel: str) -> None:
    rng = np.random.default_rng(3)
    P, N = ellipsoid(80, rng)
    gp = GPIS(GPISConfig(kernel=kernel), prior_centre_m=CENTRE)
    gp.add_contacts(P, N)
    assert np.abs(gp.mean(P)).max() < 1e-5  # value noise is 1e-4 m
    g = gp.gradient(P)
    cos = np.einsum("ij,ij->i", g, N) / np.linalg.norm(g, axis=1)
    assert cos.min() > 0.999


@pytest.mark.parametrize("kernel", ["thin_plate", "gaussian"])
def test_mean_and_variance_match_a_dense_solve(kernel: str) -> None:
    rng = np.random.default_rng(4)
    P, N = ellipsoid(30, rng)
    gp = GPIS(GPISConfig(kernel=kernel))
    for p, n in zip(P, N, strict=True):
        gp.add_contact(p, n)
    x = np.vstack([CENTRE + rng.uniform(-0.08, 0.08, (40, 3)), P[:3]])
    mean, var = gp.mean_and_variance(x)
    ref_mean, ref_var = _fresh_solve_mean_var(gp, x)
    np.testing.assert_allclose(mean, ref_mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(var, np.maximum(ref_var, 0), rtol=0, atol=1e-9 * gp.kernel.value_variance)
    assert np.all(var >= 0) and np.all(var <= gp.kernel.value_variance)
    assert var[-3:].max() < 2e-8  # at contacts: about the value noise variance (1e-8 m^2)
    assert np.median(var[:-3]) > 10 * var[-3:].max()


def test_gradient_is_the_derivative_of_the_mean() -> None:
    rng = np.random.default_rng(5)
    P, N = ellipsoid(50, rng)
    gp = GPIS()
    gp.add_contacts(P, N)
    x = CENTRE + rng.uniform(-0.08, 0.08, (20, 3))
    h = 1e-6
    fd = np.stack([(gp.mean(x + h * e) - gp.mean(x - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(gp.gradient(x), fd, rtol=0, atol=1e-7)


@pytest.mark.parametrize("prior", ["sphere", "zero"])
def test_sign_is_negative_inside_and_positive_outside_a_sphere(prior: str) -> None:
    rng = np.random.default_rng(6)
    centre, radius = np.array([0.1, 0.0, -0.05]), 0.04
    P, N = sphere(60, rng, radius, centre)
    gp = GPIS(GPISConfig(prior=prior))
    gp.add_contacts(P, N)
    u = N[:20]  # directions through contacts, and new random ones
    v = rng.standard_normal((20, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for d in (u, v):
        assert np.all(gp.mean(centre + 0.9 * radius * d) < 0)
        assert np.all(gp.mean(centre + 1.1 * radius * d) > 0)
    if prior == "sphere":  # the prior fixes the sign far from the contacts too
        assert gp.mean(centre[None])[0] < 0
        assert np.all(gp.mean(centre + 2.5 * radius * v) > 0)
    # On the contacts' sphere f is nearly the signed distance: f(0.9 r) ~ -0.1 r.
    np.testing.assert_allclose(gp.mean(centre + 0.9 * radius * v), -0.1 * radius, atol=0.2 * 0.1 * radius)


def test_default_prior_centre_is_inside_the_first_contact() -> None:
    gp = GPIS(GPISConfig(prior_radius_m=0.01))
    with pytest.raises(EstimationError, match="prior_centre_m"):
        gp.mean(np.zeros((1, 3)))
    gp.add_contact([0.0, 0.0, 0.05], [0.0, 0.0, 2.0])  # a non-unit normal is normalised
    np.testing.assert_allclose(gp.prior_centre_m, [0.0, 0.0, 0.04])
    np.testing.assert_allclose(gp.normals, [[0.0, 0.0, 1.0]])
    given = GPIS(prior_centre_m=[0.1, 0.2, 0.3])
    np.testing.assert_allclose(given.mean(np.array([[0.1, 0.2, 0.3]])), [-given.config.prior_radius_m])
    assert given.variance(np.zeros((2, 3))) == pytest.approx(given.kernel.value_variance)


# --- robustness ----------------------------------------------------------------------------------
def test_contacts_one_micrometre_apart_and_duplicates() -> None:
    rng = np.random.default_rng(7)
    P, N = ellipsoid(30, rng)
    gp = GPIS()
    gp.add_contacts(P, N)
    offset = 1e-6 * np.array([0.6, 0.0, 0.8])
    tilted = N[0] + np.array([0.01, -0.01, 0.0])
    gp.add_contact(P[0] + offset, tilted)  # 1 um from contact 0, normal 0.8 deg off
    for _ in range(3):
        gp.add_contact(P[1], N[1])  # exact duplicates
    L = gp.cholesky_factor()
    assert np.all(np.isfinite(L)) and np.all(np.diag(L) > 0)
    np.testing.assert_allclose(L, np.linalg.cholesky(gp.observation_covariance()), rtol=0, atol=1e-9)
    assert np.abs(gp.mean(P)).max() < 1e-5
    x = CENTRE + rng.uniform(-0.07, 0.07, (30, 3))
    ref_mean, _ = _fresh_solve_mean_var(gp, x)
    np.testing.assert_allclose(gp.mean(x), ref_mean, rtol=0, atol=1e-9)


def test_thousand_contacts_stay_accurate_and_fast() -> None:
    rng = np.random.default_rng(8)
    P, N = ellipsoid(1000, rng)
    gp = GPIS()
    for s in range(0, 999, 333):
        gp.add_contacts(P[s : s + 333], N[s : s + 333])
    elapsed = []
    for trial in [copy.deepcopy(gp), copy.deepcopy(gp), gp]:  # best of 3: the machine is shared
        t0 = time.perf_counter()
        trial.add_contact(P[999], N[999])
        elapsed.append(time.perf_counter() - t0)
    assert gp.n_contacts == 1000
    t_add = min(elapsed)  # about 0.15 s on the 2-core CI machine
    assert t_add < 1.0, f"one update at 1000 contacts took {t_add:.3f} s"
    assert np.abs(gp.mean(P)).max() < 1e-5
    g = gp.gradient(P[::10])
    assert (np.einsum("ij,ij->i", g, N[::10]) / np.linalg.norm(g, axis=1)).min() > 0.999
    # L L^T = K + noise on a sample of 25 contacts' rows (the full product is 1e11 flops).
    L = gp.cholesky_factor()
    rows = rng.choice(1000, 25, replace=False)
    K_rows = gp.kernel.observation_cov(P[rows], P)
    K_rows[np.arange(100), (4 * rows[:, None] + np.arange(4)).ravel()] += np.tile(gp.observation_noise, 25)
    L_rows = L[(4 * rows[:, None] + np.arange(4)).ravel()]
    np.testing.assert_allclose(L_rows @ L.T, K_rows, rtol=0, atol=1e-12 * np.abs(K_rows).max())
    # True-surface check: points 2 mm inside / outside the ellipsoid have the right sign.
    u = rng.standard_normal((200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    surf = u * AXES
    normal = surf / AXES**2
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert np.all(gp.mean(CENTRE + surf - 0.002 * normal) < 0)
    assert np.all(gp.mean(CENTRE + surf + 0.002 * normal) > 0)


@pytest.mark.parametrize("kernel", ["thin_plate", "gaussian"])
def test_scaled_config_gives_the_scaled_fit(kernel: str) -> None:
    """for_object_size is exactly scale invariant: f_s(s x) = s f(x), Var_s(s x) = s^2 Var(x)."""
    rng = np.random.default_rng(12)
    P, N = ellipsoid(40, rng)
    x = CENTRE + rng.uniform(-0.07, 0.07, (30, 3))
    ref = GPIS(GPISConfig.for_object_size(0.2, kernel=kernel))
    ref.add_contacts(P, N)
    for s in (0.025, 5.0):
        gp = GPIS(GPISConfig.for_object_size(0.2 * s, kernel=kernel))
        gp.add_contacts(s * P, N)
        np.testing.assert_allclose(gp.mean(s * x), s * ref.mean(x), rtol=1e-7, atol=1e-9 * s)
        np.testing.assert_allclose(gp.variance(s * x), s**2 * ref.variance(x), rtol=1e-6, atol=1e-12 * s**2)


@pytest.mark.parametrize("size_m", [0.005, 1.0])
def test_tiny_and_huge_objects(size_m: float) -> None:
    """A 5 mm and a 1 m sphere (diameter size_m) with the config scaled to the object."""
    rng = np.random.default_rng(9)
    radius, centre = size_m / 2, np.array([0.3, -0.2, 0.1])
    P, N = sphere(60, rng, radius, centre)
    gp = GPIS(GPISConfig.for_object_size(size_m))
    for p, n in zip(P, N, strict=True):
        gp.add_contact(p, n)
    L = gp.cholesky_factor()
    np.testing.assert_allclose(L, np.linalg.cholesky(gp.observation_covariance()), rtol=0, atol=1e-9 * np.abs(L).max())
    assert np.abs(gp.mean(P)).max() < gp.config.value_noise_m  # within the value noise (5e-4 x size)
    v = rng.standard_normal((50, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(gp.mean(centre + 0.8 * radius * v), -0.2 * radius, atol=0.03 * radius)
    np.testing.assert_allclose(gp.mean(centre + 1.2 * radius * v), 0.2 * radius, atol=0.03 * radius)


def test_default_config_rejects_a_1m_object_with_advice() -> None:
    rng = np.random.default_rng(10)
    P, N = sphere(20, rng, 0.5, np.zeros(3))
    gp = GPIS()
    with pytest.raises(EstimationError, match="R_m"):
        gp.add_contacts(P, N)
    assert gp.n_contacts == 0


@pytest.mark.parametrize(
    ("normal", "message"),
    [
        ([0.0, 0.0, 0.0], "zero length"),
        ([1e-12, 0.0, 0.0], "zero length"),
        ([np.nan, 0.0, 1.0], "not finite"),
        ([np.inf, 0.0, 0.0], "not finite"),
    ],
)
def test_bad_normals_are_rejected_and_leave_the_state_unchanged(normal: list[float], message: str) -> None:
    gp = GPIS()
    gp.add_contact([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    L = gp.cholesky_factor()
    with pytest.raises(EstimationError, match=message):
        gp.add_contact([0.01, 0.0, 0.0], normal)
    with pytest.raises(EstimationError, match=message):
        gp.add_contacts([[0.02, 0.0, 0.0], [0.01, 0.0, 0.0]], [[1.0, 0.0, 0.0], normal])
    assert gp.n_contacts == 1
    np.testing.assert_array_equal(gp.cholesky_factor(), L)


def test_bad_positions_and_shapes_are_rejected() -> None:
    gp = GPIS()
    with pytest.raises(EstimationError, match="not finite"):
        gp.add_contact([np.nan, 0.0, 0.0], [0.0, 0.0, 1.0])
    with pytest.raises(EstimationError, match="shape"):
        gp.add_contact([0.0, 0.0], [0.0, 0.0, 1.0])
    with pytest.raises(EstimationError, match="shape"):
        gp.add_contacts(np.zeros((2, 3)), np.ones((3, 3)))
    gp.add_contacts(np.zeros((0, 3)), np.zeros((0, 3)))  # empty batch: no-op
    assert gp.n_contacts == 0


def test_span_beyond_positive_definite_range_raises_atomically() -> None:
    """Contacts on a sphere of diameter 0.9 R: the thin-plate covariance is indefinite -> named error."""
    rng = np.random.default_rng(11)
    P, N = sphere(150, rng, 0.045, np.zeros(3))
    gp = GPIS(GPISConfig(R_m=0.1))
    gp.add_contacts(P[:5], N[:5])
    with pytest.raises(EstimationError, match=r"positive definite.*R_m"):
        gp.add_contacts(P[5:], N[5:])
    assert gp.n_contacts == 5


def test_queries_beyond_r_raise() -> None:
    gp = GPIS(GPISConfig(R_m=0.2))
    gp.add_contact([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    gp.mean(np.array([[0.19, 0.0, 0.0]]))
    for query in (gp.mean, gp.gradient, gp.variance):
        with pytest.raises(EstimationError, match="R_m"):
            query(np.array([[0.0, 0.25, 0.0]]))


def test_contradictory_normals_at_one_point_stay_positive_definite() -> None:
    """Opposite normals 1 um apart (a sensor glitch): the noise keeps K + noise positive definite."""
    rng = np.random.default_rng(21)
    P, N = ellipsoid(40, rng)
    gp = GPIS()
    gp.add_contacts(P, N)
    gp.add_contact(P[5] + 1e-6, -N[5])
    gp.add_contact(P[5] - 1e-6, N[5])
    L = gp.cholesky_factor()
    assert np.all(np.isfinite(L)) and np.all(np.diag(L) > 0)
    x = CENTRE + rng.uniform(-0.07, 0.07, (30, 3))
    ref_mean, ref_var = _fresh_solve_mean_var(gp, x)
    np.testing.assert_allclose(gp.mean(x), ref_mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gp.variance(x), np.maximum(ref_var, 0), rtol=0, atol=1e-12)
    # the two opposite normals average out: the gradient at that point is much shorter than 1
    assert np.linalg.norm(gp.gradient(P[5:6])[0]) < 0.5
