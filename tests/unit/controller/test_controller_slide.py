"""Slides (TouchTarget.slide, not in the paper): the fingertip moves to the target along the surface."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from palpate.nodes.controller.core import Touch, TouchConfig, TouchLoop
from palpate.nodes.controller.trajectory import ControllerConfig, ControllerState

DT_S = 0.01
TICK_NS = 10_000_000
UP = np.array([0.0, 0.0, 1.0])
R_DOWN = np.diag([1.0, -1.0, -1.0])  # the fingertip pokes along -z
NONE = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

#: Projects a point fingertip out of the object (as the simulated probe is) and says whether it touches.
Surface = Callable[[np.ndarray], tuple[np.ndarray, bool]]


def floor(p: np.ndarray) -> tuple[np.ndarray, bool]:
    """The plane z = 0, object below."""
    return (np.array([p[0], p[1], 0.0]), True) if p[2] <= 0.0 else (p, False)


def step_down_at_1cm(p: np.ndarray) -> tuple[np.ndarray, bool]:
    """A top face z = 0 for x < 1 cm, and 2 mm lower beyond: an edge the fingertip slides off."""
    height = 0.0 if p[0] < 0.01 else -0.002
    return (np.array([p[0], p[1], height]), True) if p[2] <= height else (p, False)


def wall_at_5mm(p: np.ndarray) -> tuple[np.ndarray, bool]:
    """The floor and a wall x >= 5 mm that the fingertip cannot pass."""
    q, touching = floor(p)
    if q[0] > 0.005:
        q, touching = np.array([0.005, q[1], q[2]]), True
    return q, touching


def touched_at_origin() -> TouchLoop:
    """A point fingertip (radius 0) that has touched the floor at the origin and waits for a target."""
    loop = TouchLoop(TouchConfig(tip_radius_m=0.0), ControllerConfig(), initial_target_m=(0.0, 0.0, -0.01))
    r = np.array([0.0, 0.0, 0.01])
    for tick in range(100):
        r, touching = floor(r)
        contacts = (r[None, :], UP[None, :], np.ones(1)) if touching else NONE
        step = loop.step(tick * TICK_NS, r, R_DOWN, *contacts)
        if step.touch is not None:
            return loop
        r = r + DT_S * step.linear_m_s
    raise AssertionError("no first touch")


def run_slide(
    loop: TouchLoop, surface: Surface, target: list[float], ticks: int = 500, noise_m: float = 0.0
) -> tuple[Touch | None, int, float]:
    """Aim at `target` (normal +z) with a slide from the fingertip at the origin and drive it: the touch,
    the ticks it took and the highest the fingertip rose above the surface on the way (metres);
    ``noise_m``: Gaussian noise on each reported contact position (seeded)."""
    rng = np.random.default_rng(0)
    r = loop.arming.last_fingertip.copy()
    P = loop.aim(r, R_DOWN, np.array(target), UP, np.array(target), slide=True)
    np.testing.assert_allclose(P[[0, 3]], [r, target], atol=1e-15)  # displayed as the straight line
    lift = 0.0
    for tick in range(ticks):
        r, touching = surface(r)
        reported = r + rng.normal(0.0, noise_m, 3) if noise_m else r
        contacts = (reported[None, :], UP[None, :], np.ones(1)) if touching else NONE
        if not touching:
            lift = max(lift, float(r[2] - surface(r - 0.05 * UP)[0][2]))
        step = loop.step((1000 + tick) * TICK_NS, r, R_DOWN, *contacts)
        assert not step.failed
        if step.touch is not None:
            return step.touch, tick, lift
        r = r + DT_S * step.linear_m_s
    return None, ticks, lift


def test_a_slide_reaches_its_target_along_the_surface_and_travels_its_length() -> None:
    loop = touched_at_origin()
    target = [0.02, 0.01, 0.0]
    touch, _, lift = run_slide(loop, floor, target)
    assert touch is not None and touch.index == 1 and not touch.missed
    assert np.linalg.norm(touch.position_m - target) <= TouchConfig().slide_arrive_m
    assert lift == 0.0  # in contact all the way
    distance = float(np.linalg.norm(target))
    assert distance - 0.001 <= touch.travelled_m <= distance + 0.0005  # no lift: the chord, to a step
    np.testing.assert_allclose(touch.approach_direction, -UP)  # slid in: the next curve lifts off along +z
    assert loop.slides == 1 and loop.slide is None and loop.controller.state is ControllerState.IDLE


def test_noise_on_the_contact_points_does_not_end_a_slide_early() -> None:
    """Progress is measured on the fingertip's pose: 1 mm of noise on the contact points (the noise
    sweep's largest) neither stops the slide at its first ticks nor makes it wander."""
    loop = touched_at_origin()
    target = [0.03, 0.0, 0.0]
    touch, ticks, _ = run_slide(loop, floor, target, noise_m=0.001)
    assert touch is not None and ticks >= 58  # 3 cm at 0.5 mm per tick
    assert np.linalg.norm(loop.arming.last_fingertip - target) <= TouchConfig().slide_arrive_m
    assert touch.travelled_m < 0.0305


