"""The GPIS node's decisions, between its messages and the surface estimator (pure, no transport).

- A touch joins the estimator and gives the local mesh around it. With ``grow_kernel``, an estimator
  whose thin-plate range R_m cannot hold the touch's local mesh and the whole-object mesh after it is
  rebuilt with R_m doubled (up to ``kernel_radius_cap_m``), and kept only once the touch was usable; a
  touch it cannot take leaves the estimator as it was (InputError).
- A whole-object request meshes every contact. With ``free_space``, the fingertip centres swept
  without a contact hold f >= the fingertip radius for that mesh only (``enforce``), and are dropped
  after it. With ``whole_prior: hull`` its prior is the contacts' smoothed convex hull, for that mesh
  only.
- With ``free_space``, each contact message without a contact marks the fingertip's last centre as
  swept.
"""

from __future__ import annotations

from collections import Counter
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from numpy.typing import ArrayLike

from palpate.config import NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.errors import ConfigError, EstimationError
from palpate.inputs import coordinates
from palpate.nodes.gpis.core import GPISConfig, SurfaceEstimator
from palpate.nodes.gpis.free_space import SweptSpace, enforce, within_box
from palpate.nodes.gpis.hull_prior import SmoothHull
from palpate.nodes.gpis.local import make_estimator
from palpate.nodes.gpis.reach import holding, touch_reach
from palpate.nodes.gpis.surface import (
    MAX_GRID_NODES,
    SurfaceMeshArrays,
    add_touch,
    axis_nodes,
    whole_box,
    whole_resolution,
    whole_surface,
)


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
    #: Cell size of the whole-object mesh published on request; coarser where its grid would exceed
    #: MAX_GRID_NODES (50 million nodes: an object over about 1 m across at 3 mm), said once and counted
    #: as ``whole_mesh_coarsened``.
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
    #: vertex_variance "candidates": one vertex per voxel of this edge carries the variance, metres; a launch
    #: whose planner rates by the variance refuses a step other than the planner's candidate_step_m.
    variance_step_m: PositiveFloat = 0.005
    #: vertex_variance "candidates": only vertices within this distance of the touch carry it, metres (the
    #: planner's gpv_radius_m).
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
    #: Not in the paper: the prior mean of the whole-object mesh. "same": the GP's own (gp.prior);
    #: "hull": the contacts' convex hull, smoothed (``hull_prior.SmoothHull``: the log-sum-exp of its
    #: support planes in whole_prior_directions even directions, blended over whole_prior_tau_m), so
    #: that the unexplored parts are extrapolated from the shape the contacts span. The local meshes
    #: (the planner's) keep the GP's own, so no path changes. Where the hull is no solid (under four
    #: contacts, or thinner than 2 tau in some direction) or the estimator is local, the mesh keeps
    #: the GP's own prior (counter ``whole_prior_kept``). Exact estimator only. docs/exploration.md,
    #: "The whole estimate's prior".
    whole_prior: Literal["same", "hull"] = "same"
    #: Blending length tau of the hull's planes, metres.
    whole_prior_tau_m: PositiveFloat = 0.006
    #: Directions of the hull's support planes: the prior's cost per query point, and how closely it
    #: follows the hull (256: about 13 degrees apart).
    whole_prior_directions: Annotated[int, Range(ge=4)] = 256

    def __post_init__(self) -> None:
        super().__post_init__()
        half, step = self.local_half_extent_m, self.local_resolution_m
        if step > half / 2.0:  # fewer than 4 cells across the box: no surface a planner can use
            raise ConfigError(
                f"local_resolution_m = {step!r} leaves fewer than 4 cells across the local box (2 x "
                f"local_half_extent_m = {2.0 * half!r} m), too coarse to mesh a surface there; give at most "
                f"{half / 2.0:g} m (the default is 0.005 m)",
                ("local_resolution_m",),
            )
        if 2.0 * half / step > MAX_GRID_NODES or axis_nodes(2.0 * half, step) ** 3 > MAX_GRID_NODES:
            raise ConfigError(
                f"local_resolution_m = {step!r} over a local_half_extent_m = {half!r} box makes a "
                f"local grid of more than {MAX_GRID_NODES} nodes, which no touch could mesh; coarsen it "
                f"(the default is 0.005 m)"
            )


