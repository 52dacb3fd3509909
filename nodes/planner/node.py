"""Planner node: picks the next best touch on the estimated surface after every contact."""

from __future__ import annotations

from typing import Any

import numpy as np

from palpate.errors import PlanningError
from palpate.geometry.rotations import quat_to_matrix
from palpate.messages.schemas import Pose, SurfaceMesh, TouchEvent, TouchTarget
from palpate.nodes.planner.core import Candidates, Planner, PlannerConfig, Selection, away_from, curves_clear
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
        self.unreached: list[np.ndarray] = []  # targets whose touch landed elsewhere

    def on_touches(self, message: TouchEvent) -> None:
        position, predicted = np.array(message.position_m), np.array(message.predicted_contact_m)
        self.contacts.append(position)
        self.approach = np.array(message.approach_direction)
        if np.all(np.isfinite(predicted)) and np.linalg.norm(position - predicted) > self.core.config.unreached_miss_m:
            self.unreached.append(predicted)

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
        cfg = self.core.config
        contacts = np.array(self.contacts)
        admissible = None
        centres = candidates.points_m + cfg.tip_radius_m * candidates.normals  # fingertip centre at each target
        if len(candidates.points_m):
            hop = centres - self.pose.position_m
            admissible = np.einsum("ij,ij->i", hop, hop) >= cfg.min_hop_m**2
            admissible &= away_from(candidates.points_m, np.reshape(self.unreached, (-1, 3)), cfg.unreached_radius_m)
            if cfg.check_curves and cfg.strategy == "random":  # a uniform choice needs the whole mask
                admissible &= self._clear(message, centres, candidates.normals, np.arange(len(centres)))
            if not admissible.any():  # nothing admissible: plan as the paper does
                self.ctx.count("no_admissible_candidate")
                admissible = None
        # Psi2 measures the curve the controller will run: it starts at the last contact (c_p).
        args = (candidates.points_m, candidates.normals, candidates.variance, contacts, last, self.approach, axis)
        choice = self.core.select(*args, self.ctx.rng, admissible=admissible)
        if cfg.check_curves and cfg.strategy != "random" and admissible is not None:
            choice = self._best_clear(choice, message, candidates, centres, admissible)
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

    def _clear(self, surface: SurfaceMesh, centres: np.ndarray, normals: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """curves_clear for the candidate rows ``rows``: boolean (len(rows),)."""
        assert self.pose is not None
        cfg = self.core.config
        return curves_clear(
            surface.vertices_m,
            surface.vertex_normals,
            self.pose.position_m,
            self.approach,
            centres[rows],
            normals[rows],
            cfg.tip_radius_m - cfg.curve_margin_m,
            samples=cfg.curve_samples,
        )

    def _best_clear(
        self, choice: Selection, surface: SurfaceMesh, candidates: Candidates, centres: np.ndarray, mask: np.ndarray
    ) -> Selection:
        """The best-scored candidate whose curve is clear, i.e. the argmax of the scores over the
        admissible candidates with clear curves: curves are checked in descending score order, 32 at a
        time, so usually only the first few are computed."""
        scores = choice.scores.copy()
        rel = candidates.points_m - self.contacts[-1]
        order = np.flatnonzero(mask & (np.einsum("ij,ij->i", rel, rel) <= self.core.config.radius_m**2))
        order = order[np.argsort(-scores[order], kind="stable")]
        for start in range(0, len(order), 32):
            rows = order[start : start + 32]
            clear = self._clear(surface, centres, candidates.normals, rows)
            scores[rows[~clear]] = 0.0
            if clear.any():
                index = int(rows[int(np.argmax(clear))])
                break
        else:  # no curve is clear: keep the paper's choice
            self.ctx.count("no_clear_curve")
            return choice
        point = candidates.points_m[index].copy()
        return Selection(
            index=index,
            target_m=point,
            normal=candidates.normals[index] / np.linalg.norm(candidates.normals[index]),
            predicted_contact_m=point.copy(),
            score=float(scores[index]),
            scores=scores,
            psi=choice.psi,
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
