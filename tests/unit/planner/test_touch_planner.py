"""TouchPlanner: when to plan, unreached targets, admissibility, the fallbacks (planner.core, no sockets)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from palpate.errors import InputError, PlanningError
from palpate.geometry.thinning import thin_near
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import Planner, TouchPlanner
from palpate.nodes.planner.curves import curves_clear

DOWN_WXYZ = np.array([0.0, 1.0, 0.0, 0.0])  # half turn about x: poking axis R[:, 2] = -z
TIP_M = 0.008


def plane(step: float = 0.0025, radius: float = 0.07) -> tuple[np.ndarray, np.ndarray]:
    """Points on z = 0 within `radius` of the origin (a local mesh), normals +z."""
    g = np.arange(-radius, radius + 1e-12, step)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    V = V[np.linalg.norm(V, axis=1) <= radius + 1e-12]
    return V, np.tile([0.0, 0.0, 1.0], (len(V), 1))


def touched_at_origin(config: PlannerConfig) -> TouchPlanner:
    """A planner whose one contact is the origin, made moving straight down, with no target before."""
    planner = TouchPlanner(config)
    planner.add_touch(np.zeros(3), np.full(3, np.nan), [0.0, 0.0, -1.0])
    return planner


def over(point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fingertip resting on the plane at `point`: (centre, quaternion)."""
    return point + np.array([0.0, 0.0, TIP_M]), DOWN_WXYZ


def test_plans_once_per_contact_on_the_local_surface_that_includes_it() -> None:
    V, N = plane()
    planner = touched_at_origin(PlannerConfig(strategy="gpv"))
    rng = np.random.default_rng(0)
    tip = over(np.zeros(3))
    variance = np.ones(len(V))
    assert planner.plan("global", 1, V, N, variance, tip, rng) is None
    assert planner.plan("local", 0, V, N, variance, tip, rng) is None  # an older surface
    assert planner.plan("local", 1, V, N, variance, tip, rng) is not None
    assert planner.plan("local", 1, V, N, variance, tip, rng) is None  # planned for this contact already
    planner.add_touch([0.01, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, -1.0])
    assert planner.plan("local", 1, V, N, variance, tip, rng) is None
    assert planner.plan("local", 2, V, N, variance, over(np.array([0.01, 0.0, 0.0])), rng) is not None


def test_planning_without_a_fingertip_pose_is_an_error() -> None:
    V, N = plane()
    planner = touched_at_origin(PlannerConfig())
    with pytest.raises(PlanningError, match="no fingertip pose"):
        planner.plan("local", 1, V, N, np.ones(len(V)), None, np.random.default_rng(0))


def test_a_fingertip_pose_with_nan_or_a_zero_quaternion_is_refused_before_anything_changes() -> None:
    """An outside audit: a NaN position made every candidate inadmissible without a word (the node
    checks poses; the core did not)."""
    V, N = plane()
    planner = touched_at_origin(PlannerConfig(strategy="gpv"))
    tip = over(np.zeros(3))
    for bad, field in (((np.array([np.nan, 0.0, 0.03]), tip[1]), "position_m"), ((tip[0], np.zeros(4)), "quaternion")):
        with pytest.raises(InputError, match=rf"^{field}"):
            planner.plan("local", 1, V, N, np.ones(len(V)), bad, np.random.default_rng(0))
    assert planner.plan("local", 1, V, N, np.ones(len(V)), tip, np.random.default_rng(0)) is not None  # still due


def test_a_touch_that_landed_away_from_its_target_remembers_the_target() -> None:
    planner = TouchPlanner(PlannerConfig(unreached_miss_m=0.005))
    planner.add_touch([0.0, 0.0, 0.0], [np.nan] * 3, [0.0, 0.0, -1.0])  # no target
    planner.add_touch([0.01, 0.0, 0.0], [0.0149, 0.0, 0.0], [0.0, 0.0, -1.0])  # 4.9 mm off: reached
    planner.add_touch([0.02, 0.0, 0.0], [0.0251, 0.0, 0.0], [0.6, 0.0, -0.8])  # 5.1 mm off: unreached
    assert len(planner.contacts) == 3
    np.testing.assert_array_equal(np.array(planner.unreached), [[0.0251, 0.0, 0.0]])
    np.testing.assert_array_equal(planner.approach, [0.6, 0.0, -0.8])


