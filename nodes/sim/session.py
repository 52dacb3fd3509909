"""The simulator node's decisions, between the Simulation and its messages (pure: no MuJoCo here).

- Ticks: tick k stands at k x tick_period_s. Tick 0 reports the start state without stepping (and is
  when the object goes out); every later tick first advances tick_period_s / timestep_s physics
  steps. The run ends after tick round(duration_s / tick_period_s), so it covers duration_s.
- Scripted motion (hand and finger scenes that follow the built-in exploration): before each tick's
  steps the joint targets become the motion's targets at the current simulated time.
- Joint commands name their joints: the values are put in the simulator's joint order; a command
  that lacks one of the simulator's joints is refused (InputError) and changes nothing.
- The fingertip pose's linear velocity is the finite difference of its position over one tick
  (zero at tick 0); its angular velocity is reported as zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.inputs import select_named
from palpate.messages import codec

FloatArray = NDArray[np.float64]


class Simulated(Protocol):
    """What the session drives: a Simulation (nodes/sim/core.py), or a fake in tests."""

    joint_names: list[str]

    @property
    def time_s(self) -> float: ...

    def set_joint_targets(self, q_rad: np.ndarray) -> None: ...

    def step(self, n: int = 1) -> None: ...

    def effector_pose(self) -> tuple[np.ndarray, np.ndarray]: ...


class Motion(Protocol):
    """A scripted motion: joint targets (J,) in radians at a simulated time (ExplorationMotion)."""

    def targets(self, time_s: float) -> np.ndarray: ...


@dataclass(frozen=True)
class SimTick:
    """One tick's state, for the node to publish."""

    tick: int
    stamp_ns: int
    #: Tick 0: the object (ground truth) goes out with the start state.
    first: bool
    #: Fingertip position (3,) m and orientation (4,) wxyz in the world.
    position_m: np.ndarray
    quaternion_wxyz: np.ndarray
    #: Finite-difference linear velocity (3,) m/s over the last tick, and the angular velocity (3,) rad/s.
    linear_velocity_m_s: np.ndarray
    angular_velocity_rad_s: np.ndarray


#: A zero velocity (3,), read-only over a bytes object (so the message codec passes it on without a copy).
_AT_REST = codec.frozen(np.zeros(3))


class SimSession:
    """Steps a simulation tick by tick (see the module docstring for the rules)."""

    def __init__(
        self,
        sim: Simulated,
        *,
        tick_period_s: float,
        duration_s: float,
        timestep_s: float,
        motion: Motion | None = None,
    ) -> None:
        self.sim = sim
        self.motion = motion
        self.tick_period_s = tick_period_s
        self.steps_per_tick = round(tick_period_s / timestep_s)
        self.period_ns = round(tick_period_s * 1e9)
        #: The last tick; the run has ticks 0 .. ticks.
        self.ticks = round(duration_s / tick_period_s)
        self.tick = 0
        self._previous_position: np.ndarray | None = None

    def joint_command(self, names: Sequence[str], positions_rad: ArrayLike) -> FloatArray:
        """Set the joint targets from a command (names and positions in the command's order); returns
        them in the simulator's joint order."""
        q = select_named(names, positions_rad, self.sim.joint_names, "names")
        self.sim.set_joint_targets(q)
        return q

    def step(self) -> SimTick | None:
        """Advance to the next tick and report its state; None once the run is over."""
        if self.tick > self.ticks:
            return None
        first = self.tick == 0
        if not first:
            if self.motion is not None:
                self.sim.set_joint_targets(self.motion.targets(self.sim.time_s))
            self.sim.step(self.steps_per_tick)
        position, quaternion = self.sim.effector_pose()
        linear = angular = _AT_REST
        if self._previous_position is not None:
            linear = (position - self._previous_position) / self.tick_period_s  # v = dx / dt
        self._previous_position = position
        state = SimTick(
            tick=self.tick,
            stamp_ns=self.tick * self.period_ns,
            first=first,
            position_m=position,
            quaternion_wxyz=quaternion,
            linear_velocity_m_s=linear,
            angular_velocity_rad_s=angular,
        )
        self.tick += 1
        return state
