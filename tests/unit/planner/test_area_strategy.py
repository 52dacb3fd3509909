"""The area strategy: new explored area per unit of travel, checked on a plane against a slow count."""

from __future__ import annotations

import numpy as np

from palpate.geometry.bezier import approach_curve, bezier_length
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import Planner
from palpate.nodes.planner.scores import area_scores
from tests.unit.planner.planes import DOWN, plane_grid


def slow_scores(S: np.ndarray, N: np.ndarray, C: np.ndarray, config: PlannerConfig) -> np.ndarray:
    """The docstring's formula with loops."""
    rho, beta = config.area_radius_m, config.area_hole_weight
    nearest = np.array([min(np.linalg.norm(s - c) for c in C) for s in S])
    unexplored = nearest > rho
    out = np.zeros(len(S))
    for k, s in enumerate(S):
        cost = float(bezier_length(approach_curve(C[-1], DOWN, s, N[k], scale=config.psi2_control_scale)))
        gain = 0.0
        for q in np.flatnonzero(unexplored):
            if np.linalg.norm(S[q] - s) <= rho:
                around = [j for j in range(len(S)) if np.linalg.norm(S[j] - S[q]) <= 2 * rho]
                share = sum(not unexplored[j] for j in around) / len(around)
                gain += 1.0 + beta * share
        out[k] = gain / (cost + config.area_touch_cost_m)  # Psi4 = 1: the fingertip already faces -n
    return out


def test_scores_match_the_slow_formula() -> None:
    S, N = plane_grid(half=0.025)
    C = np.array([[0.0, 0.0, 0.0], [0.005, 0.0, 0.0], [-0.01, 0.01, 0.0]])
    for beta in (0.0, 2.0):
        config = PlannerConfig(strategy="area", area_hole_weight=beta)
        fast = area_scores(S, N, C, C[-1], DOWN, DOWN, config)
        np.testing.assert_allclose(fast, slow_scores(S, N, C, config), rtol=1e-12)


def test_scores_carry_the_rotation_factor() -> None:
    # every normal is +z: poking along -z needs no turn (Psi4 = 1); poking along +x a quarter turn,
    # Psi4 = exp(-(1 + R_z . s_n) / sigma_alpha^2) = exp(-1 / 0.25); the path (from v_n) is the same
    S, N = plane_grid(half=0.02)
    C = np.zeros((1, 3))
    config = PlannerConfig(strategy="area", sigma_alpha=0.5)
    facing = area_scores(S, N, C, C[-1], DOWN, DOWN, config)
    sideways = area_scores(S, N, C, C[-1], DOWN, np.array([1.0, 0.0, 0.0]), config)
    assert facing.max() > 0.0
    np.testing.assert_allclose(sideways, np.exp(-4.0) * facing, rtol=1e-12)


def test_a_touch_in_explored_area_scores_nothing_and_the_best_hop_leaves_the_explored_disc() -> None:
    S, N = plane_grid()
    C = np.zeros((1, 3))
    config = PlannerConfig(strategy="area")
    scores = area_scores(S, N, C, C[-1], DOWN, DOWN, config)
    distance = np.linalg.norm(S, axis=1)
    assert scores[distance <= 0.001].max() == 0.0  # the contact itself explores nothing new
    best = S[np.argmax(scores)]
    assert 0.006 < np.linalg.norm(best) <= 0.015  # next to the explored disc, about one spacing away


def test_holes_in_the_explored_region_come_first_with_a_hole_weight() -> None:
    """A ring of contacts around an unexplored centre, and open surface as far away outside: with
    beta > 0 the hole wins; without it the open side (which explores as much) may win."""
    S, N = plane_grid()
    angles = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    ring = np.column_stack([0.012 * np.cos(angles), 0.012 * np.sin(angles), np.zeros(12)])
    C = np.vstack([ring, [[0.012, 0.0, 0.0]]])  # the last contact on the ring
    weighted = area_scores(S, N, C, C[-1], DOWN, DOWN, PlannerConfig(area_hole_weight=4.0))
    plain = area_scores(S, N, C, C[-1], DOWN, DOWN, PlannerConfig(area_hole_weight=0.0))
    centre = int(np.argmin(np.linalg.norm(S, axis=1)))
    outside = int(np.argmin(np.linalg.norm(S - [0.024, 0.0, 0.0], axis=1)))  # as far from the last contact
    assert weighted[centre] / weighted[outside] > plain[centre] / plain[outside]
    assert weighted[centre] > weighted[outside]


def test_a_covered_surface_leads_out_of_the_covered_region() -> None:
    S, N = plane_grid(half=0.02)
    C = S[::2].copy()  # a checkerboard of contacts: every patch within 6 mm of one
    scores = area_scores(S, N, C, C[-1], DOWN, DOWN, PlannerConfig(strategy="area"))
    nearest = np.min(np.linalg.norm(S[:, None] - C[None], axis=2), axis=1)
    assert nearest.max() <= 0.006 and scores.max() > 0.0
    assert nearest[np.argmax(scores)] > 0.0  # not a contact itself: further from the contacts


def test_the_planner_selects_by_coverage() -> None:
    S, N = plane_grid()
    C = np.zeros((1, 3))
    planner = Planner(PlannerConfig(strategy="area"))
    choice = planner.select(S, N, np.zeros(len(S)), C, C[-1], DOWN, DOWN, np.random.default_rng(0))
    assert choice.psi is None and choice.score == choice.scores.max() > 0.0
    assert 0.006 < np.linalg.norm(choice.target_m) <= 0.015


def test_a_variance_weight_scales_the_gain_by_the_relative_variance() -> None:
    S, N = plane_grid(half=0.025)
    C = np.zeros((1, 3))
    variance = np.random.default_rng(0).uniform(0.0, 1e-4, len(S))
    plain = area_scores(S, N, C, C[-1], DOWN, DOWN, PlannerConfig(strategy="area"), variance)
    config = PlannerConfig(strategy="area", area_variance_weight=3.0)
    weighted = area_scores(S, N, C, C[-1], DOWN, DOWN, config, variance)
    np.testing.assert_allclose(weighted, plain * (1.0 + 3.0 * variance / variance.max()), rtol=1e-12)
    assert config.uses_variance and not PlannerConfig(strategy="area").uses_variance
