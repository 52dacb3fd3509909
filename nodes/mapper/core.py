"""The mapper's pure core: occupancy-grid mapping at a known pose, or FastSLAM.

``Mapper(config, chain, rng)`` takes joint readings and contacts and keeps the map(s):

- mode ``known``: one grid updated at the given joint angles, no particle filter. Fed the true
  angles it is the paper's known-pose mapping; fed the noisy angles it is dead reckoning, the
  baseline FastSLAM must beat.
- mode ``fastslam``: K particles with their own grids (fastslam.py).

Both modes share one observation code path (observation.py, grid.py), so FastSLAM with sigma = 0
produces the known-pose map bit for bit.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from numpy.typing import NDArray

from palpate.config import (
    Fraction,
    NonNegative,
    NonNegativeFloat,
    Positive,
    PositiveFloat,
    PositiveInt,
    Range,
    Validated,
)
from palpate.errors import ConfigError, EstimationError
from palpate.nodes.mapper.fastslam import FastSlam
from palpate.nodes.mapper.grid import L_FREE, L_OCC, GridSpec, LogOddsGrids, SparseMap
from palpate.nodes.mapper.kinematics import KinematicChain
from palpate.nodes.mapper.observation import capsule_grid, capsule_lattice, observation_keys

FloatArray = NDArray[np.float64]


#: Free margins measured on the Rubik's cube scene's grid (region from -45 mm, cube faces 0.5 mm inside
#: their cells), by cell edge, millimetres: the least depth at which the free update clears no cube cell
#: at the true pose, and at 1 mm cells also none the finger's press reaches (docs/slam.md, item 2).
MEASURED_FREE_MARGIN_MM = {1.0: 1.5, 2.0: 0.5, 4.0: 2.5}


def measured_free_margin_m(resolution_m: float) -> float | None:
    """The measured free margin for cells of ``resolution_m`` (MEASURED_FREE_MARGIN_MM), metres; for cells
    finer than the finest measured, that one's margin (the finger's press into the surface, a fraction of a
    millimetre, does not shrink with the cells: at 0.5 mm one cell cleared most contact cells, rmse 0.137
    against 0.049 with 1.5 mm); None for another cell size."""
    mm = round(resolution_m * 1e3, 9)
    finest = min(MEASURED_FREE_MARGIN_MM)
    margin = MEASURED_FREE_MARGIN_MM[finest] if mm < finest else MEASURED_FREE_MARGIN_MM.get(mm)
    return None if margin is None else margin * 1e-3


#: Fewest cells across the region's smallest side a map may have (one cell was a resolution in millimetres).
MIN_CELLS_PER_SIDE = 2


@dataclass(frozen=True, kw_only=True)
class MapperConfig(Validated):
    """Mapper parameters; the defaults are the paper's (000_*.txt) where it gives one.

    region_min_m, region_max_m: corners of the mapped box (the object's workspace plus a margin).
    l_occ, l_free: log-odds increments log(0.9/0.1), log(0.1/0.9) (paper III).
    l_min, l_max: clamp of the log-odds, so cells can change their mind (belief 4.5e-5 .. 1-4.5e-5).
    sigma_deg: joint-noise standard deviation of the proposal (paper: 1.5 deg).
    per_joint_sigma_deg: joint name -> its own standard deviation (the others keep sigma_deg), as the
      noise node's; for joint sensors whose noise differs (a glove's abduction sensor, say).
    resample_threshold: resample when N_eff < threshold * K.
    likelihood_floor: smallest probability one cell may give a particle (see fastslam.py); 0.01
      mapped the synthetic tapping scene (tests/unit/mapper/synthetic.py) better than 0.05 or 0.2
      and as well as 0.001.
    free_weight: weight of free-volume cells against contact cells in the particle weights.
    free_reward: let free-volume cells in known free space raise a particle's weight (False: free
      cells only penalise overlap with occupied cells, which maps the Rubik's cube scene better;
      see fastslam.observation_log_likelihood and docs/slam.md).
    free_spacing_m, free_margin_m: lattice spacing and depth of the finger's free-volume samples
      (None: the grid resolution; see observation.py); free_margin_m "auto" (the default): the margin
      measured for the resolution on the Rubik's cube scene's grid (MEASURED_FREE_MARGIN_MM; 1.5 mm for
      cells finer than 1 mm), else the resolution; "cell": a point clears its cell only when the whole
      cell lies in the finger (observation.whole_cells), whatever the grid's alignment with the object:
      for another object or region (the measured margins hold for that grid only).
    chunk_edge: cells per chunk edge of the sparse storage (a power of two).
    """

    region_min_m: tuple[float, float, float]
    region_max_m: tuple[float, float, float]
    #: Edge of a grid cell, metres.
    resolution_m: PositiveFloat = 0.002
    #: "known": one map updated at the joint angles read (the true ones: known-pose mapping; noisy ones:
    #: dead reckoning); "fastslam": n_particles finger-pose hypotheses, each with its own map.
    mode: Literal["known", "fastslam"] = "fastslam"
    #: K, the number of FastSLAM particles (mode fastslam only).
    n_particles: PositiveInt = 100
    sigma_deg: NonNegativeFloat = 1.5
    per_joint_sigma_deg: Mapping[str, NonNegativeFloat] = field(default_factory=dict)
    resample_threshold: Annotated[float, Fraction] = 0.5
    l_occ: PositiveFloat = L_OCC
    l_free: Annotated[float, Range(lt=0.0)] = L_FREE
    l_min: float = -10.0
    l_max: float = 10.0
    likelihood_floor: Annotated[float, Range(gt=0.0, lt=0.5)] = 0.01
    free_weight: NonNegativeFloat = 1.0
    free_reward: bool = True
    free_spacing_m: Annotated[float | None, Positive] = None
    free_margin_m: Annotated[float | Literal["auto", "cell"] | None, NonNegative] = "auto"
    chunk_edge: PositiveInt = 8

    def __post_init__(self) -> None:
        super().__post_init__()
        GridSpec.from_bounds(self.region_min_m, self.region_max_m, self.resolution_m)  # validates
        side_m = min(hi - lo for lo, hi in zip(self.region_min_m, self.region_max_m, strict=True))
        if side_m / self.resolution_m < MIN_CELLS_PER_SIDE:  # a map of one cell: a resolution in millimetres?
            raise ConfigError(
                f"resolution_m {self.resolution_m:g} leaves fewer than {MIN_CELLS_PER_SIDE} cells across the region's "
                f"smallest side ({side_m:g} m): a map of nothing; give a finer resolution, in metres (2 mm is 0.002)",
                ("resolution_m",),
            )
        if self.chunk_edge & (self.chunk_edge - 1):
            raise ConfigError(f"chunk_edge must be a power of two, got {self.chunk_edge!r}", ("chunk_edge",))
        if not self.l_min < 0.0:
            raise ConfigError(f"l_min must be < 0 (a clamp below the prior), got {self.l_min!r}", ("l_min",))
        if not self.l_max > 0.0:
            raise ConfigError(f"l_max must be > 0 (a clamp above the prior), got {self.l_max!r}", ("l_max",))

    @property
    def n_maps(self) -> int:
        """Maps the mapper keeps: one in known mode, one per particle in fastslam mode."""
        return 1 if self.mode == "known" else self.n_particles

    def free_lattice(self) -> tuple[float, float]:
        """Spacing and margin of the finger's free-volume lattice, metres (each the resolution when None)."""
        res = self.resolution_m
        return (
            self.free_spacing_m if self.free_spacing_m is not None else res,
            self._free_margin(),
        )

    @property
    def whole_cells(self) -> bool:
        """Whether a free-volume point clears its cell only when the whole cell lies in the finger
        (``free_margin_m: cell``)."""
        return self.free_margin_m == "cell"

    def _free_margin(self) -> float:
        if self.free_margin_m == "cell":  # no point shallower than half a cell diagonal clears its cell
            return 0.5 * math.sqrt(3.0) * self.resolution_m
        if self.free_margin_m == "auto":
            measured = measured_free_margin_m(self.resolution_m)
            return self.resolution_m if measured is None else measured
        return self.resolution_m if self.free_margin_m is None else self.free_margin_m


