"""TrajectoryController driven by a fake kinematic fingertip integrated here (no MuJoCo)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from palpate.errors import ConfigError, PlanningError
from palpate.geometry import rotations
from palpate.geometry.bezier import bezier_length, bezier_point
from palpate.nodes.controller.trajectory import ControllerConfig, ControllerState, TrajectoryController

Inside = Callable[[np.ndarray], bool]
DT_S = 1e-3


@dataclass
class Run:
    r: np.ndarray
    R: np.ndarray
    trail: list[np.ndarray] = field(default_factory=list)
    states: list[ControllerState] = field(default_factory=list)
    contact_state: ControllerState | None = None


def drive(
    ctrl: TrajectoryController,
    r: np.ndarray,
    R: np.ndarray,
    inside: Inside,
    *,
    max_steps: int = 10_000,
    arm_after_m: float = 1e-3,
) -> Run:
    """Integrate r += v dt, R = exp(w dt) R until contact (``inside``), IDLE or FAILED.

    Contact detection is armed once the fingertip has moved ``arm_after_m`` (it starts on the surface).
    """
    run = Run(r=r.copy(), R=R.copy(), trail=[r.copy()])
    moved = 0.0
    for _ in range(max_steps):
        v, w = ctrl.command(run.r, run.R)
        run.states.append(ctrl.state)
        if ctrl.state in (ControllerState.IDLE, ControllerState.FAILED):
            break
        run.r = run.r + v * DT_S
        run.R = rotations.exp_so3(w * DT_S) @ run.R
        moved += float(np.linalg.norm(v)) * DT_S
        run.trail.append(run.r.copy())
        if moved > arm_after_m and inside(run.r):
            run.contact_state = ctrl.state
            ctrl.on_contact(run.r, run.R)  # the last step still belongs to this motion
            break
    return run


def below_plane(p: np.ndarray) -> bool:
    return bool(p[2] <= 0.0)


def box_with_edge_at_1cm(p: np.ndarray) -> bool:
    """Object filling x < 0.01 m, z < 0: its top face ends at an edge x = 0.01 m."""
    return bool(p[0] < 0.01 and p[2] <= 0.0)


def nothing(p: np.ndarray) -> bool:
    return False


R_DOWN = rotations.get_rotation(np.eye(3), np.array([0.0, 0.0, 1.0]))  # poking down onto a z-up surface
V_DOWN = np.array([0.0, 0.0, -1.0])


def test_reaches_a_target_on_a_plane_along_the_curve() -> None:
    ctrl = TrajectoryController()
    t_p = np.array([0.03, 0.01, 0.0])
    t_n = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    P = ctrl.start(np.zeros(3), V_DOWN, R_DOWN, t_p, t_n)
    run = drive(ctrl, np.zeros(3), R_DOWN, below_plane)
    assert run.contact_state is ControllerState.APPROACH
    assert ctrl.state is ControllerState.IDLE
    assert np.linalg.norm(run.r - t_p) < 1e-3
    # The trail follows the curve: every position within 0.2 mm of the curve.
    curve = bezier_point(P, np.linspace(0, 1, 5001))
    gaps = np.min(np.linalg.norm(np.array(run.trail)[:, None] - curve[None], axis=2), axis=1)
    assert gaps.max() < 2e-4
    # Travelled distance = arc length of the curve (up to one step at the end).
    assert ctrl.travelled_m == pytest.approx(float(bezier_length(P)), abs=2 * ctrl.config.v0_m_s * DT_S)
    assert ctrl.initial_travelled_m == 0.0
    # The fingertip faces the target normal at contact, and turned by the minimal angle.
    angle = np.degrees(np.arccos(np.clip(run.R[:, 2] @ -t_n, -1, 1)))
    assert angle < 1.0
    expected_turn = np.degrees(np.arccos(np.clip(R_DOWN[:, 2] @ -t_n, -1, 1)))
    assert ctrl.rotation_deg == pytest.approx(expected_turn, abs=1.0)


def test_missed_prediction_starts_the_recovery_curve() -> None:
    cfg = ControllerConfig()
    ctrl = TrajectoryController(cfg)
    t_p = np.array([0.03, 0.0, 0.0])  # predicted surface beyond the real edge at x = 0.01
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, t_p, np.array([0.0, 0.0, 1.0]))
    run = drive(ctrl, np.zeros(3), R_DOWN, box_with_edge_at_1cm)
    assert ctrl.recoveries == 1
    assert run.contact_state is ControllerState.RECOVERY
    # The switch happened once the fingertip was Delta_m past T(1).
    switch = run.states.index(ControllerState.RECOVERY)
    at_switch = run.trail[switch]
    assert np.linalg.norm(at_switch - t_p) == pytest.approx(cfg.miss_distance_m, abs=2 * cfg.v0_m_s * DT_S)
    # The recovery curve ends at the last contact, so it re-touches the object: here its side face.
    np.testing.assert_allclose(ctrl.target[0], np.zeros(3))
    assert run.r[0] == pytest.approx(0.01, abs=1e-4)
    assert run.r[2] < 0.0


@pytest.mark.parametrize("return_after_recovery", [True, False])
def test_fails_when_even_the_recovery_finds_nothing(return_after_recovery: bool) -> None:
    ctrl = TrajectoryController(ControllerConfig(return_after_recovery=return_after_recovery))
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    run = drive(ctrl, np.zeros(3), R_DOWN, nothing)
    assert ctrl.state is ControllerState.FAILED
    assert ctrl.recoveries == 1
    assert ctrl.straight_returns == int(return_after_recovery)  # the straight return, if any, found nothing either
    v, w = ctrl.command(run.r, run.R)
    assert not v.any() and not w.any()


def test_a_missed_recovery_goes_straight_back_to_the_last_contact() -> None:
    """A recovery that passes the last contact by (as one sliding off a cup's rim) is followed by a
    straight line to that contact, which touches there. Here the surface is a 1 mm spot at the last
    contact that only the return can touch: a stand-in for the rim the recovery curve slid past."""
    ctrl = TrajectoryController()
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    run = drive(ctrl, np.zeros(3), R_DOWN, lambda p: ctrl.straight_returns > 0 and bool(np.linalg.norm(p) < 1e-3))
    assert (ctrl.recoveries, ctrl.straight_returns) == (1, 1)
    assert run.contact_state is ControllerState.DIRECT and ctrl.state is ControllerState.IDLE
    assert np.linalg.norm(run.r) < 1e-3
    back = np.array(run.trail[run.states.index(ControllerState.DIRECT) :])
    chord = back[-1] - back[0]
    off_line = np.linalg.norm(np.cross(back - back[0], chord / np.linalg.norm(chord)), axis=1)
    assert off_line.max() < 1e-9  # a straight line
    assert ctrl.initial_travelled_m == 0.0  # exploratory travel, not the initial approach


def test_initial_approach_is_a_straight_line() -> None:
    ctrl = TrajectoryController()
    start = np.array([0.02, -0.01, 0.05])
    target = np.array([0.0, 0.0, -0.01])  # inside the object below z = 0
    ctrl.initial_approach(start, target)
    v, w = ctrl.command(start, R_DOWN)
    np.testing.assert_allclose(v, ctrl.config.v0_m_s * (target - start) / np.linalg.norm(target - start))
    assert not w.any()
    run = drive(ctrl, start, R_DOWN, below_plane, arm_after_m=0.0)
    assert run.contact_state is ControllerState.DIRECT
    # Contact where the segment crosses z = 0, within one step.
    hit = start + (target - start) * (start[2] / (start[2] - target[2]))
    assert np.linalg.norm(run.r - hit) < 2 * ctrl.config.v0_m_s * DT_S
    assert ctrl.initial_travelled_m == pytest.approx(np.linalg.norm(hit - start), abs=1e-4)
    assert ctrl.travelled_m == 0.0


def test_initial_approach_fails_past_the_target() -> None:
    ctrl = TrajectoryController()
    ctrl.initial_approach(np.array([0.0, 0.0, 0.02]), np.zeros(3))
    drive(ctrl, np.array([0.0, 0.0, 0.02]), R_DOWN, nothing, arm_after_m=0.0)
    assert ctrl.state is ControllerState.FAILED


def test_stopped_after_contact() -> None:
    ctrl = TrajectoryController()
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.02, 0, 0]), np.array([0, 0, 1.0]))
    ctrl.on_contact()
    v, w = ctrl.command(np.zeros(3), R_DOWN)
    assert ctrl.state is ControllerState.IDLE and not v.any() and not w.any()


def test_odometry_integrates_poses() -> None:
    ctrl = TrajectoryController()
    ctrl.on_contact()  # exploring: counts into travelled_m / rotation_deg
    for k in range(91):  # 1 mm steps along x while turning 1 degree per step about z
        ctrl.observe(np.array([0.001 * k, 0.0, 0.0]), rotations.exp_so3(np.radians(k) * np.array([0, 0, 1.0])))
    assert ctrl.travelled_m == pytest.approx(0.090, abs=1e-12)
    assert ctrl.rotation_deg == pytest.approx(90.0, abs=1e-9)


def test_target_at_the_start_point_still_moves() -> None:
    ctrl = TrajectoryController()
    P = ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert float(bezier_length(P)) > 0.0
    v, _ = ctrl.command(np.zeros(3), R_DOWN)
    assert np.all(np.isfinite(v)) and np.linalg.norm(v) == pytest.approx(ctrl.config.v0_m_s)
    run = drive(ctrl, np.zeros(3), R_DOWN, below_plane, arm_after_m=1e-5)
    assert run.contact_state is ControllerState.APPROACH
    assert np.linalg.norm(run.r) < 1e-3


def test_rejects_bad_inputs() -> None:
    ctrl = TrajectoryController()
    with pytest.raises(PlanningError, match="zero length"):
        ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.02, 0, 0]), np.zeros(3))
    with pytest.raises(PlanningError, match="rotation"):
        ctrl.start(np.zeros(3), V_DOWN, 2 * np.eye(3), np.array([0.02, 0, 0]), np.array([0, 0, 1.0]))
    with pytest.raises(PlanningError, match="finite"):
        ctrl.start(np.array([np.nan, 0, 0]), V_DOWN, R_DOWN, np.array([0.02, 0, 0]), np.array([0, 0, 1.0]))
    with pytest.raises(ConfigError, match="v0_m_s"):
        ControllerConfig(v0_m_s=0.0)


def test_retract_direction_keeps_v_n_into_the_surface_and_lifts_off_after_sliding() -> None:
    from palpate.nodes.controller.core import retract_direction

    normal = np.array([0.0, 0.0, 2.0])  # outward, not unit
    into = np.array([0.0, 0.6, -0.8])  # 37 degrees from the inward normal
    np.testing.assert_allclose(retract_direction(into, normal, 0.5), into, atol=0)
    sliding = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(retract_direction(sliding, normal, 0.5), [0.0, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(retract_direction(sliding, normal, -1.0), sliding, atol=0)  # Eq. 15 as written
    np.testing.assert_allclose(retract_direction(sliding, np.full(3, np.nan), 0.5), sliding, atol=0)


def floor_2cm_down(p: np.ndarray) -> bool:
    """The true surface 2 cm below the one the target was planned on (a false floor in the estimate)."""
    return bool(p[2] <= -0.02)


@pytest.mark.parametrize(("miss_distance_m", "recovers"), [(0.0, True), (0.03, False)])
def test_a_target_may_ask_for_a_longer_reach_past_it_before_the_recovery(
    miss_distance_m: float, recovers: bool
) -> None:
    """A target on a false floor 2 cm above the true one: with the controller's own Delta_m (1 cm) the
    fingertip gives up and recovers; with 3 cm asked by the target it goes on and touches the true floor."""
    ctrl = TrajectoryController()
    t_p = np.array([0.03, 0.0, 0.0])
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, t_p, np.array([0.0, 0.0, 1.0]), miss_distance_m=miss_distance_m)
    run = drive(ctrl, np.zeros(3), R_DOWN, floor_2cm_down)
    assert ctrl.recoveries == int(recovers)
    if not recovers:
        assert run.contact_state is ControllerState.APPROACH
        np.testing.assert_allclose(run.r, [0.03, 0.0, -0.02], atol=1e-3)  # straight on below the target
    # the next target, without a Delta_m of its own, has the controller's: it recovers 1 cm past it
    target = run.r + np.array([0.03, 0.0, 0.02])
    ctrl.start(run.r, V_DOWN, R_DOWN, target, np.array([0.0, 0.0, 1.0]))
    again = drive(ctrl, run.r, R_DOWN, nothing)
    switch = again.trail[again.states.index(ControllerState.RECOVERY)]
    assert np.linalg.norm(switch - target) == pytest.approx(ControllerConfig().miss_distance_m, abs=1e-4)


def test_a_straight_move_has_its_own_delta_m_and_none_left_from_an_earlier_target() -> None:
    """The straight move back after a slide that lost the surface takes the slide target's Delta_m; one
    asked without a Delta_m has the config's, whatever the target before asked for."""
    for asked, expected in ((0.03, 0.03), (0.0, ControllerConfig().miss_distance_m)):
        ctrl = TrajectoryController()
        ctrl.start(
            np.zeros(3), V_DOWN, R_DOWN, np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), miss_distance_m=0.03
        )
        target = np.array([0.0, 0.0, -0.02])
        ctrl.go_straight(np.zeros(3), target, asked)
        run = drive(ctrl, np.zeros(3), R_DOWN, nothing)
        assert ctrl.state is ControllerState.FAILED
        assert np.linalg.norm(run.r - target) == pytest.approx(expected, abs=1e-4)
    with pytest.raises(PlanningError, match="miss_distance_m"):
        TrajectoryController().go_straight(np.zeros(3), np.ones(3), float("inf"))


