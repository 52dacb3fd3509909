"""MuJoCo's model and data of one simulation, and the simulated time as a count of physics steps."""

from __future__ import annotations

import mujoco


class Physics:
    """The model, the data and the physics steps taken since the start: the simulation and its contact
    classes step the data, count here the steps they take and name the time in their errors."""

    __slots__ = ("data", "dt", "model", "steps")

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model = model
        self.data = data
        self.dt = float(model.opt.timestep)
        self.steps = 0

    @property
    def time_s(self) -> float:
        """Simulated time since the start, seconds."""
        return self.steps * self.dt