#: Bytes a particle's update takes per free-volume point (its cell keys and scores, a few arrays of it).
BYTES_PER_POINT_AND_PARTICLE = 12


def lattice_points(chain: KinematicChain, spacing_m: float, margin_m: float) -> int:
    """At least as many points as ``capsule_lattice`` lays in the chain's capsules (those of the box around
    each capsule), counted without building them."""
    total = 0
    for cap in chain.capsule_list:
        grid = capsule_grid(cap.radius_m, float(np.linalg.norm(cap.b_local_m - cap.a_local_m)), spacing_m, margin_m)
        if grid is not None:
            _, nr, nz = grid
            total += (2 * nr + 1) ** 2 * (2 * nz + 1)
    return total


def check_fits(config: MapperConfig, chain: KinematicChain) -> None:
    """``check_memory`` for a mapper of this config and chain, without building it (a sweep checks every
    setting before it records anything), and that ``per_joint_sigma_deg`` names joints of the chain."""
    unknown = sorted(set(config.per_joint_sigma_deg) - set(chain.joint_names))
    if unknown:
        raise ConfigError(
            f"per_joint_sigma_deg names joint(s) {unknown} that the mapper's finger lacks; its joints: "
            f"{list(chain.joint_names)}",
            ("per_joint_sigma_deg",),
        )
    spec = GridSpec.from_bounds(config.region_min_m, config.region_max_m, config.resolution_m)
    n_maps = config.n_maps
    check_memory(config, spec, n_maps, lattice_points(chain, *config.free_lattice()))