def test_a_target_at_the_start_without_a_direction_ends_instead_of_stalling() -> None:
    """An outside audit: v_n = 0 ("no retraction") with the target at the start gave a curve whose
    first control points coincide, and the controller stayed at tau 0 for ever, 'travelling' between
    the start and 0.5 mm. The loop now leaves along the target's normal: in free space it ends as
    the other short curves do (the recovery, then FAILED)."""
    R0 = np.diag([1.0, -1.0, -1.0])
    for chord in (0.0, 1e-4):
        ctrl = TrajectoryController()
        ctrl.start(np.zeros(3), np.zeros(3), R0, [chord, 0.0, 0.0], [0.0, 0.0, 1.0])
        run = drive(ctrl, np.zeros(3), R0, nothing, max_steps=60_000)
        assert run.states[-1] is ControllerState.FAILED, (chord, ctrl.tau, ctrl.travelled_m)


def test_the_recovery_turns_the_fingertip_to_poke_along_the_target_normal() -> None:
    """Alg. 1 line 32: R1 <- getRotation(R0, -t_n), the inverted approach. The recovery curve (Eq. 17)
    reaches the last contact moving along +t_n (from inside the object), and the fingertip turns to
    poke that way: its z axis goes from -t_n (facing the missed target) to +t_n."""
    ctrl = TrajectoryController()
    t_n = np.array([0.0, 0.0, 1.0])
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.03, 0.0, 0.0]), t_n)
    # the only surface: a 1 mm spot at the last contact, which only the recovery reaches
    run = drive(
        ctrl, np.zeros(3), R_DOWN, lambda p: ctrl.state is ControllerState.RECOVERY and bool(np.linalg.norm(p) < 1e-3)
    )
    assert run.contact_state is ControllerState.RECOVERY
    assert ctrl.direction @ t_n > 0.9  # arriving along +t_n
    angle = np.degrees(np.arccos(np.clip(run.R[:, 2] @ t_n, -1, 1)))
    assert angle < 10.0


