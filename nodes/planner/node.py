"""Planner node: picks the next best touch on the estimated surface after every contact."""

from __future__ import annotations

from typing import Any

import numpy as np

from palpate.errors import PlanningError
from palpate.inputs import coordinates, unit_quaternion, unit_vectors
from palpate.messages.schemas import Pose, SurfaceMesh, TouchEvent, TouchTarget
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import TouchPlanner
from palpate.runtime.spec import Context, NodeSpec, Port


class PlannerNode:
    """Thin wrapper around TouchPlanner: plans once per contact, when the surface that includes it arrives."""

    def __init__(self, config: PlannerConfig, ctx: Context):
        self.ctx = ctx
        self.core = TouchPlanner(config)
        self.fingertip: tuple[np.ndarray, np.ndarray] | None = None  # centre (3,) m, quaternion wxyz (4,)
        self._unmatched_said = False

    def on_touches(self, message: TouchEvent) -> None:
        # unit, as the GPIS node requires: a touch one of them takes and the other refuses would leave the
        # planner waiting for ever for a surface that counts it
        normal = unit_vectors(message.normal, "normal")
        self.core.add_touch(message.position_m, message.predicted_contact_m, message.approach_direction, normal)

    def on_pose(self, message: Pose) -> None:
        position = coordinates(message.position_m, "position_m")
        self.fingertip = (position, unit_quaternion(message.quaternion_wxyz, "quaternion_wxyz"))

    def on_surface(self, message: SurfaceMesh) -> None:
        try:
            plan = self.core.plan(
                message.region,
                message.num_contacts,
                message.vertices_m,
                message.vertex_normals,
                message.vertex_variance,
                self.fingertip,
                self.ctx.rng,
                variance_vertices=message.variance_vertices,
            )
        except PlanningError as exc:
            # the contact is planned for and no other surface will come for it: without a target the
            # fingertip would wait for ever, so the run ends here with the reason (an InputError, a
            # surface refused before anything changed, still propagates as a rejected input)
            self.ctx.count("planning_failed")
            self.ctx.request_stop(f"planner: {exc}", failed=True)
            return
        if plan is None:
            if self.core.unmatched is not None and not self._unmatched_said:
                self._unmatched_said = True
                made_of, touches = self.core.unmatched
                self.ctx.log.warning(
                    "planner: a local surface of %d contacts (SurfaceMesh.num_contacts) came after %d touch(es): "
                    "it plans on the local surface made of every touch so far, one per touch (counted as "
                    "surface_not_matching)",
                    made_of,
                    touches,
                )
            return
        choice = plan.selection
        self.ctx.publish(
            "target",
            TouchTarget(
                stamp_ns=self.ctx.stamp_ns,
                strategy=self.core.config.strategy,
                position_m=choice.target_m,
                normal=choice.normal,
                predicted_contact_m=choice.predicted_contact_m,
                score=choice.score,
                candidates_m=plan.candidates.points_m,
                candidate_scores=choice.scores,
                slide=choice.slide,
                miss_distance_m=self.core.config.target_miss_distance_m,
            ),
        )

    def on_tick(self, stamp_ns: int) -> None:
        """Planning happens when a surface arrives; per tick the planner's events go to the node's counters."""
        for name, n in self.core.take_counts().items():
            self.ctx.count(name, n)


def _facts(config: PlannerConfig) -> dict[str, tuple[Any, tuple[str, ...]]]:
    """A strategy that rates by the variance needs it from the GPIS node of the same graph (its
    ``vertex_variance``), at its candidates' spacing (the GPIS node's ``variance_step_m``)."""
    if not config.uses_variance:
        return {}
    weight = {"area": "area_variance_weight", "tour": "tour_variance_weight"}.get(config.strategy, "strategy")
    return {
        "surface:candidate_variance": ("given", (weight,)),
        "surface:candidate_step_m": (config.candidate_step_m, ("candidate_step_m",)),
    }


SPEC = NodeSpec(
    name="planner",
    config=PlannerConfig,
    factory=PlannerNode,
    inputs={"touches": Port(TouchEvent), "surface": Port(SurfaceMesh), "pose": Port(Pose)},
    outputs={"target": Port(TouchTarget)},
    facts=_facts,
    doc="Next best touch of paper 002: IGEF, GP variance (gpv), random, or ours: area, tour.",
)