def check_memory(config: MapperConfig, spec: GridSpec, n_maps: int, points: int) -> None:
    """ConfigError naming the settings when the maps' index table or one update's arrays would not fit in
    this machine's memory (numpy's allocation error came from deep in the mapper, at start or mid-run)."""
    chunks = math.prod(-(-n // config.chunk_edge) for n in spec.shape) + 1
    edge = config.chunk_edge
    need = {
        f"the maps' chunk table ({chunks:,} chunks of {edge}^3 cells a map)": 4 * n_maps * chunks,
        f"one update's free-volume arrays ({points:,} free-volume points a pose)": BYTES_PER_POINT_AND_PARTICLE
        * n_maps
        * points,
    }
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return
    maps = "one map needs" if n_maps == 1 else f"n_particles = {n_maps} maps need"
    for what, size in need.items():
        if size > have:
            raise ConfigError(
                f"{maps} {size / 2**30:.3g} GiB at resolution_m = {config.resolution_m!r} for {what}, more "
                f"than this machine's {have / 2**30:.3g} GiB; use "
                + ("fewer particles or " if n_maps > 1 else "")
                + "a coarser resolution (or free_spacing_m / free_margin_m)",
                ("n_particles",) if n_maps > 1 else ("resolution_m",),
            )


@dataclass
class MapperCounters:
    """Running counts since the mapper started."""

    updates: int = 0
    contacts: int = 0
    free_points_outside: int = 0
    contacts_outside: int = 0
    #: Contacts outside the region where the reading itself puts them (contacts_outside counts every
    #: particle's placement: under large joint noise some particles place a contact well inside the
    #: region outside it).
    contacts_outside_measured: int = 0
    resamples: int = 0
    update_seconds_total: float = 0.0
    last_update_ms: float = math.nan

    @property
    def mean_update_ms(self) -> float:
        """Mean wall-clock milliseconds per accepted update."""
        return 1e3 * self.update_seconds_total / self.updates if self.updates else math.nan


@dataclass(frozen=True)
class PoseEstimate:
    """Joint angles (J,) rad: the weighted mean over particles and the best particle's."""

    mean_q_rad: FloatArray
    best_q_rad: FloatArray


class Mapper:
    """Occupancy-grid mapper; see the module docstring for the modes."""

    def __init__(self, config: MapperConfig, chain: KinematicChain, rng: np.random.Generator) -> None:
        self.config = config
        self.chain = chain
        check_fits(config, chain)  # before anything is allocated
        self.spec = GridSpec.from_bounds(config.region_min_m, config.region_max_m, config.resolution_m)
        n_maps = config.n_maps
        spacing, margin = config.free_lattice()
        self.grids = LogOddsGrids(
            self.spec, n_maps, chunk_edge=config.chunk_edge, l_min=config.l_min, l_max=config.l_max
        )
        self.free_volume = capsule_lattice(chain, spacing, margin)
        self._free_h = self.free_volume.homogeneous()
        self._free_depth = self.free_volume.depth_cells(config.resolution_m) if config.whole_cells else ()
        self._no_free_h = tuple(np.zeros((4, 0), dtype=np.float32) for _ in self._free_h)
        self.counters = MapperCounters()
        self._q = np.zeros(chain.n_joints)
        self._filter: FastSlam | None = None
        if config.mode == "fastslam":
            self._filter = FastSlam(
                chain=chain,
                grids=self.grids,
                free_volume=self.free_volume,
                sigma_rad=np.radians([config.per_joint_sigma_deg.get(n, config.sigma_deg) for n in chain.joint_names]),
                rng=rng,
                resample_threshold=config.resample_threshold,
                likelihood_floor=config.likelihood_floor,
                free_weight=config.free_weight,
                free_reward=config.free_reward,
                l_occ=config.l_occ,
                l_free=config.l_free,
                free_depth_cells=self._free_depth,
            )

    def update(self, q_rad: FloatArray, contact_links: NDArray[np.integer], contact_local_m: FloatArray) -> None:
        """Integrate one joint reading q_rad (J,) and contacts: link indices (n,), positions (n, 3)
        in those links' frames (metres).

        Raises EstimationError (state unchanged) on a wrong shape, a non-finite value or a link
        index outside the chain. The node's handlers refuse such messages before they reach here
        (MapperSession, palpate.inputs), so in a node this is a last guard that ends the process.
        """
        t0 = time.perf_counter()
        q = np.asarray(q_rad, dtype=np.float64)
        links = np.asarray(contact_links)
        local = np.asarray(contact_local_m, dtype=np.float64)
        if local.size == 0:
            local = local.reshape(0, 3)
        J = self.chain.n_joints
        if q.shape != (J,):
            raise EstimationError(f"joint reading has shape {q.shape}, the chain has {J} joints")
        if links.ndim != 1 or local.ndim != 2 or local.shape[1] != 3:
            raise EstimationError(
                f"contacts need links (n,) and positions (n, 3); got shapes {links.shape} and {local.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise EstimationError(f"joint reading is not finite: {q.tolist()}; update rejected")
        if len(links) != len(local):
            raise EstimationError(f"{len(links)} contact links but {len(local)} contact positions")
        if len(links) and not np.issubdtype(links.dtype, np.integer):
            raise EstimationError(f"contact links must be link indices (integers), got dtype {links.dtype}")
        if len(links) and (links.min() < 0 or links.max() >= self.chain.n_links):
            raise EstimationError(f"contact links {links.tolist()} outside 0..{self.chain.n_links - 1}")
        if not np.all(np.isfinite(local)):
            raise EstimationError("contact positions are not finite; update rejected")
        c = self.counters
        if self._filter is None:
            rots, pos = self.chain.forward(q[None, :])
            free, occ = observation_keys(self.grids, rots, pos, self._free_h, links, local, self._free_depth)
            self.grids.observe(free, occ, l_free=self.config.l_free, l_occ=self.config.l_occ, count=False)
            out_f, out_c = free.n_outside, occ.n_outside
            c.contacts_outside_measured += out_c
        else:
            stats = self._filter.update(q, links, local)
            out_f, out_c = stats.free_points_outside, stats.contacts_outside
            c.resamples += int(stats.resampled)
            if len(links):
                rots, pos = self.chain.forward(q[None, :])
                _, occ = observation_keys(self.grids, rots, pos, self._no_free_h, links, local)
                c.contacts_outside_measured += occ.n_outside
        self._q = q
        c.updates += 1
        c.contacts += len(links)
        c.free_points_outside += out_f
        c.contacts_outside += out_c
        dt = time.perf_counter() - t0
        c.update_seconds_total += dt
        c.last_update_ms = 1e3 * dt

    # --- outputs ---------------------------------------------------------------------------------
    def best_map(self) -> SparseMap:
        """The map of the highest-weight particle (known mode: the one map)."""
        return self.grids.to_sparse(0) if self._filter is None else self._filter.best_map()

    def weighted_map(self) -> SparseMap:
        """Per cell, the log-odds of the weight-averaged belief (known mode: the one map)."""
        return self.grids.to_sparse(0) if self._filter is None else self._filter.weighted_map()

    def pose_estimate(self) -> PoseEstimate:
        """Weighted-mean and best-particle joint angles (known mode: the last reading)."""
        if self._filter is None:
            return PoseEstimate(mean_q_rad=self._q.copy(), best_q_rad=self._q.copy())
        return PoseEstimate(mean_q_rad=self._filter.mean_q(), best_q_rad=self._filter.best_q())

    @property
    def n_eff(self) -> float:
        """Effective sample size 1 / sum w^2 at the last update (known mode: 1)."""
        return 1.0 if self._filter is None else self._filter.n_eff

    @property
    def filter(self) -> FastSlam | None:
        """The particle filter (None in known mode), for diagnostics."""
        return self._filter