def test_a_slide_that_loses_the_surface_next_to_its_target_goes_back_to_where_it_touched() -> None:
    """Within MIN_SLIDE_CURVE_M of the target the curve would be too short to follow."""
    loop = touched_at_origin()
    target = [0.013, 0.0, -0.002]
    touch, _, lift = run_slide(loop, step_down_at_1cm, target)
    assert touch is not None and lift > 0.0
    assert 0.0095 <= touch.position_m[0] <= 0.0101 and touch.position_m[2] == 0.0  # the top face, at the edge


def test_a_slide_off_an_edge_finishes_along_the_curve_and_touches_the_target() -> None:
    loop = touched_at_origin()
    target = [0.025, 0.0, -0.002]
    touch, _, lift = run_slide(loop, step_down_at_1cm, target)
    assert touch is not None and lift > 0.0  # it left the surface at the edge
    assert np.linalg.norm(touch.position_m - target) < 0.002
    assert touch.travelled_m < 0.035


def test_a_slide_held_by_a_wall_ends_with_a_touch_in_bounded_time() -> None:
    loop = touched_at_origin()
    touch, ticks, _ = run_slide(loop, wall_at_5mm, [0.01, 0.0, 0.0])
    assert touch is not None
    assert touch.position_m[0] == pytest.approx(0.005)
    # its budget: twice the distance plus slide_slack_m, 3 cm, at 5 cm/s: 60 ticks
    assert ticks <= 62


def test_a_slide_asked_for_out_of_contact_is_an_ordinary_curve() -> None:
    loop = touched_at_origin()
    r = loop.arming.last_fingertip.copy()
    loop.step(2000 * TICK_NS, r + 0.003 * UP, R_DOWN, *NONE)  # the fingertip has left the surface
    loop.aim(r + 0.003 * UP, R_DOWN, np.array([0.02, 0.0, 0.0]), UP, np.zeros(3), slide=True)
    assert loop.slide is None and loop.controller.state is ControllerState.APPROACH