def test_a_target_within_min_hop_of_the_fingertip_or_near_an_unreached_target_is_not_chosen() -> None:
    """GP-V's argmax is the variance peak; the peak is inadmissible, so the choice is the argmax of the rest."""
    V, N = plane()
    peak = np.array([0.02, 0.0, 0.0])
    variance = np.exp(-np.sum((V - peak) ** 2, axis=1) / 0.02**2)
    config = PlannerConfig(strategy="gpv", check_curves=False)
    free = touched_at_origin(config).plan("local", 1, V, N, variance, over(np.zeros(3)), np.random.default_rng(0))
    assert free is not None and np.linalg.norm(free.selection.target_m - peak) < 1e-9
    rng = np.random.default_rng(0)

    at_peak = touched_at_origin(config).plan("local", 1, V, N, variance, over(peak), rng)  # fingertip on the peak
    assert at_peak is not None
    chosen = at_peak.selection.target_m
    assert np.linalg.norm(chosen - peak) >= config.min_hop_m
    candidates = at_peak.candidates.points_m
    admissible = np.linalg.norm(candidates - peak, axis=1) >= config.min_hop_m
    assert at_peak.selection.score == at_peak.candidates.variance[admissible].max()

    planner = TouchPlanner(config)
    planner.add_touch(np.zeros(3), peak, [0.0, 0.0, -1.0])  # aimed at the peak, landed at the origin
    avoided = planner.plan("local", 1, V, N, variance, over(np.zeros(3)), rng)
    assert avoided is not None and np.linalg.norm(avoided.selection.target_m - peak) >= config.unreached_radius_m
    away = np.linalg.norm(avoided.candidates.points_m - peak, axis=1) >= config.unreached_radius_m
    assert avoided.selection.score == avoided.candidates.variance[away].max()
    assert planner.take_counts() == {}


def test_when_nothing_is_admissible_the_papers_choice_is_made_and_counted() -> None:
    V, N = plane(radius=0.004)  # every candidate within min_hop of the fingertip
    config = PlannerConfig(strategy="gpv", check_curves=False)
    planner = touched_at_origin(config)
    variance = np.arange(len(V), dtype=np.float64)
    rng = np.random.default_rng(0)
    plan = planner.plan("local", 1, V, N, variance, over(np.zeros(3)), rng)
    assert plan is not None
    c = plan.candidates
    paper = Planner(config).select(
        c.points_m, c.normals, c.variance, np.zeros((1, 3)), np.zeros(3), [0, 0, -1.0], [0, 0, -1.0], rng
    )
    assert plan.selection.index == paper.index
    assert planner.take_counts() == {"no_admissible_candidate": 1}
    assert planner.take_counts() == {}  # taken


def ball(radius_m: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius_m)
    return np.asarray(mesh.vertices), np.asarray(mesh.vertex_normals)


@pytest.mark.parametrize("strategy", ["gpv", "igef"])
def test_the_best_target_with_a_clear_curve_is_chosen(strategy: str) -> None:
    """On a 2 cm ball touched on top, GP-V's variance peak is the bottom: its curve runs through the ball."""
    V, N = ball()
    top = V[np.argmax(V[:, 2])]
    variance = 1.0 - V[:, 2] / 0.02  # highest at the bottom
    config = PlannerConfig(strategy=strategy)  # type: ignore[arg-type]
    planner = TouchPlanner(config)
    planner.add_touch(top, np.full(3, np.nan), [0.0, 0.0, -1.0])
    tip = (top + TIP_M * np.array([0.0, 0.0, 1.0]), DOWN_WXYZ)
    plan = planner.plan("local", 1, V, N, variance, tip, np.random.default_rng(0))
    assert plan is not None
    c, choice = plan.candidates, plan.selection
    # Reference: every candidate's curve checked at once; the choice is the best admissible clear one.
    centres = c.points_m + TIP_M * c.normals
    clear = curves_clear(V, N, tip[0], [0.0, 0.0, -1.0], centres, c.normals, TIP_M - config.curve_margin_m)
    hop = np.linalg.norm(centres - tip[0], axis=1) >= config.min_hop_m
    rng = np.random.default_rng(0)
    paper = Planner(config).select(
        c.points_m, c.normals, c.variance, top[None], top, [0, 0, -1.0], [0, 0, -1.0], rng, admissible=hop
    )
    best = np.flatnonzero(clear & hop)[np.argmax(paper.scores[clear & hop])]
    assert choice.index == best and clear[choice.index]
    assert choice.score == paper.scores[best]
    np.testing.assert_array_equal(choice.target_m, c.points_m[best])
    if strategy == "gpv":  # the paper's choice is blocked, and so are the others scored above the choice
        blocked = np.flatnonzero(~clear & hop & (paper.scores > choice.score))
        assert not clear[paper.index] and len(blocked) > 32  # more than one batch of 32 was checked
        assert not choice.scores[blocked].any()  # checked and found blocked: score 0
    assert planner.take_counts() == {}


