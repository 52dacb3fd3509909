"""Planner node: picks the next best touch on the estimated surface after every contact."""

from __future__ import annotations

from typing import Any

import numpy as np

from palpate.errors import PlanningError
from palpate.messages.schemas import Pose, SurfaceMesh, TouchEvent, TouchTarget
from palpate.nodes.controller.so3 import quat_to_matrix
from palpate.nodes.planner.core import Planner, PlannerConfig
from palpate.runtime.spec import NodeSpec, Port


class PlannerNode:
    """Thin wrapper around Planner: plans once per contact, when the surface that includes it arrives."""

    def __init__(self, config: PlannerConfig, ctx: Any):
        self.ctx = ctx
        self.core = Planner(config)
        self.contacts: list[np.ndarray] = []
        self.approach = np.zeros(3)
        self.pose: Pose | None = None
        self.planned_for = 0

    def on_touches(self, message: TouchEvent) -> None:
        self.contacts.append(np.array(message.position_m))
        self.approach = np.array(message.approach_direction)

    def on_pose(self, message: Pose) -> None:
        self.pose = message

    def on_surface(self, message: SurfaceMesh) -> None:
        if (
            message.region != "local"
            or message.num_contacts != len(self.contacts)
            or self.planned_for == len(self.contacts)
        ):
            return
        self.planned_for = len(self.contacts)
        if self.pose is None:
            raise PlanningError("no fingertip pose received yet; the simulation or driver must publish one")
        last = self.contacts[-1]
        candidates = self.core.sample(message.vertices_m, message.vertex_normals, message.vertex_variance, last)
        axis = quat_to_matrix(self.pose.quaternion_wxyz)[:, 2]
        # Psi2 measures the curve the controller will run: it starts at the last contact (c_p).
        choice = self.core.select(
            candidates.points_m,
            candidates.normals,
            candidates.variance,
            np.array(self.contacts),
            last,
            self.approach,
            axis,
            self.ctx.rng,
        )
        self.ctx.publish(
            "target",
            TouchTarget(
                stamp_ns=self.ctx.stamp_ns,
                strategy=self.core.config.strategy,
                position_m=choice.target_m,
                normal=choice.normal,
                predicted_contact_m=choice.predicted_contact_m,
                score=choice.score,
                candidates_m=candidates.points_m,
                candidate_scores=choice.scores,
            ),
        )

    def on_tick(self, stamp_ns: int) -> None:
        """Planning happens when a surface arrives; nothing to do per tick."""


SPEC = NodeSpec(
    name="planner",
    config=PlannerConfig,
    factory=PlannerNode,
    inputs={"touches": Port(TouchEvent), "surface": Port(SurfaceMesh), "pose": Port(Pose)},
    outputs={"target": Port(TouchTarget)},
    doc="Next best touch of paper 002: IGEF, GP variance (gpv) or random.",
)