def test_a_curve_of_micrometres_asks_for_no_turn_faster_than_the_cap() -> None:
    """An outside audit: a target at the last contact (a local mesh of 3 nodes across) gave a curve of a few
    micrometres whose feedforward turn rate, 3,500 rad/s, the simulator refused (over 1000) for ever."""
    from palpate.nodes.controller.trajectory import MAX_ANGULAR_RAD_S

    ctrl = TrajectoryController()
    facing_up = np.array([0.0, 0.0, -1.0])  # a target whose normal turns the fingertip round
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([2e-6, 0.0, 0.0]), facing_up)
    rates = []
    r, R = np.zeros(3), R_DOWN
    for _ in range(20):
        v, w = ctrl.command(r, R)
        rates.append(float(np.linalg.norm(w)))
        r, R = r + v * DT_S, rotations.exp_so3(w * DT_S) @ R
    assert max(rates) == pytest.approx(MAX_ANGULAR_RAD_S) and MAX_ANGULAR_RAD_S < 1000.0  # the sim's limit
    ctrl.start(np.zeros(3), V_DOWN, R_DOWN, np.array([0.03, 0.0, 0.0]), facing_up)  # 3 cm: far below the cap
    assert float(np.linalg.norm(ctrl.command(np.zeros(3), R_DOWN)[1])) < 20.0
