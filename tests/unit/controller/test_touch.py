"""TouchArming (when a contact is a new touch) and TouchLoop (Algorithm 1's controller side), no MuJoCo."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from palpate.nodes.controller.core import (
    AXIS_APPROACH_M,
    HELD_M,
    ControlStep,
    Touch,
    TouchArming,
    TouchConfig,
    TouchLoop,
    retract_direction,
)
from palpate.nodes.controller.trajectory import ControllerConfig, ControllerState

DT_S = 0.01
TICK_NS = 10_000_000
UP = np.array([0.0, 0.0, 1.0])
NONE = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


def contact(at: list[float] | np.ndarray, force_n: float = 1.0, normal: np.ndarray = UP) -> tuple[np.ndarray, ...]:
    """One contact: positions (1, 3), normals (1, 3), forces (1,)."""
    return np.array([at], dtype=np.float64), np.array([normal]), np.array([force_n])


# --- TouchArming ------------------------------------------------------------------------------------


FORCE = np.array([1.0])  # one contact pushing
TIP_M = 0.008  # the fingertip's centre lies this far above a contact on a z-up surface


def slid(x: float, y: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fingertip and its contact, slid together to (x, y) on the plane z = 0: fingertip (3,),
    contact positions (1, 3), forces (1,)."""
    return np.array([x, y, TIP_M]), np.array([[x, y, 0.0]]), FORCE


def touched_arming(config: TouchConfig) -> TouchArming:
    """An arming that has announced a touch at the origin and then got a new target."""
    arming = TouchArming(config)
    assert arming.update(0, *slid(0.0))
    arming.touched(np.zeros(3), np.array([0.0, 0.0, TIP_M]))
    arming.disarm()
    return arming


def test_armed_at_first_disarmed_by_a_target_and_rearmed_when_the_contact_is_lost() -> None:
    arming = TouchArming(TouchConfig())
    assert arming.armed
    arming.disarm()
    assert not arming.update(0, *slid(0.0))
    assert arming.update(TICK_NS, np.zeros(3), NONE[0], NONE[2])  # the fingertip left the surface


def test_staying_in_contact_never_rearms_before_the_first_touch() -> None:
    arming = TouchArming(TouchConfig())
    arming.disarm()
    for tick in range(100):  # slid 10 cm, pushed for 1 s
        assert not arming.update(tick * TICK_NS, *slid(0.001 * tick))


def test_sliding_beyond_rearm_distance_rearms() -> None:
    arming = touched_arming(TouchConfig(rearm_distance_m=0.003, rearm_push_s=0.0))
    assert not arming.update(TICK_NS, *slid(0.0029))
    assert arming.update(2 * TICK_NS, *slid(0.0, 0.0031))
    off = touched_arming(TouchConfig(rearm_distance_m=0.0, rearm_push_s=0.0))
    assert not off.update(TICK_NS, *slid(0.05))  # 0 disables it


def test_sliding_exactly_rearm_distance_does_not_rearm() -> None:
    # both the fingertip and its contact 3 mm (exactly, sqrt(0.003^2)) from the last touch: not "more than"
    arming = touched_arming(TouchConfig(rearm_distance_m=0.003, rearm_push_s=0.0))
    assert not arming.update(TICK_NS, *slid(0.003))


def test_the_fingertip_rolling_over_an_edge_does_not_rearm() -> None:
    # the contact stays on the edge at the origin while the fingertip's centre turns about it by 60 deg
    arming = touched_arming(TouchConfig(rearm_distance_m=0.003, rearm_push_s=0.0))
    rolled = TIP_M * np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    assert not arming.update(TICK_NS, rolled, np.zeros((1, 3)), FORCE)


def test_the_strongest_contact_decides_the_slide() -> None:
    arming = touched_arming(TouchConfig(rearm_distance_m=0.003, rearm_push_s=0.0))
    tip, positions = np.array([0.01, 0.0, TIP_M]), np.array([[0.01, 0.0, 0.0], [0.001, 0.0, 0.0]])
    assert not arming.update(TICK_NS, tip, positions, np.array([0.5, 2.0]))
    assert arming.update(2 * TICK_NS, tip, positions, np.array([2.0, 0.5]))