class GPISSession:
    """The estimator of a GPIS node and what it does with touches, poses, contacts and requests.

    Events for the node's counters pile up until ``take_counts``: ``local_mesh_refined`` (the surface
    at a touch was thinner than the grid: its mesh was made on a finer one), ``kernel_grown``,
    ``kernel_not_grown`` (the contacts did not factor with the larger range), ``free_space_points``,
    ``free_space_refused`` (the covariance would not factor with more: the mesh has those added),
    ``whole_mesh_coarsened`` (a whole-object mesh at global_resolution_m would exceed MAX_GRID_NODES: made at
    the coarser ``whole_resolution_m``),
    ``whole_prior_kept`` (a whole-object mesh asked for the hull prior kept the GP's own, see
    GPISNodeConfig.whole_prior), ``free_space_not_applied`` (asked for, but the estimator, the local
    experts, takes no free space).
    """

    def __init__(self, config: GPISNodeConfig) -> None:
        self.config = config
        self._counts: Counter[str] = Counter()
        self.gp: SurfaceEstimator = make_estimator(config.gp, prior_centre_m=config.prior_centre_m)
        self.swept = SweptSpace(config.free_space_voxel_m)
        self.fingertip_m: np.ndarray | None = None  # the fingertip centre at the last pose
        self.whole_resolution_m = config.global_resolution_m  # the step of the last whole-object mesh

    def pose(self, position_m: ArrayLike) -> None:
        """The fingertip centre now (kept for ``no_contact``)."""
        self.fingertip_m = np.array(coordinates(position_m, "position_m"))

    def no_contact(self) -> None:
        """A contact message without a contact: the fingertip's last centre is swept free."""
        if self.fingertip_m is not None:
            self.swept.add(self.fingertip_m)

    def take_counts(self) -> dict[str, int]:
        """The events since the last call (see the class)."""
        counts, self._counts = dict(self._counts), Counter()
        return counts

    def touch(self, position_m: ArrayLike, normal: ArrayLike) -> SurfaceMeshArrays:
        """Add one touch and mesh the surface around it (InputError, nothing changed, for a touch the
        estimator cannot take)."""
        cfg = self.config
        gp = self._holding(position_m)
        touched = add_touch(
            gp,
            position_m,
            normal,
            cfg.local_half_extent_m,
            cfg.local_resolution_m,
            with_variance=cfg.vertex_variance != "none",
            variance_near=None if cfg.vertex_variance == "all" else (cfg.variance_step_m, cfg.variance_radius_m),
        )
        if touched.resolution_m < cfg.local_resolution_m:  # the surface at the touch is thinner than the grid
            self._counts["local_mesh_refined"] += 1
        if gp is not self.gp:  # grown, and the touch was usable: keep it
            self.gp = gp
            self._counts["kernel_grown"] += 1
        return touched.mesh

    def whole(self, variance: bool) -> SurfaceMeshArrays:
        """The whole-object mesh of every contact, with the GP variance at every vertex if asked."""
        cfg = self.config
        with self._whole_prior():
            try:
                if cfg.free_space:
                    self._enforce_free_space()
                step = whole_resolution(self.gp, cfg.global_margin_m, cfg.global_resolution_m)
                self.whole_resolution_m = step
                if step > cfg.global_resolution_m:
                    self._counts["whole_mesh_coarsened"] += 1
                return whole_surface(self.gp, cfg.global_margin_m, step, with_variance=variance)
            finally:
                self.gp.drop_free_space()  # the active set is this mesh's own (see GPISNodeConfig.free_space)

    def _whole_prior(self) -> AbstractContextManager[None]:
        """The whole-object mesh's prior (see GPISNodeConfig.whole_prior), for the duration of the mesh."""
        cfg, gp = self.config, self.gp
        if cfg.whole_prior == "same" or gp.n_contacts == 0:
            return nullcontext()
        hull = None
        if gp.supports_replaced_prior:
            hull = SmoothHull.of(gp.positions_m, cfg.whole_prior_tau_m, cfg.whole_prior_directions)
        if hull is None:
            self._counts["whole_prior_kept"] += 1
            return nullcontext()
        return gp.replaced_prior(hull)

    def _enforce_free_space(self) -> None:
        """f >= fingertip radius at the swept centres in the whole-object box (see GPISNodeConfig)."""
        cfg = self.config
        gp = self.gp
        if not gp.supports_free_space:  # the local experts take none (said once by the node)
            self._counts["free_space_not_applied"] += 1
            return
        if not len(self.swept) or not gp.n_contacts:
            return
        lower, upper = whole_box(gp.positions_m, cfg.global_margin_m)
        centres = self.swept.points_m()
        centres = centres[within_box(centres, lower, upper)]
        radius, spacing, tolerance = cfg.fingertip_radius_m, cfg.free_space_spacing_m, cfg.free_space_tolerance_m
        added, refused = enforce(gp, centres, radius, spacing, cfg.free_space_rounds, tolerance)
        if len(added):
            self._counts["free_space_points"] += len(added)
        if refused:  # the covariance would not factor with more: the mesh has what was added
            self._counts["free_space_refused"] += 1

    def _holding(self, position_m: ArrayLike) -> SurfaceEstimator:
        """With grow_kernel, the GP grown to hold this touch's local mesh and the whole-object mesh after
        it (see ``reach.touch_reach``), not yet kept: the touch may still be refused; else the GP."""
        cfg = self.config
        if not cfg.grow_kernel:
            return self.gp
        e = cfg.local_half_extent_m + cfg.local_resolution_m  # the local grid's half extent, at most
        reach = touch_reach(self.gp, position_m, e, cfg.global_margin_m + cfg.global_resolution_m)
        try:
            return holding(self.gp, reach, cfg.kernel_radius_cap_m)
        except EstimationError:  # the contacts do not factor with that R_m: the GP as it was refuses
            self._counts["kernel_not_grown"] += 1
            return self.gp