def test_a_slide_under_noisy_normals_arrives_when_it_weighs_them_down() -> None:
    """Normals tilted 5 deg at random (a real sensor): the contact point the fingertip's pose and normal
    place moves by tip_radius x tilt, and slides ended as 'passed' far from their targets; weighing each
    new normal 0.3 against the slide's earlier ones brings every one to its target."""
    rng = np.random.default_rng(0)

    def slide(weight: float) -> float:
        loop = TouchLoop(
            TouchConfig(tip_radius_m=0.008, slide_normal_weight=weight),
            ControllerConfig(),
            initial_target_m=(0.0, 0.0, -0.01),
        )
        r = np.array([0.0, 0.0, 0.02])
        target = np.array([0.03, 0.0, 0.0])
        aimed = False
        for tick in range(600):
            touching = r[2] <= 0.008
            if touching:
                r = np.array([r[0], r[1], 0.008])
                tilt = UP + np.radians(5.0) * rng.normal(size=3) * np.array([1.0, 1.0, 0.0])
                contacts = (np.array([[r[0], r[1], 0.0]]), (tilt / np.linalg.norm(tilt))[None, :], np.ones(1))
            step = loop.step(tick * TICK_NS, r, R_DOWN, *(contacts if touching else NONE))
            if step.touch is not None and aimed:
                return float(np.linalg.norm(r[:2] - target[:2]))
            if step.touch is not None:
                loop.aim(r, R_DOWN, target, UP, target + 0.008 * UP, slide=True)
                aimed = True
                continue
            r = r + DT_S * step.linear_m_s
        raise AssertionError("no touch")

    latest = [slide(1.0) for _ in range(5)]
    weighed = [slide(0.3) for _ in range(5)]
    assert max(latest) > 0.01  # some slides ended centimetres short
    assert max(weighed) < 0.002


def test_a_slide_whose_contact_is_exactly_slide_arrive_m_from_the_target_has_arrived() -> None:
    loop = touched_at_origin()
    r = loop.arming.last_fingertip.copy()
    target = r + np.array([TouchConfig().slide_arrive_m, 0.0, 0.0])  # 1 mm along the floor: arrived (<=)
    loop.aim(r, R_DOWN, target, UP, target, slide=True)
    step = loop.step(1000 * TICK_NS, r, R_DOWN, r[None, :], UP[None, :], np.ones(1))
    assert step.touch is not None and loop.slide is None


def test_a_slide_turns_the_fingertip_so_that_it_faces_the_target_normal_on_arrival() -> None:
    """The target's normal tilted 0.3 rad from the floor's: the fingertip turns 0.3 rad over the
    2 cm still to go at v0 = 5 cm/s (0.4 s), at 0.75 rad/s about y."""
    loop = touched_at_origin()
    r = loop.arming.last_fingertip.copy()
    tilted = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    target = r + np.array([0.02, 0.0, 0.0])
    loop.aim(r, R_DOWN, target, tilted, target, slide=True)
    step = loop.step(1000 * TICK_NS, r, R_DOWN, r[None, :], UP[None, :], np.ones(1))
    assert step.touch is None
    np.testing.assert_allclose(np.abs(step.angular_rad_s), [0.0, 0.3 / 0.4, 0.0], atol=1e-9)


def test_a_slide_ends_once_the_fingertip_has_moved_its_travel_budget() -> None:
    """A fingertip shaken 3 mm sideways a tick while it stays in contact (its poses jump) ends its slide by
    the travel budget, long before the time budget (2.2 s = 220 ticks): twice the 5 cm to the target plus
    slide_slack_m's 1 cm, 0.11 m travelled from the slide's start (the odometer already reads the first
    slide's 2 cm). The moves are 1.5 mm then 3 mm a tick: 0.0015 + 0.003 x 37 = 0.1125 m >= 0.11 m after
    tick 38, so tick 39 ends it, its own 3 mm step counted with the touch (0.1155 m)."""
    loop = touched_at_origin()
    first, _, _ = run_slide(loop, floor, [0.02, 0.0, 0.0])
    assert first is not None and loop.travelled_m > 0.019
    start_m = loop.travelled_m
    r0 = loop.arming.last_fingertip.copy()
    target = r0 + np.array([0.05, 0.0, 0.0])
    loop.aim(r0, R_DOWN, target, UP, target, slide=True)
    for tick in range(300):
        r = r0 + np.array([0.0, 0.0015 * (-1) ** tick if tick else 0.0, 0.0])
        step = loop.step((5000 + tick) * TICK_NS, r, R_DOWN, r[None, :], UP[None, :], np.ones(1))
        if step.touch is not None:
            break
    assert tick == 39
    assert loop.travelled_m - start_m == pytest.approx(0.1155)
