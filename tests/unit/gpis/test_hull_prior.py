"""The smoothed convex hull as the prior of the whole-object mesh (nodes/gpis/hull_prior.py,
GPIS.replaced_prior, GPISNodeConfig.whole_prior)."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.errors import EstimationError
from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.hull_prior import SmoothHull, even_directions
from palpate.nodes.gpis.local import AutoGPIS, LocalGPIS
from palpate.nodes.gpis.session import GPISNodeConfig, GPISSession

TAU = 0.006


def cube_corners(edge: float) -> np.ndarray:
    return edge * (np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float) - 0.5)


def ellipsoid(n: int, axes: tuple[float, float, float], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n points (n, 3) on an ellipsoid of semi-axes `axes` and their outward unit normals."""
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = np.array(axes)
    P = d * a
    N = P / a**2
    return P, N / np.linalg.norm(N, axis=1, keepdims=True)


def test_even_directions_are_unit_vectors_spread_over_the_sphere() -> None:
    U = even_directions(256)
    np.testing.assert_allclose(np.linalg.norm(U, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(U.mean(axis=0), 0.0, atol=5e-3)  # no side favoured
    nearest = np.sort(U @ U.T, axis=1)[:, -2]  # cosine to the nearest other direction
    angles = np.degrees(np.arccos(nearest))
    assert angles.min() > 9.0 and angles.max() < 16.0  # 4 pi / 256 sr each: about 12.7 deg apart


def test_the_smooth_hull_lies_between_the_support_planes_minus_tau_log_k_and_them() -> None:
    hull = SmoothHull.of(cube_corners(0.05), TAU, 256)
    assert hull is not None
    support = (cube_corners(0.05) @ hull.U.T).max(axis=0)
    np.testing.assert_allclose(hull.d, -support)
    x = np.random.default_rng(1).uniform(-0.08, 0.08, size=(500, 3))
    hard = (x @ hull.U.T + hull.d).max(axis=1)
    m = hull.mean(x)
    assert np.all(m >= hard - TAU * np.log(256) - 1e-15) and np.all(m <= hard + 1e-15)
    # the mean over the directions: at the centre of a ball of contacts, minus its radius, whatever K
    ball, _ = ellipsoid(400, (0.03, 0.03, 0.03))
    for directions in (64, 256, 1024):
        prior = SmoothHull.of(ball, TAU, directions)
        assert prior is not None
        assert prior.mean(np.zeros((1, 3)))[0] == pytest.approx(-0.03, abs=5e-4)
    # far beyond the top face the gradient blends the directions nearest +z (the lattice's lie a few
    # degrees off it); beyond a side face, that side's
    g = hull.gradient(np.array([[0.0, 0.0, 0.5], [0.5, 0.0, 0.0]]))
    assert g[0, 2] > 0.98 and np.hypot(g[0, 0], g[0, 1]) < 0.05
    assert g[1, 0] > 0.98 and np.hypot(g[1, 1], g[1, 2]) < 0.05


def test_the_smooth_hull_gradient_is_the_derivative_of_its_mean() -> None:
    P, _ = ellipsoid(60, (0.05, 0.03, 0.02))
    hull = SmoothHull.of(P, TAU, 64)
    assert hull is not None
    x = np.random.default_rng(2).uniform(-0.06, 0.06, size=(50, 3))
    h = 1e-7
    numeric = np.column_stack([(hull.mean(x + h * e) - hull.mean(x - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(hull.gradient(x), numeric, atol=1e-6)
    value, grad = hull.mean_and_gradient(x)
    np.testing.assert_array_equal(value, hull.mean(x))
    np.testing.assert_array_equal(grad, hull.gradient(x))
    big = np.random.default_rng(3).uniform(-0.06, 0.06, size=(5000, 3))  # more than one chunk of 64 planes
    one_by_one = np.concatenate([hull.mean(big[i : i + 1]) for i in range(len(big))])
    np.testing.assert_allclose(hull.mean(big), one_by_one, rtol=0, atol=1e-15)  # BLAS rounds by batch size


def test_no_smooth_hull_where_the_contacts_span_no_solid() -> None:
    assert SmoothHull.of(cube_corners(0.05)[:3], TAU, 256) is None  # fewer than four
    flat = cube_corners(0.05)
    flat[:, 2] = 0.0
    assert SmoothHull.of(flat, TAU, 256) is None  # all in a plane
    slab = cube_corners(0.05) * [1.0, 1.0, 0.2]  # 1 cm thick: less than 2 tau across
    assert SmoothHull.of(slab, TAU, 256) is None
    assert SmoothHull.of(slab, 0.004, 256) is not None


def reference_mean(gp: GPIS, prior: SmoothHull, x: np.ndarray) -> np.ndarray:
    """m(x) + k(x, X) K~^{-1} (y - m_obs) from the covariance solved afresh (no factor)."""
    P, N = gp.positions_m, gp.normals
    m, g = prior.mean_and_gradient(P)
    targets = np.concatenate([-m[:, None], N - g], axis=1).ravel()
    alpha = np.linalg.solve(gp.observation_covariance(), targets).reshape(-1, 4)
    return prior.mean(x) + gp.kernel.value_contract(x, P, alpha)


def test_a_replaced_prior_is_the_gp_with_that_prior_and_leaves_it_as_it_was() -> None:
    P, N = ellipsoid(40, (0.05, 0.03, 0.02))
    gp = GPIS(GPISConfig())
    gp.add_contacts(P, N)
    x = np.random.default_rng(3).uniform(-0.06, 0.06, size=(30, 3))
    before_mean, before_grad = gp.mean(x), gp.gradient(x)
    hull = SmoothHull.of(P, TAU, 256)
    assert hull is not None
    with gp.replaced_prior(hull):
        replaced = gp.mean(x)
        np.testing.assert_allclose(replaced, reference_mean(gp, hull, x), atol=1e-9)
        h = 1e-6  # the gradient (the whole mesh's vertex normals) is that mean's
        numeric = np.column_stack([(gp.mean(x + h * e) - gp.mean(x - h * e)) / (2 * h) for e in np.eye(3)])
        np.testing.assert_allclose(gp.gradient(x), numeric, atol=1e-6)
        assert np.abs(replaced - before_mean).max() > 1e-4  # another prior, another mean away from the contacts
        with pytest.raises(EstimationError, match="while the prior is replaced"):
            gp.add_contact([0.1, 0.0, 0.0], [1.0, 0.0, 0.0])
        with pytest.raises(EstimationError, match="replaced already"), gp.replaced_prior(hull):
            pass
        gp.add_free_space(np.array([[0.0, 0.0, 0.05]]), 0.008)
    assert gp.n_free_space == 0 and gp.n_contacts == 40  # the block's free space went with it
    np.testing.assert_array_equal(gp.mean(x), before_mean)
    np.testing.assert_array_equal(gp.gradient(x), before_grad)


def test_an_error_within_the_block_leaves_the_gp_as_it_was() -> None:
    P, N = ellipsoid(40, (0.05, 0.03, 0.02))
    gp = GPIS(GPISConfig())
    gp.add_contacts(P, N)
    x = np.random.default_rng(4).uniform(-0.06, 0.06, size=(30, 3))
    before = gp.mean(x)
    hull = SmoothHull.of(P, TAU, 256)
    assert hull is not None
    with pytest.raises(RuntimeError, match="meshing failed"), gp.replaced_prior(hull):
        gp.add_free_space(np.array([[0.0, 0.0, 0.05]]), 0.008)
        raise RuntimeError("meshing failed")
    assert gp.n_free_space == 0
    np.testing.assert_array_equal(gp.mean(x), before)
    with gp.replaced_prior(hull):  # and it can be replaced again
        np.testing.assert_allclose(gp.mean(x), reference_mean(gp, hull, x), atol=1e-9)


def test_a_prior_is_not_replaced_under_free_space_nor_in_the_local_estimator() -> None:
    P, N = ellipsoid(40, (0.05, 0.03, 0.02))
    hull = SmoothHull.of(P, TAU, 256)
    assert hull is not None
    gp = GPIS(GPISConfig())
    gp.add_contacts(P, N)
    gp.add_free_space(np.array([[0.0, 0.0, 0.05]]), 0.008)
    with pytest.raises(EstimationError, match="free-space"), gp.replaced_prior(hull):
        pass
    local = LocalGPIS(GPISConfig())
    local.add_contacts(P, N)
    assert not local.supports_replaced_prior
    with pytest.raises(EstimationError, match="local GPIS"):
        local.replaced_prior(hull)
    auto = AutoGPIS(GPISConfig(estimator="auto", auto_local_above_contacts=50))
    auto.add_contacts(P, N)
    assert auto.supports_replaced_prior
    more = ellipsoid(20, (0.05, 0.03, 0.02), seed=1)
    with pytest.raises(EstimationError, match="while the prior is replaced"), auto.replaced_prior(hull):
        auto.add_contacts(*more)  # would switch to the local estimator inside the block
    assert not auto.is_local and auto.n_contacts == 40
    auto.add_contacts(*more)
    assert auto.is_local and not auto.supports_replaced_prior


def test_the_hull_prior_changes_the_whole_mesh_only() -> None:
    """The local meshes (the planner's) are the same with and without it; the whole-object mesh is not;
    with too few contacts for a solid hull the mesh keeps the GP's prior, and says so."""
    P, N = ellipsoid(60, (0.05, 0.03, 0.02))
    sessions = {prior: GPISSession(GPISNodeConfig(whole_prior=prior)) for prior in ("same", "hull")}
    for session in sessions.values():
        session.touch(P[0], N[0])
    sessions["hull"].whole(variance=False)
    assert sessions["hull"].take_counts() == {"whole_prior_kept": 1}
    for p, n in zip(P[1:], N[1:], strict=True):
        local = [session.touch(p, n).vertices for session in sessions.values()]
        np.testing.assert_array_equal(*local)
    same, hull = (session.whole(variance=True) for session in sessions.values())
    assert sessions["hull"].take_counts() == {}
    assert not np.array_equal(same.vertices, hull.vertices)
    assert len(hull.vertex_variance) == len(hull.vertices)
    # both close the ellipsoid: every vertex within a millimetre of it
    for mesh in (same, hull):
        radial = np.linalg.norm(mesh.vertices / [0.05, 0.03, 0.02], axis=1)
        assert np.abs(radial - 1.0).max() * 0.02 < 1e-3


def test_the_local_estimator_keeps_its_own_prior_and_says_so() -> None:
    P, N = ellipsoid(60, (0.05, 0.03, 0.02))
    session = GPISSession(GPISNodeConfig(whole_prior="hull", gp=GPISConfig(estimator="local")))
    session.whole(variance=False)  # no contact yet: nothing to keep
    assert session.take_counts() == {}
    for p, n in zip(P, N, strict=True):
        session.touch(p, n)
    assert not session.whole(variance=False).is_empty
    assert session.take_counts() == {"whole_prior_kept": 1}
