"""The exploration evaluator's surface scores: whole estimate against its confident part."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from palpate.metrics.exploration import confident_faces
from palpate.nodes.explore_eval.core import EvalConfig, ExplorationEvaluator


def _cube(edge: float, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    box = trimesh.creation.box(extents=(edge, edge, edge))
    box = box.subdivide().subdivide()
    return np.asarray(box.vertices) + np.asarray(offset), np.asarray(box.faces, dtype=np.int64)


def test_confident_faces_keeps_faces_whose_three_vertices_are_sure() -> None:
    faces = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]])
    variance = np.array([0.0, 1e-8, 1e-8, 4e-6, np.nan])  # sigma 0, 0.1 mm, 0.1 mm, 2 mm, NaN
    np.testing.assert_array_equal(confident_faces(faces, variance, 0.001), faces[:1])
    np.testing.assert_array_equal(confident_faces(faces, variance, 0.003), faces[:2])


def test_phantom_surface_of_high_variance_counts_only_in_the_whole_estimate_scores() -> None:
    V, F = _cube(0.05)
    evaluator = ExplorationEvaluator(V, F, EvalConfig(rmse_samples=4000, coverage_samples=2000))
    phantom_V, phantom_F = _cube(0.02, offset=(0.1, 0.0, 0.0))  # 7.5 cm beside the true cube
    est_V = np.vstack([V, phantom_V])
    est_F = np.vstack([F, phantom_F + len(V)])
    variance = np.concatenate([np.full(len(V), 1e-8), np.full(len(phantom_V), 1e-4)])

    scores = evaluator.rmse(est_V, est_F, variance)

    assert scores.confident.estimate_to_truth_m == pytest.approx(0.0, abs=1e-9)
    assert scores.whole.estimate_to_truth_m > 0.01  # the phantom cube is 7.5 cm off
    area_true, area_phantom = 6 * 0.05**2, 6 * 0.02**2
    assert scores.confident_fraction == pytest.approx(area_true / (area_true + area_phantom), rel=1e-6)


def test_milestone_headline_is_the_confident_one_sided_rmse() -> None:
    V, F = _cube(0.05)
    evaluator = ExplorationEvaluator(V, F, EvalConfig(rmse_samples=4000, coverage_samples=2000))
    evaluator.add_touch(V[0], V[0], 0.0, 0.0, np.array([0.0, 0.0, -1.0]))
    evaluator.close_incomplete()
    shrunk = 0.98 * V  # every estimate point ~0.5 mm inside the truth
    evaluator.set_rmse(0.8, evaluator.rmse(shrunk, F, np.zeros(len(V))))
    m = evaluator.milestones[0.8]
    assert 0.2 < m.rmse_mm < 0.6
    assert m.rmse_estimate_to_truth_mm == pytest.approx(m.rmse_mm, rel=1e-9)
    assert m.confident_fraction == pytest.approx(1.0)


def test_budgets_grow_with_the_objects_covering_bound() -> None:
    """A 5 cm cube keeps the fixed budgets; a 50 cm cube (bound ~4000 contacts) gets 2.5x its bound."""
    small = ExplorationEvaluator(*_cube(0.05), EvalConfig(coverage_samples=1000))
    assert small.covering_bound < 800 / 2.5 and small.contact_budget == 800 and small.travel_budget_m == 20.0
    big = ExplorationEvaluator(*_cube(0.5), EvalConfig(coverage_samples=1000))
    bound = 1.2092 * 0.8 * 6 * 0.5**2 / (np.pi * 0.006**2)  # COVERING_DENSITY * goal * area / (pi r^2)
    assert big.covering_bound == pytest.approx(bound, rel=1e-4)
    assert big.contact_budget == int(np.ceil(2.5 * big.covering_bound))
    assert big.travel_budget_m == pytest.approx(0.05 * big.covering_bound)
    fixed = ExplorationEvaluator(*_cube(0.5), EvalConfig(coverage_samples=1000, contacts_per_bound=0.0))
    assert fixed.contact_budget == 800
    summary = big.summary()
    assert summary["contact_budget"] == big.contact_budget and summary["travel_budget_m"] == big.travel_budget_m


def test_shape_checkpoints_spread_out_on_an_object_with_a_large_bound() -> None:
    """Every 10 contacts up to a bound of 600; beyond, bound / 60 contacts apart (rounded up)."""
    config = EvalConfig()
    assert [config.shape_interval(b) for b in (5.0, 171.0, 600.0, 600.5, 9237.6)] == [10, 10, 10, 11, 154]
    assert EvalConfig(shape_checkpoints_per_bound=0.0).shape_interval(9237.6) == 10
    assert EvalConfig(shape_every_contacts=0).shape_interval(9237.6) == 0  # checkpoints off
    small = ExplorationEvaluator(*_cube(0.05), EvalConfig(coverage_samples=1000))
    big = ExplorationEvaluator(*_cube(0.5), EvalConfig(coverage_samples=1000))  # bound ~4000
    assert small.shape_interval == 10 and big.shape_interval == int(np.ceil(big.covering_bound / 60))


def test_a_run_ends_at_the_scaled_contact_budget() -> None:
    config = EvalConfig(coverage_samples=1000, max_contacts=3, contacts_per_bound=0.0)
    ev = ExplorationEvaluator(*_cube(0.05), config)
    far = np.array([0.025, 0.0, 0.0])
    for k in range(3):
        assert ev.finished == ""
        ev.add_touch(far, np.full(3, np.nan), 0.01 * k, 0.0, np.array([-1.0, 0.0, 0.0]))
    assert ev.finished == "contact budget"


def test_a_run_whose_touches_add_no_coverage_ends_as_no_progress() -> None:
    config = EvalConfig(coverage_samples=1000, max_touches_without_gain=3)
    ev = ExplorationEvaluator(*_cube(0.05), config)
    down = np.array([-1.0, 0.0, 0.0])
    ev.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.0, 0.0, down)
    for k in range(3):  # the same spot again: nothing new
        assert ev.finished == ""
        ev.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.01 * k, 0.0, down)
    assert ev.finished == "no progress"
    ev = ExplorationEvaluator(*_cube(0.05), config)
    for y in np.linspace(-0.02, 0.02, 6):  # every touch somewhere new
        ev.add_touch(np.array([0.025, y, 0.0]), np.full(3, np.nan), 0.0, 0.0, down)
    assert ev.finished == ""
    unlimited = ExplorationEvaluator(*_cube(0.05), EvalConfig(coverage_samples=1000, max_touches_without_gain=0))
    for _ in range(6):
        unlimited.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.0, 0.0, down)
    assert unlimited.finished == ""


def test_shape_scores_of_the_estimate_join_the_series_and_the_milestone() -> None:
    V, F = _cube(0.05)
    ev = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000, shape_samples=2000))
    ev.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.0, 0.0, np.array([-1.0, 0.0, 0.0]))
    perfect = ev.shape(V, F)
    assert perfect.contacts == 1 and perfect.chamfer_mm < 1e-4 and perfect.fscore_2mm == 1.0
    shifted = ev.shape(V + np.array([0.003, 0.0, 0.0]), F)  # the same contact count: replaces the point
    assert len(ev.shape_series) == 1 and ev.shape_series[0] is shifted
    assert 0.0 < shifted.fscore_2mm < 1.0 and shifted.chamfer_mm > 0.5
    ev.close_incomplete()
    ev.set_rmse(0.5, ev.rmse(V, F, np.zeros(len(V))), shifted)
    assert ev.milestones[0.5].fscore_2mm == shifted.fscore_2mm
    assert ev.summary()["shape"][0]["fscore_2mm"] == shifted.fscore_2mm


def test_shape_scores_of_an_earlier_request_are_labelled_with_its_touch() -> None:
    # a surface answering the request of touch 1 that comes after touch 2: its point says touch 1
    V, F = _cube(0.05)
    ev = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000, shape_samples=500))
    for k, x in enumerate((0.025, -0.025)):
        ev.add_touch(np.array([x, 0.0, 0.0]), np.full(3, np.nan), 0.1 * (k + 1), 0.0, np.array([-1.0, 0.0, 0.0]))
    early = ev.shape(V, F, contacts=1)
    assert early.contacts == 1 and early.travel_cm == 10.0 and early.coverage == ev.touches[0].coverage
    assert ev.touches[0].coverage < ev.touches[1].coverage


def test_a_touch_that_brings_coverage_exactly_to_the_goal_reaches_it_and_completes_the_run() -> None:
    V, F = _cube(0.05)
    side, down = np.array([0.025, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    probe = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000))
    probe.add_touch(side, np.full(3, np.nan), 0.0, 0.0, down)
    exact = probe.touches[0].coverage  # the same samples (rng seed 0) in every evaluator of this cube
    ev = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000, coverage_goal=exact, milestones=(exact,)))
    assert ev.add_touch(side, np.full(3, np.nan), 0.0, 0.0, down) == [exact]  # coverage == milestone: reached
    assert ev.finished == "goal" and ev.summary()["complete"]


def test_a_goal_that_is_no_milestone_is_recorded_as_one_and_completes_the_run() -> None:
    """An outside walkthrough: --set eval.eval.coverage_goal=0.1 ended runs 'finished: goal' and
    'complete: false' (complete looked the goal up among the milestones)."""
    V, F = _cube(0.05)
    side, down = np.array([0.025, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    ev = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000, coverage_goal=0.005))
    assert ev.config.recorded == (0.005, 0.5, 0.8)
    assert ev.add_touch(side, np.full(3, np.nan), 0.0, 0.0, down) == [0.005]
    ev.close_incomplete()
    summary = ev.summary()
    assert ev.finished == "goal" and summary["complete"]
    assert summary["milestones"]["0.5"]["reached"] and not summary["milestones"]["50"]["reached"]
    assert list(summary["milestones"]) == ["0.5", "50", "80"]  # percent; "0" had hidden a goal below 1 %


def test_a_touch_whose_travel_equals_the_travel_budget_ends_the_run() -> None:
    config = EvalConfig(coverage_samples=1000, max_travel_m=0.5, travel_per_bound_m=0.0)
    ev = ExplorationEvaluator(*_cube(0.05), config)
    down = np.array([-1.0, 0.0, 0.0])
    ev.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.49, 0.0, down)
    assert ev.finished == ""
    ev.add_touch(np.array([-0.025, 0.0, 0.0]), np.full(3, np.nan), 0.5, 0.0, down)  # 0.5 m >= 0.5 m budget
    assert ev.finished == "travel budget"


def test_an_incomplete_runs_milestones_hold_its_last_odometry_and_mean_miss() -> None:
    """Three touches, the budget ends the run: the milestones keep the last touch's travel and rotation
    (the odometry is cumulative), the mean of the defined prediction misses, and the run is incomplete."""
    config = EvalConfig(coverage_samples=1000, max_contacts=3, contacts_per_bound=0.0)
    ev = ExplorationEvaluator(*_cube(0.05), config)
    axis = np.array([-1.0, 0.0, 0.0])
    ev.add_touch(np.array([0.025, 0.0, 0.0]), np.array([0.026, 0.0, 0.0]), 0.10, 5.0, axis)  # 1 mm miss
    ev.add_touch(np.array([-0.025, 0.0, 0.0]), np.array([-0.028, 0.0, 0.0]), 0.30, 12.0, axis)  # 3 mm miss
    ev.add_touch(np.array([0.0, 0.025, 0.0]), np.full(3, np.nan), 0.45, 20.0, axis)  # no prediction
    assert ev.finished == "contact budget"
    ev.close_incomplete()
    for fraction in (0.5, 0.8):
        m = ev.milestones[fraction]
        assert not m.reached and m.contacts == 3
        assert m.travel_cm == pytest.approx(45.0)  # 100 x the last touch's 0.45 m
        assert m.rotation_deg == pytest.approx(20.0)  # the last touch's reading, not a sum
        assert m.prediction_miss_mm == pytest.approx(2.0)  # mean of 1 mm and 3 mm; the NaN left out
    summary = ev.summary()
    assert summary["complete"] is False and summary["finished"] == "contact budget"


def test_a_touch_records_its_measured_normal_and_none_without_one() -> None:
    V, F = _cube(0.05)
    ev = ExplorationEvaluator(V, F, EvalConfig())
    down = np.array([0.0, 0.0, -1.0])
    ev.add_touch(V[0], V[0], 0.0, 0.0, down, normal=np.array([0.0, 0.6, 0.8]))
    ev.add_touch(V[1], V[1], 0.0, 0.0, down)
    touches = ev.summary()["touches"]
    assert touches[0]["normal"] == [0.0, 0.6, 0.8]
    assert touches[1]["normal"] is None


@pytest.mark.parametrize("estimate", ["no faces", "zero area"])
def test_an_estimate_without_surface_scores_as_nothing_at_checkpoints_and_milestones(estimate: str) -> None:
    """A collapsed estimate (every triangle of zero area) raised at a milestone where an empty one
    scored NaN, and the shape checkpoints scored both as infinitely far."""
    V, F = _cube(0.05)
    ev = ExplorationEvaluator(V, F, EvalConfig(coverage_samples=1000, shape_samples=500))
    ev.add_touch(np.array([0.025, 0.0, 0.0]), np.full(3, np.nan), 0.0, 0.0, np.array([-1.0, 0.0, 0.0]))
    faces = np.zeros((0, 3), dtype=np.int64) if estimate == "no faces" else np.array([[0, 1, 2]])
    vertices = np.zeros((3, 3))
    shape = ev.shape(vertices, faces)
    assert shape.chamfer_mm == np.inf and shape.fscore_2mm == 0.0
    scores = ev.rmse(vertices, faces, np.zeros(3))
    assert np.isnan(scores.whole.symmetric_m) and np.isnan(scores.confident.symmetric_m)
    assert np.isnan(scores.confident_fraction)
