"""GPIS node: adds each touch to the implicit surface and publishes the surface mesh around it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import numpy as np

from palpate.config import KeyPath, NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.errors import ConfigError, EstimationError, InputError
from palpate.inputs import coordinates
from palpate.messages.schemas import ContactSet, Pose, SurfaceMesh, SurfaceRequest, TouchEvent
from palpate.nodes.gpis.core import GPISConfig, SurfaceEstimator
from palpate.nodes.gpis.free_space import SweptSpace, enforce, within_box
from palpate.nodes.gpis.local import make_estimator
from palpate.nodes.gpis.reach import holding, touch_reach
from palpate.nodes.gpis.surface import (
    MAX_GRID_NODES,
    SurfaceMeshArrays,
    add_touch,
    axis_nodes,
    whole_box,
    whole_surface,
)
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class GPISNodeConfig(Validated):
    """GPIS parameters and the meshes the node publishes."""

    gp: GPISConfig = field(default_factory=GPISConfig)
    #: Centre of the prior sphere (Algorithm 1's initial target, inside the object); null: from the first touch.
    prior_centre_m: tuple[float, float, float] | None = None
    #: Half edge of the box meshed around the latest contact; at least the planner's candidate radius.
    local_half_extent_m: PositiveFloat = 0.06
    #: Marching-cubes cell size of the local mesh (5 mm gives candidates 2-5 mm apart).
    local_resolution_m: PositiveFloat = 0.005
    #: Cell size of the whole-object mesh published on request.
    global_resolution_m: PositiveFloat = 0.003
    #: Margin around the contacts' bounding box for the whole-object mesh.
    global_margin_m: NonNegativeFloat = 0.03
    #: Where the local mesh carries the GP variance (Eq. 6): "candidates", only at the vertices GP-V
    #: rates (one per variance_step_m voxel within variance_radius_m of the touch, the planner's
    #: candidate_step_m and gpv_radius_m); "all" vertices; "none" (IGEF and the others need none and
    #: run ~2-4x faster); "auto": the launcher makes it "candidates" when a planner reading the surface
    #: rates by the variance, else "none" (a node started without a launcher takes "candidates"). The
    #: whole-object mesh carries it at every vertex when its request asks for it.
    vertex_variance: Literal["auto", "candidates", "all", "none"] = "candidates"
    variance_step_m: PositiveFloat = 0.005
    variance_radius_m: PositiveFloat = 0.06
    #: An object larger than the thin-plate kernel's R_m allows (gp.R_m, 0.5 m: about 0.4 m across):
    #: rebuild the GP with R_m doubled (``reach.holding``; counter ``kernel_grown``, status metric
    #: ``kernel_R_m``), up to kernel_radius_cap_m, instead of refusing the touch. False refuses it, as an input error.
    grow_kernel: bool = True
    #: Largest R_m growing may reach, metres (objects up to about 6 m across); beyond it the fit degrades
    #: (the relative jitter, a fraction of R_m^3, outweighs the value noise) and touches are refused.
    kernel_radius_cap_m: PositiveFloat = 8.0
    #: Not in the paper: the whole-object mesh keeps the free space the fingertip swept, f >=
    #: fingertip_radius_m at every centre it passed without a contact (``free_space``; the node then
    #: reads the fingertip pose and the contacts every tick). For each whole-object mesh, the swept
    #: centres in its box where the mean breaks it get f = fingertip_radius_m, one per
    #: free_space_spacing_m voxel, for up to free_space_rounds rounds, and lose it after the mesh. The
    #: local meshes (the planner's) do not. Exact estimator only (the local one takes none).
    #: docs/exploration.md, "Free space as an inequality".
    free_space: bool = False
    #: The fingertip's radius, metres (the controller's tip_radius_m).
    fingertip_radius_m: PositiveFloat = 0.008
    #: Swept centres are kept one per voxel of this edge.
    free_space_voxel_m: PositiveFloat = 0.002
    #: Each round observes at most one swept centre (the most broken) per voxel of this edge.
    free_space_spacing_m: PositiveFloat = 0.004
    #: Rounds of the active set per whole-object mesh (each observation moves the mean elsewhere too).
    free_space_rounds: Annotated[int, Range(ge=1)] = 6
    #: A centre counts as breaking f >= r only below r - this.
    free_space_tolerance_m: NonNegativeFloat = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        half, step = self.local_half_extent_m, self.local_resolution_m
        if 2.0 * half / step > MAX_GRID_NODES or axis_nodes(2.0 * half, step) ** 3 > MAX_GRID_NODES:
            raise ConfigError(
                f"local_resolution_m = {step!r} over a local_half_extent_m = {half!r} box makes a "
                f"local grid of more than {MAX_GRID_NODES} nodes, which no touch could mesh; coarsen it "
                f"(the default is 0.005 m)"
            )


class GPISNode:
    """Thin wrapper around GPIS: one update and one local mesh per touch."""

    def __init__(self, config: GPISNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.gp: SurfaceEstimator = make_estimator(config.gp, prior_centre_m=config.prior_centre_m)
        self.swept = SweptSpace(config.free_space_voxel_m)
        self.fingertip_m: np.ndarray | None = None  # the fingertip centre at the last pose

    def on_pose(self, message: Pose) -> None:
        self.fingertip_m = np.array(coordinates(message.position_m, "position_m"))

    def on_contacts(self, message: ContactSet) -> None:
        if len(message.forces_n) == 0 and self.fingertip_m is not None:
            self.swept.add(self.fingertip_m)

    def on_touches(self, message: TouchEvent) -> None:
        cfg = self.config
        gp = self._holding(message)
        touched = add_touch(
            gp,
            message.position_m,
            message.normal,
            cfg.local_half_extent_m,
            cfg.local_resolution_m,
            with_variance=cfg.vertex_variance != "none",
            variance_near=None if cfg.vertex_variance == "all" else (cfg.variance_step_m, cfg.variance_radius_m),
        )
        if touched.resolution_m < cfg.local_resolution_m:  # the surface at the touch is thinner than the grid
            self.ctx.count("local_mesh_refined")
        if gp is not self.gp:  # grown, and the touch was usable: keep it
            self.gp = gp
            self.ctx.count("kernel_grown")
            self.ctx.metrics["kernel_R_m"] = gp.config.R_m
        self._publish(touched.mesh, "local")

    def on_request(self, message: SurfaceRequest) -> None:
        if message.region != "global":
            raise InputError("region", f"{message.region!r} is no region a request can name; use 'global'")
        cfg = self.config
        try:
            if cfg.free_space:
                self._enforce_free_space()
            mesh = whole_surface(self.gp, cfg.global_margin_m, cfg.global_resolution_m, with_variance=message.variance)
        finally:
            self.gp.drop_free_space()  # the active set is this mesh's own (see GPISNodeConfig.free_space)
        self._publish(mesh, "global")

    def _enforce_free_space(self) -> None:
        """f >= fingertip radius at the swept centres in the whole-object box (see GPISNodeConfig)."""
        cfg = self.config
        gp = self.gp
        if not len(self.swept) or not gp.n_contacts or not gp.supports_free_space:
            return
        lower, upper = whole_box(gp.positions_m, cfg.global_margin_m)
        centres = self.swept.points_m()
        centres = centres[within_box(centres, lower, upper)]
        radius, spacing, tolerance = cfg.fingertip_radius_m, cfg.free_space_spacing_m, cfg.free_space_tolerance_m
        added, refused = enforce(gp, centres, radius, spacing, cfg.free_space_rounds, tolerance)
        if len(added):
            self.ctx.count("free_space_points", len(added))
        if refused:  # the covariance would not factor with more: the mesh has what was added
            self.ctx.count("free_space_refused")

    def _holding(self, message: TouchEvent) -> SurfaceEstimator:
        """With grow_kernel, the GP grown to hold this touch's local mesh and the whole-object mesh after
        it (see ``reach.touch_reach``), not yet kept: the touch may still be refused; else the GP."""
        cfg = self.config
        if not cfg.grow_kernel:
            return self.gp
        e = cfg.local_half_extent_m + cfg.local_resolution_m  # the local grid's half extent, at most
        reach = touch_reach(self.gp, message.position_m, e, cfg.global_margin_m + cfg.global_resolution_m)
        try:
            return holding(self.gp, reach, cfg.kernel_radius_cap_m)
        except EstimationError:  # the contacts do not factor with that R_m: the GP as it was refuses
            self.ctx.count("kernel_not_grown")
            return self.gp

    def _publish(self, mesh: SurfaceMeshArrays, region: str) -> None:
        self.ctx.metrics["contacts"] = float(self.gp.n_contacts)
        self.ctx.publish(
            "surface",
            SurfaceMesh(
                stamp_ns=self.ctx.stamp_ns,
                region=region,
                num_contacts=self.gp.n_contacts,
                vertices_m=mesh.vertices,
                faces=mesh.faces,
                vertex_normals=mesh.vertex_normals,
                variance_vertices=mesh.variance_vertices,
                vertex_variance=mesh.vertex_variance,
            ),
        )

    def on_tick(self, stamp_ns: int) -> None:
        """The surface changes only with touches."""


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
