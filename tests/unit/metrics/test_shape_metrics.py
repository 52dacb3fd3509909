"""Chamfer distance and F-score against hand-computed cases: a sphere and the same sphere shifted."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.integrate import quad

from palpate.metrics.shape import ShapeScorer, fscore_from_distances, shape_scores

R = 0.05  # sphere radius, m
S = 0.003  # shift of the second sphere along x, m


def sphere(centre_x: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=R)
    return np.asarray(mesh.vertices) + np.array([centre_x, 0.0, 0.0]), np.asarray(mesh.faces)


def distance_to_shifted(x: float) -> float:
    """Distance from the point R u of sphere A (u_x = x) to sphere B of centre S e_x."""
    return abs(np.sqrt(R * R - 2.0 * R * S * x + S * S) - R)


def fraction_within(tau: float) -> float:
    """Area fraction of sphere A within tau of sphere B: u_x is uniform on [-1, 1] (Archimedes), and
    |sqrt(R^2 - 2 R S x + S^2) - R| <= tau  <=>  x in [(S^2 - 2 R tau - tau^2), (S^2 + 2 R tau - tau^2)] / (2 R S)."""
    lo = max(-1.0, (S * S - 2.0 * R * tau - tau * tau) / (2.0 * R * S))
    hi = min(1.0, (S * S + 2.0 * R * tau - tau * tau) / (2.0 * R * S))
    return max(0.0, hi - lo) / 2.0


def test_shifted_sphere_matches_the_closed_form() -> None:
    scores = shape_scores(sphere(S), sphere(), samples=20000, rng=np.random.default_rng(1))
    expected_mean, _ = quad(distance_to_shifted, -1.0, 1.0, points=[S / (2 * R)])
    expected_mean /= 2.0  # mean over x uniform on [-1, 1]
    # both one-sided means are the same integral by symmetry; sampling error ~ 1 %, faceting ~ 10 um
    np.testing.assert_allclose(scores.accuracy_m, expected_mean, rtol=0.03)
    np.testing.assert_allclose(scores.completeness_m, expected_mean, rtol=0.03)
    np.testing.assert_allclose(scores.chamfer_m, expected_mean, rtol=0.03)
    expected_f = [fraction_within(t) for t in scores.thresholds_m]  # P = R, so F = P
    assert expected_f[0] == pytest.approx(1 / 3, abs=1e-3) and expected_f[-1] == 1.0
    np.testing.assert_allclose(scores.precision, expected_f, atol=0.015)
    np.testing.assert_allclose(scores.recall, expected_f, atol=0.015)
    np.testing.assert_allclose(scores.fscore, expected_f, atol=0.015)
    assert scores.fscore_at(0.002) == scores.fscore[1]


def test_identical_surfaces_score_perfectly() -> None:
    scores = shape_scores(sphere(), sphere(), samples=5000)
    assert scores.chamfer_m < 1e-7
    assert scores.fscore == (1.0, 1.0, 1.0, 1.0)


def test_an_estimate_without_faces_scores_zero() -> None:
    scorer = ShapeScorer(sphere(), samples=1000)
    scores = scorer.score((np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)))
    assert scores.fscore == (0.0, 0.0, 0.0, 0.0) and scores.chamfer_m == float("inf")


def test_a_partial_estimate_is_precise_but_incomplete() -> None:
    V, F = sphere()
    upper = F[(V[F][:, :, 2] > 0.0).all(axis=1)]  # the upper hemisphere only
    scores = ShapeScorer(sphere(), samples=20000, rng=np.random.default_rng(2)).score((V, upper))
    assert scores.precision[0] == pytest.approx(1.0)
    assert scores.recall[0] == pytest.approx(0.5, abs=0.02)
    assert scores.fscore[0] == pytest.approx(2 * 0.5 / 1.5, abs=0.02)
    assert scores.completeness_m > 100 * scores.accuracy_m


def test_fscore_from_distances_by_hand() -> None:
    P, Rc, F = fscore_from_distances(np.array([0.0, 0.002, 0.004]), np.array([0.001, 0.003]), [0.001, 0.003])
    np.testing.assert_allclose(P, (1 / 3, 2 / 3), rtol=1e-12)
    np.testing.assert_allclose(Rc, (0.5, 1.0), rtol=1e-12)
    np.testing.assert_allclose(F, (2 * (1 / 3) * 0.5 / (1 / 3 + 0.5), 2 * (2 / 3) / (2 / 3 + 1.0)), rtol=1e-12)
    assert fscore_from_distances(np.array([1.0]), np.array([1.0]), [0.1])[2] == (0.0,)


def test_bad_thresholds_are_refused() -> None:
    with pytest.raises(ValueError, match="thresholds_m"):
        ShapeScorer(sphere(), thresholds_m=(0.001, float("nan")))
    with pytest.raises(KeyError, match="no F-score"):
        shape_scores(sphere(), sphere(), samples=100).fscore_at(0.003)
    # one threshold given as a number (an outside audit: "'float' object is not iterable")
    assert ShapeScorer(sphere(), samples=100, thresholds_m=0.002).thresholds_m == (0.002,)  # type: ignore[arg-type]


def test_a_point_exactly_at_the_threshold_counts_on_both_sides() -> None:
    # "within tau" is inclusive for precision and recall alike: a distance of 0.001 (the same float as
    # the threshold) counts at tau = 0.001
    P, Rc, F = fscore_from_distances(np.array([0.001, 0.0015]), np.array([0.001, 0.0005]), [0.001])
    assert P == (0.5,) and Rc == (1.0,)
    assert F[0] == pytest.approx(2 * 0.5 * 1.0 / 1.5, rel=1e-12)