def test_a_contact_reading_that_jumps_while_the_fingertip_stays_does_not_rearm() -> None:
    # 1 mm of position noise moves two readings of one contact more than 3 mm apart one time in four:
    # measured on the contact points, one press counted as several touches, with no travel between them
    loop = TouchLoop(TouchConfig(rearm_push_s=0.0), ControllerConfig(), initial_target_m=np.zeros(3))
    r = np.array([0.0, 0.0, 0.008])
    loop.step(0, r + UP, R_DOWN, *NONE)  # the initial approach starts
    assert loop.step(TICK_NS, r, R_DOWN, *contact([0.0, 0.0, 0.0])).touch is not None
    loop.aim(r, R_DOWN, np.array([0.01, 0.0, 0.0]), UP, np.array([0.01, 0.0, 0.0]))
    for tick, jump in enumerate(([0.005, 0.0, 0.0], [0.0, -0.006, 0.0], [0.004, 0.004, 0.0]), start=2):
        assert loop.step(tick * TICK_NS, r, R_DOWN, *contact(jump)).touch is None


def test_pushing_without_interruption_for_rearm_push_s_rearms() -> None:
    arming = touched_arming(TouchConfig(rearm_distance_m=0.0, rearm_push_s=0.1))

    def push(tick: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return slid(0.2 * HELD_M * tick)  # creeping, so never held in place for 0.1 s

    assert not arming.update(1 * TICK_NS, *push(1))  # the push starts here
    assert not arming.update(10 * TICK_NS, *push(10))  # 0.09 s
    assert not arming.update(11 * TICK_NS, *push(11)[:2], np.array([0.0]))  # an interruption: the clock restarts
    assert not arming.update(12 * TICK_NS, *push(12))
    assert not arming.update(21 * TICK_NS, *push(21))  # 0.09 s since the restart
    assert arming.update(22 * TICK_NS, *push(22))  # 0.1 s
    assert arming.push_since_ns is None
    off = touched_arming(TouchConfig(rearm_distance_m=0.0, rearm_push_s=0.0))
    assert not any(off.update(tick * TICK_NS, *slid(0.0)) for tick in range(1, 200))  # 0 disables it


def test_a_fingertip_held_in_place_in_contact_for_rearm_push_s_rearms_whatever_the_force() -> None:
    """Wedged in a gap, the reported contact need not push (force 0) while another blocks the fingertip."""
    arming = touched_arming(TouchConfig(rearm_distance_m=0.0, rearm_push_s=0.1))
    tip, positions = slid(0.0)[:2]
    unforced = np.array([0.0])
    assert not arming.update(1 * TICK_NS, tip, positions, unforced)  # held from here
    assert not arming.update(10 * TICK_NS, tip + 0.5 * HELD_M, positions, unforced)  # 0.09 s, within HELD_M
    assert not arming.update(11 * TICK_NS, tip + 2 * HELD_M, positions, unforced)  # it moved: the clock restarts
    assert not arming.update(20 * TICK_NS, tip + 2 * HELD_M, positions, unforced)
    assert arming.update(21 * TICK_NS, tip + 2 * HELD_M, positions, unforced)  # 0.1 s since
    assert arming.held is None
    arming.disarm()  # a new target: the fingertip waited in place for it, which is no hold
    assert not arming.update(100 * TICK_NS, tip, positions, unforced)


def test_a_new_target_restarts_the_held_in_place_clock() -> None:
    """Held in place (force 0) from tick 1; a new target at tick 6 starts the 0.1 s over from tick 11."""
    arming = touched_arming(TouchConfig(rearm_distance_m=0.0, rearm_push_s=0.1))
    tip, positions = slid(0.0)[:2]
    unforced = np.array([0.0])
    assert not arming.update(1 * TICK_NS, tip, positions, unforced)  # held from here
    assert not arming.update(6 * TICK_NS, tip, positions, unforced)
    arming.disarm()  # a new target
    assert not arming.update(11 * TICK_NS, tip, positions, unforced)  # 0.1 s since tick 1, but held anew from here
    assert not arming.update(20 * TICK_NS, tip, positions, unforced)  # 0.09 s since tick 11
    assert arming.update(21 * TICK_NS, tip, positions, unforced)  # 0.1 s since tick 11


def test_v_n_exactly_at_the_retract_cosine_is_kept() -> None:
    # v_n . (-n) = 0.8 exactly, the cosine asked for: v_n points into the surface enough (>=)
    v_n = np.array([0.6, 0.0, -0.8])
    np.testing.assert_array_equal(retract_direction(v_n, UP, 0.8), v_n)
    np.testing.assert_array_equal(retract_direction(v_n, UP, 0.81), -UP)


# --- TouchLoop ----------------------------------------------------------------------------------------

Inside = Callable[[np.ndarray], bool]
R_DOWN = np.diag([1.0, -1.0, -1.0])  # poking axis R[:, 2] = -z


def drive(loop: TouchLoop, r: np.ndarray, inside: Inside, ticks: int = 2000) -> tuple[np.ndarray, Touch | None]:
    """Integrate r += v dt (orientation held) until a touch or `ticks`; a point fingertip touches the
    object where `inside` holds, with the contact at the fingertip and normal +z."""
    for tick in range(ticks):
        contacts = contact(r) if inside(r) else NONE
        step = loop.step(tick * TICK_NS, r, R_DOWN, *contacts)
        if step.touch is not None:
            assert not step.linear_m_s.any() and not step.angular_rad_s.any()
            return r, step.touch
        r = r + DT_S * step.linear_m_s
    return r, None


def below_plane(p: np.ndarray) -> bool:
    return bool(p[2] <= 0.0)


def box_with_edge_at_1cm(p: np.ndarray) -> bool:
    """Object filling x < 0.01 m, z < 0: its top face ends at an edge x = 0.01 m."""
    return bool(p[0] < 0.01 and p[2] <= 0.0)


def point_loop(**touch: float) -> TouchLoop:
    return TouchLoop(TouchConfig(tip_radius_m=0.0, **touch), ControllerConfig(), initial_target_m=(0.0, 0.0, -0.01))


def test_the_initial_approach_ends_in_touch_0_and_the_fingertip_waits_for_a_target() -> None:
    loop = point_loop()
    r, touch = drive(loop, np.array([0.0, 0.0, 0.02]), below_plane)
    assert touch is not None and touch.index == 0 and loop.touches == 1
    np.testing.assert_allclose(touch.position_m, r)
    assert r[2] == pytest.approx(0.0, abs=0.05 * DT_S + 1e-12)
    np.testing.assert_allclose(touch.normal, UP)
    np.testing.assert_allclose(touch.approach_direction, [0.0, 0.0, -1.0])  # straight into the surface
    assert np.isnan(touch.predicted_contact_m).all() and not touch.missed
    assert touch.travelled_m == 0.0  # the initial approach is not an exploratory action
    assert loop.controller.state is ControllerState.IDLE
    # Still in contact and no target: zero command, no second touch.
    step = loop.step(10**9, r, R_DOWN, *contact(r))
    assert step.touch is None and not step.linear_m_s.any() and not step.failed


def test_a_target_is_reached_on_its_curve_and_the_contact_it_starts_in_is_not_a_touch() -> None:
    loop = point_loop()
    r, _ = drive(loop, np.array([0.0, 0.0, 0.02]), below_plane)
    target, predicted = np.array([0.02, 0.01, 0.0]), np.array([0.02, 0.01, 0.001])
    P = loop.aim(r, R_DOWN, target, UP, predicted)
    np.testing.assert_allclose(P[0], r)
    np.testing.assert_allclose(P[3], target)
    step = loop.step(0, r, R_DOWN, *contact(r))  # still touching the last contact: moving, but disarmed
    assert step.touch is None and step.linear_m_s.any()
    r, touch = drive(loop, r + DT_S * step.linear_m_s, below_plane)
    assert touch is not None and touch.index == 1
    assert np.linalg.norm(touch.position_m - target) < 1e-3
    np.testing.assert_array_equal(touch.predicted_contact_m, predicted)
    assert touch.travelled_m == pytest.approx(loop.travelled_m) and touch.travelled_m > 0.02


def test_the_curve_guides_the_fingertip_centre_one_radius_off_the_target() -> None:
    loop = TouchLoop(TouchConfig(tip_radius_m=0.008), ControllerConfig(), initial_target_m=(0.0, 0.0, -0.01))
    r = np.array([0.0, 0.0, 0.008])
    assert loop.step(0, r, R_DOWN, *contact([0.0, 0.0, 0.0])).touch is not None
    normal = np.array([0.0, 0.6, 0.8])
    P = loop.aim(r, R_DOWN, np.array([0.02, 0.0, 0.0]), normal, np.zeros(3))
    np.testing.assert_allclose(P[3], [0.02, 0.0048, 0.0064], atol=1e-15)


@pytest.mark.parametrize(
    ("start", "min_cos", "expected"),
    [
        ([-0.06, 0.0, 0.08], 0.5, [0.6, 0.0, -0.8]),  # into the surface (cos 0.8): Eq. 15's v_n
        ([-0.1, 0.0, 0.0], 0.5, [0.0, 0.0, -1.0]),  # sliding along it: lift off along the normal
        ([-0.1, 0.0, 0.0], -1.0, [1.0, 0.0, 0.0]),  # -1 keeps Eq. 15 as written
    ],
)
def test_a_touch_retracts_along_v_n_only_when_v_n_points_into_the_surface(
    start: list[float], min_cos: float, expected: list[float]
) -> None:
    loop = TouchLoop(TouchConfig(retract_min_cos=min_cos), ControllerConfig(), initial_target_m=(0.0, 0.0, 0.0))
    step = loop.step(0, np.array(start), R_DOWN, *contact([0.0, 0.0, 0.0]))  # touching at once
    assert isinstance(step, ControlStep) and step.touch is not None
    np.testing.assert_allclose(step.touch.approach_direction, expected, atol=1e-12)
    np.testing.assert_allclose(loop.retract_from, expected, atol=1e-12)


def test_a_touch_made_by_the_recovery_curve_is_marked_missed() -> None:
    loop = point_loop()
    r, first = drive(loop, np.array([0.0, 0.0, 0.02]), box_with_edge_at_1cm)
    assert first is not None and not first.missed
    loop.aim(r, R_DOWN, np.array([0.03, 0.0, 0.0]), UP, np.array([0.03, 0.0, 0.0]))  # beyond the edge
    r, touch = drive(loop, r, box_with_edge_at_1cm)
    assert touch is not None and touch.index == 1 and touch.missed
    assert loop.controller.recoveries == 1
    assert r[0] == pytest.approx(0.01, abs=1e-3)  # back on the side face below the edge
    loop.aim(r, R_DOWN, np.array([0.0, 0.0, 0.0]), UP, np.zeros(3))
    _, again = drive(loop, r, box_with_edge_at_1cm)
    assert again is not None and again.index == 2 and not again.missed  # counted once


def test_a_touch_made_by_the_straight_return_is_marked_missed_and_keeps_the_run_going() -> None:
    """The recovery curve passes the last contact by (here the object is only touchable once the
    straight return has started: a stand-in for a rim the curve slid past); the straight return
    touches at the last contact, a missed touch, and the loop has not failed."""
    loop = point_loop()
    r, first = drive(loop, np.array([0.0, 0.0, 0.02]), below_plane)
    assert first is not None
    loop.aim(r, R_DOWN, np.array([0.03, 0.0, 0.0]), UP, np.array([0.03, 0.0, 0.0]))
    r, touch = drive(loop, r, lambda p: loop.controller.straight_returns > 0 and bool(np.linalg.norm(p - r) < 1e-3))
    assert touch is not None and touch.index == 1 and touch.missed
    assert (loop.controller.recoveries, loop.controller.straight_returns) == (1, 1)
    np.testing.assert_allclose(touch.position_m, first.position_m, atol=1e-3)  # back at the last contact
    np.testing.assert_array_equal(touch.predicted_contact_m, [0.03, 0.0, 0.0])  # 3 cm off: unreached
    assert not loop.step(0, touch.position_m, R_DOWN, *NONE).failed


def test_an_initial_approach_into_nothing_fails() -> None:
    loop = point_loop()
    r, touch = drive(loop, np.array([0.0, 0.0, 0.02]), lambda p: False, ticks=200)
    assert touch is None
    step = loop.step(0, r, R_DOWN, *NONE)
    assert step.failed and not step.linear_m_s.any()
    assert r[2] == pytest.approx(-0.02, abs=0.05 * DT_S)  # 1 cm past the initial target


R_FACING_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # poking axis R[:, 2] = +x


def drive_facing_x(loop: TouchLoop, wall_x: float, ticks: int) -> tuple[np.ndarray, ControlStep]:
    """From (0, 0.1, 0.2) with the poking axis +x until a touch, a failure or ``ticks``: a point fingertip
    touches the wall x >= wall_x. Returns the last position and step."""
    r = np.array([0.0, 0.1, 0.2])
    for tick in range(ticks):
        contacts = contact(r, normal=np.array([-1.0, 0.0, 0.0])) if r[0] >= wall_x else NONE
        step = loop.step(tick * TICK_NS, r, R_FACING_X, *contacts)
        if step.touch is not None or step.failed:
            return r, step
        r = r + DT_S * step.linear_m_s
    return r, step


def test_without_an_initial_target_the_first_approach_runs_along_the_poking_axis() -> None:
    loop = TouchLoop(TouchConfig(tip_radius_m=0.0), ControllerConfig())
    r, step = drive_facing_x(loop, wall_x=0.03, ticks=200)
    assert step.touch is not None and step.touch.index == 0
    np.testing.assert_allclose(step.touch.approach_direction, [1.0, 0.0, 0.0], atol=1e-12)
    assert r[0] == pytest.approx(0.03, abs=0.05 * DT_S + 1e-12) and r[1:].tolist() == [0.1, 0.2]


def test_without_an_initial_target_and_no_surface_the_first_approach_fails_past_its_reach() -> None:
    loop = TouchLoop(TouchConfig(tip_radius_m=0.0), ControllerConfig())
    r, step = drive_facing_x(loop, wall_x=math.inf, ticks=2000)
    assert step.failed and step.touch is None
    # AXIS_APPROACH_M along the axis, then the controller's 1 cm miss distance
    assert r[0] == pytest.approx(AXIS_APPROACH_M + 0.01, abs=0.05 * DT_S + 1e-9)


@pytest.mark.parametrize("initial_target_m", [(0.0, 0.0, 0.0), None])
def test_a_pose_at_the_initial_target_or_the_origin_waits_instead_of_starting(
    initial_target_m: tuple[float, float, float] | None,
) -> None:
    """An uninitialised driver reports the fingertip at (0, 0, 0): at an initial target there, no approach
    direction exists; without a target, an approach from a pose that is not yet one would run 0.5 m
    along its axis. The loop waits (zero command) and starts on the next real pose."""
    loop = TouchLoop(TouchConfig(tip_radius_m=0.0), ControllerConfig(), initial_target_m=initial_target_m)
    step = loop.step(0, np.zeros(3), R_DOWN, *NONE)
    assert not loop.started and not step.linear_m_s.any() and not step.failed and step.touch is None
    step = loop.step(TICK_NS, np.array([0.0, 0.0, 0.02]), R_DOWN, *NONE)
    assert loop.started
    np.testing.assert_allclose(step.linear_m_s / np.linalg.norm(step.linear_m_s), [0.0, 0.0, -1.0])


def test_a_fingertip_driven_that_does_not_move_and_touches_nothing_is_blocked() -> None:
    """An outside clock-source driver whose contacts were all refused (sent in millimetres): its fingertip
    stood against the object, the controller pushed until the launch's duration (600 s) and the run ended
    with exit 0. Blocked for BLOCKED_S, the run fails, naming why."""
    from palpate.nodes.controller.core import BLOCKED_S

    loop = TouchLoop(TouchConfig(), ControllerConfig(), initial_target_m=np.zeros(3))
    start = np.array([0.0, 0.0, 0.05])
    moving = start.copy()
    for tick in range(600):  # moving as driven: never blocked
        step = loop.step(tick * TICK_NS, moving, R_DOWN, *NONE)
        moving = moving + DT_S * step.linear_m_s
        if not step.linear_m_s.any():
            break
    assert not loop.blocked
    loop = TouchLoop(TouchConfig(), ControllerConfig(), initial_target_m=np.zeros(3))
    ticks = round(BLOCKED_S / DT_S)
    steps = [loop.step(tick * TICK_NS, start, R_DOWN, *NONE) for tick in range(ticks + 1)]  # held where it is
    assert not any(step.failed for step in steps[:-1]) and steps[-1].failed
    assert loop.blocked.startswith("controller: the fingertip has not moved for 5 s while driven at 0.05 m/s")


@pytest.mark.parametrize("fault", ["pause", "jump", "back"])
def test_a_fingertip_that_got_no_pose_for_a_while_is_not_called_blocked(fault: str) -> None:
    """An outside real-time driver that paused 6 s (or whose stamps jumped 6 s) failed the run with 'has not
    moved for 5 s ... something holds it': one step 6 s after the other said nothing of a held fingertip."""
    from palpate.nodes.controller.core import BLOCKED_S

    loop = TouchLoop(TouchConfig(), ControllerConfig(), initial_target_m=np.zeros(3))
    start = np.array([0.0, 0.0, 0.05])
    loop.step(0, start, R_DOWN, *NONE)
    after = {"pause": 6e9, "jump": 3600e9, "back": -6e9}[fault]
    steps = [loop.step(int(after) + k * TICK_NS, start, R_DOWN, *NONE) for k in range(10)]
    assert not loop.blocked and not any(step.failed for step in steps)
    # held for BLOCKED_S from there on, step by step, it still counts as blocked
    ticks = round(BLOCKED_S / DT_S)
    steps = [loop.step(int(after) + (10 + k) * TICK_NS, start, R_DOWN, *NONE) for k in range(ticks + 1)]
    assert steps[-1].failed and loop.blocked
