"""SimSession against a fake simulation (no MuJoCo): the tick schedule, scripted-motion targets, joint
commands in the simulator's order, and the pose's finite-difference velocity."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from palpate.errors import InputError
from palpate.nodes.sim.session import SimSession, SimTick

JOINTS = ["mcp_abd", "mcp_flex", "pip", "dip"]


class FakeSim:
    """Moves the fingertip along x at 0.5 m/s of simulated time (quadratically in y); records calls."""

    def __init__(self, timestep_s: float = 0.002) -> None:
        self.joint_names = list(JOINTS)
        self.timestep_s = timestep_s
        self.steps = 0
        self.calls: list[tuple[str, object]] = []

    @property
    def time_s(self) -> float:
        return self.steps * self.timestep_s

    def set_joint_targets(self, q_rad: np.ndarray) -> None:
        self.calls.append(("targets", np.array(q_rad)))

    def step(self, n: int = 1) -> None:
        self.steps += n
        self.calls.append(("step", n))

    def effector_pose(self) -> tuple[np.ndarray, np.ndarray]:
        t = self.time_s
        return np.array([0.5 * t, t * t, 0.1]), np.array([1.0, 0.0, 0.0, 0.0])


class FakeMotion:
    def __init__(self) -> None:
        self.asked: list[float] = []

    def targets(self, time_s: float) -> np.ndarray:
        self.asked.append(time_s)
        return np.full(4, time_s)


def _session(sim: FakeSim, motion: FakeMotion | None = None, **timing: float) -> SimSession:
    args = {"tick_period_s": 0.01, "duration_s": 0.05, "timestep_s": sim.timestep_s, **timing}
    return SimSession(sim, motion=motion, **args)


def _run(session: SimSession) -> list[SimTick]:
    states = []
    while (state := session.step()) is not None:
        states.append(state)
    return states


def test_ticks_start_unstepped_then_step_a_tick_each_until_the_duration() -> None:
    sim = FakeSim()
    session = _session(sim)
    assert (session.steps_per_tick, session.period_ns, session.ticks) == (5, 10_000_000, 5)
    states = _run(session)
    assert [s.tick for s in states] == [0, 1, 2, 3, 4, 5]  # 0 .. duration / period, inclusive
    assert [s.stamp_ns for s in states] == [k * 10_000_000 for k in range(6)]
    assert [s.first for s in states] == [True] + [False] * 5  # the object goes out once, at tick 0
    assert sim.calls == [("step", 5)] * 5  # tick 0 reports the start state; no targets without a motion
    assert sim.time_s == pytest.approx(0.05)
    assert session.step() is None  # and stays over


@pytest.mark.parametrize(
    ("timing", "expected"),
    [
        ({"tick_period_s": 0.006, "duration_s": 0.03}, (3, 6_000_000, 5)),
        ({"tick_period_s": 0.01, "duration_s": 0.034}, (5, 10_000_000, 3)),  # rounded to whole ticks
        ({"tick_period_s": 0.002, "duration_s": 1.0}, (1, 2_000_000, 500)),
        # quotients a hair below a whole number (0.009 / 0.0002 = 44.99999999999999, 0.3 / 0.1 =
        # 2.9999999999999996) are rounded, not truncated
        ({"tick_period_s": 0.009, "timestep_s": 0.0002, "duration_s": 0.09}, (45, 9_000_000, 10)),
        ({"tick_period_s": 0.1, "duration_s": 0.3}, (50, 100_000_000, 3)),
    ],
)
def test_schedule_follows_the_period_and_the_duration(timing: dict[str, float], expected: tuple[int, int, int]) -> None:
    session = _session(FakeSim(), **timing)
    assert (session.steps_per_tick, session.period_ns, session.ticks) == expected
    assert len(_run(session)) == expected[2] + 1


def test_scripted_motion_sets_targets_at_the_current_time_before_each_step() -> None:
    sim, motion = FakeSim(), FakeMotion()
    _run(_session(sim, motion, duration_s=0.03))
    assert motion.asked == pytest.approx([0.0, 0.01, 0.02])  # before the steps of ticks 1, 2, 3
    kinds = [kind for kind, _ in sim.calls]
    assert kinds == ["targets", "step"] * 3
    np.testing.assert_array_equal(sim.calls[2][1], np.full(4, motion.asked[1]))


def test_pose_velocity_is_the_finite_difference_over_a_tick() -> None:
    states = _run(_session(FakeSim()))
    np.testing.assert_array_equal(states[0].linear_velocity_m_s, np.zeros(3))
    for before, after in itertools.pairwise(states):
        expected = (after.position_m - before.position_m) / 0.01
        np.testing.assert_allclose(after.linear_velocity_m_s, expected, rtol=0, atol=1e-12)
        t = (after.tick - 0.5) * 0.01  # the central value of d(t^2)/dt over the tick
        np.testing.assert_allclose(after.linear_velocity_m_s, [0.5, 2 * t, 0.0], rtol=0, atol=1e-12)
    assert all(np.array_equal(s.angular_velocity_rad_s, np.zeros(3)) for s in states)
    np.testing.assert_array_equal(states[-1].quaternion_wxyz, [1.0, 0.0, 0.0, 0.0])


def test_joint_command_is_put_in_the_simulator_order() -> None:
    sim = FakeSim()
    session = _session(sim)
    q = session.joint_command(["extra", "dip", "pip", "mcp_flex", "mcp_abd"], [9.0, 0.4, 0.3, 0.2, 0.1])
    np.testing.assert_array_equal(q, [0.1, 0.2, 0.3, 0.4])
    [(kind, sent)] = sim.calls
    assert kind == "targets"
    np.testing.assert_array_equal(sent, [0.1, 0.2, 0.3, 0.4])


def test_joint_command_lacking_a_joint_is_refused_and_sets_nothing() -> None:
    sim = FakeSim()
    session = _session(sim)
    with pytest.raises(InputError, match=r"names: lacks 2 of the"):
        session.joint_command(["mcp_flex", "pip"], [0.0, 0.0])
    assert sim.calls == []
