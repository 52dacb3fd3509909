"""The tour strategy: patch weights against the formula, the cheapest order against hand-checked
costs, and small planar cases whose tour can be worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import Planner
from palpate.nodes.planner.tour import best_order, greedy_insertion, patch_weights, tour_cost_m, tour_plan
from tests.unit.planner.planes import DOWN, UP, plane_grid


def test_patch_weights_match_the_formula_with_loops() -> None:
    S, _ = plane_grid(half=0.03)
    C = np.array([[0.0, 0.0, 0.0], [0.01, 0.005, 0.0]])
    variance = np.random.default_rng(1).uniform(0.0, 1e-4, len(S))
    config = PlannerConfig(strategy="tour", tour_hole_weight=2.0, tour_far_weight=1.5, tour_variance_weight=0.5)
    nearest = np.array([min(np.linalg.norm(s - c) for c in C) for s in S])
    rho = config.area_radius_m
    slow = np.zeros(len(S))
    for q in range(len(S)):
        if nearest[q] <= rho:
            continue
        around = [j for j in range(len(S)) if np.linalg.norm(S[j] - S[q]) <= 2 * rho]
        share = sum(nearest[j] <= rho for j in around) / len(around)
        far = min(nearest[q] / config.tour_far_m, 1.0)
        slow[q] = (1.0 + 2.0 * share + 1.5 * far) * (1.0 + 0.5 * variance[q] / variance.max())
    np.testing.assert_allclose(patch_weights(S, nearest, config, variance), slow, rtol=1e-12)
    assert config.uses_variance and not PlannerConfig(strategy="tour", tour_variance_weight=0.0).uses_variance


def test_best_order_tries_every_order() -> None:
    # sites on a line at x = 3, 1, 2 from a start at 0: the cheapest order is 1, 2, 3 (rows 1, 2, 0)
    x = np.array([3.0, 1.0, 2.0])
    order = best_order(np.abs(x), np.abs(x[:, None] - x[None, :]))
    np.testing.assert_array_equal(order, [1, 2, 0])
    # an asymmetric hop cost (0 -> 1 dear, 1 -> 0 cheap) reverses it
    hop = np.array([[0.0, 10.0], [1.0, 0.0]])
    np.testing.assert_array_equal(best_order(np.array([1.0, 1.0]), hop), [1, 0])


def test_a_one_site_tour_is_the_area_choice_of_its_weights() -> None:
    S, N = plane_grid()
    C = np.zeros((1, 3))
    config = PlannerConfig(strategy="tour", tour_sites=1, tour_variance_weight=0.0)
    tour = tour_plan(S, N, C, C[-1], DOWN, DOWN, config)
    assert len(tour.sites) == 1 and tour.scores.argmax() == tour.sites[0]
    assert 0.006 < np.linalg.norm(S[tour.sites[0]]) <= 0.015  # next to the explored disc


def test_the_tour_visits_sites_in_travel_order_and_spaces_them() -> None:
    """A strip 5 mm wide and 10 cm long, explored at x = 0: the tour goes out along the strip, one site
    after the other, its sites about a coverage diameter apart, never back over explored patches."""
    x = np.arange(0.0, 0.1 + 1e-9, 0.005)
    S = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    N = np.tile(UP, (len(S), 1))
    C = np.zeros((1, 3))
    config = PlannerConfig(strategy="tour", tour_sites=4, tour_far_weight=0.0)
    tour = tour_plan(S, N, C, C[-1], DOWN, DOWN, config)
    xs = S[tour.sites, 0]
    assert len(xs) == 4 and np.all(np.diff(xs) > 0.0)  # outward, in order
    assert np.all(np.diff(xs) >= 0.01)  # sites explore disjoint patches (2 rho = 12 mm, on a 5 mm grid)
    assert np.all(tour.gains > 0.0)
    ranked = np.argsort(-tour.scores)[:4]
    np.testing.assert_array_equal(ranked, tour.sites)  # the scores rank the tour first, in its order


def test_a_far_weight_favours_patches_far_from_every_contact() -> None:
    S, _ = plane_grid()
    near = patch_weights(S, np.linalg.norm(S, axis=1), PlannerConfig(strategy="tour", tour_far_weight=0.0))
    far = patch_weights(S, np.linalg.norm(S, axis=1), PlannerConfig(strategy="tour", tour_far_weight=1.0))
    d = np.linalg.norm(S, axis=1)
    assert np.all(far[d >= 0.03] - near[d >= 0.03] == 1.0)  # saturated at D = 3 cm
    assert np.all(far[(d > 0.006) & (d < 0.03)] - near[(d > 0.006) & (d < 0.03)] < 1.0)
    assert np.all(far[d <= 0.006] == 0.0)  # explored


def test_a_covered_surface_leads_out_of_the_covered_region() -> None:
    S, N = plane_grid(half=0.02)
    C = S[::2].copy()
    tour = tour_plan(S, N, C, C[-1], DOWN, DOWN, PlannerConfig(strategy="tour"))
    nearest = np.min(np.linalg.norm(S[:, None] - C[None], axis=2), axis=1)
    assert len(tour.sites) == 1 and nearest[tour.sites[0]] > 0.0


def test_the_planner_selects_the_tours_first_site_within_the_tour_radius() -> None:
    S, N = plane_grid(half=0.08)
    C = np.zeros((1, 3))
    config = PlannerConfig(strategy="tour")
    assert config.radius_m == config.tour_radius_m == 0.06
    choice = Planner(config).select(S, N, np.zeros(len(S)), C, C[-1], DOWN, DOWN, np.random.default_rng(0))
    assert choice.psi is None and choice.score == choice.scores.max()
    assert np.all(choice.scores[np.linalg.norm(S, axis=1) > 0.06] == 0.0)
    again = Planner(config).select(S, N, np.zeros(len(S)), C, C[-1], DOWN, DOWN, np.random.default_rng(5))
    np.testing.assert_array_equal(choice.scores, again.scores)  # deterministic, whatever the rng


def test_no_site_lies_on_explored_ground_next_to_a_contact() -> None:
    """A strip explored up to 5 mm from a contact: its last patches (6 and 7 mm out) are explored from
    a site at least rho / 2 from the contact, not from the site 1 mm beside it, whose touch, landing a
    millimetre off, could leave them unexplored again and again."""
    x = np.arange(-0.007, 0.0075, 0.001)
    S = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    N = np.tile(UP, (len(S), 1))
    C = np.array([[-0.001, 0.0, 0.0]])
    config = PlannerConfig(strategy="tour")
    tour = tour_plan(S, N, C, C[-1] + [0.0, 0.0, 0.008], DOWN, DOWN, config)
    rho = config.area_radius_m
    assert len(tour.sites) == 1
    site = S[tour.sites[0]]
    assert np.linalg.norm(site - C[0]) >= rho / 2
    assert np.linalg.norm(site - [0.007, 0.0, 0.0]) <= rho  # it still explores the strip's end


def _line_sites() -> tuple[np.ndarray, np.ndarray]:
    """Sites at x = 1, 2, 3 on a line, the fingertip at 0: start (3,) and hop (3, 3) the distances."""
    x = np.array([1.0, 2.0, 3.0])
    return x.copy(), np.abs(x[:, None] - x[None, :])


def test_tour_cost_counts_every_hop_and_every_touch() -> None:
    start, hop = _line_sites()
    hop[0, 2] = 5.0  # one-way: 1 -> 3 costs 5, 3 -> 1 still 2
    # r -> x3 (3) + x3 -> x1 (2) + x1 -> x2 (1) + 3 touches of 0.25
    assert tour_cost_m([2, 0, 1], start, hop, 0.25) == pytest.approx(3.0 + 2.0 + 1.0 + 0.75)
    # r -> x1 (1) + x1 -> x3 (5, the one-way cost) + 2 touches
    assert tour_cost_m([0, 2], start, hop, 0.25) == pytest.approx(1.0 + 5.0 + 0.5)
    assert tour_cost_m([1], start, hop, 0.25) == pytest.approx(2.25)


def test_greedy_insertion_puts_a_site_on_the_way_between_two_others() -> None:
    start, hop = _line_sites()
    cover = np.eye(3)  # each site explores its own patch; the middle one is worth 0.2, the others 1
    w = np.array([1.0, 0.2, 1.0])
    config = PlannerConfig(strategy="tour", tour_touch_cost_m=0.0, tour_sites=3)
    # J = (sum of gains) / travel. 1st: x1 (1 / 1). 2nd: x3 at the end (2 / 3) beats x2 at the end
    # (1.2 / 2). 3rd, x2 into tour (x1, x3) of travel 3: first 2.2 / (3 + 2 + 1 - 1), between
    # 2.2 / (3 + 1 + 1 - 2) = 0.73 (the hop x1 -> x3 it replaces is saved), last 2.2 / (3 + 1) = 0.55
    assert greedy_insertion(cover, w, np.ones(3), start, hop, config) == [0, 1, 2]