def test_random_chooses_uniformly_among_the_clear_admissible_targets_with_the_same_draw() -> None:
    V, N = ball()
    top = V[np.argmax(V[:, 2])]
    config = PlannerConfig(strategy="random")
    planner = TouchPlanner(config)
    planner.add_touch(top, np.full(3, np.nan), [0.0, 0.0, -1.0])
    tip = (top + TIP_M * np.array([0.0, 0.0, 1.0]), DOWN_WXYZ)
    plan = planner.plan("local", 1, V, N, np.ones(len(V)), tip, np.random.default_rng(3))
    assert plan is not None
    c = plan.candidates
    centres = c.points_m + TIP_M * c.normals
    clear = curves_clear(V, N, tip[0], [0.0, 0.0, -1.0], centres, c.normals, TIP_M - config.curve_margin_m)
    ok = clear & (np.linalg.norm(centres - tip[0], axis=1) >= config.min_hop_m)
    assert 0 < ok.sum() < len(ok)
    assert plan.selection.index == np.flatnonzero(ok)[np.random.default_rng(3).integers(ok.sum())]


def test_when_no_curve_is_clear_the_papers_choice_is_kept_and_counted() -> None:
    """Normals pointing into the plane put everything above it inside the estimate: no curve is clear."""
    V, N = plane()
    config = PlannerConfig(strategy="igef")
    planner = touched_at_origin(config)
    plan = planner.plan("local", 1, V, -N, np.ones(len(V)), over(np.zeros(3)), np.random.default_rng(0))
    assert plan is not None
    c = plan.candidates
    centres = c.points_m + TIP_M * c.normals
    hop = np.linalg.norm(centres - over(np.zeros(3))[0], axis=1) >= config.min_hop_m
    rng = np.random.default_rng(0)
    paper = Planner(config).select(
        c.points_m, c.normals, c.variance, np.zeros((1, 3)), np.zeros(3), [0, 0, -1.0], [0, 0, -1.0], rng, hop
    )
    assert plan.selection.index == paper.index
    np.testing.assert_array_equal(plan.selection.scores, paper.scores)
    assert planner.take_counts() == {"no_clear_curve": 1}


def test_gpv_on_the_variance_at_its_candidates_chooses_as_on_the_variance_everywhere() -> None:
    """The GPIS node's vertex_variance "candidates" (thin_near with GP-V's step and radius) loses nothing."""
    V, N = plane(step=0.002)
    rng = np.random.default_rng(4)
    variance = rng.uniform(0.0, 1e-4, len(V))
    config = PlannerConfig(strategy="gpv")
    full = touched_at_origin(config).plan("local", 1, V, N, variance, over(np.zeros(3)), np.random.default_rng(0))
    sites = thin_near(V, np.zeros(3), config.candidate_step_m, config.gpv_radius_m).astype(np.int32)
    assert 0 < len(sites) < len(V) / 2
    part = touched_at_origin(config).plan(
        "local", 1, V, N, variance[sites], over(np.zeros(3)), np.random.default_rng(0), variance_vertices=sites
    )
    assert full is not None and part is not None
    np.testing.assert_array_equal(part.candidates.points_m, full.candidates.points_m)
    np.testing.assert_array_equal(part.selection.target_m, full.selection.target_m)


def test_variance_vertices_out_of_range_or_unordered_are_refused_by_name() -> None:
    V, N = plane()
    planner = touched_at_origin(PlannerConfig(strategy="gpv"))
    for bad in ([0, len(V)], [3, 2], [-1, 4]):
        with pytest.raises(InputError, match=r"^variance_vertices: must be ascending distinct"):
            planner.plan(
                "local", 1, V, N, np.ones(2), over(np.zeros(3)), np.random.default_rng(0), variance_vertices=bad
            )
    with pytest.raises(InputError, match=r"^vertex_variance: has 3 values for 2 variance_vertices"):
        planner.plan(
            "local", 1, V, N, np.ones(3), over(np.zeros(3)), np.random.default_rng(0), variance_vertices=[0, 1]
        )
    assert planner.planned_for == 0  # refused before anything changed


@pytest.mark.parametrize("strategy", ["igef", "gpv", "tour"])
def test_vertices_without_a_normal_are_no_candidates_and_other_normals_must_be_unit(strategy: str) -> None:
    """The GPIS node sends a zero normal where the GP's gradient vanishes: such a vertex is left out of
    the candidates (it was a PlanningError that ended the run); a row neither unit nor zero is refused
    by name before anything changes."""
    V, N = plane()
    N = N.copy()
    N[np.linalg.norm(V, axis=1) < 0.03] = 0.0  # every vertex near the last contact
    variance = np.ones(len(V))
    plan = touched_at_origin(PlannerConfig(strategy=strategy)).plan(
        "local", 1, V, N, variance, over(np.zeros(3)), np.random.default_rng(0)
    )
    assert plan is not None
    assert np.all(np.linalg.norm(plan.candidates.points_m, axis=1) >= 0.03)
    np.testing.assert_allclose(np.linalg.norm(plan.candidates.normals, axis=1), 1.0)
    N[5] = [0.0, 0.0, 0.3]
    planner = touched_at_origin(PlannerConfig(strategy=strategy))
    with pytest.raises(InputError, match=r"^vertex_normals: row 5 has norm 0.3, neither 0 nor 1"):
        planner.plan("local", 1, V, N, variance, over(np.zeros(3)), np.random.default_rng(0))
    assert planner.planned_for == 0


