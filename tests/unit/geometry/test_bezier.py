"""Cubic Bezier kernels against finite differences, fine polylines and brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from palpate.geometry.bezier import (
    Cubic,
    approach_curve,
    bezier_derivative,
    bezier_length,
    bezier_point,
    bezier_second_derivative,
    recovery_curve,
)


def polyline_length(P: np.ndarray, tau0: float = 0.0, tau1: float = 1.0, n: int = 200_001) -> float:
    pts = bezier_point(P, np.linspace(tau0, tau1, n))
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _de_casteljau(p: np.ndarray, t: float) -> np.ndarray:
    """Slow reference: repeated linear interpolation of the control points."""
    pts = [np.asarray(q, dtype=np.float64) for q in p]
    while len(pts) > 1:
        pts = [(1 - t) * a + t * b for a, b in itertools.pairwise(pts)]
    return pts[0]


@pytest.fixture
def curves() -> np.ndarray:
    return np.random.default_rng(1).normal(scale=0.05, size=(6, 4, 3))


def test_endpoints_and_end_tangents(curves: np.ndarray) -> None:
    pts = bezier_point(curves, [0.0, 1.0])
    np.testing.assert_allclose(pts[:, 0], curves[:, 0], atol=1e-15)
    np.testing.assert_allclose(pts[:, 1], curves[:, 3], atol=1e-15)
    d = bezier_derivative(curves, [0.0, 1.0])
    np.testing.assert_allclose(d[:, 0], 3 * (curves[:, 1] - curves[:, 0]), atol=1e-15)
    np.testing.assert_allclose(d[:, 1], 3 * (curves[:, 3] - curves[:, 2]), atol=1e-15)


def test_points_match_de_casteljau(curves: np.ndarray) -> None:
    tau = np.linspace(0.0, 1.0, 11)
    pts = bezier_point(curves, tau)
    assert pts.shape == (len(curves), 11, 3)
    for P, row in zip(curves, pts, strict=True):
        for t, point in zip(tau, row, strict=True):
            np.testing.assert_allclose(point, _de_casteljau(P, t), rtol=0, atol=1e-15)


def test_derivatives_match_finite_differences(curves: np.ndarray) -> None:
    tau = np.linspace(0.05, 0.95, 19)
    h = 1e-6
    fd1 = (bezier_point(curves, tau + h) - bezier_point(curves, tau - h)) / (2 * h)
    np.testing.assert_allclose(bezier_derivative(curves, tau), fd1, rtol=1e-6, atol=1e-9)
    fd2 = (bezier_derivative(curves, tau + h) - bezier_derivative(curves, tau - h)) / (2 * h)
    np.testing.assert_allclose(bezier_second_derivative(curves, tau), fd2, rtol=1e-6, atol=1e-8)


def test_length_matches_fine_polyline(curves: np.ndarray) -> None:
    lengths = bezier_length(curves)
    assert lengths.shape == (6,)
    reference = [polyline_length(P) for P in curves]
    np.testing.assert_allclose(lengths, reference, rtol=1e-6)


def test_length_broadcasts_over_leading_dims(curves: np.ndarray) -> None:
    grid = curves.reshape(2, 3, 4, 3)
    np.testing.assert_allclose(bezier_length(grid), bezier_length(curves).reshape(2, 3), rtol=1e-14)


def test_length_of_a_straight_curve_is_the_chord() -> None:
    a, b = np.array([0.01, -0.02, 0.03]), np.array([0.05, 0.02, -0.01])
    P = np.stack([a, a + (b - a) / 3, a + 2 * (b - a) / 3, b])
    np.testing.assert_allclose(bezier_length(P), np.linalg.norm(b - a), rtol=1e-13)


def test_partial_lengths_add_up(curves: np.ndarray) -> None:
    P = curves[0]
    np.testing.assert_allclose(bezier_length(P, 0.0, 0.37) + bezier_length(P, 0.37, 1.0), bezier_length(P), rtol=1e-6)
    np.testing.assert_allclose(bezier_length(P, 0.2, 0.6), polyline_length(P, 0.2, 0.6), rtol=1e-6)


def test_length_near_an_exact_cusp() -> None:
    # T'(0.3) = 0: choose p2 - p1 so that 0.49 a + 0.42 b + 0.09 c = 0
    a, c = np.array([1.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.0])
    b = -(0.49 * a + 0.09 * c) / 0.42
    P = 0.01 * np.cumsum(np.stack([np.zeros(3), a, b, c]), axis=0)
    np.testing.assert_allclose(bezier_length(P), polyline_length(P, n=400_001), rtol=1e-3)


def test_closest_tau_matches_brute_force(curves: np.ndarray) -> None:
    rng = np.random.default_rng(2)
    dense = np.linspace(0.0, 1.0, 200_001)
    for P in curves:
        pts = bezier_point(P, dense)
        for _ in range(5):
            r = P.mean(axis=0) + rng.normal(scale=0.04, size=3)
            for tau_min in (0.0, 0.4):
                tau = Cubic(P).closest_tau(r, tau_min, 1.0)
                assert tau_min <= tau <= 1.0
                window = dense >= tau_min
                brute = np.min(np.linalg.norm(pts[window] - r, axis=1))
                found = np.linalg.norm(bezier_point(P, [tau])[0] - r)
                assert found <= brute + 1e-12


def numpy_closest_tau(cubic: Cubic, r: np.ndarray, tau_min: float, tau_max: float, samples: int = 33) -> float:
    """The numpy grid and Python Newton steps that ``bezier_kernels.closest_search`` replaced."""
    A, end, tangent = cubic.A, cubic.end, cubic.end_tangent
    grid = tau_min + (tau_max - tau_min) * np.linspace(0.0, 1.0, samples)
    g_in = np.minimum(grid, 1.0)[:, None]
    pts = A[0] + g_in * (A[1] + g_in * (A[2] + g_in * A[3])) + np.maximum(grid - 1.0, 0.0)[:, None] * tangent
    d2 = np.einsum("ij,ij->i", pts - r, pts - r)
    i = int(np.argmin(d2))
    lo, hi, t = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, samples - 1)]), float(grid[i])
    a = A.tolist()
    for _ in range(5):
        g = dg = 0.0
        for k, rk in enumerate(r.tolist()):
            if t > 1.0:
                diff = float(end[k]) + (t - 1.0) * float(tangent[k]) - rk
                g += diff * float(tangent[k])
                dg += float(tangent[k]) * float(tangent[k])
            else:
                diff = a[0][k] + t * (a[1][k] + t * (a[2][k] + t * a[3][k])) - rk
                d1 = a[1][k] + t * (2.0 * a[2][k] + 3.0 * t * a[3][k])
                g += diff * d1
                dg += d1 * d1 + diff * (2.0 * a[2][k] + 6.0 * t * a[3][k])
        if dg <= 1e-300:
            break
        t_new = min(max(t - g / dg, lo), hi)
        converged = abs(t_new - t) < 1e-12
        t = t_new
        if converged:
            break
    p = cubic.point(t) - r
    return t if float(p @ p) <= float(d2[i]) else float(grid[i])


def test_closest_tau_gives_the_bits_of_the_numpy_search() -> None:
    rng = np.random.default_rng(5)
    differing = 0
    for _ in range(3000):
        P = rng.normal(scale=0.02, size=(4, 3))
        cubic = Cubic(P)
        r = P[rng.integers(4)] + rng.normal(scale=0.01, size=3)
        tau_min = float(rng.uniform(0.0, 1.0))
        tau_max = tau_min + float(rng.choice([0.0, rng.uniform(0.0, 1.5)]))
        differing += cubic.closest_tau(r, tau_min, tau_max) != numpy_closest_tau(cubic, r, tau_min, tau_max)
    assert differing == 0


def test_closest_tau_respects_the_lower_bound() -> None:
    P = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0]])
    assert Cubic(P).closest_tau(np.array([0.0, 0.001, 0.0]), 0.5) == pytest.approx(0.5)
    assert Cubic(P).closest_tau(np.array([0.012, 0.001, 0.0])) == pytest.approx(0.4, abs=1e-12)


def test_closest_tau_on_the_straight_continuation() -> None:
    P = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0]])  # |T'(1)| = 0.03
    r = np.array([0.036, 0.002, 0.0])  # 6 mm past the end
    assert Cubic(P).closest_tau(r, 0.0, 1.5) == pytest.approx(1.2, abs=1e-12)
    np.testing.assert_allclose(Cubic(P).point(1.2), [0.036, 0, 0], atol=1e-15)
    assert Cubic(P).closest_tau(r, 0.0, 1.0) == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("r", "samples", "message"),
    [
        ([0.0, 0.0], 33, r"a point r of shape \(3,\), got shape \(2,\)"),  # it read past the array's end
        ([[0.01, 0.0, 0.0]], 33, r"a point r of shape \(3,\), got shape \(1, 3\)"),
        ([np.nan, 0.0, 0.0], 33, r"a finite point r, got \[nan, 0.0, 0.0\]"),  # it answered 0.0
        ([0.0, np.inf, 0.0], 33, r"a finite point r"),
        ([0.03, 0.0, 0.0], 1, r"samples >= 2"),  # it answered 0.0 where T(1) is the point
    ],
)
def test_closest_tau_refuses_what_it_cannot_search(r: list, samples: int, message: str) -> None:
    P = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0]])
    with pytest.raises(ValueError, match=message):
        Cubic(P).closest_tau(r, samples=samples)
    assert Cubic(P).closest_tau([0.03, 0.0, 0.0], samples=2) == pytest.approx(1.0)


def test_cubic_agrees_with_vectorised_functions(curves: np.ndarray) -> None:
    cubic = Cubic(curves[3])
    for t in (0.0, 0.3, 0.77, 1.0):
        np.testing.assert_allclose(cubic.point(t), bezier_point(curves[3], [t])[0], atol=1e-15)
        np.testing.assert_allclose(cubic.derivative(t), bezier_derivative(curves[3], [t])[0], atol=1e-15)
    # beyond tau = 1: the straight continuation T(1) + (tau - 1) T'(1), C1 with the curve
    end, tangent = bezier_point(curves[3], [1.0])[0], bezier_derivative(curves[3], [1.0])[0]
    np.testing.assert_allclose(cubic.point(1.3), end + 0.3 * tangent, atol=1e-15)
    np.testing.assert_allclose(cubic.derivative(1.3), tangent, atol=1e-15)


def test_approach_curve_is_eq15() -> None:
    r = np.array([0.0, 0.0, 0.0])
    v_n = np.array([0.0, 0.0, -1.0])  # was moving down into the surface
    t_p = np.array([0.03, 0.0, 0.0])
    t_n = np.array([0.0, 0.0, 1.0])
    P = approach_curve(r, v_n, t_p, t_n)
    d = np.linalg.norm(r - t_p)
    np.testing.assert_allclose(P, [r, r - v_n * d / 3, t_p + t_n * d / 3, t_p], atol=1e-15)
    tangents = bezier_derivative(P, [0.0, 1.0])
    np.testing.assert_allclose(tangents[0], -v_n * d, atol=1e-15)  # Eq. 14: retract along -v_n
    np.testing.assert_allclose(tangents[1], -t_n * d, atol=1e-15)  # arrive against the normal


def test_recovery_curve_is_eq17() -> None:
    r = np.array([0.03, 0.0, -0.01])
    v_n = np.array([0.0, 0.0, -1.0])
    t_p = np.zeros(3)
    t_n = np.array([0.0, 0.0, 1.0])
    P = recovery_curve(r, v_n, t_p, t_n)
    d = np.linalg.norm(r - t_p)
    np.testing.assert_allclose(P, [r, r + v_n * d / 3, t_p - t_n * d / 3, t_p], atol=1e-15)
    tangents = bezier_derivative(P, [0.0, 1.0])
    np.testing.assert_allclose(tangents[0], v_n * d, atol=1e-15)  # Eq. 16: velocity continuous
    np.testing.assert_allclose(tangents[1], t_n * d, atol=1e-15)
    # bit for bit the written-out Eq. 17 on random inputs (it is computed as Eq. 15 with signs reversed)
    rng = np.random.default_rng(11)
    r, v_n, t_p, t_n = rng.normal(size=(4, 50, 3))
    v_n /= np.linalg.norm(v_n, axis=-1, keepdims=True)
    t_n /= np.linalg.norm(t_n, axis=-1, keepdims=True)
    beta = (1.0 / 3.0) * np.maximum(np.linalg.norm(r - t_p, axis=-1, keepdims=True), 0.01)
    expected = np.stack([r, r + v_n * beta, t_p - t_n * beta, t_p], axis=-2)
    assert np.array_equal(recovery_curve(r, v_n, t_p, t_n, min_chord_m=0.01), expected)


def test_curves_broadcast_over_candidates() -> None:
    rng = np.random.default_rng(3)
    targets = rng.normal(scale=0.03, size=(7, 3))
    normals = rng.normal(size=(7, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    P = approach_curve(np.zeros(3), np.array([0, 0, -1.0]), targets, normals)
    assert P.shape == (7, 4, 3)
    for i in range(7):
        np.testing.assert_allclose(P[i], approach_curve(np.zeros(3), np.array([0, 0, -1.0]), targets[i], normals[i]))


def test_min_chord_keeps_a_curve_to_its_own_start() -> None:
    r = np.array([0.01, 0.02, 0.03])
    P = approach_curve(r, np.array([0, 0, -1.0]), r, np.array([0, 0, 1.0]), min_chord_m=1e-3)
    length = float(bezier_length(P))
    assert np.isfinite(length) and length > 1e-4
    assert float(bezier_length(approach_curve(r, np.array([0, 0, -1.0]), r, np.array([0, 0, 1.0])))) == 0.0


def test_scalar_point_and_derivative_give_the_bits_of_numpy() -> None:
    """The controller's float paths against the power form evaluated on arrays (and the continuation)."""
    rng = np.random.default_rng(7)
    for _ in range(2000):
        cubic = Cubic(rng.normal(scale=0.02, size=(4, 3)))
        A = cubic.A
        for tau in (float(rng.uniform(0.0, 1.0)), float(rng.uniform(1.0, 2.0))):
            if tau > 1.0:
                point, slope = cubic.end + (tau - 1.0) * cubic.end_tangent, cubic.end_tangent
            else:
                point = A[0] + tau * (A[1] + tau * (A[2] + tau * A[3]))
                slope = A[1] + tau * (2.0 * A[2] + 3.0 * tau * A[3])
            assert cubic.point_xyz(tau) == point.tolist()
            assert cubic.derivative_xyz(tau) == slope.tolist()


