"""GPIS node: adds each touch to the implicit surface and publishes the surface mesh around it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from palpate.config import KeyPath
from palpate.errors import InputError
from palpate.messages.schemas import ContactSet, Pose, SurfaceMesh, SurfaceRequest, TouchEvent
from palpate.nodes.gpis import surface
from palpate.nodes.gpis.session import GPISNodeConfig, GPISSession
from palpate.nodes.gpis.surface import SurfaceMeshArrays
from palpate.runtime.spec import Context, NodeSpec, Port


class GPISNode:
    """Thin wrapper around GPISSession: one update and one local mesh per touch."""

    def __init__(self, config: GPISNodeConfig, ctx: Context):
        self.ctx = ctx
        self.session = GPISSession(config)
        self._coarsened_said = False
        self._options_said: set[str] = set()  # whole-mesh options the estimator dropped, said once each

    def on_pose(self, message: Pose) -> None:
        self.session.pose(message.position_m)

    def on_contacts(self, message: ContactSet) -> None:
        if len(message.forces_n) == 0:
            self.session.no_contact()

    def on_touches(self, message: TouchEvent) -> None:
        try:
            mesh = self.session.touch(message.position_m, message.normal)
        finally:  # a refused touch may have tried to grow the kernel
            self._count()
        self._publish(mesh, "local")

    def on_request(self, message: SurfaceRequest) -> None:
        if message.region != "global":
            raise InputError("region", f"{message.region!r} is no region a request can name; use 'global'")
        try:
            mesh = self.session.whole(message.variance)
        finally:
            counts = self._count()
        gp = self.session.gp
        dropped = (
            ("whole_prior: hull", "whole_prior_kept", gp.supports_replaced_prior),
            ("free_space", "free_space_not_applied", gp.supports_free_space),
        )
        for option, key, supported in dropped:
            if counts.get(key) and not supported and option not in self._options_said:
                self._options_said.add(option)
                self.ctx.log.warning(
                    "gpis: %s is not applied to this whole-object mesh: the estimator is now the local experts "
                    "(past gp.auto_local_above_contacts = %d contacts), which take only their own prior and no "
                    "free space (counted as %s)",
                    option,
                    self.session.config.gp.auto_local_above_contacts,
                    key,
                )
        if counts.get("whole_mesh_coarsened") and not self._coarsened_said:
            self._coarsened_said = True
            self.ctx.log.warning(
                "gpis: the whole-object mesh at global_resolution_m = %g m would exceed %d grid nodes: made at %.3g "
                "m (and so on, counted as whole_mesh_coarsened)",
                self.session.config.global_resolution_m,
                surface.MAX_GRID_NODES,
                self.session.whole_resolution_m,
            )
        self._publish(mesh, "global")

    def _count(self) -> dict[str, int]:
        counts = self.session.take_counts()
        for name, n in counts.items():
            self.ctx.count(name, n)
        if "kernel_grown" in counts:
            self.ctx.metrics["kernel_R_m"] = self.session.gp.config.R_m
        return counts

    def on_tick(self, stamp_ns: int) -> None:
        """The surface changes only with touches."""

    def _publish(self, mesh: SurfaceMeshArrays, region: str) -> None:
        n_contacts = self.session.gp.n_contacts
        self.ctx.metrics["contacts"] = float(n_contacts)
        self.ctx.publish(
            "surface",
            SurfaceMesh(
                stamp_ns=self.ctx.stamp_ns,
                region=region,
                num_contacts=n_contacts,
                vertices_m=mesh.vertices,
                faces=mesh.faces,
                vertex_normals=mesh.vertex_normals,
                variance_vertices=mesh.variance_vertices,
                vertex_variance=mesh.vertex_variance,
            ),
        )


def _ports(config: GPISNodeConfig) -> tuple[dict[str, Port], dict[str, Port]]:
    inputs = {"touches": Port(TouchEvent), "request": Port(SurfaceRequest, optional=True)}
    if config.free_space:
        inputs |= {"pose": Port(Pose), "contacts": Port(ContactSet)}
    return inputs, {"surface": Port(SurfaceMesh)}


def _facts(config: GPISNodeConfig) -> dict[str, tuple[Any, tuple[str, ...]]]:
    """Whether the local mesh carries the GP variance, and at which spacing of candidates: a planner that
    rates by it states that it needs it (palpate.launch checks that both say the same)."""
    facts: dict[str, tuple[Any, tuple[str, ...]]] = {
        "surface:candidate_variance": (
            "given" if config.vertex_variance != "none" else "not given",
            ("vertex_variance",),
        )
    }
    if config.vertex_variance in ("candidates", "auto"):
        facts["surface:candidate_step_m"] = (config.variance_step_m, ("variance_step_m",))
    return facts


def _settle(config: GPISNodeConfig, stated: Callable[[str], list[Any]]) -> dict[KeyPath, Any]:
    """``vertex_variance: auto``: "candidates" when a planner reading the surface rates by the variance
    (it states that it needs it, see the planner's facts), else "none"."""
    if config.vertex_variance != "auto":
        return {}
    needed = "given" in stated("surface:candidate_variance")
    return {("vertex_variance",): "candidates" if needed else "none"}


SPEC = NodeSpec(
    name="gpis",
    config=GPISNodeConfig,
    factory=GPISNode,
    ports_from_config=_ports,
    facts=_facts,
    settle=_settle,
    doc="Gaussian process implicit surface of paper 002: local mesh per touch, whole mesh on request.",
)