def test_gpv_on_a_mesh_without_variance_names_the_gpis_setting() -> None:
    V, N = plane()
    planner = touched_at_origin(PlannerConfig(strategy="gpv"))
    with pytest.raises(PlanningError, match="vertex_variance to candidates, all or auto"):
        planner.plan("local", 1, V, N, np.zeros(0), over(np.zeros(3)), np.random.default_rng(0), variance_vertices=[])


@pytest.mark.parametrize(
    ("config", "normal", "slides"),
    [
        (PlannerConfig(strategy="tour"), [0.0, 0.0, 1.0], True),  # the tour slides by default
        (PlannerConfig(strategy="igef"), [0.0, 0.0, 1.0], False),  # the paper's strategies lift
        (PlannerConfig(strategy="igef", slide_max_m=0.06), [0.0, 0.0, 1.0], True),  # any strategy may
        (PlannerConfig(strategy="igef", tour_slide_max_m=0.06), [0.0, 0.0, 1.0], False),  # the tour's alone
        (PlannerConfig(strategy="tour", tour_slide_max_m=0.0), [0.0, 0.0, 1.0], False),  # the tour lifting
        (PlannerConfig(strategy="tour", tour_slide_max_m=0.001), [0.0, 0.0, 1.0], False),  # too far
        (PlannerConfig(strategy="tour", slide_max_angle_deg=30.0), [0.0, 0.6, 0.8], False),  # 37 deg off
        (PlannerConfig(strategy="tour", slide_max_angle_deg=40.0), [0.0, 0.6, 0.8], True),
        (PlannerConfig(strategy="tour"), [0.0, 0.0, 0.0], False),  # no normal given
    ],
)
def test_a_target_near_the_last_contact_and_facing_as_it_does_is_reached_by_a_slide(
    config: PlannerConfig, normal: list[float], slides: bool
) -> None:
    V, N = plane()
    planner = TouchPlanner(config)
    planner.add_touch(np.zeros(3), np.full(3, np.nan), [0.0, 0.0, -1.0], normal)
    plan = planner.plan("local", 1, V, N, np.ones(len(V)), over(np.zeros(3)), np.random.default_rng(0))
    assert plan is not None
    assert np.linalg.norm(plan.selection.target_m) > 0.001  # every target of the plane lies that far
    assert plan.selection.slide is slides


def test_a_target_exactly_at_the_slide_reach_is_reached_by_a_slide() -> None:
    V, N = plane()
    rng = np.random.default_rng(0)

    def plan(reach_m: float) -> tuple[np.ndarray, bool]:
        planner = TouchPlanner(PlannerConfig(strategy="igef", slide_max_m=reach_m))
        planner.add_touch(np.zeros(3), np.full(3, np.nan), [0.0, 0.0, -1.0], [0.0, 0.0, 1.0])
        plan = planner.plan("local", 1, V, N, np.ones(len(V)), over(np.zeros(3)), rng)
        assert plan is not None
        return plan.selection.target_m, plan.selection.slide

    target, _ = plan(0.06)
    reach = float(np.linalg.norm(target))  # the chosen target's distance from the contact at the origin
    at_reach, slides = plan(reach)
    np.testing.assert_array_equal(at_reach, target)  # the same choice (the reach decides only the slide)
    assert slides  # a target at the reach lies within it (<=)
    assert plan(float(np.nextafter(reach, 0.0)))[1] is False  # a hair less: it lifts


@pytest.mark.parametrize("strategy", ["igef", "gpv", "tour"])
def test_an_approach_direction_within_the_messages_tolerance_plans(strategy: str) -> None:
    """approach_curve refuses directions that are not unit vectors; one the planner takes from a touch
    (norm within palpate.inputs.UNIT_TOLERANCE, a driver's float32 arithmetic) still plans."""
    V, N = plane()
    planner = TouchPlanner(PlannerConfig(strategy=strategy))
    planner.add_touch(np.zeros(3), np.full(3, np.nan), [0.0, 0.0, -1.008])
    assert planner.plan("local", 1, V, N, np.ones(len(V)), over(np.zeros(3)), np.random.default_rng(0)) is not None