@pytest.mark.parametrize(
    ("v_n", "t_n", "message"),
    [
        ([0.0, 0.0, -2.0], [0.0, 0.0, 1.0], "v_n needs unit vectors \\(or zero\\), got one of length 2"),
        ([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], "t_n needs unit vectors, got one of length 0"),
        ([0.0, 0.0, -1.0], [0.0, 0.5, 0.5], "t_n needs unit vectors, got one of length 0.707107"),
        ([np.nan, 0.0, 0.0], [0.0, 0.0, 1.0], "v_n needs finite vectors"),
        ([0.0, 0.0, -1.0], [0.0, 1.0], "t_n needs 3-vectors"),
    ],
)
def test_approach_curve_refuses_directions_that_are_not_unit(v_n: list[float], t_n: list[float], message: str) -> None:
    """A scaled direction moved the control points by its length without a word (now named)."""
    with pytest.raises(ValueError, match=message):
        approach_curve(np.zeros(3), v_n, np.ones(3), t_n)


def test_approach_curve_takes_zero_retraction_and_float32_normals() -> None:
    n = np.array([0.6, 0.0, 0.8], dtype=np.float32)  # |n| = 1 only to float32's precision
    P = approach_curve(np.zeros(3), np.zeros(3), np.ones(3), n)
    np.testing.assert_array_equal(P[1], np.zeros(3))
    np.testing.assert_allclose(P[2], 1.0 + n.astype(np.float64) * np.sqrt(3.0) / 3.0)


def test_the_curves_take_every_direction_the_messages_take() -> None:
    """A review: lengths up to sqrt(1.02) passed where the messages take up to 1.01, so a touch's approach
    direction of length 1.00998 ended the planner node."""
    from palpate import inputs
    from palpate.geometry import bezier

    tol = inputs.UNIT_TOLERANCE
    for length in (1.0 + 0.9999 * tol, 1.0 - 0.9999 * tol, 1.00998):
        v = inputs.unit_or_zero([0.0, 0.0, -length], "v")  # taken by a node's input check
        approach_curve(np.zeros(3), v, np.ones(3), [0.0, 0.0, length])
    with pytest.raises(ValueError, match=r"got one of length 1\.0101"):
        approach_curve(np.zeros(3), [0.0, 0.0, -1.0101], np.ones(3), [0.0, 0.0, 1.0])
    assert tol == bezier.UNIT_TOLERANCE
